"""Rod solve (Wang 2017 Eq. 16 generalised to the spec's layer geometry and axis deflection):
forward-model parity, recovery over the contract's ranges, honest u at small omega, refusals.
"""

import numpy as np
import pytest

from borescan.geometry import Hole, RodAxis, RodLayer, rod_readings
from borescan.physics.rod import rod_section_geometry
from borescan.rod import RodSolveError, rod_cost_mm2, rod_crb, solve_rod
from borescan.rod_eq16 import HOLD_FIX
from borescan.rod_eq16 import rod_jacobian, rod_residuals, rod_start
from borescan.rod_model import _k, _RodProblem

# Wang 2017 Section 4: two 150 mm ring gauges on a 500 mm rod; OD2-P30W04 span 8 mm.
LAYERS = [RodLayer(1, 100.0, 71.0), RodLayer(2, 400.0, 71.0)]
HOLES = [Hole((0.0, 0.0), 75.0), Hole((0.01, -0.02), 75.012)]
R_TRUE = np.array([75.0, 75.012])
L0 = [71.0, 71.0]
SKEW = RodAxis(1.0, 0.5, np.deg2rad(0.3), np.deg2rad(120.0))  # rod axis skew to the holes' axis
SIG = 0.02 / np.sqrt(3)  # 20 um linearity read as a uniform +-20 um error: sigma = 11.5 um
# the spec's full layer geometry (beam offset, tilt, in-plane angle)
GEOM = [
    RodLayer(1, 100.0, 71.0, phi_rad=0.02, d_mm=0.3, gamma_rad=np.deg2rad(0.3)),
    RodLayer(2, 400.0, 71.0, phi_rad=-0.05, d_mm=-0.2, gamma_rad=np.deg2rad(-0.4)),
]


def _scan(axis=SKEW, n=12, seed=0, noise=True, spread=2 * np.pi, layers=LAYERS):
    rng = np.random.default_rng(seed)
    alpha = np.sort(rng.uniform(0, spread, n))
    v = rod_readings(alpha, layers, HOLES, axis)
    assert np.all((v > 0) & (v < 8)), "readings inside the 8 mm span"
    if noise:
        v = v + rng.uniform(-0.02, 0.02, v.shape)
    return alpha, v


def draw_contract_scan(rng):
    """Effect-free scan over the contract's ranges (as bench/bench_rod_contract.py): 2-3 holes of
    100-200 mm, 8-40 poses at random angles, 5-30 readings per pose (means), noise 2-20 um,
    eccentricity <= 2.5 mm, deflection <= 1 deg, |d| <= 0.5 mm, |gamma| <= 0.5 deg.
    """
    m = int(rng.integers(2, 4))
    r = rng.uniform(50.0, 100.0, m)
    h = rng.uniform(50.0, 150.0) + np.concatenate([[0.0], np.cumsum(rng.uniform(100.0, 300.0, m - 1))])
    layers = [
        RodLayer(
            j + 1,
            h[j],
            r[j] - 4.0,
            phi_rad=rng.uniform(-0.1, 0.1),
            d_mm=rng.uniform(-0.5, 0.5),
            gamma_rad=np.deg2rad(rng.uniform(-0.5, 0.5)),
        )
        for j in range(m)
    ]
    off = rng.uniform(-0.05, 0.05, (m, 2))
    holes = [Hole((off[j, 0], off[j, 1]), r[j]) for j in range(m)]
    e, te = 2.5 * np.sqrt(rng.uniform()), rng.uniform(0, 2 * np.pi)
    axis = RodAxis(
        e * np.cos(te), e * np.sin(te), np.deg2rad(rng.uniform(0.0, 1.0)), rng.uniform(0, 2 * np.pi)
    )
    n, k, sig = int(rng.integers(8, 41)), int(rng.integers(5, 31)), rng.uniform(0.002, 0.020)
    alpha = rng.uniform(0, 2 * np.pi, n)
    v0 = rod_readings(alpha, layers, holes, axis)
    v = v0 + sig * rng.standard_normal((k,) + v0.shape).mean(axis=0)
    return layers, holes, axis, alpha, v, sig / np.sqrt(k)


