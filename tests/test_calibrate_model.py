"""The full-data calibration's model is the device model: parity with the twin, Jacobians by differences."""

from __future__ import annotations

import numpy as np
import pytest

from borescan.calibrate.problem import ScanNuisance
from borescan.calibrate.residuals import normal_equations, residuals, residuals_and_jacobian
from borescan.calibrate.result import AcceptanceRule
from borescan.calibrate.starts import build_problem, fit_inputs
from borescan.effects import Effect
from borescan.geometry import Beams, Bore
from borescan.kinematics import angle_model_from_arrays
from borescan.physics.tri import TriBase, tri_forward, tri_spindle_jacobian
from borescan.physics.tri_params import dbeta_drho_at_psi, dd_b_drho_at_g, straighten, unstraighten

R_MM = 40.0
BEAMS = Beams(
    (1, 2, 3), np.array([0.05, 2.15, 4.2]), np.array([1.2, -0.8, 0.4]), np.array([35.5, 35.2, 35.8])
)
CENTER = np.array([3.0, -2.0])
TAU_S = np.array([0.0, 0.0015, -0.0007])


def _scan(direction: str, rpm: float, scale: float, phase: float, offset, seed: int):
    """Twin readings of a ring gauge with speed_error (scale - 1) and channel delays, and the fit's view."""
    t = np.linspace(0.0, 2.0 * 60.0 / rpm, 1500)
    sgn = 1.0 if direction == "ccw" else -1.0
    omega = 2.0 * np.pi * rpm / 60.0
    base = TriBase(
        beams=BEAMS,
        bore=Bore(tuple(CENTER), R_MM),
        spindle_xy_mm=CENTER + np.asarray(offset),
        turned_rad=lambda tt: omega * tt,
        phase_rad=phase,
        direction=sgn,
    )
    effects = [Effect("speed_error", {"eps": scale - 1.0})] + [
        Effect("channel_delay", {"channel": ch, "tau_s": tau})
        for ch, tau in zip(BEAMS.channels, TAU_S)
        if tau
    ]
    twin = tri_forward(base, t, effects)
    noisy = twin + np.random.default_rng(seed).normal(0.0, 1e-4, twin.shape)  # a noise floor for the problem
    return t, twin, noisy, angle_model_from_arrays(rpm_nominal=rpm, direction=direction)


def _problem(scans):
    inp = fit_inputs(
        [s[0] for s in scans],
        [s[2] for s in scans],
        BEAMS.channels,
        BEAMS,
        scan_ids=[f"scan{k}" for k in range(len(scans))],
        angle_models=[s[3] for s in scans],
        rpm=None,
        direction=None,
        phase0_rad=0.0,
        spindle_xy_mm=None,
        center_xy_mm=None,
        range_mm=None,
        channel_time_offsets_s=TAU_S,
    )
    pb, _ = build_problem(inp, BEAMS, R_MM, AcceptanceRule.defaults(), 100, 1e10)
    return pb


CASES = [("ccw", 60.0, 1.0123, 0.0, (0.9, -0.4)), ("cw", 45.0, 0.987, 0.0, (-0.3, 1.1))]


def test_the_calibration_model_is_the_twin():
    """At the true parameters the fit's readings (residual + reading) are the twin's to 1e-9 mm.

    The twin composes the registry's ``speed_error`` (eps = scale - 1) and ``channel_delay`` on the base
    geometry (:func:`borescan.physics.tri.tri_forward`); the calibration evaluates phase + scale Phi at
    t - tau_c and the gauge at the origin (o = S - C). The phase is held at 0 (no prior: the gauge).
    """
    scans = [_scan(*case, seed=k) for k, case in enumerate(CASES)]
    pb = _problem(scans)
    nuis = [ScanNuisance(np.asarray(case[4], float), case[3], case[2]) for case in CASES]
    x = pb.pack(BEAMS, nuis)
    r = residuals(pb, x)
    model = r + np.concatenate([s[2][m] for s, m in zip(scans, pb.masks)])
    twin = np.concatenate([s[1][m] for s, m in zip(scans, pb.masks)])
    assert model.size == sum(s[1].size for s in scans)  # every reading valid
    assert np.max(np.abs(model - twin)) < 1e-9


def _fd(f, x: np.ndarray, h: np.ndarray) -> np.ndarray:
    cols = []
    for i in range(x.size):
        xp, xm = x.copy(), x.copy()
        xp[i] += h[i]
        xm[i] -= h[i]
        cols.append((f(xp) - f(xm)) / (2.0 * h[i]))
    return np.column_stack(cols)


