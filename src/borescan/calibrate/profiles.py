"""The full-data calibration's cost profiled along each rho, and what a non-linear profile adds.

rho enters the readings mostly through rho^2 (the first harmonic's amplitude |o| sqrt(1 + rho^2 /
R^2)), so its cost valley can be skewed and curved, beta moving non-linearly with it: each rho's
profile (every other parameter refitted) is checked at rho +- 2 u (:func:`rho_profile`); where it is
not the linear one it is walked out to Delta chi^2 = 12.5 and the likelihood-weighted spread of
every parameter along it enters the covariance (:func:`profile_covariance`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from borescan.calibrate.problem import FullProblem
from borescan.calibrate.residuals import solve_fixed

__all__ = ["ProfileResult", "rho_profile", "profile_covariance"]

#: the linearisation check of a rho: at rho_hat +- 2 u the profile's Delta chi^2 must lie within
#: 4 +- 1 (its width within ~12 % of the linear one) and every parameter within half its u of the
#: linear prediction; otherwise the profile is walked out to Delta chi^2 = 12.5 (weights below 0.2 %)
_PROFILE_CHECK_DCHI2 = 1.0
_PROFILE_CHECK_BEND = 0.5
_PROFILE_END_DCHI2 = 12.5
_PROFILE_MAX_STEPS = 14
#: a profile point lower than the estimate by more than 0.01 s^2 is a lower minimum
_LOWER_TOL = -0.01


@dataclass(frozen=True)
class ProfileResult:
    """One rho's profile.

    Attributes
    ----------
    info : JSON-safe dict (``linear``, the check's Delta values, and when walked ``rho_range_mm``,
        ``n_points``, ``profile_minima``, ``delta_ssr_over_s2_at_ends`` or ``profile_failed``).
    second_moment : likelihood-weighted second moment of the public parameters about the estimate
        (trapezoid rule in rho, weights exp(-Delta/2)), None when linear or failed.
    points, weights : the public parameters' deltas at the walked points and their weights.
    lower : an internal vector of lower cost than the estimate when the profile found one.
    """

    info: dict
    second_moment: np.ndarray | None = None
    points: np.ndarray | None = None
    weights: np.ndarray | None = None
    lower: np.ndarray | None = None


@dataclass(frozen=True)
class _Walk:
    """The profile's state: the estimate, its cost, the linear regression on rho, the points so far."""

    pb: FullProblem
    i: int
    x_hat: np.ndarray
    cost0: float
    s2: float
    b_int: np.ndarray
    pts: dict

    def at(self, delta: float, x_from: np.ndarray) -> tuple[np.ndarray, float, bool]:
        """Return the minimum with rho at rho_hat + delta (warm-started from ``x_from``) and its Delta."""
        rho0 = float(self.x_hat[self.i])
        xs = x_from + self.b_int * (delta - (x_from[self.i] - rho0))
        xs[self.i] = rho0 + delta
        x, cost, ok = solve_fixed(self.pb, xs, self.i)
        return x, 2.0 * (cost - self.cost0) / self.s2, ok


def _check(w: _Walk, u: float, cov_free: np.ndarray, out: dict) -> np.ndarray | None:
    """Check the profile at rho +- 2 u against the linear prediction (``out["linear"]``).

    Returns a lower internal vector when one is found, else None.
    """
    pb, i = w.pb, w.i
    p0 = pb.public(w.x_hat)
    u_pub = np.sqrt(np.clip(np.diag(cov_free), 0.0, None))
    b_pub = cov_free[:, i] / cov_free[i, i]
    checks = []
    for k in (-2.0, 2.0):
        if abs(float(w.x_hat[i]) + k * u) >= pb.rule.head_radius_mm:
            out["linear"] = False
            continue
        x, d, ok = w.at(k * u, w.x_hat)
        if not ok:
            out["linear"] = False
            continue
        if d < _LOWER_TOL:
            return x
        w.pts[k * u] = (x, d)
        checks.append(d)
        dev = pb.public(x) - p0 - b_pub * k * u
        bend = np.abs(dev) / np.where(u_pub > 0, u_pub, np.inf)
        if abs(d - 4.0) > _PROFILE_CHECK_DCHI2 or float(np.max(bend)) > _PROFILE_CHECK_BEND:
            out["linear"] = False
    out["check_delta_ssr_over_s2"] = [float(d) for d in checks]
    return None


