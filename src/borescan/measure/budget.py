"""GUM budget of a measured diameter (``diameter_uncertainty``).

The readings, the calibration's budget, the temperature and the expansion coefficient.

Part of :mod:`borescan.measure` (package doc).
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass
import numpy as np
from ..artifacts import ArtifactCte, ScanTemperature, artifact_key, diameter_at_20
from ..atomic import json_ready
from ..geometry import Beams
from ..physics.tri_params import straighten, unstraighten
from ..uncertainty import Budget, Combined, Input, Term
from .rotating import DiameterModel, _with_params, wall_points_machine
from .sensors import sensor_terms

__all__ = [
    "DiameterUncertainty",
    "diameter_uncertainty",
]


@dataclass(frozen=True)
class DiameterUncertainty:
    """A diameter at the measured temperature and at 20 degC with its GUM budget.

    diameter_mm, combined_t : D at the scan's temperature and its Combined (u, nu_eff, k, U);
    diameter_20_mm, combined_20 : D20 = D_T / (1 + alpha (T - 20)) (ISO 1) and its Combined;
    temperature : ScanTemperature; cte : ArtifactCte; thermal_correction_mm = D20 - D_T and
    u_thermal_correction_mm (from the temperature and expansion coefficient);
    budget : outputs (D_T, D20); rows_20 / rows_t : budget tables.
    """

    diameter_mm: float
    combined_t: Combined
    diameter_20_mm: float
    combined_20: Combined
    temperature: ScanTemperature
    cte: ArtifactCte
    thermal_correction_mm: float
    u_thermal_correction_mm: float
    budget: Budget

    @property
    def rows_20(self) -> list[dict]:
        """Budget rows of the diameter at 20 degC."""
        return self.budget.rows(1)

    @property
    def rows_t(self) -> list[dict]:
        """Budget rows of the diameter at the measuring temperature."""
        return self.budget.rows(0)

    def columns(self) -> dict:
        """Return the extra ``diameters`` columns (tables.py) of this result."""
        c20, ct = self.combined_20, self.combined_t
        return {
            "temperature_c": self.temperature.temperature_c,
            "u_temperature_c": self.temperature.u_c,
            "temperature_assumed": self.temperature.assumed,
            "cte_per_k": self.cte.cte_per_k,
            "cte_assumed": self.cte.assumed,
            "diameter_20_mm": self.diameter_20_mm,
            "u_diameter_20_mm": c20.u,
            "expanded_u_diameter_20_mm": c20.U,
            "expanded_u_diameter_mm": ct.U,
            "k": c20.k,
            "k_at_t": ct.k,
            "coverage_probability": c20.p,
            "nu_eff": c20.nu_eff if np.isfinite(c20.nu_eff) else None,
            "coverage_method": c20.method,
            "thermal_correction_mm": self.thermal_correction_mm,
            "u_thermal_correction_mm": self.u_thermal_correction_mm,
            "budget_json": json.dumps(json_ready(self.rows_20), sort_keys=True),
        }


def _unit_polar(d: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Return distances and unit vectors of points ``d`` from the origin.

    Distances and unit vectors (rr, n_x, n_y) of points ``d`` (2, m) from the origin: the first
    step of :func:`_ls_radius_change` (the start circle's centre), kept per block of points.
    """
    rr = np.hypot(d[0], d[1])
    return rr, d[0] / rr, d[1] / rr


def _ls_radius_change(
    d: np.ndarray,
    r0: float,
    max_iter: int = 50,
    first: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
) -> float | None:
    """Radius change dr [mm] of the least-squares circle of points given relative to a nearby circle.

    ``d`` (2, m): the points' x and y minus the start circle's centre [mm]; ``r0`` its radius [mm].
    Gauss-Newton on (dc, dr), residuals e_i = |d_i - dc| - (r0 + dr), step -(J^T J)^-1 J^T e with
    J = [-n_x, -n_y, -1] (n_i the unit vector from the centre to the point), until a step is below
    tol = 1e-13 r0 as in :func:`borescan.circlefit.fit_circle_ls`: the same minimum. Near it each
    step is the previous one times a rate (about that step and the residuals over r0), which the
    ratio of the last two steps bounds: it also stops when the last step times that ratio is below
    tol, from a circle a small move away after two steps. The increments are kept apart from r0 so
    that differences of such changes carry no rounding of the radius itself. None when the sum of
    squares grows by more than its rounding (1e-9 relative) or no step converges. ``first``: the
    points' :func:`_unit_polar` when the caller has it (the same numbers as the first step's own).
    """
    tol = 1e-13 * max(1.0, r0)
    dc = np.zeros(2)
    dr = 0.0
    f_prev, last = np.inf, 0.0  # last: the previous step's size (none yet)
    for it in range(max_iter):
        rr, nx, ny = first if it == 0 and first is not None else _unit_polar(d - dc[:, None])
        e = (rr - r0) - dr
        f = float(e @ e)
        if not np.isfinite(f) or f > f_prev * (1.0 + 1e-9):
            return None
        f_prev = f
        sx, sy = float(nx.sum()), float(ny.sum())
        JTJ = np.array([[nx @ nx, nx @ ny, sx], [nx @ ny, ny @ ny, sy], [sx, sy, float(e.size)]])
        step = np.linalg.solve(JTJ, np.array([nx @ e, ny @ e, e.sum()]))
        dc += step[:2]
        dr += step[2]
        size = float(np.max(np.abs(step)))
        if size <= tol or size * size <= tol * last:
            return dr
        last = size
    return None


