"""Scan scenarios drawn over the whole contract (``shared/spec``), not only the demo's geometry.

The digital twin (:mod:`borescan.simulate`) draws Yang's device at 60 rpm by default. The
functions here draw the scene of a scan at random over everything the raw-scan format and the
geometry page allow, so that the solvers are tested where independent generators will take them.
All randomness comes from the :class:`numpy.random.Generator` passed in; the functions are
otherwise pure (no global state, no I/O except :func:`write_battery`).

Three-sensor ring-gauge calibration scans (:func:`draw_tri_calibration`), ranges in
:data:`TRI_CONTRACT`:

- ring gauge: bore radius R20 75-200 mm, certified diameter 2 R20 (u 1.5 um, k = 2), CTE
  11.5e-6 /K at 20 degC (no thermal change unless an effect says so); centre C anywhere in
  +-300 mm of the machine frame;
- spindle axis S at |S - C| 0.5-3 mm in a random direction;
- three beams at random directions, at least 20 deg apart, |rho| <= 15 mm, d_b such that the
  readings stay inside the sensor range (4-10 mm per channel) over the whole revolution, except
  in ~30 % of the scans where one channel leaves its range (below 0 or above the range: null)
  for 5-30 % of every revolution;
- noise sigma 1-5 um; 400-1000 samples per revolution; 20-120 revolutions; 20-120 rpm; ccw or
  cw; random phase;
- in ~40 % of the scans a speed change: constant speed, a ramp of 0.5-2 s to 0.4-0.9 or 1.1-1.6
  times the first speed, then constant; the ramp's knots lie on spindle clock ticks, so the rpm
  column integrated over the spindle clock is the profile exactly. Both speeds stay in 20-120
  rpm and 400-1000 samples per revolution;
- an encoder (``angle_rad``) in half of the scans, else a null encoder column (the angle is
  the integral of the ``rpm`` column); spindle stream rate 50-500 Hz;
- ~0.1-1 % sporadic nulls (set after simulation, before writing);
- ``center`` and ``spindle.position`` in scan.json in ~70 % of the scans, each coordinate off
  the truth by a uniform error within +-2 um (the machine's stated accuracy); the spindle
  stream's ``x_mm``/``y_mm`` carry the same reported position (what the machine reports);
- ``device.nominal`` beams: the truth perturbed by up to +-30 mrad (beta), +-1 mm (rho),
  +-1 mm (d_b): a design geometry, not the truth.

The truth of each scan (``truth["contract"]``) records everything an evaluation needs: the
true beams, R, S, C, the angle source, the noise, the reported positions and their errors, the
speed profile, the out-of-range channel and the nulls.

Static three-sensor sets (:func:`draw_tri_static`, :data:`STATIC_CONTRACT`): a ring gauge with
a certified diameter (verification) or a part with a nominal one (measurement), bore radius
75-200 mm, 3-12 device poses within 3 mm of the centre at random angles, 5-30 samples per pose,
noise 1-5 um (the sensors' stated repeatability), beams drawn as above or given.

Rod scans (:func:`draw_rod_scan`, :data:`ROD_CONTRACT`): 2-3 coaxial holes of 100-200 mm, 8-40
poses at random angles, 5-30 readings per pose, noise 2-20 um, eccentricity up to 2.5 mm,
deflection up to 1 deg, real layer geometry (phi, d, gamma); half in ring-gauge sets with
certified diameters (verification), half in parts with nominal ones (measurement).

:func:`write_battery` writes a battery of such scans deterministically (``kinds``): scan i is drawn from
its own child seed ``SeedSequence(seed, spawn_key=(i,))``, so adding scans never changes the
earlier ones. Command: ``borescan simulate contract --n N --seed S --out DIR``.
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import replace
from pathlib import Path
from typing import Callable, Sequence

import numpy as np
import polars as pl

from borescan.geometry import Beams

__all__ = [
    "TRI_CONTRACT",
    "draw_beam_directions",
    "draw_speed_profile",
    "spindle_tick_s",
    "reading_span_mm",
    "draw_tri_calibration",
    "draw_tri_measurement",
    "STATIC_CONTRACT",
    "ROD_CONTRACT",
    "draw_tri_static",
    "draw_rod_geometry",
    "draw_rod_scan",
    "battery_rng",
    "BATTERY_KINDS",
    "battery_scan_id",
    "write_battery",
]

#: Ranges of the three-sensor calibration scenarios (units in the names; probabilities as shares).
TRI_CONTRACT: dict = {
    "bore_radius_mm": (75.0, 200.0),
    "center_xy_mm": (-300.0, 300.0),
    "spindle_offset_mm": (0.5, 3.0),
    "rho_max_mm": 15.0,
    "min_beam_separation_rad": math.radians(20.0),
    "range_mm": (4.0, 10.0),
    "range_margin_mm": 0.2,
    "noise_mm": (0.001, 0.005),
    "samples_per_rev": (400, 1000),
    "n_rev": (20, 120),
    "rpm": (20.0, 120.0),
    "p_speed_change": 0.4,
    "ramp_s": (0.5, 2.0),
    "speed_factor": ((0.4, 0.9), (1.1, 1.6)),
    "ramp_start_fraction": (0.2, 0.6),
    "p_encoder": 0.5,
    "spindle_rate_hz": (50.0, 500.0),
    "p_out_of_range": 0.3,
    "out_of_range_fraction": (0.05, 0.3),
    "null_fraction": (0.001, 0.01),
    "p_position_known": 0.7,
    "position_error_mm": 0.002,
    "nominal_beta_rad": 0.030,
    "nominal_rho_mm": 1.0,
    "nominal_d_b_mm": 1.0,
    "gauge_u_diameter_mm": 0.0015,
    "cte_per_k": 11.5e-6,
}


# --------------------------------------------------------------------------- building blocks


def draw_beam_directions(
    rng: np.random.Generator,
    n_beams: int = 3,
    min_separation_rad: float = TRI_CONTRACT["min_beam_separation_rad"],
) -> np.ndarray:
    """Beam directions beta, uniform on the circle, every pair at least ``min_separation_rad`` apart.

    Rejection sampling of independent uniform directions (the accepted set is uniform over the
    allowed configurations); the channel order is the draw order.

    Parameters
    ----------
    rng : numpy Generator
    n_beams : number of beams
    min_separation_rad : smallest circular distance between two beams [rad]

    Returns
    -------
    ndarray (n_beams,) in [0, 2 pi) [rad]
    """
    if n_beams * min_separation_rad >= 2 * math.pi:
        raise ValueError("the beams cannot be that far apart")
    while True:
        beta = rng.uniform(0.0, 2 * math.pi, n_beams)
        d = np.abs(beta[:, None] - beta[None, :]) % (2 * math.pi)
        d = np.minimum(d, 2 * math.pi - d)
        if n_beams < 2 or d[np.triu_indices(n_beams, 1)].min() >= min_separation_rad:
            return beta


def spindle_tick_s(k: int | np.ndarray, spindle_rate_hz: float) -> np.ndarray:
    """Time of spindle clock tick k exactly as the simulator writes it: round(k 1e9 / rate) ns [s].

    Parameters
    ----------
    k : tick index (or indices)
    spindle_rate_hz : spindle stream rate [Hz]

    Returns
    -------
    ndarray (same shape as k) [s]
    """
    k = np.asarray(k, dtype=np.int64)
    t_ns = np.round(k.astype(np.float64) * (1e9 / spindle_rate_hz)).astype(np.int64)
    return t_ns * 1e-9


def draw_speed_profile(
    rng: np.random.Generator,
    *,
    change: bool,
    n_rev: int,
    spindle_rate_hz: float,
    contract: dict = TRI_CONTRACT,
) -> dict:
    """Commanded speed and samples per revolution; with ``change`` a ramp to another speed.

    Without a change: rpm uniform in ``contract["rpm"]``, samples per revolution an integer
    uniform in ``contract["samples_per_rev"]``. With a change: the factor f from one of the two
    bins of ``contract["speed_factor"]`` (chosen with equal odds), then rpm_1 and the samples per
    revolution at rpm_1 drawn where both speeds stay inside those ranges (rpm_2 = f rpm_1, the
    samples per revolution at rpm_2 are spr_1 / f; the sample rate is fixed). The ramp starts
    after ``contract["ramp_start_fraction"]`` of ``n_rev`` revolutions at rpm_1 and lasts
    ``contract["ramp_s"]``; both knots are put on spindle clock ticks
    (:func:`spindle_tick_s`).

    Returns
    -------
    dict with ``rpm_nominal`` (the first speed), ``samples_per_rev`` (at the first speed),
    ``sample_rate_hz``, ``rpm_profile`` (knots ((t_s, rpm), ...), empty for constant speed),
    ``speed_factor``, ``ramp_start_s``, ``ramp_end_s`` (None without a change).
    """
    rpm_lo, rpm_hi = contract["rpm"]
    spr_lo, spr_hi = contract["samples_per_rev"]
    if not change:
        rpm = float(rng.uniform(rpm_lo, rpm_hi))
        spr = int(rng.integers(spr_lo, spr_hi + 1))
        return {
            "rpm_nominal": rpm,
            "samples_per_rev": spr,
            "sample_rate_hz": spr * rpm / 60.0,
            "rpm_profile": (),
            "speed_factor": None,
            "ramp_start_s": None,
            "ramp_end_s": None,
        }
    bins = contract["speed_factor"]
    lo, hi = bins[int(rng.integers(0, len(bins)))]
    f = float(rng.uniform(lo, hi))
    rpm = float(rng.uniform(max(rpm_lo, rpm_lo / f), min(rpm_hi, rpm_hi / f)))
    spr_min, spr_max = math.ceil(max(spr_lo, spr_lo * f)), math.floor(min(spr_hi, spr_hi * f))
    spr = int(rng.integers(spr_min, spr_max + 1))
    t1 = float(rng.uniform(*contract["ramp_start_fraction"])) * n_rev * 60.0 / rpm
    ramp = float(rng.uniform(*contract["ramp_s"]))
    k1 = max(1, int(round(t1 * spindle_rate_hz)))
    k2 = max(k1 + 1, int(round((t1 + ramp) * spindle_rate_hz)))
    t1_s, t2_s = (float(x) for x in spindle_tick_s(np.array([k1, k2]), spindle_rate_hz))
    profile = ((0.0, rpm), (t1_s, rpm), (t2_s, rpm * f))
    return {
        "rpm_nominal": rpm,
        "samples_per_rev": spr,
        "sample_rate_hz": spr * rpm / 60.0,
        "rpm_profile": profile,
        "speed_factor": f,
        "ramp_start_s": t1_s,
        "ramp_end_s": t2_s,
    }


def reading_span_mm(
    beta_rad: np.ndarray, rho_mm: np.ndarray, offset_xy_mm: np.ndarray, radius_mm: float, n_phi: int = 4096
) -> np.ndarray:
    """Distances s from each beam's foot point to the wall over one revolution (d_b = 0).

    The exact circle model of the spec (s > 0 the root of |S + Rot(phi)(F + s u) - C| = R),
    evaluated by :func:`borescan.geometry.tri_spindle_readings` on ``n_phi`` angles.

    Parameters
    ----------
    beta_rad, rho_mm : (c,) beam directions [rad] and offsets [mm]
    offset_xy_mm : (2,) S - C [mm]
    radius_mm : bore radius [mm]

    Returns
    -------
    ndarray (n_phi, c) [mm]
    """
    from borescan.geometry import Bore, tri_spindle_readings

    c = len(beta_rad)
    beams = Beams(tuple(range(1, c + 1)), np.asarray(beta_rad, float), np.asarray(rho_mm, float), np.zeros(c))
    phi = np.linspace(0.0, 2 * math.pi, n_phi, endpoint=False)[:, None]
    return tri_spindle_readings(
        phi, np.asarray(offset_xy_mm, float), beams, Bore((0.0, 0.0), float(radius_mm))
    )


# --------------------------------------------------------------------------- three-sensor calibration


def draw_tri_calibration(
    rng: np.random.Generator,
    *,
    scan_id: str,
    night: str,
    effect_free: bool = True,
    device_id: str | None = None,
    contract: dict = TRI_CONTRACT,
    effect_scale: float = 1.0,
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
    contract : ranges, :data:`TRI_CONTRACT` by default
    effect_scale : the effect's magnitude times this (:func:`borescan.discrepancy.battery.scale_effect`)

    Returns
    -------
    borescan.simulate.SimulatedScan
        ``truth["contract"]`` holds the draw (see module doc); ``truth["scene"]`` the TriScene.
    """
    from borescan import simulate

    c = 3
    channels = (1, 2, 3)
    # bore, spindle axis
    R = float(rng.uniform(*contract["bore_radius_mm"]))
    C = rng.uniform(*contract["center_xy_mm"], 2)
    ecc = float(rng.uniform(*contract["spindle_offset_mm"]))
    ecc_dir = float(rng.uniform(0.0, 2 * math.pi))
    o = ecc * np.array([math.cos(ecc_dir), math.sin(ecc_dir)])
    S = C + o
    # beams and sensor ranges
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
    beams = Beams(channels, beta, rho, d_b)
    # kinematics
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
    # what the machine reports
    known = bool(rng.random() < contract["p_position_known"])
    e = contract["position_error_mm"]
    err_S = rng.uniform(-e, e, 2)
    err_C = rng.uniform(-e, e, 2)
    S_rep, C_rep = S + err_S, C + err_C
    nominal = Beams(
        channels,
        beta + rng.uniform(-contract["nominal_beta_rad"], contract["nominal_beta_rad"], c),
        rho + rng.uniform(-contract["nominal_rho_mm"], contract["nominal_rho_mm"], c),
        d_b + rng.uniform(-contract["nominal_d_b_mm"], contract["nominal_d_b_mm"], c),
    )
    null_fraction = float(rng.uniform(*contract["null_fraction"]))
    effects = []
    if not effect_free:
        from borescan.discrepancy.battery import TRI_EFFECTS, random_effect, scale_effect

        name = str(rng.choice(TRI_EFFECTS))
        effects = [
            scale_effect(
                random_effect(name, rng, channels, speed["rpm_nominal"] / 60.0, speed["sample_rate_hz"]),
                effect_scale,
            )
        ]
    sim_seed = int(rng.integers(0, 2**31 - 1))

    scene = simulate.TriScene(
        beams=beams,
        bore_center_xy_mm=(float(C[0]), float(C[1])),
        bore_radius_20_mm=R,
        spindle_xy_mm=(float(S[0]), float(S[1])),
        rpm_nominal=speed["rpm_nominal"],
        phase_rad=phase,
        direction=direction,
        sample_rate_hz=speed["sample_rate_hz"],
        range_mm=tuple(float(r) for r in range_mm),
        cte_per_k=contract["cte_per_k"],
        temperature_c=20.0,
        rpm_profile=speed["rpm_profile"],
    )
    d_nom = round(2 * R)
    artifact = {
        "id": f"RG-{d_nom}",
        "type": "ring_gauge",
        "nominal_diameter_mm": float(d_nom),
        "certified_diameter_mm": 2 * R,
        "u_diameter_mm": contract["gauge_u_diameter_mm"],
        "k": 2,
        "certificate": f"RG-{d_nom}/{night[:4]}/{2 * R:.6f}",
        "cte_per_k": contract["cte_per_k"],
    }
    sim = simulate.simulate_tri_spindle(
        scene,
        scan_id=scan_id,
        night=night,
        kind="calibration",
        n_rev=float(n_rev),
        effects=effects,
        noise_mm=noise_mm,
        seed=sim_seed,
        device_id=device_id or f"TRI-{scan_id}"[:64],
        nominal_beams=nominal,
        artifact=artifact,
        spindle_label="P1",
        center_xy_mm=(float(C_rep[0]), float(C_rep[1])) if known else None,
        encoder=encoder,
        spindle_rate_hz=spindle_rate_hz,
    )
    # sporadic nulls
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
    if known:
        meta["spindle"]["position"] = {"label": "P1", "x_mm": float(S_rep[0]), "y_mm": float(S_rep[1])}
    else:
        meta["spindle"].pop("position", None)
        meta.pop("center", None)
    n = int(sim.truth["n_samples"])
    truth = dict(sim.truth)
    truth["contract"] = {
        "generator": "borescan.scenarios.draw_tri_calibration",
        "effect_free": not effects,
        "beams": beams.to_nominal(),
        "nominal_beams": nominal.to_nominal(),
        "bore_radius_mm": R,
        "center_xy_mm": [float(x) for x in C],
        "spindle_xy_mm": [float(x) for x in S],
        "offset_xy_mm": [float(x) for x in o],
        "spindle_offset_mm": ecc,
        "position_known": known,
        "center_reported_xy_mm": [float(x) for x in C_rep] if known else None,
        "spindle_reported_xy_mm": [float(x) for x in S_rep],
        "center_error_xy_mm": [float(x) for x in err_C],
        "spindle_error_xy_mm": [float(x) for x in err_S],
        "position_error_mm": e,
        "angle_source": "encoder" if encoder else "profile",
        "encoder": encoder,
        "direction": direction,
        "phase_rad": phase,
        "rpm_nominal": speed["rpm_nominal"],
        "rpm_profile": [list(k) for k in speed["rpm_profile"]],
        "speed_change": change,
        "speed_factor": speed["speed_factor"],
        "ramp_start_s": speed["ramp_start_s"],
        "ramp_end_s": speed["ramp_end_s"],
        "samples_per_rev": speed["samples_per_rev"],
        "sample_rate_hz": speed["sample_rate_hz"],
        "spindle_rate_hz": spindle_rate_hz,
        "n_rev": n_rev,
        "n_samples": n,
        "noise_mm": noise_mm,
        "range_mm": [float(r) for r in range_mm],
        "out_of_range": out_of_range,
        "null_fraction": null_fraction,
        "n_sporadic_nulls": int(null_mask.sum()),
        "simulate_seed": sim_seed,
    }
    return replace(sim, meta=meta, lds=lds, spindle=spindle, truth=truth)