def _walk(w: _Walk, u: float) -> np.ndarray | None:
    """Walk the profile out on both sides to Delta = 12.5 (the step doubled on flat stretches).

    Returns a lower internal vector when one is found, else None.
    """
    rho0 = float(w.x_hat[w.i])
    for sgn in (-1.0, 1.0):
        side = sorted((dl for dl in w.pts if dl * sgn > 0), key=abs)
        delta = side[-1] if side else 0.0
        x_prev, d_prev = w.pts[delta]
        step = u
        for _ in range(_PROFILE_MAX_STEPS):
            if d_prev > _PROFILE_END_DCHI2:
                break
            new = delta + sgn * step
            if abs(rho0 + new) >= w.pb.rule.head_radius_mm:
                break
            x, d, ok = w.at(new, x_prev)
            if not ok:
                break
            if d < _LOWER_TOL:
                return x
            w.pts[new] = (x, d)
            if d - d_prev < 1.0:  # a flat stretch: widen the step
                step *= 2.0
            delta, x_prev, d_prev = new, x, d
    return None


def rho_profile(
    pb: FullProblem,
    j: int,
    x_hat: np.ndarray,
    cost0: float,
    s2: float,
    cov_int: np.ndarray,
    cov_free: np.ndarray,
) -> ProfileResult:
    """Profile of the full-data cost along rho of channel index ``j``.

    Each point holds rho at a value and minimises the cost over every other parameter
    (:func:`~borescan.calibrate.residuals.solve_fixed`, warm-started from the neighbour plus the
    linear regression on rho); Delta = 2 (cost - cost0) / s^2 is the profile likelihood ratio in
    chi^2 units.
    """
    i = pb.i_rho0 + j
    u = float(np.sqrt(cov_free[i, i]))
    w = _Walk(pb, i, x_hat, cost0, s2, cov_int[:, i] / cov_int[i, i], {0.0: (x_hat, 0.0)})
    out: dict = {"u_rho_linear_mm": u, "linear": True}
    lower = _check(w, u, cov_free, out)
    if lower is not None:
        return ProfileResult(out, lower=lower)
    if out["linear"]:
        return ProfileResult(out)
    lower = _walk(w, u)
    if lower is not None:
        return ProfileResult(out, lower=lower)
    return _spread(w, j, out)


def _spread(w: _Walk, j: int, out: dict) -> ProfileResult:
    """Return the walked profile's likelihood-weighted spread and its local minima."""
    pb, i, rho0 = w.pb, w.i, float(w.x_hat[w.i])
    deltas = np.array(sorted(w.pts))
    dchi = np.array([w.pts[dl][1] for dl in deltas])
    out["rho_range_mm"] = [float(rho0 + deltas[0]), float(rho0 + deltas[-1])]
    out["n_points"] = int(deltas.size)
    if deltas.size < 3 or deltas[0] >= 0.0 or deltas[-1] <= 0.0:
        # no refit converged on one side: the linear covariance stays, and the diagnostics say so
        out["profile_failed"] = True
        return ProfileResult(out)
    p0 = pb.public(w.x_hat)
    P = np.array([pb.public(w.pts[dl][0]) - p0 for dl in deltas])
    wts = np.exp(-0.5 * np.clip(dchi, 0.0, None))
    # trapezoid weights in rho
    h = np.diff(deltas)
    tw = np.zeros(deltas.size)
    tw[:-1] += h / 2.0
    tw[1:] += h / 2.0
    wts = wts * tw
    out["delta_ssr_over_s2_at_ends"] = [float(dchi[0]), float(dchi[-1])]
    out["profile_minima"] = [
        {
            "rho_mm": [float(v) for v in pb.public(w.pts[deltas[k]][0])[i - j : i - j + pb.c]],
            "delta_ssr_over_s2": float(dchi[k]),
        }
        for k in range(1, deltas.size - 1)
        if deltas[k] != 0.0 and dchi[k] < dchi[k - 1] and dchi[k] < dchi[k + 1]
    ]
    return ProfileResult(out, second_moment=(P * wts[:, None]).T @ P / wts.sum(), points=P, weights=wts)