def test_the_internal_jacobian_is_the_central_difference_of_the_residuals():
    """The analytic Jacobian in (psi, rho, g, offset, speed scale) equals central differences.

    Step 1e-4 (rad, mm, -): the truncation error (~h^2 f3 / 6) was measured at 2.6e-7 of a column and
    falls as h^2 (2.6e-5 at h = 1e-3); the rounding error eps |v| / h (v ~ 5 mm) is ~1e-11 per unit,
    2e-8 of the smallest column (a rho's, 6e-4). Tolerance 2e-6 of each column's largest entry.
    """
    scans = [_scan(*case, seed=k) for k, case in enumerate(CASES)]
    pb = _problem(scans)
    nuis = [ScanNuisance(np.asarray(case[4], float), case[3], case[2]) for case in CASES]
    x = pb.pack(BEAMS, nuis)
    _, J = residuals_and_jacobian(pb, x)
    J_fd = _fd(lambda z: residuals(pb, z), x, np.full(x.size, 1e-4))
    scale = np.max(np.abs(J_fd), axis=0)
    assert np.all(scale > 0)
    assert np.max(np.abs(J - J_fd) / scale) < 2e-6


@pytest.mark.parametrize("name", ["beta", "rho", "ox", "oy", "phi"])
def test_the_spindle_jacobian_is_the_central_difference_of_the_twin(name):
    """Each column of :func:`tri_spindle_jacobian` against central differences of :func:`tri_forward`.

    The twin is evaluated with the beam, the spindle position or the device angle moved by +-1e-6;
    tolerance 1e-6 of the column's largest entry (as above).
    """
    h = 1e-6
    t = np.linspace(0.0, 1.0, 400)
    phi = 0.3 + 2.0 * np.pi * t
    off = np.array([0.9, -0.4])
    _, jac = tri_spindle_jacobian(phi, BEAMS, off, R_MM)

    def twin(beams=BEAMS, o=off, phase=0.3):
        base = TriBase(beams, Bore((0.0, 0.0), R_MM), o, lambda tt: 2.0 * np.pi * tt, phase_rad=phase)
        return tri_forward(base, t)

    fd = np.zeros((BEAMS.channels.__len__(), t.size))
    for j in range(3):
        if name in ("beta", "rho"):
            attr = "beta_rad" if name == "beta" else "rho_mm"
            up, dn = getattr(BEAMS, attr).copy(), getattr(BEAMS, attr).copy()
            up[j] += h
            dn[j] -= h
            kw_up = {"beta_rad": BEAMS.beta_rad, "rho_mm": BEAMS.rho_mm, "d_b_mm": BEAMS.d_b_mm, attr: up}
            kw_dn = dict(kw_up, **{attr: dn})
            d = (twin(beams=Beams(BEAMS.channels, **kw_up)) - twin(beams=Beams(BEAMS.channels, **kw_dn))) / (
                2 * h
            )
        elif name in ("ox", "oy"):
            e = np.array([h, 0.0]) if name == "ox" else np.array([0.0, h])
            d = (twin(o=off + e) - twin(o=off - e)) / (2 * h)
        else:
            d = (twin(phase=0.3 + h) - twin(phase=0.3 - h)) / (2 * h)
        fd[j] = d[:, j]
    scale = np.max(np.abs(fd))
    assert scale > 0
    assert np.max(np.abs(jac[name] - fd)) < 1e-6 * scale


def test_straightening_round_trips_and_its_derivatives_are_the_closed_forms():
    """psi = beta + asin(rho / R), g = d_b + rho^2 / (2R): inverse to rounding; d/drho by differences."""
    psi, g = straighten(BEAMS.beta_rad, BEAMS.rho_mm, BEAMS.d_b_mm, R_MM)
    np.testing.assert_allclose(psi - BEAMS.beta_rad, np.arcsin(BEAMS.rho_mm / R_MM), rtol=0, atol=1e-15)
    np.testing.assert_allclose(g - BEAMS.d_b_mm, BEAMS.rho_mm**2 / (2 * R_MM), rtol=0, atol=1e-13)
    beta, d_b = unstraighten(psi, BEAMS.rho_mm, g, R_MM)
    np.testing.assert_allclose(beta, BEAMS.beta_rad, rtol=0, atol=1e-15)
    np.testing.assert_allclose(d_b, BEAMS.d_b_mm, rtol=0, atol=1e-13)
    h = 1e-6
    b_up, d_up = unstraighten(psi, BEAMS.rho_mm + h, g, R_MM)
    b_dn, d_dn = unstraighten(psi, BEAMS.rho_mm - h, g, R_MM)
    np.testing.assert_allclose((b_up - b_dn) / (2 * h), dbeta_drho_at_psi(BEAMS.rho_mm, R_MM), rtol=1e-7)
    # d_b ~ 36 mm rounds to eps 36 mm = 8e-15 mm: 8e-9 in a difference over 2h
    np.testing.assert_allclose(
        (d_up - d_dn) / (2 * h), dd_b_drho_at_g(BEAMS.rho_mm, R_MM), rtol=1e-7, atol=5e-8
    )