def test_solver_model_equals_the_forward_model():
    """The solver's unknowns (gauge: axis through the origin, centres relative to the axis at the
    spot height, rho = r k(omega^2)) reproduce geometry.rod_readings to 1e-12 mm.
    """
    axis = RodAxis(1.7, -0.9, np.deg2rad(0.8), 2.1)
    alpha = np.linspace(0.0, 2 * np.pi, 17)
    v = rod_readings(alpha, GEOM, HOLES, axis)
    w = axis.omega_rad * np.array([np.cos(axis.omega_az_rad), np.sin(axis.omega_az_rad)])
    r = np.array([h.radius_mm for h in HOLES])
    z = np.array([lay.h_mm + rr * np.tan(lay.gamma_rad) for lay, rr in zip(GEOM, r)])
    c = (
        np.array([h.center_xy_mm for h in HOLES])
        - [axis.dx_mm, axis.dy_mm]
        - (z * np.sinc(axis.omega_rad / np.pi))[:, None] * w
    )
    prob = _RodProblem(v, np.ones_like(v, dtype=bool), GEOM, 0, True, alpha_fix=alpha[0])
    p = prob.pack(r * _k(w @ w), c, alpha, w)
    assert np.max(np.abs(prob.readings(*prob.unpack(p)) - v)) < 1e-12
    assert np.max(np.abs(prob.residual(p))) < 1e-12
    holes, ax = rod_section_geometry(GEOM, c, r, w)
    assert np.max(np.abs(rod_readings(alpha, GEOM, holes, ax) - v)) < 1e-12


def test_noise_free_recovery_exact_with_layer_geometry_and_deflection():
    axis = RodAxis(1.0, 0.5, np.deg2rad(0.7), 0.4)
    alpha = np.linspace(0.3, 0.3 + 2 * np.pi, 11, endpoint=False)
    v = rod_readings(alpha, GEOM, HOLES, axis)
    sol = solve_rod(v, layers=GEOM)  # sigma from the residuals (0): the debiasing is then void
    assert sol.method == "joint" and sol.rank == sol.n_params == 3 * 2 + 11 - 1 + 2
    assert np.allclose(sol.radius_mm, R_TRUE, atol=1e-8)
    assert sol.deflection_rad == pytest.approx(axis.omega_rad, abs=1e-7)
    # gauge: pose 0 at angle 0, i.e. the part frame turned by -alpha_0; the azimuth is an axis (mod pi)
    az = axis.omega_az_rad - alpha[0]
    assert np.mod(sol.deflection_az_rad - az + np.pi / 2, np.pi) - np.pi / 2 == pytest.approx(0.0, abs=1e-5)
    c, s = np.cos(-alpha[0]), np.sin(-alpha[0])
    assert np.allclose(
        sol.eccentricity_mm, [c * 1.0 - s * 0.5, s * 1.0 + c * 0.5], atol=1e-6
    )  # hole 1 at the origin
    assert sol.cost_mm2 < 1e-20


def test_deflection_free_solve_removes_the_eq16_bias():
    """omega = 1 deg, r = 75 mm: Eq. 16 (omega held) is biased by ~ r omega^2 / 4 = 5.7 um in r,
    many standard uncertainties at 2 um noise; the joint solve recovers r within 3 u.
    """
    axis = RodAxis(1.2, -0.8, np.deg2rad(1.0), 0.7)
    rng = np.random.default_rng(3)
    alpha = rng.uniform(0, 2 * np.pi, 30)
    v = rod_readings(alpha, GEOM, HOLES, axis) + 0.002 * rng.standard_normal((30, 2))
    old = solve_rod(v, layers=GEOM, u_reading_mm=0.002, deflection="none")
    assert old.method == "eq16" and np.all(np.abs(old.radius_mm - R_TRUE) > 5 * old.u_radius_mm)
    sol = solve_rod(v, layers=GEOM, u_reading_mm=0.002)
    assert np.all(np.abs(sol.radius_mm - R_TRUE) < 3 * sol.u_radius_mm)
    assert abs(sol.deflection_sq_rad2 - axis.omega_rad**2) < 3 * sol.u_deflection_sq_rad2
    crb = rod_crb(alpha, layers=GEOM, holes=HOLES, axis=axis, sigma_mm=0.002)
    assert np.all(sol.u_radius_mm / crb < 1.2) and np.all(sol.u_radius_mm / crb > 0.8)
    # the solve reports through the project's one fit result: same covariance, parameter names
    assert sol.fit.cov.shape == sol.cov.shape and np.array_equal(sol.fit.cov, sol.cov)
    assert sol.fit.names[:2] == ("rho_1_mm", "rho_2_mm") and sol.fit.names[-2:] == ("w_x_rad", "w_y_rad")
    assert sol.fit.rank == sol.rank == sol.fit.p and sol.fit.sigma == 0.002


