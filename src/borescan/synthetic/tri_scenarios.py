"""Three-sensor scans drawn over the contract: calibration spindle scans, rotating measurements, static sets.

The ranges are :data:`borescan.synthetic.contract.TRI_CONTRACT` and
:data:`~borescan.synthetic.contract.STATIC_CONTRACT` (module doc there).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, replace

import numpy as np
import polars as pl

from borescan.geometry import Beams
from borescan.synthetic import simulate
from borescan.synthetic.contract import (
    STATIC_CONTRACT,
    TRI_CONTRACT,
    artifact_of,
    draw_beam_directions,
    draw_speed_profile,
    reading_span_mm,
)
from borescan.synthetic.scenes import TriScene

__all__ = ["draw_tri_calibration", "draw_tri_measurement", "draw_tri_static"]


@dataclass(frozen=True)
class _RingDraw:
    """The drawn bore, spindle axis, beams and sensor ranges of a calibration scan."""

    radius_mm: float
    center_xy_mm: np.ndarray
    spindle_offset_mm: float
    offset_xy_mm: np.ndarray
    beams: Beams
    range_mm: np.ndarray
    out_of_range: dict | None

    @property
    def spindle_xy_mm(self) -> np.ndarray:
        """The spindle axis S = C + o [mm]."""
        return self.center_xy_mm + self.offset_xy_mm


@dataclass(frozen=True)
class _MotionDraw:
    """The drawn kinematics and noise of a calibration scan."""

    n_rev: int
    spindle_rate_hz: float
    speed_change: bool
    speed: dict
    encoder: bool
    direction: str
    phase_rad: float
    noise_mm: float


@dataclass(frozen=True)
class _ReportDraw:
    """What the machine reports of a calibration scan: positions (when known) and the design beams."""

    position_known: bool
    spindle_error_xy_mm: np.ndarray
    center_error_xy_mm: np.ndarray
    nominal: Beams


def _draw_ring(rng: np.random.Generator, contract: dict, channels: tuple[int, ...]) -> _RingDraw:
    """Bore, spindle axis, beams and sensor ranges (the readings in range but for one channel in ~30 %)."""
    c = len(channels)
    R = float(rng.uniform(*contract["bore_radius_mm"]))
    C = rng.uniform(*contract["center_xy_mm"], 2)
    ecc = float(rng.uniform(*contract["spindle_offset_mm"]))
    ecc_dir = float(rng.uniform(0.0, 2 * math.pi))
    o = ecc * np.array([math.cos(ecc_dir), math.sin(ecc_dir)])
    beta = draw_beam_directions(rng, c, contract["min_beam_separation_rad"])
    rho = rng.uniform(-contract["rho_max_mm"], contract["rho_max_mm"], c)
    s = reading_span_mm(beta, rho, o, R)
    s_min, s_max = s.min(axis=0), s.max(axis=0)
    span = s_max - s_min
    m = contract["range_margin_mm"]
    r_lo, r_hi = contract["range_mm"]
    range_mm = np.array([rng.uniform(max(r_lo, sp + 2 * m), r_hi) for sp in span])
    d_b = np.array([rng.uniform(s_max[j] - range_mm[j] + m, s_min[j] - m) for j in range(c)])
    out_of_range = None
    if rng.random() < contract["p_out_of_range"]:
        j = int(rng.integers(0, c))
        q = float(rng.uniform(*contract["out_of_range_fraction"]))
        side = "low" if rng.random() < 0.5 else "high"
        # v < 0 where s < d_b (low); v > range where s > d_b + range (high)
        d_b[j] = np.quantile(s[:, j], q) if side == "low" else np.quantile(s[:, j], 1.0 - q) - range_mm[j]
        out_of_range = {"channel": channels[j], "side": side, "fraction_per_rev": q}
    return _RingDraw(R, C, ecc, o, Beams(channels, beta, rho, d_b), range_mm, out_of_range)


def _draw_motion(rng: np.random.Generator, contract: dict) -> _MotionDraw:
    """Revolutions, spindle stream rate, speed profile, encoder, direction, phase and noise."""
    n_rev = int(rng.integers(contract["n_rev"][0], contract["n_rev"][1] + 1))
    spindle_rate_hz = float(rng.uniform(*contract["spindle_rate_hz"]))
    change = bool(rng.random() < contract["p_speed_change"])
    speed = draw_speed_profile(
        rng, change=change, n_rev=n_rev, spindle_rate_hz=spindle_rate_hz, contract=contract
    )
    encoder = bool(rng.random() < contract["p_encoder"])
    direction = "ccw" if rng.random() < 0.5 else "cw"
    phase = float(rng.uniform(0.0, 2 * math.pi))
    noise_mm = float(rng.uniform(*contract["noise_mm"]))
    return _MotionDraw(n_rev, spindle_rate_hz, change, speed, encoder, direction, phase, noise_mm)


def _draw_report(rng: np.random.Generator, contract: dict, beams: Beams) -> _ReportDraw:
    """Whether the positions are known, their errors, and the design beams (the truth perturbed)."""
    c = len(beams.channels)
    known = bool(rng.random() < contract["p_position_known"])
    e = contract["position_error_mm"]
    err_S = rng.uniform(-e, e, 2)
    err_C = rng.uniform(-e, e, 2)
    nominal = Beams(
        beams.channels,
        beams.beta_rad + rng.uniform(-contract["nominal_beta_rad"], contract["nominal_beta_rad"], c),
        beams.rho_mm + rng.uniform(-contract["nominal_rho_mm"], contract["nominal_rho_mm"], c),
        beams.d_b_mm + rng.uniform(-contract["nominal_d_b_mm"], contract["nominal_d_b_mm"], c),
    )
    return _ReportDraw(known, err_S, err_C, nominal)


def _ring_gauge(radius_mm: float, night: str, contract: dict) -> dict:
    """Return the ring gauge of a calibration scan: certified diameter 2 R, u from the contract, k = 2.

    Its nominal is its size to the micrometre, as a ring gauge's is (the spec's example): a nominal
    rounded to the millimetre lay up to 0.5 mm from the certificate, and ingest set such a scan aside
    as a likely typo (``plausibility.certified_vs_nominal_max_mm``).
    """
    d_nom = round(2 * radius_mm)
    return {
        "id": f"RG-{d_nom}",
        "type": "ring_gauge",
        "nominal_diameter_mm": round(2 * radius_mm, 3),
        "certified_diameter_mm": 2 * radius_mm,
        "u_diameter_mm": contract["gauge_u_diameter_mm"],
        "k": 2,
        "certificate": f"RG-{d_nom}/{night[:4]}/{2 * radius_mm:.6f}",
        "cte_per_k": contract["cte_per_k"],
    }


def _as_reported(sim, rng: np.random.Generator, null_fraction: float, rep: _ReportDraw, S_rep: np.ndarray):
    """Return the scan with sporadic nulls and the reported positions: (meta, lds, spindle, null mask)."""
    vals = sim.lds["value_mm"].to_numpy().astype(float, copy=True)
    null_mask = rng.random(vals.size) < null_fraction
    vals[null_mask] = np.nan
    lds = sim.lds.with_columns(pl.Series("value_mm", vals, dtype=pl.Float64, nan_to_null=True))
    # reported positions: the spindle stream and scan.json carry what the machine reports
    spindle = sim.spindle.with_columns(
        pl.lit(float(S_rep[0]), dtype=pl.Float64).alias("x_mm"),
        pl.lit(float(S_rep[1]), dtype=pl.Float64).alias("y_mm"),
    )
    meta = json.loads(json.dumps(sim.meta))
    if rep.position_known:
        meta["spindle"]["position"] = {"label": "P1", "x_mm": float(S_rep[0]), "y_mm": float(S_rep[1])}
    else:
        meta["spindle"].pop("position", None)
        meta.pop("center", None)
    return meta, lds, spindle, null_mask


def _calibration_truth(
    ring: _RingDraw, mo: _MotionDraw, rep: _ReportDraw, contract: dict, extra: dict
) -> dict:
    """``truth["contract"]`` of a calibration scan (module doc of :mod:`borescan.synthetic.contract`)."""
    S, C = ring.spindle_xy_mm, ring.center_xy_mm
    S_rep, C_rep = S + rep.spindle_error_xy_mm, C + rep.center_error_xy_mm
    known = rep.position_known
    speed = mo.speed
    return {
        "generator": "borescan.synthetic.tri_scenarios.draw_tri_calibration",
        "effect_free": extra["effect_free"],
        "beams": ring.beams.to_nominal(),
        "nominal_beams": rep.nominal.to_nominal(),
        "bore_radius_mm": ring.radius_mm,
        "center_xy_mm": [float(x) for x in C],
        "spindle_xy_mm": [float(x) for x in S],
        "offset_xy_mm": [float(x) for x in ring.offset_xy_mm],
        "spindle_offset_mm": ring.spindle_offset_mm,
        "position_known": known,
        "center_reported_xy_mm": [float(x) for x in C_rep] if known else None,
        "spindle_reported_xy_mm": [float(x) for x in S_rep],
        "center_error_xy_mm": [float(x) for x in rep.center_error_xy_mm],
        "spindle_error_xy_mm": [float(x) for x in rep.spindle_error_xy_mm],
        "position_error_mm": contract["position_error_mm"],
        "angle_source": "encoder" if mo.encoder else "profile",
        "encoder": mo.encoder,
        "direction": mo.direction,
        "phase_rad": mo.phase_rad,
        "rpm_nominal": speed["rpm_nominal"],
        "rpm_profile": [list(k) for k in speed["rpm_profile"]],
        "speed_change": mo.speed_change,
        "speed_factor": speed["speed_factor"],
        "ramp_start_s": speed["ramp_start_s"],
        "ramp_end_s": speed["ramp_end_s"],
        "samples_per_rev": speed["samples_per_rev"],
        "sample_rate_hz": speed["sample_rate_hz"],
        "spindle_rate_hz": mo.spindle_rate_hz,
        "n_rev": mo.n_rev,
        "n_samples": extra["n_samples"],
        "noise_mm": mo.noise_mm,
        "range_mm": [float(r) for r in ring.range_mm],
        "out_of_range": ring.out_of_range,
        "null_fraction": extra["null_fraction"],
        "n_sporadic_nulls": extra["n_sporadic_nulls"],
        "simulate_seed": extra["simulate_seed"],
    }


def draw_tri_calibration(
    rng: np.random.Generator,
    *,
    scan_id: str,
    night: str,
    effect_free: bool = True,
    device_id: str | None = None,
    contract: dict = TRI_CONTRACT,
    effect_scale: float = 1.0,
    extra_effects: tuple = (),
):
    """Return a ring-gauge calibration spindle scan drawn over the contract (module doc).

    Parameters
    ----------
    rng : numpy Generator; every random draw comes from it
    scan_id, night : scan id and night (``YYYY-MM-DD``)
    effect_free : False adds one named effect of the spec at a realistic magnitude
        (:func:`borescan.discrepancy.battery.random_effect`), listed in the truth
    device_id : device id in scan.json (default ``TRI-<scan_id>``, one device per scan: each
        scan has its own beams)
    contract : ranges, :data:`~borescan.synthetic.contract.TRI_CONTRACT` by default
    effect_scale : the effect's magnitude times this (:func:`borescan.discrepancy.battery.scale_effect`)
    extra_effects : effects added as they are (a pair's second effect, sized by the caller); the other
        draws are the same with or without them

    Returns
    -------
    borescan.synthetic.simulate.SimulatedScan
        ``truth["contract"]`` holds the draw (see :mod:`borescan.synthetic.contract`); ``truth["scene"]``
        the TriScene.
    """
    channels = (1, 2, 3)
    ring = _draw_ring(rng, contract, channels)
    mo = _draw_motion(rng, contract)
    rep = _draw_report(rng, contract, ring.beams)
    null_fraction = float(rng.uniform(*contract["null_fraction"]))
    effects = []
    if not effect_free:
        from borescan.discrepancy.battery import TRI_EFFECTS, random_effect, scale_effect

        name = str(rng.choice(TRI_EFFECTS))
        rev_hz, rate_hz = mo.speed["rpm_nominal"] / 60.0, mo.speed["sample_rate_hz"]
        effects = [scale_effect(random_effect(name, rng, channels, rev_hz, rate_hz), effect_scale)]
    sim_seed = int(rng.integers(0, 2**31 - 1))
    S, C = ring.spindle_xy_mm, ring.center_xy_mm
    C_rep = C + rep.center_error_xy_mm
    scene = TriScene(
        beams=ring.beams,
        bore_center_xy_mm=(float(C[0]), float(C[1])),
        bore_radius_20_mm=ring.radius_mm,
        spindle_xy_mm=(float(S[0]), float(S[1])),
        rpm_nominal=mo.speed["rpm_nominal"],
        phase_rad=mo.phase_rad,
        direction=mo.direction,
        sample_rate_hz=mo.speed["sample_rate_hz"],
        range_mm=tuple(float(r) for r in ring.range_mm),
        cte_per_k=contract["cte_per_k"],
        temperature_c=20.0,
        rpm_profile=mo.speed["rpm_profile"],
    )
    effects = [*effects, *extra_effects]  # a second effect, drawn and sized by the caller
    sim = simulate.simulate_tri_spindle(
        scene,
        scan_id=scan_id,
        night=night,
        kind="calibration",
        n_rev=float(mo.n_rev),
        effects=effects,
        noise_mm=mo.noise_mm,
        seed=sim_seed,
        device_id=device_id or f"TRI-{scan_id}"[:64],
        nominal_beams=rep.nominal,
        artifact=_ring_gauge(ring.radius_mm, night, contract),
        spindle_label="P1",
        center_xy_mm=(float(C_rep[0]), float(C_rep[1])) if rep.position_known else None,
        encoder=mo.encoder,
        spindle_rate_hz=mo.spindle_rate_hz,
    )
    meta, lds, spindle, null_mask = _as_reported(sim, rng, null_fraction, rep, S + rep.spindle_error_xy_mm)
    extra = {
        "effect_free": not effects,
        "n_samples": int(sim.truth["n_samples"]),
        "null_fraction": null_fraction,
        "n_sporadic_nulls": int(null_mask.sum()),
        "simulate_seed": sim_seed,
    }
    truth = dict(sim.truth)
    truth["contract"] = _calibration_truth(ring, mo, rep, contract, extra)
    return replace(sim, meta=meta, lds=lds, spindle=spindle, truth=truth)


def draw_tri_measurement(
    rng: np.random.Generator,
    *,
    scan_id: str,
    night: str,
    calibration,
    effect_free: bool = True,
    effect_scale: float = 1.0,
    extra_effects: tuple = (),
):
    """Return a rotating measurement of a part on the device of a calibration scan.

    The calibration scan is drawn by :func:`draw_tri_calibration` (``calibration``: that SimulatedScan): the
    same device id, beams, design geometry, spindle, kinematics, encoder and noise, a part whose diameter is
    the gauge's within +-0.1 mm (so the readings stay in range), a new phase; measured later that night.
    ``effect_free`` False adds one named effect as the calibration draw does.

    Returns
    -------
    borescan.synthetic.simulate.SimulatedScan
        ``truth["contract"]`` holds the draw.
    """
    from borescan.discrepancy.battery import TRI_EFFECTS, random_effect, scale_effect

    c = calibration.truth["contract"]
    R = float(c["bore_radius_mm"]) + float(rng.uniform(-0.05, 0.05))
    scene = replace(
        TriScene.from_dict(calibration.truth["scene"]),
        bore_radius_20_mm=R,
        phase_rad=float(rng.uniform(0.0, 2 * math.pi)),
    )
    effects = []
    if not effect_free:
        name = str(rng.choice(TRI_EFFECTS))
        effects = [
            scale_effect(
                random_effect(name, rng, (1, 2, 3), scene.rpm_nominal / 60.0, scene.sample_rate_hz),
                effect_scale,
            )
        ]
    art = {
        "id": f"P-{scan_id}"[:40],
        "type": "part",
        "nominal_diameter_mm": float(round(2 * R, 1)),
        "cte_per_k": TRI_CONTRACT["cte_per_k"],
    }
    effects = [*effects, *extra_effects]  # a second effect, drawn and sized by the caller
    sim = simulate.simulate_tri_spindle(
        scene,
        scan_id=scan_id,
        night=night,
        kind="measurement",
        n_rev=float(c["n_rev"]),
        effects=effects,
        noise_mm=float(c["noise_mm"]),
        seed=int(rng.integers(0, 2**31 - 1)),
        device_id=calibration.meta["device"]["id"],
        nominal_beams=Beams.from_nominal(c["nominal_beams"]),
        artifact=art,
        spindle_label="BORE",
        encoder=bool(c["encoder"]),
        spindle_rate_hz=float(c["spindle_rate_hz"]),
        started_at=simulate.started_at_plus(night, 23, 0),
    )
    truth = dict(sim.truth)
    truth["contract"] = {
        "generator": "borescan.synthetic.tri_scenarios.draw_tri_measurement",
        "effect_free": not effects,
        "calibration_scan_id": calibration.meta["scan_id"],
        "bore_radius_mm": R,
        "beams": c["beams"],
        "nominal_beams": c["nominal_beams"],
        "encoder": c["encoder"],
        "speed_change": c["speed_change"],
        "noise_mm": c["noise_mm"],
    }
    return replace(sim, truth=truth)


def draw_tri_static(
    rng: np.random.Generator,
    *,
    scan_id: str,
    night: str,
    beams: Beams | None = None,
    effect_free: bool = True,
    contract: dict = STATIC_CONTRACT,
    effect_scale: float = 1.0,
    extra_effects: tuple = (),
):
    """Return a static three-sensor set drawn over the contract.

    A ring gauge with a certified diameter (a verification) or a part with a nominal one (a measurement), 3-12
    device poses within 3 mm of the bore centre at random angles, 5-30 samples per pose, noise 1-5 um.
    ``beams`` (default: drawn as for :func:`draw_tri_calibration`) is the device; d_b and the ranges keep
    every reading inside its sensor's range.

    Returns
    -------
    borescan.synthetic.simulate.SimulatedScan
        ``truth["contract"]`` holds the draw (true diameter, poses, beams).
    """
    R = float(rng.uniform(*contract["bore_radius_mm"]))
    n_p = int(rng.integers(contract["n_poses"][0], contract["n_poses"][1] + 1))
    r = contract["device_offset_mm"] * np.sqrt(rng.uniform(0, 1, n_p))
    a = rng.uniform(0, 2 * math.pi, n_p)
    xy = np.stack([r * np.cos(a), r * np.sin(a)], -1)
    ang = rng.uniform(0, 2 * math.pi, n_p)
    if beams is None:
        beta = draw_beam_directions(rng, 3, TRI_CONTRACT["min_beam_separation_rad"])
        rho = rng.uniform(-TRI_CONTRACT["rho_max_mm"], TRI_CONTRACT["rho_max_mm"], 3)
    else:
        beta, rho = np.asarray(beams.beta_rad, float), np.asarray(beams.rho_mm, float)
    # distances from each beam's foot to the wall at every pose: the extreme offset bounds them
    s = np.concatenate([reading_span_mm(beta, rho, xy[p], R, n_phi=256) for p in range(n_p)])
    s_min, s_max = s.min(axis=0), s.max(axis=0)
    range_mm = np.array([max(10.0, float(hi - lo) + 1.0) for lo, hi in zip(s_min, s_max)])
    d_b = s_min - 0.5 * (range_mm - (s_max - s_min)) if beams is None else np.asarray(beams.d_b_mm, float)
    dev = Beams((1, 2, 3), beta, rho, d_b)
    noise = float(rng.uniform(*contract["noise_mm"]))
    kind = "ring_gauge" if rng.random() < contract["p_ring_gauge"] else "part"
    art = artifact_of(  # one gauge or part per scan: two gauges of one night never share an id
        kind,
        f"{'RG' if kind == 'ring_gauge' else 'P'}-{round(2 * R)}-{scan_id}"[:40],
        [2 * R],
        [0.0],
        TRI_CONTRACT["cte_per_k"],
    )
    effects = []
    if not effect_free:
        from borescan.discrepancy.battery import random_effect, scale_effect

        name = str(rng.choice(("sensor_offset", "sensor_gain", "sensor_nonlinearity", "sensor_drift")))
        effects = [scale_effect(random_effect(name, rng, (1, 2, 3), 1.0, 1000.0), effect_scale)]
    scene = TriScene(
        beams=dev,
        bore_center_xy_mm=(0.0, 0.0),
        bore_radius_20_mm=R,
        range_mm=tuple(float(x) for x in range_mm),
    )
    effects = [*effects, *extra_effects]  # a second effect, drawn and sized by the caller
    sim = simulate.simulate_tri_static(
        scene,
        xy,
        ang,
        scan_id=scan_id,
        night=night,
        kind="verification" if kind == "ring_gauge" else "measurement",
        samples_per_pose=int(
            rng.integers(contract["samples_per_pose"][0], contract["samples_per_pose"][1] + 1)
        ),
        effects=effects,
        noise_mm=noise,
        seed=int(rng.integers(0, 2**31 - 1)),
        device_id=f"TRI-{scan_id}"[:64],
        nominal_beams=dev,
        artifact=art,
    )
    meta = json.loads(json.dumps(sim.meta))
    for sensor in meta.get("sensors", []):  # the data sheet states the repeatability the scan has
        sensor["repeatability_mm"] = noise
    truth = dict(sim.truth)
    truth["contract"] = {
        "generator": "borescan.synthetic.tri_scenarios.draw_tri_static",
        "effect_free": not effects,
        "beams": dev.to_nominal(),
        "bore_radius_mm": R,
        "diameter_mm": 2 * R,
        "artifact": kind,
        "noise_mm": noise,
        "n_poses": n_p,
        "range_mm": [float(x) for x in range_mm],
    }
    return replace(sim, meta=meta, truth=truth)