def _rotating_diameter_changes(model: DiameterModel, beams: Beams, moves) -> list[float]:
    """Return the diameter changes of a rotating scan for moved beams.

    D(beams moved by dl) - D(beams) [mm] of a rotating scan, for moves ``(j, dl)`` of channel j's
    parameters (``dl`` (3c,) per channel (beta, rho, d_b), zero but for channel j).

    The scan's least-squares circle (c0, r0) is fitted once; for each move only channel j's wall
    points are recomputed (:func:`wall_points_machine`), and the moved points' circle is found by
    Gauss-Newton from (c0, r0) (:func:`_ls_radius_change`): D' - D = 2 (dr' - dr_0), dr_0 the same
    iteration on the unmoved points (the base circle's own last digits). A fresh fit
    (:class:`DiameterModel`) where the iteration does not converge.
    """
    v = np.asarray(model.readings_mm, dtype=float)
    n, c = v.shape
    P = wall_points_machine(v, model.phi_rad, model.spindle_xy_mm, beams)  # (n, c, 2)
    ok = np.all(np.isfinite(P), axis=-1)
    Pk = P[ok]
    circ = model.ls_circle(beams, Pk)
    c0, r0 = np.asarray(circ.center_xy_mm), circ.radius_mm
    blocks = [(P[ok[:, j], j] - c0).T for j in range(c)]  # per channel (2, m_j), relative to c0
    polar = [_unit_polar(b) for b in blocks]  # a move changes one channel's: the others' are kept

    def first_step(parts):
        return tuple(np.concatenate(x) for x in zip(*parts))

    dr0 = _ls_radius_change(np.concatenate(blocks, axis=1), r0, first=first_step(polar))
    phi = np.broadcast_to(np.asarray(model.phi_rad, dtype=float).reshape(n, -1), (n, c))
    S = np.broadcast_to(np.asarray(model.spindle_xy_mm, dtype=float), (n, 2))
    out = []
    for j, dl in moves:
        b = _with_params(beams, dl)
        one = Beams((b.channels[j],), b.beta_rad[j : j + 1], b.rho_mm[j : j + 1], b.d_b_mm[j : j + 1])
        k = ok[:, j]
        moved = list(blocks)
        moved[j] = (wall_points_machine(v[k, j : j + 1], phi[k, j], S[k], one)[:, 0] - c0).T
        moved_polar = list(polar)
        moved_polar[j] = _unit_polar(moved[j])
        dr = (
            None
            if dr0 is None
            else _ls_radius_change(np.concatenate(moved, axis=1), r0, first=first_step(moved_polar))
        )
        out.append(2.0 * (dr - dr0) if dr is not None else model(b) - circ.diameter_mm)
    return out


def _second_order_variance(model: DiameterModel, beams: Beams, cov_second: np.ndarray, R_mm: float) -> float:
    """Variance of D from the calibration's second-order term (:func:`diameter_uncertainty`).

    The fit estimates psi = beta + asin(rho/R) and g = d_b + rho^2/(2R) linearly and rho with
    error delta; the calibration's second-order term of d_b is 3 u(rho)^4 / (4 R^2) (the fit's).
    Along that path (psi, g fixed) D moves by q delta^2 at second order; its contribution is
    q^2 3 u^4 (variance and squared bias of q delta^2, as the fit counts them), q from a central
    second difference over +-u(rho). For a rotating scan the differences D(+-u) - D come from
    Gauss-Newton steps from the scan's own circle (:func:`_rotating_diameter_changes`), the same
    minima as fresh fits.
    """
    c = len(beams.channels)
    moves, us = [], []
    for j in range(c):
        s2 = float(cov_second[3 * j + 2, 3 * j + 2])
        if s2 <= 0.0:
            continue
        u = (s2 * 4.0 * R_mm**2 / 3.0) ** 0.25
        rho = float(beams.rho_mm[j])
        for h in (u, -u):
            dl = np.zeros(3 * c)
            psi, g = straighten(beams.beta_rad[j], rho, beams.d_b_mm[j], R_mm)
            beta_h, d_b_h = unstraighten(psi, rho + h, g, R_mm)  # rho moved at fixed psi and g
            dl[3 * j] = beta_h - beams.beta_rad[j]
            dl[3 * j + 1] = h
            dl[3 * j + 2] = d_b_h - beams.d_b_mm[j]
            moves.append((j, dl))
        us.append(u)
    if not moves:
        return 0.0
    if model.kind == "rotating":
        dd = _rotating_diameter_changes(model, beams, moves)
        second = [dd[2 * k] + dd[2 * k + 1] for k in range(len(us))]
    else:
        d0 = model(beams)
        vals = [model(_with_params(beams, dl)) for _, dl in moves]
        second = [vals[2 * k] - 2.0 * d0 + vals[2 * k + 1] for k in range(len(us))]
    var = 0.0
    for u, s in zip(us, second):
        q = s / (2.0 * u * u)
        var += 3.0 * q * q * u**4
    return var


