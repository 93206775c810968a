"""Other minima of the rod solve near the chosen one: the choice between them as two weighted solutions.

:func:`borescan.rod.solve_rod` starts from both reflections of the pose angles (alpha -> -alpha, a
near-symmetry broken by the beams' offsets and angles only at second order) and from both signs of
the deflection, and keeps the lowest cost. Where another start's minimum has a chi^2 = cost /
sigma^2 less than ``DELTA_CHI2_MAX`` above it, the data do not rule it out: its radii differ by
0.1-0.5 um on a typical calibration hold and by up to 8 um on a hold held far off centre and
deflected (the coverage bench's chain 3). The solve then states it (``RodSolution.other_minima``)
with its chi^2 above the chosen one's and its weight, the likelihood ratio normalised over the
minima, w_k = exp(-dchi2_k / 2) / (1 + sum_l exp(-dchi2_l / 2)) (flat prior between them, each
minimum's curvature alike: both are images of one geometry). The budgets carry the choice as one
input: the chosen radii are reported, the error of that choice is r_k - r_0 with probability w_k,
and its root mean square sqrt(sum_k w_k (r_k - r_0)^2) is the input's u (mean folded in, as the
layer-geometry input does; :func:`minima_radius_cov`).

Two minima are the same when every pose angle agrees within ``SAME_POSE_RAD`` (a reflection moves
the poses by up to pi), or when their radii agree within ``SAME_RADIUS_U`` of their u: with the
design's phi = d = gamma = 0 the reflection is an exact symmetry, its minimum the same solution
mirrored (radii equal but for the deflection average's sampling, 1e-4-1e-2 um); such a choice adds
below 0.13 % to the radius' u.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

__all__ = [
    "DELTA_CHI2_MAX",
    "SAME_POSE_RAD",
    "SAME_RADIUS_U",
    "RodMinimum",
    "other_minima",
    "minima_radius_cov",
]

#: a minimum this far (chi^2) above the chosen one is ruled out by the data (issue 36's bound,
#: where the three-sensor mirror is also resolved)
DELTA_CHI2_MAX = 25.0
#: two minima whose pose angles all agree within this [rad] are one (a reflection moves them by ~pi)
SAME_POSE_RAD = 0.05
#: ... or whose radii all agree within this fraction of their u (the chosen solution mirrored)
SAME_RADIUS_U = 0.05


@dataclass(frozen=True)
class RodMinimum:
    """Another minimum of the rod solve (module doc).

    delta_chi2 : its chi^2 above the chosen minimum's (cost difference / sigma^2)
    weight : its probability among the minima (the chosen one has 1 - sum of the others')
    radius_mm : (m,) its radii, as the solve reports radii (deflection averaged)
    cost_mm2 : its sum of squared residuals
    """

    delta_chi2: float
    weight: float
    radius_mm: np.ndarray
    cost_mm2: float

    def to_dict(self) -> dict:
        """Return the minimum as JSON-ready numbers."""
        return {
            "delta_chi2": float(self.delta_chi2),
            "weight": float(self.weight),
            "radius_mm": [float(x) for x in self.radius_mm],
            "cost_mm2": float(self.cost_mm2),
        }


def _pose_gap_rad(a, b) -> float:
    """Largest pose-angle difference of two minima, wrapped to [0, pi] [rad]."""
    d = np.mod(np.asarray(a) - np.asarray(b) + np.pi, 2 * np.pi) - np.pi
    return float(np.max(np.abs(d))) if d.size else 0.0


def other_minima(
    candidates, chosen_p, chosen_cost: float, chosen, alpha_of: Callable, radii_at: Callable
) -> tuple[RodMinimum, ...]:
    """Return the start minima distinct from the chosen one within ``DELTA_CHI2_MAX`` (module doc).

    ``candidates``: (p, cost) of every start's LM minimum; ``chosen``: the solution at ``chosen_p``
    (its sigma, radii and their u); ``alpha_of(p)``: its pose angles; ``radii_at(p, cost)``: its
    radii as the solve reports them (raises ValueError where that minimum's geometry gives none: it
    is then not a solution, and left out). Sorted by chi^2.
    """
    sigma_mm = float(chosen.sigma_mm)
    if not np.isfinite(sigma_mm) or sigma_mm <= 0:
        return ()
    same_r = SAME_RADIUS_U * np.asarray(chosen.u_radius_mm, dtype=float)
    a0 = alpha_of(chosen_p)
    kept: list[tuple[np.ndarray, float, np.ndarray]] = []
    for p, cost in sorted(candidates, key=lambda c: c[1]):
        d = (cost - chosen_cost) / sigma_mm**2
        if not np.isfinite(d) or d >= DELTA_CHI2_MAX:
            continue
        a = alpha_of(p)
        if _pose_gap_rad(a, a0) < SAME_POSE_RAD or any(_pose_gap_rad(a, b) < SAME_POSE_RAD for *_, b in kept):
            continue
        try:
            r = np.asarray(radii_at(p, cost), dtype=float)
        except ValueError:
            continue
        if np.all(np.abs(r - chosen.radius_mm) <= same_r):  # the chosen solution, mirrored
            continue
        kept.append((r, float(cost), a))
    if not kept:
        return ()
    dchi2 = np.array([max((c - chosen_cost) / sigma_mm**2, 0.0) for _, c, _ in kept])
    lik = np.exp(-0.5 * dchi2)
    w = lik / (1.0 + lik.sum())
    return tuple(RodMinimum(float(d), float(wk), r, c) for (r, c, _), d, wk in zip(kept, dchi2, w))


def minima_radius_cov(radius_mm, minima) -> np.ndarray:
    """Return sum_k w_k (r_k - r_0)(r_k - r_0)^T [mm^2]: the choice's second moment (module doc)."""
    r0 = np.asarray(radius_mm, dtype=float)
    out = np.zeros((r0.size, r0.size))
    for mk in minima:
        dr = np.asarray(mk.radius_mm, dtype=float) - r0
        out += mk.weight * np.outer(dr, dr)
    return out
