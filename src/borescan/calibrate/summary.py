"""What the full-data calibration states besides its parameters: minima, per-scan figures, acceptance.

Distinct minima from the mirror starts and dips along the rho profiles (:func:`distinct_minima`),
each scan's nuisance estimates and residual-to-noise ratios (:func:`scan_figures`), the acceptance
rule (:func:`acceptance_problems`) and the notes that explain the diagnostics (:data:`NOTES`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from borescan.calibrate.problem import FullProblem, ScanNuisance
from borescan.calibrate.profiles import ProfileResult
from borescan.calibrate.result import AcceptanceRule
from borescan.geometry import Beams, centred_beam_length_mm
from borescan.mirror import RESOLVED_DCHI2

__all__ = ["Minima", "distinct_minima", "scan_figures", "acceptance_problems", "NOTES"]


@dataclass(frozen=True)
class Minima:
    """Distinct minima besides the one kept, and the mirror search's log with each one's Delta chi^2."""

    minima: list[dict]
    tried: list[dict]


def distinct_minima(
    pb: FullProblem,
    cost: float,
    s2: float,
    tried: Sequence[dict],
    alternatives: Sequence,
    profiles: Sequence[ProfileResult],
    p_hat: np.ndarray,
    cov_free: np.ndarray,
) -> Minima:
    """Return the distinct minima (mirror starts, profile dips), Delta = 2 (cost - cost_kept) / s^2.

    Each says whether the profile of every rho it moves already spans it; they are reported, not added
    to the covariance: a mirror within RESOLVED_DCHI2 is the flagged beam's second solution
    (``diagnostics["mirror_check"]``), one further away weighs less than exp(-12.5).
    """
    minima, seen, log = [], [p_hat], []
    u_pub = np.sqrt(np.clip(np.diag(cov_free), 0.0, None))
    u_pub[u_pub == 0] = 1.0
    for entry, alt in zip(tried, alternatives):
        if alt is None:
            log.append(dict(entry))
            continue
        d_chi2 = 2.0 * (alt.cost - cost) / s2
        log.append(dict(entry, delta_ssr_over_s2=float(d_chi2), within_noise=bool(d_chi2 < 4.0)))
        p_alt = pb.public(alt.x)
        if any(np.max(np.abs(p_alt - q) / u_pub) < 0.1 for q in seen):
            continue
        seen.append(p_alt)
        src = f"mirror start of channel {entry['channel']}"
        minima.append((src, p_alt, d_chi2))
    out = [_spanned(pb, src, p, d, p_hat, u_pub, profiles) for src, p, d in minima]
    for prof in profiles:
        for dip in prof.info.get("profile_minima", []):
            out.append(
                {
                    "source": f"profile of rho of channel {prof.info['channel']}",
                    "rho_mm": dip["rho_mm"],
                    "delta_ssr_over_s2": dip["delta_ssr_over_s2"],
                }
            )
    return Minima(out, log)


def _spanned(pb: FullProblem, source, p_alt, d_chi2, p_hat, u_pub, profiles: Sequence[ProfileResult]) -> dict:
    """Return a mirror start's minimum, with whether its own channels' walked profiles span it.

    Spanned: every rho in which the minimum differs from the estimate (by more than 2 u) lies on its own
    channel's walked profile, whose spread the covariance holds already (a profile of another channel
    that merely contains this minimum's value of its own rho says nothing about it).
    """
    i_rho0 = pb.i_rho0
    moved = [j for j in range(pb.c) if abs(p_alt[i_rho0 + j] - p_hat[i_rho0 + j]) > 2.0 * u_pub[i_rho0 + j]]
    spanned = bool(moved) and all(
        (not profiles[j].info["linear"])
        and profiles[j].info["rho_range_mm"][0] <= p_alt[i_rho0 + j] <= profiles[j].info["rho_range_mm"][1]
        for j in moved
    )
    return {
        "source": source,
        "rho_mm": [float(x) for x in p_alt[i_rho0 : i_rho0 + pb.c]],
        "delta_ssr_over_s2": float(d_chi2),
        "spanned_by_profile": bool(spanned),
    }


def scan_figures(
    pb: FullProblem, r: np.ndarray, nuis: Sequence[ScanNuisance], cov_free: np.ndarray
) -> tuple[dict[str, dict], np.ndarray]:
    """Return per scan its nuisance estimates with u, residual rms and noise floors, and the ratios (K, c).

    ``r``: the residuals of the used readings, scan after scan.
    """
    nuisance = {}
    bounds = np.concatenate([[0], np.cumsum([int(m.sum()) for m in pb.masks])])
    ratios = np.zeros((pb.K, pb.c))
    for k, (nu, cl, am) in enumerate(zip(nuis, pb.cols, pb.angle_models)):
        res_k = np.full(pb.ys[k].shape, np.nan)
        res_k[pb.masks[k]] = r[bounds[k] : bounds[k + 1]]
        rms_ch = np.sqrt(np.nanmean(res_k**2, axis=0))
        with np.errstate(divide="ignore", invalid="ignore"):
            ratios[k] = np.where(pb.floors[k] > 0, rms_ch / pb.floors[k], np.inf)
        off = nu.offset_mm
        entry = {
            "offset_x_mm": float(off[0]),
            "offset_y_mm": float(off[1]),
            "oe_mm": float(np.hypot(*off)),
            "u_offset_x_mm": float(np.sqrt(cov_free[cl.ox, cl.ox])),
            "u_offset_y_mm": float(np.sqrt(cov_free[cl.oy, cl.oy])),
            "angle_source": am.source,
            "phase0_rad": float(nu.phase_rad),
            "phase_free": bool(pb.free_phase[k]),
            "speed_scale": float(nu.speed_scale),
            "u_speed_scale": float(np.sqrt(cov_free[cl.scale, cl.scale])) if cl.scale is not None else 0.0,
            "omega_rad_s": float(nu.speed_scale * am.mean_omega_rad_s()),
            "residual_rms_mm": float(np.sqrt(np.mean(r[bounds[k] : bounds[k + 1]] ** 2))),
            "noise_floor_mm": [float(f) for f in pb.floors[k]],
            "residual_to_noise": [float(x) for x in ratios[k]],
        }
        entry["u_omega_rad_s"] = float(abs(entry["u_speed_scale"] * am.mean_omega_rad_s()))
        entry["rpm"] = float(abs(entry["omega_rad_s"]) * 60.0 / (2.0 * np.pi))
        if cl.phase is not None:
            entry["u_phase0_rad"] = float(np.sqrt(cov_free[cl.phase, cl.phase]))
        nuisance[pb.scan_ids[k]] = entry
    return nuisance, ratios


def acceptance_problems(
    beams: Beams,
    nuis: Sequence[ScanNuisance],
    ratios: np.ndarray,
    scan_ids: Sequence[str],
    channels: Sequence[int],
    R_mm: float,
    range_arr: np.ndarray,
    rule: AcceptanceRule,
) -> list[str]:
    """Why a converged fit is not a calibration (empty when it is)."""
    out = []
    for k, sid in enumerate(scan_ids):
        for j, ch in enumerate(channels):
            if not ratios[k, j] <= rule.max_residual_to_noise:
                out.append(
                    f"{sid} channel {ch}: residual rms is {ratios[k, j]:.2f} times the readings' own "
                    "noise floor "
                    f"(limit {rule.max_residual_to_noise:g}): the model misses an effect"
                )
    for j, ch in enumerate(channels):
        rho, d_b = float(beams.rho_mm[j]), float(beams.d_b_mm[j])
        if abs(rho) > rule.head_radius_mm:
            out.append(
                f"channel {ch}: |rho| = {abs(rho):.3f} mm exceeds the head radius {rule.head_radius_mm:g} mm"
            )
            continue
        oe = max(float(np.hypot(*n.offset_mm)) for n in nuis)
        s0 = float(centred_beam_length_mm(rho, R_mm))
        lo, hi = s0 - oe - range_arr[j], s0 + oe
        if not (lo - 0.01 <= d_b <= hi + 0.01):
            out.append(
                f"channel {ch}: d_b = {d_b:.4f} mm outside [{lo:.4f}, {hi:.4f}] mm, what a gauge of radius "
                f"{R_mm:.4f} mm with offset {oe:.4f} mm and a {range_arr[j]:g} mm sensor allow"
            )
    return out


#: the notes of the calibration's diagnostics, each next to what it explains
NOTES = {
    "g_note": "g = d_b + rho^2 / (2 R): the mean level the data fix best (R the gauge radius)",
    "mirror_note": (
        "per beam: the mirror's depth predicted by N e^4 "
        "rho^2 / (2 sigma^2 R^4) and refitted from -rho; "
        "resolved (no mirror, or delta chi^2 >= "
        f"{RESOLVED_DCHI2:g}): one value, u from its own curvature; "
        "flagged: two solutions with covariance, delta chi^2 "
        "and weight, the probability of the wrong sign, "
        "the bore range where the calibration may be used "
        "and the spindle offset that would resolve it"
    ),
    "minima_note": (
        "distinct minima of SSR + prior besides the one kept "
        "(mirror starts, dips along the rho profiles), "
        "delta_ssr_over_s2 = 2 (cost - cost_kept) / s^2; "
        "below 4 the data cannot reject it (ambiguous); "
        "not in the covariance: a beam whose rho sign such "
        "a minimum flips is flagged in mirror_check and "
        "carried as two weighted solutions"
    ),
    "rho_profile_note": (
        "the cost profiled along rho (every other parameter refitted) where the mirror check needs it: "
        "a beam whose mirror was refitted, found no separate minimum within "
        f"{RESOLVED_DCHI2:g} chi^2 and is predicted within it; linear when at rho +- 2 u "
        "it rises by 4 +- 1 s^2 and bends no parameter by more than u / 2; otherwise the "
        "likelihood-weighted "
        "spread of every parameter along the profile enters the covariance"
    ),
    "not_profiled": (
        "not profiled: its sign is resolved (no mirror, or the mirror predicted or refitted at least "
        f"{RESOLVED_DCHI2:g} chi^2 above) or flagged (two solutions): one value, u from its own curvature"
    ),
    "weak_rho_note": (
        "|rho| < 2 u(rho): rho is not distinguished from 0; d_b = g - rho^2/(2R) is then far from "
        "linear in the data, and u(d_b) carries the second-order term 3 u(rho)^4 / (4 R^2)"
    ),
    "censoring_note": (
        "valid readings whose fitted value lies within k_sigma noise sigmas of a sensor "
        "range limit "
        "(0 or range_mm) or beyond it, per scan and channel: the sensor nulls a reading on "
        "its noisy "
        "value, so near a limit the valid ones are a truncated (biased) sample; not fitted"
    ),
}