def _problem_with_holes(encoder: bool):
    """Return the problem of the two scans with missing readings and both offsets reported.

    ``encoder``: scan 0's angle from its spindle stream's encoder (absolute: the first beam's direction
    free, no phase or scale).
    """
    scans = [_scan(*case, seed=k) for k, case in enumerate(CASES)]
    ys = [s[2].copy() for s in scans]
    ys[0][100:180, 1] = np.nan
    ys[1][::7, 0] = np.nan
    models = [s[3] for s in scans]
    if encoder:
        t = scans[0][0]
        models[0] = angle_model_from_arrays(
            rpm_nominal=None,
            direction="ccw",
            spindle_t_s=t,
            spindle_angle_rad=2.0 * np.pi * CASES[0][1] / 60.0 * t,
        )
    inp = fit_inputs(
        [s[0] for s in scans],
        ys,
        BEAMS.channels,
        BEAMS,
        scan_ids=["scan0", "scan1"],
        angle_models=models,
        rpm=None,
        direction=None,
        phase0_rad=0.0,
        spindle_xy_mm=[CENTER + np.asarray(case[4]) for case in CASES],
        center_xy_mm=[CENTER, CENTER],
        range_mm=None,
        channel_time_offsets_s=TAU_S,
    )
    return build_problem(inp, BEAMS, R_MM, AcceptanceRule.defaults(), 100, 1e10)[0]


@pytest.mark.parametrize("encoder", [False, True])
def test_the_normal_equations_are_those_of_the_jacobian(encoder):
    """:func:`normal_equations` (per channel's non-zero columns) against J^T J and J^T f of the whole J.

    Problems with missing readings, prior rows, free and held phases, speed scales, and (encoder) the
    first beam's direction free; evaluated away from the minimum, with and without the readings
    :func:`residuals` keeps (bit for bit the same). The same sums in another order:
    within 1e-12 of each entry's scale sqrt((J^T J)_ii (J^T J)_jj) (resp. |J_i| |f|).
    """
    pb = _problem_with_holes(encoder)
    assert pb.ch0_free == int(encoder) and all(p is not None for p in pb.priors)
    assert any(cl.phase is not None for cl in pb.cols) and any(cl.scale is not None for cl in pb.cols)
    assert sum(int(m.sum()) for m in pb.masks) < sum(m.size for m in pb.masks)
    nuis = [ScanNuisance(np.asarray(case[4], float) + 0.01, case[3] + 0.002, case[2]) for case in CASES]
    x = pb.pack(BEAMS, nuis) + np.random.default_rng(5).normal(0.0, 1e-3, pb.n_params)
    f, J = residuals_and_jacobian(pb, x)
    np.testing.assert_array_equal(f, residuals(pb, x))
    JtJ, Jtf = normal_equations(pb, x, f)  # with the readings the residuals have just computed at x
    pb.row_cache.pop("readings")
    JtJ_own, Jtf_own = normal_equations(pb, x, f)  # and computing them
    np.testing.assert_array_equal(JtJ, JtJ_own)
    np.testing.assert_array_equal(Jtf, Jtf_own)
    d = np.sqrt(np.diag(J.T @ J))
    assert np.max(np.abs(JtJ - J.T @ J) / np.outer(d, d)) < 1e-12
    assert np.max(np.abs(Jtf - J.T @ f) / (d * np.linalg.norm(f))) < 1e-12


def test_a_calibration_solve_from_the_normal_equations_is_the_solve_from_the_jacobian():
    """The calibration's solve (its iterations' factor from :func:`normal_equations`) against
    :func:`borescan.levmar.levenberg_marquardt` on the Jacobian alone, from a start off the minimum:
    the same minimum (cost within 1e-9 relative, parameters within 1e-4 of their standard
    uncertainty: both stop once a step is below xtol = 1e-10 of the scaled parameter vector, which is
    1.5e-5 u of an offset here, on steps that differ in their last digits), the same evaluation
    counts within one.
    """
    from borescan.calibrate.residuals import solve
    from borescan.levmar import levenberg_marquardt

    pb = _problem_with_holes(False)
    nuis = [ScanNuisance(np.asarray(case[4], float) + 0.05, case[3] + 0.01, case[2]) for case in CASES]
    x0 = pb.pack(BEAMS, nuis) + np.random.default_rng(6).normal(0.0, 2e-3, pb.n_params)
    a = levenberg_marquardt(
        lambda x: residuals(pb, x),
        x0,
        lambda x: residuals_and_jacobian(pb, x)[1],
        max_nfev=pb.max_nfev,
        xtol=1e-10,
        ftol=1e-10,
        gtol=1e-10,
    )
    b = solve(pb, x0)
    assert a.success and b.success
    assert abs(b.nfev - a.nfev) <= 1 and abs(b.njev - a.njev) <= 1
    assert abs(b.cost - a.cost) <= 1e-9 * a.cost
    s2 = 2.0 * a.cost / (a.fun.size - a.x.size)
    u = np.sqrt(np.diag(np.linalg.inv(a.jac.T @ a.jac)) * s2)
    assert np.all(np.abs(b.x - a.x) <= 1e-4 * u)
    np.testing.assert_array_equal(b.jac, residuals_and_jacobian(pb, b.x)[1])
