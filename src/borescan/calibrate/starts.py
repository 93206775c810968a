"""The full-data calibration's problem built from its inputs, and starting values that cannot miss.

:func:`build_problem` checks the inputs (one entry per scan, shapes, enough readings) and gathers
what every step of the fit needs into a :class:`~borescan.calibrate.problem.FullProblem`.
Starting values (:func:`scan_starts`): the speed scale from the readings' spectrum over
``rule.speed_scale_range`` refined on the first-harmonic misfit
(:func:`borescan.kinematics.estimate_speed_scale`); offset and levels from the linear first
harmonic (:func:`borescan.physics.tri.first_harmonic_start`); the beams from the design
(:func:`start_vector`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from borescan.calibrate.problem import (
    FullProblem,
    ScanNuisance,
    channel_offsets,
    nuisance_columns,
    per_scan_xy,
)
from borescan.calibrate.result import AcceptanceRule, CalibrationError
from borescan.geometry import Beams, centred_beam_length_mm
from borescan.kinematics import AngleModel, angle_model_from_arrays, estimate_speed_scale
from borescan.noise import noise_floor_mm
from borescan.physics.tri import first_harmonic_start

__all__ = ["ScanStarts", "FitInputs", "build_problem", "scan_starts", "start_vector"]


@dataclass(frozen=True)
class ScanStarts:
    """Starting values of the scans' nuisance parameters and the channels' mean levels.

    Attributes
    ----------
    nuisance : per scan offset [mm], phase [rad] and speed scale [-].
    levels_mm : the first harmonic's constant per channel, averaged over the scans (c,) [mm].
    """

    nuisance: tuple[ScanNuisance, ...]
    levels_mm: np.ndarray


@dataclass(frozen=True)
class FitInputs:
    """The data of a full-data calibration, per scan (checked by :func:`build_problem`).

    Attributes
    ----------
    ts, ys : per scan sample times (n_k,) [s] and readings (n_k, c), NaN missing [mm].
    scan_ids, channels : the scans; the channels (ascending).
    angle_models : per scan :class:`~borescan.kinematics.AngleModel`.
    phases0_rad : per scan the phase held where it is not free [rad].
    priors : per scan the reported offset S - C (2,) or None [mm].
    range_mm : sensor range per channel [mm]; tau_s : channel time offsets (c,) or None [s].
    """

    ts: tuple[np.ndarray, ...]
    ys: tuple[np.ndarray, ...]
    scan_ids: tuple[str, ...]
    channels: tuple[int, ...]
    angle_models: tuple[AngleModel, ...]
    phases0_rad: tuple[float, ...]
    priors: tuple[np.ndarray | None, ...]
    range_mm: np.ndarray
    tau_s: np.ndarray | None


def fit_inputs(
    t_s,
    readings_mm,
    channels,
    nominal: Beams,
    *,
    scan_ids,
    angle_models,
    rpm,
    direction,
    phase0_rad,
    spindle_xy_mm,
    center_xy_mm,
    range_mm,
    channel_time_offsets_s,
) -> FitInputs:
    """Check the arguments of :func:`~borescan.calibrate.full_fit.fit_full_calibration`, per scan."""
    multi = isinstance(t_s, (list, tuple))
    ts = [np.asarray(x, dtype=float) for x in (t_s if multi else [t_s])]
    ys = [np.asarray(x, dtype=float) for x in (readings_mm if multi else [readings_mm])]
    K = len(ts)
    scan_ids = list(scan_ids) if scan_ids is not None else [f"scan{k + 1}" for k in range(K)]
    if len(scan_ids) != K or len(ys) != K:
        raise ValueError("t_s, readings_mm and scan_ids must have one entry per scan")
    channels = tuple(int(c) for c in channels)
    if tuple(nominal.channels) != channels:
        raise ValueError(f"nominal beams are for channels {nominal.channels}, readings for {channels}")
    c = len(channels)
    for k in range(K):
        if ys[k].shape != (ts[k].size, c):
            raise ValueError(f"{scan_ids[k]}: readings shape {ys[k].shape}, expected ({ts[k].size}, {c})")
    if angle_models is None:
        rpms = np.broadcast_to(np.asarray(rpm, float), (K,))
        angle_models = [angle_model_from_arrays(rpm_nominal=float(r), direction=direction) for r in rpms]
    angle_models = list(angle_models)
    if len(angle_models) != K:
        raise ValueError("angle_models needs one entry per scan")
    Ss, Cs = per_scan_xy(spindle_xy_mm, K), per_scan_xy(center_xy_mm, K)
    return FitInputs(
        ts=tuple(ts),
        ys=tuple(ys),
        scan_ids=tuple(scan_ids),
        channels=channels,
        angle_models=tuple(angle_models),
        phases0_rad=tuple(float(x) for x in np.broadcast_to(np.asarray(phase0_rad, float), (K,))),
        priors=tuple(None if (Ss[k] is None or Cs[k] is None) else Ss[k] - Cs[k] for k in range(K)),
        range_mm=np.broadcast_to(np.asarray(10.0 if range_mm is None else range_mm, float), (c,)),
        tau_s=channel_offsets(channel_time_offsets_s, c),
    )


def scan_starts(
    inp: FitInputs,
    commanded_rad: Sequence[np.ndarray],
    masks: Sequence[np.ndarray],
    free_phase: Sequence[bool],
    nominal: Beams,
    rule: AcceptanceRule,
) -> ScanStarts:
    """Return per scan the speed scale, offset and phase to start from, and the mean levels.

    A commanded angle's speed scale from the readings' spectrum; the offset from the first harmonic,
    or the reported one where there is a prior (which then sets a free phase); a phase held at
    ``phase0`` turns the first harmonic's offset, which was fitted at phase 0.
    """
    K, c = len(inp.ts), len(inp.channels)
    nuis, kconst = [], np.zeros(c)
    for k, am in enumerate(inp.angle_models):
        Phi, prior = commanded_rad[k], inp.priors[k]
        g = 1.0
        if am.fits_speed_and_phase:
            try:
                g = estimate_speed_scale(Phi, inp.ys[k], scale_range=rule.speed_scale_range)
            except ValueError as exc:
                raise CalibrationError(
                    [inp.scan_ids[k]], f"no rotation found in the readings: {exc}"
                ) from exc
        off, kc, _ = first_harmonic_start(
            g * Phi if am.fits_speed_and_phase else Phi, inp.ys[k], masks[k], nominal.beta_rad
        )
        ph = inp.phases0_rad[k] if am.fits_speed_and_phase else 0.0
        if prior is not None:
            if free_phase[k]:
                ph = float(np.arctan2(prior[1], prior[0]) - np.arctan2(off[1], off[0]))
            off = prior
        elif am.fits_speed_and_phase:
            cph, sph = np.cos(ph), np.sin(ph)
            off = np.array([cph * off[0] - sph * off[1], sph * off[0] + cph * off[1]])
        nuis.append(ScanNuisance(np.asarray(off, float), ph, g))
        kconst += kc / K
    return ScanStarts(tuple(nuis), kconst)


def build_problem(
    inp: FitInputs, nominal: Beams, R_mm: float, rule: AcceptanceRule, max_nfev: int, cond_max: float
) -> tuple[FullProblem, ScanStarts]:
    """Return the problem of a full-data calibration and its starts.

    Raises ``CalibrationError`` when there are no more readings and prior rows than parameters.
    """
    K, c = len(inp.ts), len(inp.channels)
    masks = [np.isfinite(y) for y in inp.ys]
    n_obs = int(sum(m.sum() for m in masks))
    Phis = [am.commanded_rad(t) for am, t in zip(inp.angle_models, inp.ts)]
    tau_c = inp.tau_s
    # the angle each reading belongs to: (n, 1) for every channel, (n, c) with carried channel delays
    Phis_c = [
        P[:, None] if tau_c is None else am.commanded_rad(t[:, None] - tau_c[None, :])
        for P, am, t in zip(Phis, inp.angle_models, inp.ts)
    ]
    commanded = [am.fits_speed_and_phase for am in inp.angle_models]
    free_phase = [commanded[k] and inp.priors[k] is not None for k in range(K)]
    absolute = any(
        am.source == "encoder" and inp.priors[k] is not None for k, am in enumerate(inp.angle_models)
    )
    ch0_free = int(absolute)
    cols, n_params = nuisance_columns(3 * c - 1 + ch0_free, free_phase, commanded)
    n_prior = 2 * sum(p is not None for p in inp.priors)
    if n_obs + n_prior <= n_params:
        raise CalibrationError(inp.scan_ids, f"{n_obs} valid samples for {n_params} parameters")
    # noise floor of the readings themselves (model-free), per scan and channel
    floors = np.array([noise_floor_mm(y, order=4) for y in inp.ys])  # (K, c)
    sigma = float(np.sqrt(np.mean(floors**2))) if np.all(np.isfinite(floors)) else 0.0
    # the machine's stated accuracy is a half-width (rectangular, GUM 4.3.7: u = a / sqrt(3)) on each of
    # the centre and the spindle position, so o = S - C has u = a sqrt(2/3) per coordinate
    prior_w = (sigma if sigma > 0 else 1e-3) / (rule.position_accuracy_mm * np.sqrt(2.0 / 3.0))
    starts = scan_starts(inp, Phis, masks, free_phase, nominal, rule)
    pb = FullProblem(
        scan_ids=inp.scan_ids,
        channels=inp.channels,
        R_mm=float(R_mm),
        ys=inp.ys,
        masks=tuple(masks),
        angle_models=inp.angle_models,
        commanded_rad=tuple(Phis_c),
        commanded=tuple(commanded),
        free_phase=tuple(free_phase),
        priors=inp.priors,
        prior_w=float(prior_w),
        floors=floors,
        sigma=sigma,
        range_mm=inp.range_mm,
        tau_s=tau_c,
        absolute=absolute,
        beta1_fixed_rad=float(nominal.beta_rad[0]),
        phase_held_rad=tuple(nu.phase_rad for nu in starts.nuisance),
        cols=cols,
        n_params=n_params,
        rule=rule,
        max_nfev=max_nfev,
        cond_max=cond_max,
    )
    return pb, starts


def start_vector(pb: FullProblem, nominal: Beams, starts: ScanStarts) -> np.ndarray:
    """Return the internal start: the design's beams at the mean levels, the scans' starts.

    The mirror solutions (rho_c -> -rho_c at fixed psi and g) keep the first harmonic and the mean
    level, so each beam has two minima of nearly equal cost that only the second harmonic's phase
    tells apart (:mod:`borescan.calibrate.mirror_search`).
    """
    d_b0 = centred_beam_length_mm(nominal.rho_mm, pb.R_mm) - starts.levels_mm
    beams = Beams(pb.channels, nominal.beta_rad.copy(), nominal.rho_mm.copy(), d_b0)
    return pb.pack(beams, starts.nuisance)