def _profile_variance(model: DiameterModel, beams: Beams, prof: dict, jac_params) -> float:
    """Variance of D from a non-linear rho profile of the calibration, beyond its linear part.

    The calibration walks the cost along one rho, every other parameter refitted, and weighs each
    point by its likelihood ratio (:func:`borescan.calibrate.full_fit.fit_full_calibration`); the parameters'
    second moment there replaces their linear covariance along that rho where it is larger. D is
    evaluated at each point, M_D = sum w (D(p_k) - D(p))^2; the linear covariance already gives D
    (J . c)^2 / u_lin^2 along that rho (c the linear covariance's column of rho, J = dD/dp); the
    term is the excess max(M_D - (J . c)^2 / u_lin^2, 0). Along a profile the beams' rho^2 terms
    move together (beta and d_b follow rho), so D can move far less than its linear sensitivities
    to each parameter say.
    """
    pts = np.asarray(prof["points"]["delta_params"], dtype=float)
    w = np.asarray(prof["points"]["weight"], dtype=float)
    d0 = model(beams)
    dD = np.array([model(_with_params(beams, d)) - d0 for d in pts])
    m_d = float(np.sum(w * dD**2) / np.sum(w))
    col = np.asarray(prof["linear_cov_column"], dtype=float)
    u_lin = float(prof["u_rho_linear_mm"])
    lin = float(np.asarray(jac_params, dtype=float) @ col) ** 2 / u_lin**2 if u_lin > 0 else 0.0
    return max(m_d - lin, 0.0)


def _gauge_radius_of(calibration_budget: Budget) -> float | None:
    for t in calibration_budget.terms:
        if t.input.key.startswith("gauge:") and t.input.key.endswith(":D20") and t.input.estimate:
            return 0.5 * float(t.input.estimate)
    return None


def _add_calibration_terms(b: Budget, calibration_budget: Budget, jac_params, f, model, beams, rho_profiles):
    """Add the calibration budget's terms to the diameter's budget ``b`` (:func:`diameter_uncertainty`).

    Mapped by ``jac_params`` = dD/d(beta, rho, d_b), or with the scan's ``model`` and ``beams`` by D
    itself: the second-order term of d_b, a non-linear rho profile's spread, a mirror's secant.
    """
    to_both = np.array([[1.0], [f]])
    jp = np.asarray(jac_params, dtype=float)
    R_g = _gauge_radius_of(calibration_budget)
    both = np.array([1.0, f])
    profile_of = {f":profile{p['channel']}": p for p in (rho_profiles or ()) if "points" in p}
    for t in calibration_budget.terms:
        key = t.input.key
        if model is not None and beams is not None:
            if key.endswith(":second_order") and t.cov is not None and R_g:
                var = _second_order_variance(model, beams, t.cov, R_g)
                b.add(
                    Term(
                        t.input,
                        cov=np.outer(both, both) * var,
                        note="D's own curvature along the fit's path (psi, g fixed), not d_b's",
                    )
                )
                continue
            prof = profile_of.get(key[key.rfind(":") :]) if key.startswith("fit:") else None
            if prof is not None and t.cov is not None:
                var = _profile_variance(model, beams, prof, jp)
                b.add(
                    Term(
                        t.input,
                        cov=np.outer(both, both) * var,
                        note="D's own spread along the rho profile's points beyond its linear "
                        "part, not the "
                        "parameters' spread mapped linearly",
                    )
                )
                continue
            if ":mirror" in key and t.sensitivity is not None:
                dD = model(_with_params(beams, t.sensitivity)) - model(beams)
                b.add(Term(t.input, both * dD, note="secant: D with the mirror solution's beams minus D"))
                continue
        b.add(t.mapped(to_both @ jp[None, :]))


