"""The mirror solutions of the full-data calibration: each beam's rho of the other sign, refitted.

rho_c -> -rho_c at fixed psi and g keeps the first harmonic and the mean level, so each beam has
two minima of nearly equal cost that only the second harmonic's phase tells apart. The search
(:func:`mirror_search`) refits from the mirror (:func:`mirror_start`) of every beam the mirror check
needs it for and keeps the lower cost (issue 38, :func:`triage`): a beam with no mirror (|rho| + 2 u(rho)
<= sqrt(2) e), or whose predicted depth (:func:`borescan.mirror.predicted_depth`) and unrefitted
mirror start both lie at least :data:`MIRROR_CLEAR_DCHI2` above the kept minimum, is resolved without
a refit (this replaced a screen that fitted every mirror start on a subsample of a long scan first:
the triage costs one evaluation of the residuals a beam). Each beam's check
(:func:`mirror_checks`, :mod:`borescan.mirror`, issue 36) is built from what the search found.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from borescan.calibrate.problem import FullProblem
from borescan.calibrate.residuals import residuals, solve
from borescan.fit import fit_result, jacobian_summary
from borescan.levmar import LMResult
from borescan.mirror import (
    RESOLVED_DCHI2,
    BeamMirror,
    MirrorSolution,
    mirror_exists,
    offset_to_resolve_mm,
    predicted_depth,
    valid_bore_radius_range_mm,
)
from borescan.physics.tri_params import rho_arc_rad

__all__ = [
    "MIRROR_CLEAR_DCHI2",
    "MIRROR_RHO_MARGIN_U",
    "BeamTriage",
    "triage",
    "MirrorSearch",
    "mirror_start",
    "mirror_search",
    "mirror_checks",
]

#: a beam whose predicted mirror depth (Eq. (1) of :mod:`borescan.mirror`) and unrefitted mirror start
#: (rho -> -rho at fixed psi and g, every other parameter kept) both lie at least this far above the kept
#: minimum (chi^2 units, four times :data:`~borescan.mirror.RESOLVED_DCHI2`) is resolved without the
#: exact refit from -rho. A refit only lowers the start's cost; on the first 25 scans of the contract
#: battery (seed 20270611) a refitted separate mirror lay at 0.69-1.0 of its start and 0.48-1.23 of the
#: prediction (the 0.48 at a depth of 10), so at 100 it stays far above 25. A start below the kept
#: minimum (the fit sits in the mirror's valley) is always refitted.
MIRROR_CLEAR_DCHI2 = 4.0 * RESOLVED_DCHI2
#: a mirror may exist when |rho| + this many u(rho) exceeds sqrt(2) e (the margin of the fitted rho)
MIRROR_RHO_MARGIN_U = 2.0


@dataclass(frozen=True)
class BeamTriage:
    """Whether a beam's mirror is refitted, decided at a solution (:func:`triage`).

    Attributes
    ----------
    predicted_delta_chi2 : Eq. (1) of :mod:`borescan.mirror` at the solution's rho, offsets and noise.
    start_delta_chi2 : 2 (cost at the unrefitted mirror start - cost) / s^2; None when not evaluated
        (no mirror possible).
    refit : whether the exact refit from -rho is needed; reason : why not (empty when refitted).
    """

    predicted_delta_chi2: float
    start_delta_chi2: float | None
    refit: bool
    reason: str = ""

    def log(self) -> dict:
        """Return the JSON-safe entry of the mirror search's log for a beam not refitted."""
        out = {"predicted_delta_chi2": float(self.predicted_delta_chi2), "not_refitted": self.reason}
        if self.start_delta_chi2 is not None:
            out["start_delta_chi2"] = float(self.start_delta_chi2)
        return out