def profile_covariance(
    pb: FullProblem, profiles: list[ProfileResult], cov_free: np.ndarray, p_hat: np.ndarray, flagged: set[int]
) -> np.ndarray:
    """Return the covariance with each non-linear profile's spread beyond the linear part.

    Where the profile of a rho is not the linear prediction, the spread of every parameter along it
    (likelihood-weighted second moment about the estimate) replaces the linear part along that rho
    wherever it is larger (PSD part of the difference: never smaller than the linear covariance); over
    several such profiles each parameter gets the largest excess one of them gives, not their sum
    (:func:`_largest_per_parameter`).
    A flagged beam's profile (its sign not resolved, ``flagged``), or one along which a flagged rho
    changed sign, adds nothing: the two solutions carry it. Each used profile's ``info`` gets its
    points, weights and extra covariance in the calibration's parameter order.
    """
    i_rho0 = pb.i_rho0
    parts: list[tuple[dict, np.ndarray]] = []
    for j, prof in enumerate(profiles):
        M, P, wts, info = prof.second_moment, prof.points, prof.weights, prof.info
        if M is None:
            continue
        if j in flagged:  # a flagged beam's profile walks into its mirror's valley
            info["not_used"] = "the sign of this rho is not resolved: two solutions instead of one spread"
            continue
        crossed = [
            int(pb.channels[f])
            for f in sorted(flagged)
            if np.any(np.sign(p_hat[i_rho0 + f] + P[:, i_rho0 + f]) != np.sign(p_hat[i_rho0 + f]))
        ]
        if crossed:  # refitted along this rho, a flagged beam went over to its mirror: that is its two
            # solutions' spread, not this beam's own curvature
            info["not_used"] = f"along this profile the flagged rho of channel(s) {crossed} changed sign"
            continue
        i = i_rho0 + j
        E = M - np.outer(cov_free[:, i], cov_free[:, i]) / cov_free[i, i]
        w, V = np.linalg.eigh(0.5 * (E + E.T))
        parts.append((info, (V * np.clip(w, 0.0, None)) @ V.T))
        info["u_rho_profile_mm"] = float(np.sqrt(M[i, i]))
        # what a quantity computed from the beams needs to map this spread by itself (a secant per
        # point, not the linear sensitivities): the points, their weights, the linear covariance's column
        # of this rho and the extra covariance this profile adds, all in the calibration's parameter order
        info["points"] = {
            "delta_params": pb.params_of(P).tolist(),
            "weight": [float(x) for x in wts / wts.sum()],
        }
        info["linear_cov_column"] = pb.params_of(cov_free[:, i]).tolist()
    extra = _largest_per_parameter([E for _, E in parts])
    for (info, _), E in zip(parts, extra):
        info["extra_cov_params"] = pb.params_of(pb.params_of(E).T).tolist()
    return cov_free + sum(extra, np.zeros_like(cov_free))


def _largest_per_parameter(parts: list[np.ndarray]) -> list[np.ndarray]:
    """Return the profiles' extra covariances scaled so that each parameter gets the largest one's excess.

    Each profile j gives var(q) = linear + E_j[q, q] (the spread of q's conditional mean along rho_j on top
    of its linear conditional variance); adding every E_j counted a correlated excess once per profile
    (u / CRB of 1.3 on beams whose own profile gave 0.94-0.99, ``bench.bench_calibration_contract`` scan 5).
    Their sum S is scaled by D = diag(sqrt(max_j E_j[q, q] / S[q, q])): D S D keeps S's correlations and
    stays positive semi-definite, and each E_j becomes D E_j D (the parts still add up to it).
    """
    if not parts:
        return []
    S = sum(parts, np.zeros_like(parts[0]))
    top = np.max([np.diag(E) for E in parts], axis=0)
    d = np.sqrt(np.divide(top, np.diag(S), out=np.zeros_like(top), where=np.diag(S) > 0))
    return [E * np.outer(d, d) for E in parts]