def test_recovery_over_the_contract_ranges():
    """30 effect-free scans over the contract's ranges (fixed seed): every solved diameter within
    4 u, no wrong minimum (cost <= cost at the truth + sqrt(2 N) sigma^2), refusals only with
    their named reasons and rare.
    """
    rng = np.random.default_rng(20170)
    z, solved = [], 0
    for _ in range(30):
        layers, holes, axis, alpha, v, sig = draw_contract_scan(rng)
        try:
            sol = solve_rod(v, layers=layers, u_reading_mm=sig)
        except RodSolveError as err:
            assert str(err).startswith(("degenerate geometry", "deflection not separable")), err
            continue
        solved += 1
        r = np.array([h.radius_mm for h in holes])
        z.append((sol.radius_mm - r) / sol.u_radius_mm)
        c_true = rod_cost_mm2(v, alpha, layers, holes, axis)
        assert sol.cost_mm2 <= c_true + np.sqrt(2 * v.size) * sig**2
    z = np.concatenate(z)
    assert solved >= 26
    assert np.max(np.abs(z)) < 4.0
    assert 0.7 < np.sqrt(np.mean(z**2)) < 1.3


def test_small_deflection_few_poses_large_noise_is_honest():
    """omega = 0.05 deg (signal far below the noise), 16 poses, 8 um pose means: the data cannot
    see the deflection, so its direction and size are averaged over the prior (omega <= 2 deg)
    instead of taken at the noisy maximum-likelihood beta (a Rice magnitude, biased up, radii low).
    The prior's mean omega^2 pulls the radii low by a fraction of u only; the z spread stays near 1.
    """
    axis = RodAxis(1.5, 0.4, np.deg2rad(0.05), 1.0)
    rng = np.random.default_rng(8)
    alpha = rng.uniform(0, 2 * np.pi, 16)
    v0 = rod_readings(alpha, GEOM, HOLES, axis)
    zf, zm, refused = [], [], 0
    for i in range(16):
        v = v0 + 0.008 * rng.standard_normal(v0.shape)  # a pose mean of 6 readings with 20 um noise
        try:
            f = solve_rod(v, layers=GEOM, u_reading_mm=0.008)
        except RodSolveError as err:
            assert str(err).startswith(("deflection not separable", "degenerate geometry"))
            refused += 1
            continue
        zf.append((f.radius_mm - R_TRUE) / f.u_radius_mm)
        if i < 6:
            m = solve_rod(v, layers=GEOM, u_reading_mm=0.008, deflection="mle", max_deflection_ratio=np.inf)
            zm.append((m.radius_mm - R_TRUE) / m.u_radius_mm)
    zf, zm = np.array(zf), np.array(zm)
    assert refused <= 2
    assert -1.0 < zf.mean() < 0.35 and 0.6 < zf.std() < 1.3 and np.max(np.abs(zf)) < 4.0
    assert zm.mean() < 0.0  # the MLE's Rice bias pulls the radii low


def test_exact_jacobian_matches_finite_differences():
    _, v = _scan()
    L = v + np.array(L0)
    mask = np.isfinite(L)
    p, _ = rod_start(L, mask)
    J = rod_jacobian(p, L, mask)
    h = 1e-7
    num = np.column_stack(
        [
            (rod_residuals(p + h * e, L, mask) - rod_residuals(p - h * e, L, mask)) / (2 * h)
            for e in np.eye(p.size)
        ]
    )
    assert np.allclose(J, num, atol=1e-6)


