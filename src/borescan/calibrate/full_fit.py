"""The full-data calibration of a three-sensor device: every sample of its ring-gauge spindle scans.

Model (spec "Spindle scan", exact via :func:`borescan.geometry.tri_spindle_readings`):
v_c(t) = s - d_b_c with |o + Rot(phi(t))(F_c + s u_c)| = R, o = S - C (machine frame).
The angle phi(t) comes from each scan's :class:`~borescan.kinematics.AngleModel`: the encoder
angle itself, or phase + (1 + eps) Phi(t) with Phi the integral of the rpm profile (or
rpm_nominal t). The Yang 2017 Eq. 8 relations hold at the extremes of this model.

Unknowns: per channel beta, rho, d_b; per scan o (2), and with a commanded (not measured)
angle the speed scale 1 + eps and the phase. A ring gauge is a circle, so the data fix
beta_c + phi - angle(o) and |o| only. Hence:

- a scan with ``center_xy_mm`` and ``spindle_xy_mm`` gives o a prior (each coordinate within
  +-``rule.position_accuracy_mm``, standard uncertainty that / sqrt(3)), which fixes angle(o);
- with an encoder and such a prior the beams are absolute (beta of every channel free);
  otherwise beta of the first channel is held at ``nominal`` (the gauge freedom, said in
  ``diagnostics["gauge"]`` and ``diagnostics["beta_reference"]``);
- a commanded angle's phase is free only where the prior fixes angle(o) (else it is held at
  ``phase0_rad``, the same gauge freedom).

Starting values that cannot miss: the speed scale from the readings' spectrum over
``rule.speed_scale_range`` refined on the first-harmonic misfit; offset and levels from the
linear first harmonic; the beams from the design. Internally beta + asin(rho / R) and
d_b + rho^2 / (2 R) (the quantities the data fix best) are the fitted parameters, which
straightens the valleys; then each beam's mirror solution (rho of opposite sign at the same
first harmonic, a second minimum of nearly equal cost) is refitted on every sample where the mirror
check needs it and the lower cost kept (``diagnostics["mirror_solutions"]``; a beam without a
mirror, or whose predicted depth and unrefitted mirror start both lie far above the kept minimum, is
not refitted: :func:`~borescan.calibrate.mirror_search.triage`). rho enters the readings mostly through
rho^2 (the first harmonic's amplitude |o| sqrt(1 + rho^2 / R^2)), so its cost valley can be
skewed and curved, beta moving non-linearly with it: the profile of each rho whose beam the mirror
check leaves near the threshold without a separate mirror (every other parameter refitted) is checked
at rho +- 2 u; where it is not the linear one it is walked out to
Delta chi^2 = 12.5 and the likelihood-weighted spread of every parameter along it enters the
covariance (``diagnostics["rho_profiles"]``); a lower cost found on the way is refitted and kept.
Distinct minima (mirror starts, dips along a profile) are listed with 2 (cost - cost_kept) / s^2
(``diagnostics["minima"]``, ``"n_minima"``, ``"ambiguous_minima"`` when one is within 4 s^2).
Each beam's mirror check (``diagnostics["mirror_check"]``, :mod:`borescan.mirror`, issue 36): the
depth N e^4 rho^2 / (2 sigma^2 R^4) next to the lowest minimum found with that beam's rho of the
other sign; resolved (none, or >= 25 in chi^2): one value with u from its own curvature; flagged:
two weighted solutions (refitted from the final solution's mirror, covariance from their own
Jacobians), never folded into one u, and a non-linear profile of another beam along which the
flagged rho changes sign adds nothing to that beam. u(d_b) of a linear
profile includes the second-order term of d_b = g - rho^2 / (2R) (3 u(rho)^4 / (4 R^2)). Solved with
:func:`borescan.levmar.levenberg_marquardt` (MINPACK's Levenberg-Marquardt on a LAPACK QR,
analytic Jacobian). Covariance
s^2 (J^T J)^-1, s^2 = SSR / dof.

Censoring at the sensor range: the sensor nulls a reading whose noisy value leaves [0, range], so
near a limit the valid readings are a truncated, biased sample. After the first solution, the
valid readings whose fitted value lies within
:data:`~borescan.calibrate.censoring.CENSOR_GUARD_SIGMA` noise sigmas of a limit (or beyond it)
are set aside and the fit is redone without them
(:func:`~borescan.calibrate.censoring.censoring_keep`,
``diagnostics["censoring_guard"]``); a limit beyond which the channel has valid readings is not
treated as one.

Acceptance (:class:`~borescan.calibrate.result.AcceptanceRule`): each channel's residual rms within
``max_residual_to_noise`` of its readings' own noise floor, |rho| within the head radius,
d_b within what the gauge and the sensor range allow; otherwise ``CalibrationError`` with
the reason.


The steps are small functions on the problem (:class:`~borescan.calibrate.problem.FullProblem`):
its construction and starts (:mod:`~borescan.calibrate.starts`), residuals, Jacobian and solves
(:mod:`~borescan.calibrate.residuals`), censoring (:mod:`~borescan.calibrate.censoring`), the
mirror search and checks (:mod:`~borescan.calibrate.mirror_search`), the rho profiles
(:mod:`~borescan.calibrate.profiles`) and what is stated besides the parameters
(:mod:`~borescan.calibrate.summary`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from borescan.calibrate.censoring import CENSOR_GUARD_SIGMA, censored_problem
from borescan.calibrate.mirror_search import MirrorSearch, mirror_checks, mirror_search
from borescan.calibrate.problem import FullProblem
from borescan.calibrate.profiles import ProfileResult, profile_covariance, rho_profile
from borescan.calibrate.residuals import residuals_and_jacobian, solve
from borescan.calibrate.result import AcceptanceRule, CalibrationError, TriCalibration, make_calibration_id
from borescan.calibrate.starts import build_problem, fit_inputs, start_vector
from borescan.calibrate.summary import NOTES, acceptance_problems, distinct_minima, scan_figures
from borescan.fit import FitResult, fit_result
from borescan.geometry import Beams
from borescan.kinematics import AngleModel
from borescan.levmar import LMResult
from borescan.mirror import BeamMirror

__all__ = ["fit_full_calibration"]


def fit_full_calibration(
    t_s,
    readings_mm,
    channels: Sequence[int],
    nominal: Beams,
    R_mm: float,
    spindle_xy_mm=None,
    rpm=60.0,
    *,
    center_xy_mm=None,
    direction: str = "ccw",
    phase0_rad=0.0,
    angle_models: Sequence[AngleModel] | None = None,
    range_mm=None,
    rule: AcceptanceRule | None = None,
    scan_ids: Sequence[str] | None = None,
    device_id: str = "",
    raw_sha256: dict[str, str] | None = None,
    night: str | None = None,
    max_nfev: int = 1000,
    cond_max: float = 1e10,
    channel_time_offsets_s=None,
) -> TriCalibration:
    """Least-squares calibration on every sample of one or more ring-gauge spindle scans (module doc).

    Parameters
    ----------
    t_s : (n,) or list of (n_k,) sample times per scan [s]
    readings_mm : (n, c) or list of (n_k, c), NaN = missing [mm]
    channels : channel numbers (c,), ascending; nominal : Beams, the design geometry (a start)
    R_mm : ring gauge radius at the scan's temperature [mm]
    spindle_xy_mm, center_xy_mm : per scan spindle axis and gauge centre (machine frame) or None
    rpm, direction, phase0_rad : without ``angle_models``: constant speed ``rpm`` per scan
    angle_models : per scan :class:`~borescan.kinematics.AngleModel` (overrides rpm/direction)
    range_mm : sensor range per channel (d_b plausibility), default 10 mm
    max_nfev, cond_max : iteration limit; largest acceptable condition number
    channel_time_offsets_s : (c,) per channel tau: its reading at stamp t is the geometry of time
        t - tau (a device model's carried ``channel_delay``); the angle of channel c is evaluated
        there. None: every channel at its stamp.

    Returns
    -------
    TriCalibration with method "full_lsq"

    Raises
    ------
    CalibrationError naming the scans when the fit does not converge, the Jacobian is rank
    deficient or worse conditioned than ``cond_max``, there are fewer samples than parameters,
    or the result fails the acceptance rule.
    """
    rule = rule or AcceptanceRule.defaults()
    inp = fit_inputs(
        t_s,
        readings_mm,
        channels,
        nominal,
        scan_ids=scan_ids,
        angle_models=angle_models,
        rpm=rpm,
        direction=direction,
        phase0_rad=phase0_rad,
        spindle_xy_mm=spindle_xy_mm,
        center_xy_mm=center_xy_mm,
        range_mm=range_mm,
        channel_time_offsets_s=channel_time_offsets_s,
    )
    pb, starts = build_problem(inp, nominal, R_mm, rule, max_nfev, cond_max)
    try:
        pb, search, censored = _first_solution(pb, start_vector(pb, nominal, starts))
        solved = _profiled(pb, search)
    except (ValueError, FloatingPointError) as exc:  # NaN readings from a diverging step
        raise CalibrationError(pb.scan_ids, f"full_lsq fit failed: {exc}") from exc
    cal = _calibration(solved, censored)
    return TriCalibration(
        calibration_id=make_calibration_id(device_id, pb.scan_ids, "full_lsq", night),
        device_id=device_id,
        method="full_lsq",
        scan_ids=tuple(pb.scan_ids),
        raw_sha256=dict(raw_sha256 or {}),
        **cal,
    )


def _first_solution(pb: FullProblem, x0: np.ndarray) -> tuple[FullProblem, MirrorSearch, dict]:
    """Solve from the start, set the censored readings aside and solve again, then search the mirrors.

    Returns the problem without the censored readings, the search and the censored counts.
    """
    sol = solve(pb, x0)
    if not (bool(sol.success) and np.isfinite(sol.cost)):
        return pb, MirrorSearch(sol, (), ()), {}
    pb, censored = censored_problem(pb, sol.x)
    if any(sum(v) for v in censored.values()):
        if pb.n_obs + pb.n_prior <= pb.n_params:
            raise CalibrationError(
                pb.scan_ids,
                f"{pb.n_obs} valid samples (away from the sensor range limits) for {pb.n_params} parameters",
            )
        with np.errstate(all="ignore"):
            sol = solve(pb, sol.x)
    return pb, mirror_search(pb, sol), censored


@dataclass(frozen=True)
class _Solved:
    """The kept solution with its linearisation (at the last profiled solution), mirror checks and profiles.

    ``r`` and ``fit`` are those of the last linearisation; after three rounds that each found a lower
    minimum along a profile, ``sol`` is the last refit (as before the split).
    """

    pb: FullProblem
    sol: LMResult
    r: np.ndarray
    fit: FitResult
    cov_free: np.ndarray
    profiles: list[ProfileResult]
    tried: tuple[dict, ...]
    alternatives: tuple
    checks: list[BeamMirror]


def _linearised(pb: FullProblem, sol: LMResult) -> tuple[FitResult, np.ndarray]:
    """Return the fit result at ``sol`` and the public covariance; refuse a fit that did not converge.

    Raises ``CalibrationError`` on no convergence, a rank-deficient or too ill-conditioned Jacobian.
    """
    r, J = np.asarray(sol.fun), np.asarray(sol.jac)  # at sol.x (levenberg_marquardt returns both)
    converged = bool(sol.success) and bool(np.all(np.isfinite(r)))
    if not converged:
        raise CalibrationError(
            pb.scan_ids, f"full_lsq did not converge after {sol.nfev} evaluations ({sol.message})"
        )
    fit = fit_result(
        pb.internal_names(), sol.x, r, J, success=converged, message=str(sol.message), nfev=int(sol.nfev)
    )
    if fit.rank < pb.n_params or fit.condition > pb.cond_max:
        raise CalibrationError(
            pb.scan_ids,
            f"full_lsq Jacobian rank {fit.rank} of {pb.n_params}, condition {fit.condition:.3g} (limit "
            f"{pb.cond_max:.3g}); "
            "the data do not determine the parameters (is the spindle offset from the gauge centre?)",
        )
    return fit, pb.public_cov(sol.x, fit.cov)


def _profiled(pb: FullProblem, search: MirrorSearch) -> _Solved:
    """Linearise at the kept solution, check each beam's mirror and profile the rho that need it.

    A rho is profiled where the mirror check leaves its beam in one valley through both signs
    (:attr:`borescan.mirror.BeamMirror.one_valley`); every other beam is one Gaussian value on its own
    curvature (issue 38), a flagged one with its second solution.

    Up to three rounds: a lower cost along a profile (the optimizer had stopped short of the minimum)
    is refitted, its mirrors searched, and the new solution linearised, checked and profiled again.
    """
    sol, tried, alts = search.sol, search.tried, search.alternatives
    for _round in range(3):
        fit, cov_free = _linearised(pb, sol)
        r = np.asarray(sol.fun)
        nuis = pb.unpack(sol.x)[1]
        same = search.sol is sol  # the search's decisions and own refits were made at this solution
        found = MirrorSearch(sol, tried, alts, search.triage if same else (), search.own if same else ())
        checks = mirror_checks(pb, sol, fit.sigma**2, found, cov_free, nuis)
        profiles, lower = [], None
        for j, check in enumerate(checks):
            if check.one_valley:  # the sign undetermined, no separate minimum: its valley's spread
                prof = rho_profile(pb, j, sol.x, float(sol.cost), fit.sigma**2, fit.cov, cov_free)
            else:
                prof = ProfileResult({"linear": True, "not_profiled": NOTES["not_profiled"]})
            prof.info["channel"] = int(pb.channels[j])
            profiles.append(prof)
            if prof.lower is not None:
                lower = prof.lower
                break
        if lower is None:
            break
        with np.errstate(all="ignore"):
            trial = solve(pb, lower)
        if not (bool(trial.success) and np.isfinite(trial.cost) and trial.cost < sol.cost):
            break
        search = mirror_search(pb, trial)
        sol, tried, alts = search.sol, tried + search.tried, alts + search.alternatives
    return _Solved(pb, sol, r, fit, cov_free, profiles, tried, alts, checks)


def _rank_all_free(pb: FullProblem, x: np.ndarray) -> int:
    """Rank of the Jacobian with beta of the first channel and every phase free (the gauge's rank)."""
    _, Jf = residuals_and_jacobian(pb, x, full=True)
    cf = np.linalg.norm(Jf, axis=0)
    cf[cf == 0] = 1.0
    svf = np.linalg.svd(Jf / cf, compute_uv=False)
    return int(np.sum(svf > svf[0] * max(Jf.shape) * np.finfo(float).eps * 1e3))


def _calibration(s: _Solved, censored: dict) -> dict:
    """Return the calibration's fields from the solution: beams, covariance, figures, diagnostics.

    Raises ``CalibrationError`` when the result fails the acceptance rule.
    """
    pb, sol, fit = s.pb, s.sol, s.fit
    s2 = fit.sigma**2
    beams, nuis = pb.unpack(sol.x)
    p_hat = pb.public(sol.x)
    u2_rho = np.diag(s.cov_free)[pb.i_rho0 : pb.i_rho0 + pb.c].copy()
    # the mirror check of every beam (issue 36): a flagged beam is carried as two weighted solutions
    checks = s.checks
    flagged = {j for j, m in enumerate(checks) if not m.resolved}
    cov_free = profile_covariance(pb, s.profiles, s.cov_free, p_hat, flagged)
    # d_b = g - rho^2 / (2R) is quadratic in rho: with rho ~ N(rho_hat, u^2) the linear term above
    # misses var(rho^2) = 2 u^4 and the bias E[rho_hat^2] - rho^2 = u^2; both are added to u(d_b)^2
    # as 3 u^4 / (4 R^2) where the rho profile was linear (else the profile's spread holds them)
    for j, prof in enumerate(s.profiles):
        if prof.info["linear"]:
            cov_free[pb.i_g0 + j, pb.i_g0 + j] += 3.0 * u2_rho[j] ** 2 / (4.0 * pb.R_mm**2)
    minima = distinct_minima(pb, float(sol.cost), s2, s.tried, s.alternatives, s.profiles, p_hat, cov_free)
    nuisance, ratios = scan_figures(pb, s.r, nuis, cov_free)
    problems = acceptance_problems(
        beams, nuis, ratios, pb.scan_ids, pb.channels, pb.R_mm, pb.range_mm, pb.rule
    )
    if problems:
        raise CalibrationError(pb.scan_ids, "calibration refused: " + "; ".join(problems))
    cov = pb.params_of(pb.params_of(cov_free).T)
    n_obs = pb.n_obs
    return {
        "beams": beams,
        "cov": cov,
        "residual_rms_mm": float(np.sqrt(float(s.r[:n_obs] @ s.r[:n_obs]) / n_obs)),
        "dof": n_obs + pb.n_prior - pb.n_params,
        "rank": fit.rank,
        "condition": fit.condition,
        "converged": True,
        "nuisance": nuisance,
        "fit": fit,
        "diagnostics": _diagnostics(s, censored, checks, minima, cov_free, ratios),
    }


def _gauge(pb: FullProblem) -> str:
    """Return the sentence saying what holds the gauge freedom of a ring gauge."""
    if pb.absolute:
        return (
            "beams absolute in the encoder frame: the scan's centre and spindle position fix the offset "
            "direction"
        )
    return (
        f"beta of channel {pb.channels[0]} held at the design value {pb.beta1_fixed_rad!r} rad: a ring gauge "
        "fixes only "
        "beta_c - beta_1, |offset| and beta_1 + phase - angle(offset) per scan, and no scan has both "
        "an encoder "
        "angle and a known centre and spindle position"
    )


def _diagnostics(
    s: _Solved, censored: dict, checks, minima, cov_free: np.ndarray, ratios: np.ndarray
) -> dict:
    """Return the calibration's diagnostics (JSON-safe once sanitised by :meth:`TriCalibration.to_dict`)."""
    pb, sol, fit = s.pb, s.sol, s.fit
    i_rho0, i_g0 = pb.i_rho0, pb.i_g0
    rho_hat = pb.unpack(sol.x)[0].rho_mm
    u_rho = np.sqrt(np.diag(cov_free)[i_rho0:i_g0])
    return {
        **({} if pb.tau_s is None else {"channel_time_offsets_s": [float(x) for x in pb.tau_s]}),
        "gauge": _gauge(pb),
        "beta_reference": "absolute" if pb.absolute else f"channel {pb.channels[0]} fixed",
        "n_obs": pb.n_obs,
        "n_prior_rows": pb.n_prior,
        "n_params": pb.n_params,
        "n_params_all_free": pb.n_params + (0 if pb.ch0_free else 1) + pb.K,
        "rank_all_free": _rank_all_free(pb, sol.x),
        "nfev": int(sol.nfev),
        "cost": float(sol.cost),
        "singular_values_scaled": fit.extra["singular_values"],
        "g_mm": sol.x[i_g0 : pb.n_beam],
        "u_g_mm": np.sqrt(np.diag(fit.cov)[i_g0 : pb.n_beam]),
        "g_note": NOTES["g_note"],
        "weak_rho_channels": [
            int(ch) for ch, r_, u_ in zip(pb.channels, rho_hat, u_rho) if abs(r_) < 2.0 * u_
        ],
        "mirror_solutions": minima.tried,
        "mirror_check": [m.to_dict() for m in checks],
        "mirror_note": NOTES["mirror_note"],
        "n_minima": 1 + len(minima.minima),
        "minima": minima.minima,
        "ambiguous_minima": any(m["delta_ssr_over_s2"] < 4.0 for m in minima.minima),
        "minima_note": NOTES["minima_note"],
        "rho_profiles": [p.info for p in s.profiles],
        "rho_profile_note": NOTES["rho_profile_note"],
        "weak_rho_note": NOTES["weak_rho_note"],
        "acceptance": {
            "max_residual_to_noise": pb.rule.max_residual_to_noise,
            "residual_to_noise_max": float(np.max(ratios)),
            "head_radius_mm": pb.rule.head_radius_mm,
            "position_accuracy_mm": pb.rule.position_accuracy_mm,
        },
        "param_names": pb.public_names(),
        "cov_free": cov_free,
        "censoring_guard": {
            "k_sigma": CENSOR_GUARD_SIGMA,
            "range_mm": [float(x) for x in pb.range_mm],
            "set_aside": censored,
            "note": NOTES["censoring_note"],
        },
    }