def diameter_uncertainty(
    diameter_mm: float,
    *,
    jac_params=None,
    calibration_budget: Budget | None = None,
    jac_readings=None,
    u_readings_mm: float,
    dof_readings: float,
    sensors: dict | None = None,
    channels=(),
    noise_mm=None,
    temperature: ScanTemperature,
    cte: ArtifactCte,
    artifact: dict,
    scan_id: str,
    p: float,
    default_resolution_mm: float,
    readings_what: str = "readings",
    calibration_id: str | None = None,
    model: DiameterModel | None = None,
    beams: Beams | None = None,
    rho_profiles: list[dict] | None = None,
    extra_terms: Sequence[tuple[Input, float]] = (),
) -> DiameterUncertainty:
    """GUM budget of a measured diameter, at the scan's temperature and at 20 degC.

    D_T = f(readings, beams); D20 = D_T / (1 + alpha (T - 20)). Terms:

    - every term of ``calibration_budget`` (outputs: the calibration's (beta, rho, d_b) per channel)
      mapped by ``jac_params`` (3c,) = dD/d(beta, rho, d_b); with the scan's ``model`` and the
      calibrated ``beams``, the fit's two non-linear terms are mapped by D itself: an unresolved
      mirror solution by the secant D(p + d) - D(p), and the second-order term of d_b by D's own
      curvature along the fit's path (:func:`_second_order_variance`): for a bore of about the
      gauge's size the rho^2 terms of d_b and of the wall points cancel, and D carries little of it;
      the spread along a non-linear rho profile (``rho_profiles``, the calibration's
      ``diagnostics["rho_profiles"]``) by D at the profile's points (:func:`_profile_variance`), for
      the same reason;
    - ``extra_terms``: (input, dD_T / d input) of inputs the readings depend on directly (a carried
      device-model parameter: the same key as in the calibration's budget, so the two add);
    - the readings: u = ``u_readings_mm`` with ``dof_readings`` (Type A; nu = inf: the data sheet's
      repeatability, Type B);
    - each sensor's linearity and resolution at this measurement (:func:`sensor_terms`, sensitivity
      ``jac_readings`` (c,));
    - the scan's temperature T and the artifact's alpha, which only D20 depends on:
      dD20/dT = -D_T alpha / f^2, dD20/dalpha = -D_T (T - 20) / f^2, f = 1 + alpha (T - 20);
      every other sensitivity of D20 is that of D_T times 1 / f.

    Parameters
    ----------
    diameter_mm : D_T [mm]
    p : coverage probability; default_resolution_mm : ``uncertainty.sensor_resolution_mm``
    artifact : scan.json ``artifact`` (its key names the expansion coefficient: the same gauge's
        alpha in a calibration and a verification is one input)

    Returns
    -------
    DiameterUncertainty
    """
    d20, f, dT_sens, da_sens = diameter_at_20(diameter_mm, cte.cte_per_k, temperature.temperature_c)
    to_both = np.array([[1.0], [f]])
    b = Budget(("D_T", "D_20"), ("mm", "mm"), np.array([diameter_mm, d20]))
    if calibration_budget is not None and jac_params is not None:
        _add_calibration_terms(b, calibration_budget, jac_params, f, model, beams, rho_profiles)
    for inp, dD in extra_terms:
        b.add(Term(inp, np.array([1.0, f]) * float(dD)))
    dof = float(dof_readings)
    b.add(
        Term(
            Input(
                f"readings:{scan_id}",
                f"scatter of the readings of {scan_id}",
                "D_rd",
                "mm",
                None,
                float(u_readings_mm),
                "normal",
                dof,
                "A" if np.isfinite(dof) else "B",
                "between/within the poses' diameters"
                if np.isfinite(dof)
                else "sensors' repeatability (data sheet), larger than the scatter",
            ),
            np.array([1.0, f]),
        )
    )
    if jac_readings is not None and sensors is not None:
        jv = np.asarray(jac_readings, dtype=float)
        for t in sensor_terms(
            sensors, channels, to_both @ jv[None, :], scan_id, noise_mm, default_resolution_mm, readings_what
        ):
            b.add(t)
    b.add(
        Term(
            temperature.budget_input(
                f"temperature:{scan_id}",
                f"temperature of {artifact.get('id') or 'the artifact'} during {scan_id}",
            ),
            np.array([0.0, dT_sens]),
        )
    )
    b.add(
        Term(
            cte.budget_input(
                f"cte:{artifact_key(artifact)}",
                f"expansion coefficient of {artifact.get('id') or 'the artifact'}",
            ),
            np.array([0.0, da_sens]),
        )
    )
    b = b.merged()
    ct, c20 = b.combined(0, p), b.combined(1, p)
    corr = b.combined(np.array([-1.0, 1.0]), p)
    return DiameterUncertainty(
        float(diameter_mm), ct, d20, c20, temperature, cte, d20 - float(diameter_mm), corr.u, b
    )