def test_solve_jacobian_in_one_stacked_call_is_the_column_by_column_central_difference():
    """_RodProblem.jac evaluates its 12 perturbed geometries as one stack (rod_ray_readings over a
    leading axis); column by column, each unknown stepped alone through rod_readings of the holes and
    axis of rod_section_geometry, gives the same matrix to 1e-9 of its largest entry, in w and in beta
    = w^2, with the spec's full layer geometry and a deflected axis.
    """
    from borescan.rod_model import _beta, _w_of_beta

    rng = np.random.default_rng(5)
    n, m = 9, 2
    prob = _RodProblem(np.zeros((n, m)), np.ones((n, m), dtype=bool), GEOM, 0, True)
    rho, c = np.array([75.0, 75.01]), rng.uniform(-1.0, 1.0, (m, 2))
    alpha, w = np.sort(rng.uniform(0, 2 * np.pi, n)), np.array([0.011, -0.007])
    alpha[0] = 0.0
    p = prob.pack(rho, c, alpha, w)

    def model(q, beta=None):
        r, cc, a, ww = prob.unpack(q)
        if beta is not None:
            ww = _w_of_beta(beta, w)
        holes, axis = rod_section_geometry(GEOM, cc, r / _k(float(ww @ ww)), ww)
        return rod_readings(a, GEOM, holes, axis)

    for beta_step in (None, 1e-4):
        J = -prob.jac(p, beta_step=beta_step).reshape(n, m, -1)
        cols = []
        for i in range(p.size):
            e = np.zeros(p.size)
            if beta_step is not None and i >= p.size - 2:
                b = np.zeros(2)
                b[i - p.size + 2] = beta_step
                cols.append((model(p, _beta(w) + b) - model(p, _beta(w) - b)) / (2 * beta_step))
                continue
            step = 1e-6 if i >= 3 * m else 1e-5
            e[i] = step
            cols.append((model(p + e) - model(p - e)) / (2 * step))
        ref = np.stack(cols, axis=-1)
        assert np.max(np.abs(J - ref)) <= 1e-9 * np.max(np.abs(ref)), beta_step


def test_missing_readings_are_skipped():
    _, v = _scan(n=14, seed=3)
    v[2, 0] = np.nan
    v[7, 1] = np.nan
    sol = solve_rod(v, L0, u_reading_mm=SIG)
    assert np.all(np.abs(sol.radius_mm - R_TRUE) < 3 * sol.u_radius_mm)
    v[4, :] = [np.nan, 3.0]  # poses seen by one layer only (2, 4, 7): dropped, angle NaN
    sol = solve_rod(v, L0, u_reading_mm=SIG)
    assert np.isnan(sol.alpha_rad[4]) and np.isfinite(sol.alpha_rad[5]) and sol.n_params == 6 + 11 - 1 + 2


def test_refuses_underdetermined():
    _, v = _scan(n=5)
    with pytest.raises(RodSolveError, match=r"underdetermined: 10 readings < 3m \+ n - 1 \+ 2 = 12 unknowns"):
        solve_rod(v, L0)
    with pytest.raises(RodSolveError, match="one hole"):
        solve_rod(v[:, :1], L0[:1])


def test_refuses_poses_that_cannot_separate_the_deflection():
    """8 poses over 150 deg: the section's second harmonic trades against the radii and the centres."""
    axis = RodAxis(1.5, 0.5, np.deg2rad(0.5), np.deg2rad(120.0))
    alpha = np.deg2rad(np.linspace(0, 150, 8))
    v = rod_readings(alpha, GEOM, HOLES, axis) + 0.002 * np.random.default_rng(1).standard_normal((8, 2))
    with pytest.raises(
        RodSolveError,
        match=r"deflection not separable from the radii: freeing the rod axis deflection multiplies "
        r"u\(r\) by \d",
    ):
        solve_rod(v, layers=GEOM, u_reading_mm=0.002)
    sol = solve_rod(
        v, layers=GEOM, u_reading_mm=0.002, max_deflection_ratio=np.inf
    )  # the caller may accept it
    assert sol.deflection_ratio > 10.0
    eq16 = solve_rod(v, layers=GEOM, u_reading_mm=0.002, deflection="none")  # omega held: no such refusal
    assert eq16.method == "eq16"


