"""One local refinement of a rod solve: the same readings solved with slightly other layers.

:func:`borescan.rod.solve_rod` searches for the global minimum (both reflections, deflection
starts, per-pose repairs: module doc, "Start"). A caller that re-solves the same readings with
layers a little off (the layer geometry's draws, :mod:`borescan.rod_layer_geometry`) moves that
minimum a little; :func:`refine_rod` follows it with one Levenberg-Marquardt run from it and
checks that it stayed in its basin (:class:`RodBasin`), so the caller solves afresh only where
it did not.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from borescan.geometry import RodLayer
from borescan.rod import RodSolution, _Limits, _solution
from borescan.rod_eq16 import RodSolveError, _prepare
from borescan.rod_model import _lm, _RodProblem, rod_layers

__all__ = ["RodBasinError", "RodBasin", "refine_rod"]


#: the refinement's LM tolerance (x, f, gradient): 1e-10, where the solve's 1e-14 costs 1.8 x the
#: evaluations to move the radii by 1e-5 um more (the coverage bench's chain 3, 24 draws)
REFINE_TOL = 1e-10


class RodBasinError(RodSolveError):
    """:func:`refine_rod` left the basin of the solution it started from (solve afresh instead)."""


@dataclass(frozen=True)
class RodBasin:
    """How near :func:`refine_rod`'s minimum must stay to its start's to be the same minimum moved.

    max_dchi2 : its chi^2 = cost / sigma^2 at most this above the start's
    max_pose_move_rad : no pose angle moved by more than this [rad] (a reflection moves some by ~pi)
    max_deflection_move_rad : the deflection vector w moved by at most this [rad], or by at most
        ``max_deflection_move_frac`` of the start's |w| where that is more (w -> -w moves it by 2 |w|)
    """

    max_dchi2: float = 9.0
    max_pose_move_rad: float = 0.05
    max_deflection_move_rad: float = 0.005
    max_deflection_move_frac: float = 0.5

    def deflection_bound_rad(self, w_start) -> float:
        """Return how far w may move from ``w_start`` [rad]."""
        return max(self.max_deflection_move_rad, self.max_deflection_move_frac * float(np.hypot(*w_start)))


def refine_rod(
    readings_mm,
    start: RodSolution,
    *,
    layers: Sequence[RodLayer],
    u_reading_mm: float | None = None,
    coaxiality_mm: float | None = None,
    fix_pose: int = 0,
    basin: RodBasin = RodBasin(),
) -> RodSolution:
    """Solve ``readings_mm`` with other ``layers`` by one local refinement of ``start``.

    ``start``: :func:`solve_rod`'s result for the same readings (with its ``u_reading_mm``,
    ``coaxiality_mm``, ``fix_pose`` and defaults) and layers near ``layers``. One
    Levenberg-Marquardt run from its unknowns (tolerance ``REFINE_TOL``), none of
    :func:`solve_rod`'s starts, reflections or pose repairs (the start's solve has searched
    those), then the same covariance, refusals and
    radii over the deflection: where the minimum found is the start's moved, the result is what
    :func:`solve_rod` returns with ``layers`` (to the optimisers' tolerances: 1e-5 um).

    Raises :class:`RodBasinError` when the minimum is not the start's moved (``basin``) and
    :class:`RodSolveError` as :func:`solve_rod` does.
    """
    if start.fit is None or start.method not in ("joint", "joint-mle", "eq16"):
        raise RodBasinError(f"a {start.method!r} solution has no minimum to refine")
    deflection = {"joint": "free", "joint-mle": "mle", "eq16": "none"}[start.method]
    v_in = np.asarray(readings_mm, dtype=float)
    lays = rod_layers(None, layers, v_in.shape[1] if v_in.ndim == 2 else None)
    l0 = np.array([lay.l0_mm for lay in lays])
    L, mask, keep = _prepare(v_in, l0, 2 if deflection != "none" else 0)
    prob = _RodProblem(L - l0, mask, lays, fix_pose, deflection != "none")
    p0 = np.asarray(start.fit.x, dtype=float)
    if p0.size != prob.n_par:
        raise RodBasinError(f"the start has {p0.size} unknowns, these readings {prob.n_par}")
    try:
        p, cost, nfev = _lm(prob, p0, prob.n_par, REFINE_TOL)
    except ValueError as exc:  # a step put a beam outside its hole
        raise RodBasinError(f"the refinement failed: {exc}") from exc
    _rho, _c, alpha, w = prob.unpack(p)
    _rho0, _c0, alpha0, w0 = prob.unpack(p0)
    sigma2 = start.sigma_mm**2
    dchi2 = (cost - start.cost_mm2) / sigma2 if np.isfinite(cost) else np.inf
    d_pose = float(np.max(np.abs(np.mod(alpha - alpha0 + np.pi, 2 * np.pi) - np.pi), initial=0.0))
    d_w = float(np.hypot(*(w - w0)))
    if not (
        dchi2 <= basin.max_dchi2
        and d_pose <= basin.max_pose_move_rad
        and d_w <= basin.deflection_bound_rad(w0)
    ):
        raise RodBasinError(
            f"the refinement left its start's basin: chi2 {dchi2:+.3g} above it, a pose moved "
            f"{d_pose:.3g} rad, the deflection {d_w:.3g} rad ({basin})"
        )
    return _solution(
        prob, p, cost, nfev, keep, _Limits(u_reading_mm, deflection, coaxiality_mm=coaxiality_mm)
    )