def draw_tri_measurement(
    rng: np.random.Generator,
    *,
    scan_id: str,
    night: str,
    calibration,
    effect_free: bool = True,
    effect_scale: float = 1.0,
):
    """Return a rotating measurement of a part on the device of a calibration scan.

    The calibration scan is drawn by :func:`draw_tri_calibration` (``calibration``: that SimulatedScan): the
    same device id, beams, design geometry, spindle, kinematics, encoder and noise, a part whose diameter is
    the gauge's within +-0.1 mm (so the readings stay in range), a new phase; measured later that night.
    ``effect_free`` False adds one named effect as the calibration draw does.

    Returns
    -------
    borescan.simulate.SimulatedScan; ``truth["contract"]`` holds the draw.
    """
    from borescan import simulate
    from borescan.discrepancy.battery import TRI_EFFECTS, random_effect, scale_effect

    c = calibration.truth["contract"]
    R = float(c["bore_radius_mm"]) + float(rng.uniform(-0.05, 0.05))
    scene = replace(
        simulate.TriScene.from_dict(calibration.truth["scene"]),
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
        "generator": "borescan.scenarios.draw_tri_measurement",
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


# --------------------------------------------------------------------------- static sets and rods

#: Ranges of the static three-sensor sets (ring gauges with certified diameters, parts with
#: nominal ones) and of the rod scans; units in the names.
STATIC_CONTRACT: dict = {
    "bore_radius_mm": (75.0, 200.0),
    "device_offset_mm": 3.0,
    "n_poses": (3, 12),
    "samples_per_pose": (5, 30),
    "noise_mm": (0.001, 0.005),
    "p_ring_gauge": 0.5,
}
ROD_CONTRACT: dict = {
    "n_holes": (2, 3),
    "hole_radius_mm": (50.0, 100.0),
    "n_poses": (8, 40),
    "samples_per_pose": (5, 30),
    "noise_mm": (0.002, 0.020),
    "eccentricity_mm": 2.5,
    "deflection_deg": 1.0,
    "range_mm": 30.0,
    "p_ring_gauge": 0.5,
}


def _artifact(kind: str, ident: str, diameters_mm, z_mm, cte_per_k: float, u_mm: float = 0.0015) -> dict:
    """Return a ring-gauge set (certified diameters, u, k = 2) or a part (nominal diameters only)."""
    d = [float(x) for x in diameters_mm]
    feats = [
        {"id": f"H{j + 1}", "z_mm": float(z), "nominal_diameter_mm": float(round(x, 1))}
        for j, (x, z) in enumerate(zip(d, z_mm))
    ]
    if kind == "ring_gauge":
        for f, x in zip(feats, d):
            f.update({"certified_diameter_mm": x, "u_diameter_mm": u_mm, "k": 2})
        art = {
            "id": ident,
            "type": "ring_gauge",
            "nominal_diameter_mm": feats[0]["nominal_diameter_mm"],
            "certified_diameter_mm": d[0],
            "u_diameter_mm": u_mm,
            "k": 2,
            "certificate": f"{ident}/cert",
            "cte_per_k": cte_per_k,
        }
    else:
        art = {
            "id": ident,
            "type": "part",
            "nominal_diameter_mm": feats[0]["nominal_diameter_mm"],
            "cte_per_k": cte_per_k,
        }
    if len(feats) > 1:
        art["features"] = feats
    return art


def draw_tri_static(
    rng: np.random.Generator,
    *,
    scan_id: str,
    night: str,
    beams: Beams | None = None,
    effect_free: bool = True,
    contract: dict = STATIC_CONTRACT,
    effect_scale: float = 1.0,
):
    """Return a static three-sensor set drawn over the contract.

    A ring gauge with a certified diameter (a verification) or a part with a nominal one (a measurement), 3-12
    device poses within 3 mm of the bore centre at random angles, 5-30 samples per pose, noise 1-5 um.
    ``beams`` (default: drawn as for :func:`draw_tri_calibration`) is the device; d_b and the ranges keep
    every reading inside its sensor's range.

    Returns
    -------
    borescan.simulate.SimulatedScan; ``truth["contract"]`` holds the draw (true diameter, poses, beams).
    """
    from borescan import simulate

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
    art = _artifact(kind, f"{'RG' if kind == 'ring_gauge' else 'P'}-{round(2 * R)}", [2 * R], [0.0], 11.5e-6)
    effects = []
    if not effect_free:
        from borescan.discrepancy.battery import random_effect, scale_effect

        name = str(rng.choice(("sensor_offset", "sensor_gain", "sensor_nonlinearity", "sensor_drift")))
        effects = [scale_effect(random_effect(name, rng, (1, 2, 3), 1.0, 1000.0), effect_scale)]
    scene = simulate.TriScene(
        beams=dev,
        bore_center_xy_mm=(0.0, 0.0),
        bore_radius_20_mm=R,
        range_mm=tuple(float(x) for x in range_mm),
    )
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
        "generator": "borescan.scenarios.draw_tri_static",
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


def draw_rod_geometry(rng: np.random.Generator, contract: dict = ROD_CONTRACT) -> dict:
    """Return a rod geometry drawn over the contract.

    Rod geometry over the contract: 2-3 coaxial holes of radius 50-100 mm 100-300 mm apart,
    layer geometry (l0, phi, d, gamma) of a real rod, eccentricity up to 2.5 mm and deflection up
    to 1 deg, 8-40 poses at random angles, 5-30 readings per pose, noise 2-20 um.

    Returns
    -------
    dict: layers, holes, axis, alpha (pose angles [rad]), n (poses), k (readings per pose),
    m (holes), noise [mm]
    """
    from borescan.geometry import Hole, RodAxis, RodLayer

    m = int(rng.integers(contract["n_holes"][0], contract["n_holes"][1] + 1))
    r = rng.uniform(*contract["hole_radius_mm"], m)
    h = rng.uniform(50.0, 150.0) + np.concatenate([[0.0], np.cumsum(rng.uniform(100.0, 300.0, m - 1))])
    layers = [
        RodLayer(
            j + 1,
            float(h[j]),
            float(r[j] - 4.0),
            phi_rad=float(rng.uniform(-0.1, 0.1)),
            d_mm=float(rng.uniform(-0.5, 0.5)),
            gamma_rad=float(np.deg2rad(rng.uniform(-0.5, 0.5))),
        )
        for j in range(m)
    ]
    off = rng.uniform(-0.05, 0.05, (m, 2))
    holes = [Hole((float(off[j, 0]), float(off[j, 1])), float(r[j])) for j in range(m)]
    e, te = contract["eccentricity_mm"] * np.sqrt(rng.uniform()), rng.uniform(0, 2 * np.pi)
    axis = RodAxis(
        float(e * np.cos(te)),
        float(e * np.sin(te)),
        float(np.deg2rad(rng.uniform(0.0, contract["deflection_deg"]))),
        float(rng.uniform(0, 2 * np.pi)),
    )
    n = int(rng.integers(contract["n_poses"][0], contract["n_poses"][1] + 1))
    k = int(rng.integers(contract["samples_per_pose"][0], contract["samples_per_pose"][1] + 1))
    sig = float(rng.uniform(*contract["noise_mm"]))
    alpha = rng.uniform(0, 2 * np.pi, n)
    return {
        "layers": layers,
        "holes": holes,
        "axis": axis,
        "alpha": alpha,
        "n": n,
        "k": k,
        "m": m,
        "noise": sig,
    }


def draw_rod_scan(
    rng: np.random.Generator,
    *,
    scan_id: str,
    night: str,
    effect_free: bool = True,
    contract: dict = ROD_CONTRACT,
    effect_scale: float = 1.0,
    calibration: bool = False,
):
    """Return a rod scan drawn over the contract.

    The geometry is :func:`draw_rod_geometry`'s, in a ring-gauge set with certified diameters (half of the
    scans: what a rod is verified on) or in a part with nominal ones. Each layer's sensor (range 30 mm) sits
    mid-range so that eccentricity and deflection stay inside it.

    ``calibration``: a rod calibration scan instead (kind ``calibration``, always in a ring-gauge
    set; the same draws otherwise).

    Returns
    -------
    borescan.simulate.SimulatedScan; ``truth["contract"]`` holds the draw.
    """
    from borescan import simulate

    g = draw_rod_geometry(rng, contract)
    layers = [
        replace(lay, l0_mm=float(hh.radius_mm - contract["range_mm"] / 2))
        for lay, hh in zip(g["layers"], g["holes"])
    ]
    kind = "ring_gauge" if rng.random() < contract["p_ring_gauge"] or calibration else "part"
    art = _artifact(
        kind,
        f"{'RGS' if kind == 'ring_gauge' else 'CYL'}-{scan_id}"[:40],
        [2 * hh.radius_mm for hh in g["holes"]],
        [lay.h_mm for lay in layers],
        11.5e-6,
    )
    scene = simulate.RodScene(
        layers=tuple(layers),
        holes=tuple(g["holes"]),
        axis=g["axis"],
        range_mm=(contract["range_mm"],) * g["m"],
    )
    effects = []
    if not effect_free:
        from borescan.discrepancy.battery import random_effect, scale_effect

        name = str(
            rng.choice(
                (
                    "sensor_offset",
                    "sensor_gain",
                    "sensor_nonlinearity",
                    "sensor_drift",
                    "quantization",
                    "outliers",
                    "thermal_expansion",
                    "beam_tilt",
                )
            )
        )
        effects = [
            scale_effect(random_effect(name, rng, scene.channels, 0.1, scene.sample_rate_hz), effect_scale)
        ]
    sim = simulate.simulate_rod(
        scene,
        g["alpha"],
        samples_per_pose=g["k"],
        noise_mm=g["noise"],
        seed=int(rng.integers(0, 2**31 - 1)),
        artifact=art,
        nominal_layers=layers,
        effects=effects,
        scan_id=scan_id,
        night=night,
        device_id=f"ROD-{scan_id}"[:64],
        kind="calibration" if calibration else "verification" if kind == "ring_gauge" else "measurement",
    )
    meta = json.loads(json.dumps(sim.meta))
    for sensor in meta.get("sensors", []):  # the data sheet states the repeatability the scan has
        sensor["repeatability_mm"] = g["noise"]
    truth = dict(sim.truth)
    truth["contract"] = {
        "generator": "borescan.scenarios.draw_rod_scan",
        "effect_free": not effects,
        "artifact": kind,
        "diameters_mm": [2 * hh.radius_mm for hh in g["holes"]],
        "n_poses": g["n"],
        "samples_per_pose": g["k"],
        "noise_mm": g["noise"],
        "eccentricity_mm": float(np.hypot(g["axis"].dx_mm, g["axis"].dy_mm)),
        "deflection_rad": g["axis"].omega_rad,
    }
    return replace(sim, meta=meta, truth=truth)


# --------------------------------------------------------------------------- battery


def battery_rng(seed: int, index: int) -> np.random.Generator:
    """Return the generator of scan ``index`` of the battery ``seed``.

    Return the generator of scan ``index`` of the battery ``seed``:
    ``SeedSequence(seed, spawn_key=(index,))``.

    The same as ``SeedSequence(seed).spawn(n)[index]`` for any n > index, so a longer battery
    starts with the scans of a shorter one.
    """
    return np.random.default_rng(np.random.SeedSequence(int(seed), spawn_key=(int(index),)))


#: battery scan kinds -> (id prefix, child-seed stream): calibration scans keep the stream they always had
BATTERY_KINDS = {
    "calibration": ("CT", 0),
    "static": ("CS", 1),
    "rod": ("CR", 2),
    "measurement": ("CM", 3),
    "rod_calibration": ("CK", 4),
}


def battery_scan_id(seed: int, index: int, kind: str = "calibration") -> str:
    """Return the scan id of scan ``index`` of battery ``seed``.

    ``CT<seed>-<index:05d>`` (calibration), ``CS...`` (static sets), ``CR...`` (rods), ``CM...`` (rotating
    measurements), ``CK...`` (rod calibrations).
    """
    return f"{BATTERY_KINDS[kind][0]}{int(seed)}-{int(index):05d}"


def _kind_rng(seed: int, index: int, kind: str) -> np.random.Generator:
    stream = BATTERY_KINDS[kind][1]
    if stream == 0:
        return battery_rng(seed, index)
    return np.random.default_rng(np.random.SeedSequence(int(seed), spawn_key=(int(index), stream)))


def _battery_night(index: int, per_night: int = 25) -> str:
    """Night of scan ``index``: ``per_night`` scans a night from 2027-01-01."""
    from datetime import date, timedelta

    return (date(2027, 1, 1) + timedelta(days=index // per_night)).isoformat()


def write_battery(
    out_dir: Path | str,
    n: int,
    seed: int,
    *,
    effect_free: bool = True,
    only: Sequence[int] | None = None,
    progress: Callable[[int, int, Path], None] | None = None,
    kinds: Sequence[str] = ("calibration",),
    effect_share: float | None = None,
    effect_scale_range: tuple[float, float] = (1.0, 1.0),
    per_night: int = 25,
) -> list[Path]:
    """Write ``n`` contract calibration scans: raw tree under ``out_dir/raw``, truth under ``out_dir/truth``.

    Scan i (0-based) is :func:`draw_tri_calibration` with :func:`battery_rng` (seed, i), id
    :func:`battery_scan_id` and its own device (``TRI-<scan id>``); 25 scans a night from
    2027-01-01. ``out_dir/battery.json`` lists the seed, n and the scan ids. Writing the same
    battery again is a no-op (raw folders are write-once; same content is accepted).

    Parameters
    ----------
    out_dir : output folder
    n : number of scans (>= 1)
    seed : battery seed (>= 0)
    effect_free : False draws one named effect per scan
    only : write only these scan indices (each in 0..n-1): the same scans as in the whole
        battery, e.g. to re-examine a few
    progress : called as progress(k, total, scan_folder) after each scan (k counts from 0)
    kinds : which scans, ``n`` of each: ``"calibration"`` (:func:`draw_tri_calibration`),
        ``"static"`` (:func:`draw_tri_static`: ring gauges with certified diameters and parts
        with nominal ones), ``"rod"`` (:func:`draw_rod_scan`), ``"measurement"``
        (:func:`draw_tri_measurement` on the device of calibration scan i, the same night),
        ``"rod_calibration"`` (:func:`draw_rod_scan` as a calibration scan); each kind from its own seed
        stream
    effect_share : None: ``effect_free`` for every scan; else each scan has an effect with this
        probability, drawn with its size factor (log-uniform in ``effect_scale_range``) from the
        scan's own stream ``SeedSequence(seed, spawn_key=(i, 10 + kind stream))``, so the scans'
        other draws are those of the effect-free battery
    per_night : scans a night (index // per_night nights after 2027-01-01)

    Returns
    -------
    list of the scan folders, in the order written.
    """
    from borescan import simulate

    if int(n) < 1:
        raise ValueError(f"n must be >= 1, got {n}")
    if int(seed) < 0:
        raise ValueError(f"seed must be >= 0, got {seed}")
    indices = list(range(int(n))) if only is None else [int(i) for i in only]
    if any(i < 0 or i >= int(n) for i in indices):
        raise ValueError(f"scan indices must lie in 0..{int(n) - 1}, got {indices}")
    out_dir = Path(out_dir)
    raw, truth = out_dir / "raw", out_dir / "truth"
    unknown = [k for k in kinds if k not in BATTERY_KINDS]
    if unknown or not kinds:
        raise ValueError(f"kinds must be among {sorted(BATTERY_KINDS)}, got {list(kinds)}")
    jobs = [(kind, i) for kind in kinds for i in indices]
    paths = []
    for k, (kind, i) in enumerate(jobs):
        free, factor = _effect_draw(seed, i, kind, effect_free, effect_share, effect_scale_range)
        night, sid = _battery_night(i, per_night), battery_scan_id(seed, i, kind)
        rng = _kind_rng(seed, i, kind)
        if kind == "measurement":
            cal = draw_tri_calibration(
                _kind_rng(seed, i, "calibration"), scan_id=battery_scan_id(seed, i), night=night
            )
            sim = draw_tri_measurement(
                rng, scan_id=sid, night=night, calibration=cal, effect_free=free, effect_scale=factor
            )
        elif kind == "rod_calibration":
            sim = draw_rod_scan(
                rng, scan_id=sid, night=night, effect_free=free, effect_scale=factor, calibration=True
            )
        else:
            draw = {"calibration": draw_tri_calibration, "static": draw_tri_static, "rod": draw_rod_scan}[
                kind
            ]
            sim = draw(rng, scan_id=sid, night=night, effect_free=free, effect_scale=factor)
        paths.append(simulate.write_simulated(sim, raw, truth))
        if progress is not None:
            progress(k, len(jobs), paths[-1])
    index = {
        "generator": "borescan.scenarios.write_battery",
        "seed": int(seed),
        "n": int(n),
        "effect_free": bool(effect_free),
        "kinds": list(kinds),
        "effect_share": effect_share,
        "effect_scale_range": list(effect_scale_range),
        "per_night": int(per_night),
        "scan_ids": [battery_scan_id(seed, i, kind) for kind, i in jobs],
    }
    tmp = out_dir / ".battery.json.tmp"
    tmp.write_text(json.dumps(index, indent=2) + "\n")
    os.replace(tmp, out_dir / "battery.json")
    return paths


def _effect_draw(
    seed: int, index: int, kind: str, effect_free: bool, share: float | None, scale_range: tuple[float, float]
) -> tuple[bool, float]:
    """(effect_free, size factor) of scan ``index`` of ``kind`` (see :func:`write_battery`)."""
    if share is None:
        return effect_free, 1.0
    if not 0.0 <= share <= 1.0:
        raise ValueError(f"effect share must lie in 0..1, got {share}")
    lo, hi = (float(x) for x in scale_range)
    if not 0.0 < lo <= hi:
        raise ValueError(f"effect size factors must satisfy 0 < low <= high, got {scale_range}")
    rng = np.random.default_rng(
        np.random.SeedSequence(int(seed), spawn_key=(int(index), 10 + BATTERY_KINDS[kind][1]))
    )
    free = bool(rng.random() >= share)
    return free, float(math.exp(rng.uniform(math.log(lo), math.log(hi))))