def test_refuses_parallel_rod_and_bunched_poses():
    """Rod parallel to the holes: offsets (x_m, y_m) equal, |p| and r trade against the angles."""
    _, v = _scan(axis=RodAxis(1.0, 0.5, 0.0, 0.0))
    with pytest.raises(RodSolveError, match="degenerate geometry") as err:
        solve_rod(v, L0, u_reading_mm=SIG)
    assert str(err.value).endswith(HOLD_FIX)  # what hold would do (the next test)
    _, v = _scan(spread=np.deg2rad(2.0))
    with pytest.raises(RodSolveError, match="all poses are at nearly one angle"):
        solve_rod(v, L0, u_reading_mm=SIG)
    _, v = _scan(spread=np.deg2rad(20.0))  # bunched, but not flat: ill-conditioned joint solve
    with pytest.raises(RodSolveError, match="degenerate geometry") as err:
        solve_rod(v, L0, u_reading_mm=SIG)
    assert str(err.value).endswith(HOLD_FIX)


def test_every_refusal_a_new_hold_would_fix_says_which_hold_and_where_to_plan_it():
    """The solve's own refusal names the hold that would give radii and ``borescan plan --rod-scan``
    (so every caller says it: the calibrate and measure stages, the plan, the benches); a refusal
    that no hold fixes (one hole, readings of the wrong shape) does not.
    """
    hold_refused = [  # (the rank / condition refusals: the test above)
        (_scan(n=5)[1], {}),  # underdetermined
        (_scan(spread=np.deg2rad(2.0))[1], {"u_reading_mm": SIG}),  # constant readings
        (_scan(axis=RodAxis(), n=20, seed=4)[1], {"u_reading_mm": SIG}),  # centred rod
    ]
    for v, kw in hold_refused:
        with pytest.raises(RodSolveError) as err:
            solve_rod(v, L0, **kw)
        assert str(err.value).endswith(HOLD_FIX), str(err.value)
    axis = RodAxis(1.5, 0.5, np.deg2rad(0.5), np.deg2rad(120.0))  # deflection not separable
    alpha = np.deg2rad(np.linspace(0, 150, 8))
    v = rod_readings(alpha, GEOM, HOLES, axis) + 0.002 * np.random.default_rng(1).standard_normal((8, 2))
    with pytest.raises(RodSolveError, match="deflection not separable") as err:
        solve_rod(v, layers=GEOM, u_reading_mm=0.002)
    assert str(err.value).endswith(HOLD_FIX)
    assert "borescan plan --rod-scan" in HOLD_FIX and "deflected across its eccentricity" in HOLD_FIX
    for bad in (_scan()[1][:, :1], np.zeros(6)):
        with pytest.raises(RodSolveError) as err:
            solve_rod(bad, L0[:1] if bad.ndim == 2 else L0)
        assert HOLD_FIX not in str(err.value)


def test_centred_rod_gives_radii_without_angles():
    _, v = _scan(axis=RodAxis(), n=20, seed=4)
    with pytest.raises(RodSolveError, match="centred='mean'"):
        solve_rod(v, L0, u_reading_mm=SIG)
    sol = solve_rod(v, L0, u_reading_mm=SIG, centred="mean")
    assert sol.method == "centred" and np.all(np.isnan(sol.alpha_rad))
    assert np.all(np.abs(sol.radius_mm - R_TRUE) < 3 * sol.u_radius_mm)
    assert np.allclose(sol.u_radius_mm, SIG / np.sqrt(20))