def _depth_inputs(pb: FullProblem, x: np.ndarray, j: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Return beam ``j``'s valid readings per scan, the scans' offsets e [mm] and the channel's noise [mm]."""
    e_k = np.array([float(np.hypot(*n.offset_mm)) for n in pb.unpack(x)[1]])
    n_k = np.array([int(m[:, j].sum()) for m in pb.masks])
    return n_k, e_k, np.asarray(pb.floors, float)[:, j]


def triage(pb: FullProblem, sol: LMResult, j: int, u_rho_mm: float) -> BeamTriage:
    """Decide whether beam ``j``'s mirror must be refitted at solution ``sol`` (module doc).

    No mirror is possible where |rho| + :data:`MIRROR_RHO_MARGIN_U` u(rho) <= sqrt(2) e (u finite);
    otherwise the cost at the unrefitted mirror start is evaluated (one evaluation of the residuals) and
    the beam is resolved without a refit when it and the predicted depth are both at least
    :data:`MIRROR_CLEAR_DCHI2` (a fit without residual cost, s^2 = 0, is always refitted).
    """
    rho = float(pb.unpack(sol.x)[0].rho_mm[j])
    n_k, e_k, sig_k = _depth_inputs(pb, sol.x, j)
    d_pred = predicted_depth(n_k, e_k, rho, sig_k, pb.R_mm)
    if np.isfinite(u_rho_mm) and not mirror_exists(abs(rho) + MIRROR_RHO_MARGIN_U * u_rho_mm, e_k):
        return BeamTriage(
            d_pred, None, False, f"no mirror: |rho| + {MIRROR_RHO_MARGIN_U:g} u(rho) <= sqrt(2) e"
        )
    s2 = 2.0 * float(sol.cost) / max(pb.n_obs + pb.n_prior - pb.n_params, 1)
    if not s2 > 0.0:
        return BeamTriage(d_pred, None, True)
    with np.errstate(all="ignore"):
        r = residuals(pb, mirror_start(pb, sol.x, j))
    d_start = float(r @ r - 2.0 * float(sol.cost)) / s2
    if np.isfinite(d_start) and min(d_pred, d_start) >= MIRROR_CLEAR_DCHI2:
        return BeamTriage(
            d_pred,
            d_start,
            False,
            f"predicted depth and unrefitted mirror start both >= {MIRROR_CLEAR_DCHI2:g} above the solution",
        )
    return BeamTriage(d_pred, d_start, True)


@dataclass(frozen=True)
class MirrorSearch:
    """What a mirror search gives: the kept solution, the log of each start, each start's minimum.

    ``tried`` (one dict per start, JSON-safe) is aligned with ``alternatives`` (the start's minimum:
    an :class:`~borescan.levmar.LMResult`, or None when it failed or was not refitted). ``triage``: per
    beam the decision at the kept solution (:func:`triage`), empty when the search did not run;
    ``own``: per beam index, the exact refit from its mirror at the kept solution (what
    :func:`mirror_checks` would refit again).
    """

    sol: LMResult
    tried: tuple[dict, ...]
    alternatives: tuple[Any, ...]
    triage: tuple[BeamTriage, ...] = ()
    own: tuple[tuple[int, LMResult], ...] = ()


def mirror_start(pb: FullProblem, x: np.ndarray, j: int) -> np.ndarray:
    """Return the mirror of beam ``j`` (rho -> -rho at fixed psi and g).

    The gauge-fixed first beam's psi is not free: flipping its rho moves psi_1 by delta = -2 asin(rho_1 /
    R), and the readings depend on psi_c + phase - angle(o), so every other psi moves by delta too and
    each scan's frame turns by delta (its offset without a prior, else its free phase back by delta).
    """
    i_rho0 = pb.i_rho0
    xf = np.array(x, dtype=float, copy=True)
    xf[i_rho0 + j] = -xf[i_rho0 + j]
    if j == 0 and not pb.ch0_free:
        delta = -2.0 * float(rho_arc_rad(x[i_rho0], pb.R_mm))
        xf[: pb.c - 1] += delta
        cd, sd = np.cos(delta), np.sin(delta)
        for k, cl in enumerate(pb.cols):
            if pb.priors[k] is None:
                ox, oy = x[cl.ox], x[cl.oy]
                xf[cl.ox], xf[cl.oy] = cd * ox - sd * oy, sd * ox + cd * oy
            elif cl.phase is not None:
                xf[cl.phase] -= delta
    return xf


def _u_rho(pb: FullProblem, sol: LMResult) -> np.ndarray:
    """Return u of each rho at ``sol`` from its Jacobian (s^2 (J^T J)^-1)."""
    s2 = 2.0 * float(sol.cost) / max(pb.n_obs + pb.n_prior - pb.n_params, 1)
    u = np.sqrt(np.clip(np.diag(jacobian_summary(sol.jac).cov_unit) * s2, 0.0, None))
    return u[pb.i_rho0 : pb.i_rho0 + pb.c]


def mirror_search(pb: FullProblem, sol: LMResult) -> MirrorSearch:
    """Refit from the mirror of each beam that needs it (:func:`triage`); keep the lowest cost."""
    tried, alts, own = [], [], {}
    u_rho = _u_rho(pb, sol)
    decided: dict[int, BeamTriage] = {}
    for j in range(pb.c):
        decided[j] = tri = triage(pb, sol, j, float(u_rho[j]))
        if not tri.refit:
            tried.append(
                {"channel": int(pb.channels[j]), "cost_kept": float(sol.cost), "mirror_taken": False}
            )
            tried[-1].update(tri.log())
            alts.append(None)
            continue
        with np.errstate(all="ignore"):
            trial = solve(pb, mirror_start(pb, sol.x, j))
        fine = bool(trial.success) and bool(np.isfinite(trial.cost))
        better = fine and trial.cost < sol.cost
        tried.append(
            {
                "channel": int(pb.channels[j]),
                "cost_kept": float(sol.cost),
                "cost_mirror": float(trial.cost),
                "mirror_taken": better,
            }
        )
        alts.append((sol if better else trial) if fine else None)
        own[j] = (sol, trial)
        if better:
            sol = trial
            u_rho = _u_rho(pb, sol)
            decided = {}  # the decisions so far were at the solution left behind
    # the decisions at the kept solution: those taken after the last change, the others again
    final = tuple(decided.get(j) or triage(pb, sol, j, float(u_rho[j])) for j in range(pb.c))
    refits = tuple((j, t) for j, (at, t) in sorted(own.items()) if at is sol)
    return MirrorSearch(sol, tuple(tried), tuple(alts), final, refits)


def _candidates(
    pb: FullProblem, sol, s2, alternatives, cov_free, p_hat, rho_hat
) -> dict[int, tuple[float, Any]]:
    """Return per beam the lowest minimum of the search with that beam's rho of the other sign."""
    u_pub = np.sqrt(np.clip(np.diag(cov_free), 0.0, None))
    u_pub[u_pub == 0] = 1.0
    best: dict[int, tuple[float, Any]] = {}
    for alt in alternatives:
        if alt is None or not np.isfinite(alt.cost):
            continue
        p_alt = pb.public(alt.x)
        if bool(np.max(np.abs(p_alt - p_hat) / u_pub) < 0.1):
            continue
        d_alt = max(2.0 * (float(alt.cost) - float(sol.cost)) / s2, 0.0)
        for j in range(pb.c):
            if (
                np.sign(p_alt[pb.i_rho0 + j]) != np.sign(rho_hat[j])
                and d_alt < best.get(j, (np.inf, None))[0]
            ):
                best[j] = (d_alt, alt)
    return best


def _flagged_mirror(
    pb: FullProblem, sol, s2, trial, p_alt, cov_free, p_hat, j: int, common: dict
) -> BeamMirror:
    """Return the check of beam ``j`` carried as two weighted solutions (the kept one and ``trial``)."""
    d_chi2 = max(2.0 * (float(trial.cost) - float(sol.cost)) / s2, 0.0)
    fr = fit_result(
        [f"p{i}" for i in range(trial.x.size)],
        trial.x,
        np.asarray(trial.fun),
        np.asarray(trial.jac),
        success=True,
    )
    cov_alt = pb.params_of(pb.params_of(pb.public_cov(trial.x, fr.cov)).T)
    w_alt = float(np.exp(-0.5 * d_chi2))
    w_main = 1.0 / (1.0 + w_alt)
    pa, pm = pb.params_of(p_alt), pb.params_of(p_hat)
    # the beam's direction uncertainty (a gauge-fixed beta: the smallest of the other beams')
    u_b = np.sqrt(np.clip(np.diag(pb.params_of(pb.params_of(cov_free).T))[0::3], 0.0, None))
    u_beta = float(u_b[j]) if u_b[j] > 0 else float(np.min(u_b[u_b > 0], initial=np.inf))
    lo, hi = valid_bore_radius_range_mm(pb.R_mm, pm, pa, u_beta)
    return BeamMirror(
        **common,
        refit_delta_chi2=d_chi2,
        resolved=False,
        weight_main=w_main,
        p_wrong_sign=1.0 - w_main,
        alternative=MirrorSolution(
            tuple(float(v) for v in pa),
            tuple(tuple(float(v) for v in row) for row in cov_alt),
            d_chi2,
            1.0 - w_main,
        ),
        rho_alt_mm=float(pa[3 * j + 1]),
        valid_bore_diameter_mm=(2.0 * lo, 2.0 * hi),
    )


def mirror_checks(pb: FullProblem, sol, s2: float, search: MirrorSearch, cov_free, nuis) -> list[BeamMirror]:
    """One :class:`borescan.mirror.BeamMirror` per channel.

    Every minimum of the mirror search (from any beam's start; delta chi^2 = 2 (cost - cost_kept) / s^2)
    is a candidate mirror of each beam whose rho it has of the other sign; the lowest is the beam's. No
    mirror: no such minimum (the refits returned to the kept solution, within 0.1 u of every parameter,
    or kept the sign, or the beam was not refitted: :func:`triage`). A beam whose mirror lies within
    :data:`borescan.mirror.RESOLVED_DCHI2` is refitted once more from the final solution's mirror (the
    search's own refit from there when it has one); that refit, or the candidate where it is lower, is its
    second solution, with covariance from its own Jacobian. Weights exp(-delta chi^2 / 2) over the kept
    solution and this beam's mirror.
    """
    p_hat = pb.public(sol.x)
    rho_hat = pb.unpack(sol.x)[0].rho_mm
    best = _candidates(pb, sol, s2, search.alternatives, cov_free, p_hat, rho_hat)
    decided = search.triage if search.sol is sol else ()
    own = dict(search.own) if search.sol is sol else {}
    out = []
    for j, ch in enumerate(pb.channels):
        n_k, e_k, sig_k = _depth_inputs(pb, sol.x, j)
        rho = float(rho_hat[j])
        sigma = float(np.sqrt(np.sum(n_k * sig_k**2) / max(n_k.sum(), 1)))
        tri = decided[j] if decided else None
        common = dict(
            channel=int(ch),
            rho_mm=rho,
            offset_mm=float(np.max(e_k)),
            mirror_possible=mirror_exists(rho, e_k),
            predicted_delta_chi2=predicted_depth(n_k, e_k, rho, sig_k, pb.R_mm),
            offset_to_resolve_mm=offset_to_resolve_mm(pb.R_mm, sigma, float(n_k.sum()), rho),
            refitted=tri is None or tri.refit,
            start_delta_chi2=None if tri is None else tri.start_delta_chi2,
        )
        d_chi2, cand = best.get(j, (None, None))
        if d_chi2 is not None and d_chi2 < RESOLVED_DCHI2:
            common["refitted"] = True
            trial = own.get(j)
            if trial is None:
                with np.errstate(all="ignore"):
                    trial = solve(pb, mirror_start(pb, sol.x, j))
            i = pb.i_rho0 + j
            ok = (
                bool(trial.success)
                and np.isfinite(trial.cost)
                and np.sign(pb.public(trial.x)[i]) != np.sign(rho)
            )
            if not ok or cand.cost < trial.cost:
                trial = cand  # another start found this beam's other sign lower than its own refit
            p_alt = pb.public(trial.x)
            if np.sign(p_alt[i]) != np.sign(rho):
                out.append(_flagged_mirror(pb, sol, s2, trial, p_alt, cov_free, p_hat, j, common))
                continue
            d_chi2 = None
        out.append(
            BeamMirror(**common, refit_delta_chi2=d_chi2, resolved=True, weight_main=1.0, p_wrong_sign=0.0)
        )
    return _with_range_limit(pb, sol.x, out)


def _with_range_limit(pb: FullProblem, x: np.ndarray, checks: list[BeamMirror]) -> list[BeamMirror]:
    """Give each beam whose sign is not determined the largest offset the sensors' range allows.

    :func:`borescan.plan.largest_offset_mm` of the fitted beams with the sensors' ranges on this gauge,
    and the samples per channel that would resolve the beam at that offset
    (:func:`borescan.plan.samples_to_resolve`): what :meth:`borescan.mirror.BeamMirror.fix` advises.
    Computed only where some sign is not determined.
    """
    if all(m.sign_determined for m in checks):
        return checks
    from borescan.plan import DeviceDesign, largest_offset_mm, samples_to_resolve

    beams = pb.unpack(x)[0]
    sig = np.asarray(pb.floors, float).max(axis=0)
    limit = largest_offset_mm(
        DeviceDesign(beams, tuple(float(v) for v in sig), tuple(float(v) for v in pb.range_mm)), pb.R_mm
    )
    out = []
    for j, m in enumerate(checks):
        if m.sign_determined:
            out.append(m)
            continue
        n_k = np.array([int(mk[:, j].sum()) for mk in pb.masks])
        sigma = float(np.sqrt(np.sum(n_k * np.asarray(pb.floors, float)[:, j] ** 2) / max(n_k.sum(), 1)))
        n_fix = samples_to_resolve(pb.R_mm, sigma, limit, m.rho_mm) if limit > 0 else float("inf")
        out.append(replace(m, offset_limit_mm=float(limit), samples_to_resolve=float(n_fix)))
    return out