def test_a_solve_at_the_design_layers_does_not_depend_on_the_readings_last_bits():
    """At phi = d = 0 the mirror image of a minimum (alpha -> -alpha, cy -> -cy, w_y -> -w_y) and its
    deflection's sign (w -> -w) are minima exactly as low; the multi-start found one or another as
    the readings' last bits fell (each of 6 holds below gave 3-4 images over 6 perturbations of 2 ulp,
    radii apart by up to 1 % of u: the deflection is averaged over by sampling, which is not
    symmetric). The solve takes one image by sign (beta_y = 2 w_x w_y >= 0): the same image and the
    same radii to 1e-4 u whatever the last bits.
    """
    for seed in range(3):
        rng = np.random.default_rng(seed)
        axis = RodAxis(1.5, 0.8, np.deg2rad(rng.uniform(0.3, 1.0)), rng.uniform(0, 2 * np.pi))
        alpha = rng.uniform(0, 2 * np.pi, 24)
        v = rod_readings(alpha, LAYERS, HOLES, axis) + 0.001 * rng.standard_normal((24, 2))
        sols = [
            solve_rod(
                v + rng.integers(-2, 3, v.shape) * np.spacing(np.abs(v)) * (t > 0),
                layers=LAYERS,
                u_reading_mm=0.001,
                coaxiality_mm=0.05,
            )
            for t in range(5)
        ]
        images = {(*np.sign(s.deflection_xy_rad), np.sign(np.sum(np.sin(s.alpha_rad)))) for s in sols}
        assert len(images) == 1, (seed, images)
        w = sols[0].deflection_xy_rad
        assert w[0] * w[1] > 0, (seed, w)
        for s in sols[1:]:
            assert np.all(np.abs(s.radius_mm - sols[0].radius_mm) <= 1e-4 * sols[0].u_radius_mm), seed


def test_pose_angles_eliminated_from_the_bound_as_the_full_inverse():
    """rod_crb's elimination of the pose angles (each moves only its own pose's readings: a diagonal
    block of the Fisher matrix) gives the other unknowns' block of the full Fisher matrix's inverse,
    within 1e-9 relative, on a random Jacobian of that structure (40 poses x 3 readings, 11 other
    unknowns, columns scaled over 6 decades); with an angle of no information it falls back to the
    full pseudo-inverse (the same numbers, each within 1e-9 of sqrt(C_ii C_jj)).
    """
    from borescan.rod_model import _cov_without_poses

    rng = np.random.default_rng(11)
    n, m, k = 40, 3, 11
    J = np.zeros((n * m + 4, k + n - 1))
    J[:, :k] = rng.standard_normal((n * m + 4, k)) * np.logspace(-3, 3, k)
    for i in range(1, n):  # pose 0's angle is the fixed one
        J[i * m : (i + 1) * m, k + i - 1] = rng.standard_normal(m) * 50.0
    P = np.linalg.pinv(J)  # (J^T J)^+ = J^+ J^+T, from the SVD of J itself (the better conditioned)
    full = (P @ P.T)[:k, :k]
    cov = _cov_without_poses(J, k, n - 1)
    np.testing.assert_allclose(
        cov, full, rtol=1e-9, atol=1e-9 * np.sqrt(np.outer(np.diag(full), np.diag(full))).max()
    )
    J[2 * m : 3 * m, k + 1] = 0.0  # pose 2's angle unseen: singular, the pseudo-inverse of the whole
    P = np.linalg.pinv(J)
    ref = (P @ P.T)[:k, :k]
    # an entry within 1e-9 of its row's and column's scale, sqrt(C_ii C_jj) (|C_ij| is at most that): a
    # small entry carries the rounding of the large ones (1.2e-9 relative on an Intel Xeon host)
    scale = np.sqrt(np.outer(np.diag(ref), np.diag(ref)))
    assert np.all(np.abs(_cov_without_poses(J, k, n - 1) - ref) <= 1e-9 * scale)


def test_the_posteriors_quadratic_forms_are_the_three_index_sums():
    """``rod_deflection._quadratic_forms`` (the importance sampling's likelihoods over 12 000 draws of the
    deflection) is x_i^T A x_i of every row: the einsum it replaced, within rounding, for a symmetric and
    a general A, rows of 2 (the deflection) and of 2 (m - 1) (a coaxial prior's hole differences).
    """
    from borescan.rod_deflection import _quadratic_forms

    rng = np.random.default_rng(4)
    for p in (2, 4, 6):
        x = rng.standard_normal((12_000, p)) * 10.0 ** rng.uniform(-6, 0, p)
        for A in (rng.standard_normal((p, p)), np.cov(rng.standard_normal((p, 3 * p)))):
            want = np.einsum("ij,jk,ik->i", x, A, x)
            scale = np.einsum("ij,jk,ik->i", np.abs(x), np.abs(A), np.abs(x))  # the sum of |terms|
            assert np.all(np.abs(_quadratic_forms(x, A) - want) <= 1e-14 * scale)
