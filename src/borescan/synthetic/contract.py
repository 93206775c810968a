"""The contract of the scan scenarios (``shared/spec``): the ranges every draw spans, its building blocks.

The digital twin (:mod:`borescan.synthetic.simulate`) draws Yang's device at 60 rpm by default. The
scenarios (:mod:`borescan.synthetic.tri_scenarios`, :mod:`borescan.synthetic.rod_scenarios`) draw
the scene of a scan at random over everything the raw-scan format and the geometry page allow, so
that the solvers are tested where independent generators will take them. All randomness comes from
the :class:`numpy.random.Generator` passed in; the functions are otherwise pure (no global state, no
I/O except :func:`borescan.synthetic.battery.write_battery`).

Three-sensor ring-gauge calibration scans
(:func:`~borescan.synthetic.tri_scenarios.draw_tri_calibration`), ranges in :data:`TRI_CONTRACT`:

- ring gauge: bore radius R20 75-200 mm, certified diameter 2 R20 (u 1.5 um, k = 2), CTE 11.5e-6 /K
  at 20 degC (no thermal change unless an effect says so); centre C anywhere in +-300 mm of the
  machine frame;
- spindle axis S at |S - C| 0.5-3 mm in a random direction;
- three beams at random directions, at least 20 deg apart, |rho| <= 15 mm, d_b such that the
  readings stay inside the sensor range (4-10 mm per channel) over the whole revolution, except in
  ~30 % of the scans where one channel leaves its range (below 0 or above the range: null) for 5-30
  % of every revolution;
- noise sigma 1-5 um; 400-1000 samples per revolution; 20-120 revolutions; 20-120 rpm; ccw or cw;
  random phase;
- in ~40 % of the scans a speed change: constant speed, a ramp of 0.5-2 s to 0.4-0.9 or 1.1-1.6
  times the first speed, then constant; the ramp's knots lie on spindle clock ticks, so the rpm
  column integrated over the spindle clock is the profile exactly. Both speeds stay in 20-120 rpm
  and 400-1000 samples per revolution;
- an encoder (``angle_rad``) in half of the scans, else a null encoder column (the angle is the
  integral of the ``rpm`` column); spindle stream rate 50-500 Hz;
- ~0.1-1 % sporadic nulls (set after simulation, before writing);
- ``center`` and ``spindle.position`` in scan.json in ~70 % of the scans, each coordinate off the
  truth by a uniform error within +-2 um (the machine's stated accuracy); the spindle stream's
  ``x_mm``/``y_mm`` carry the same reported position (what the machine reports);
- ``device.nominal`` beams: the truth perturbed by up to +-30 mrad (beta), +-1 mm (rho), +-1 mm
  (d_b): a design geometry, not the truth.

The truth of each scan (``truth["contract"]``) records everything an evaluation needs: the true
beams, R, S, C, the angle source, the noise, the reported positions and their errors, the speed
profile, the out-of-range channel and the nulls.

Static three-sensor sets (:func:`~borescan.synthetic.tri_scenarios.draw_tri_static`,
:data:`STATIC_CONTRACT`): a ring gauge with a certified diameter (verification) or a part with a
nominal one (measurement), bore radius 75-200 mm, 3-12 device poses within 3 mm of the centre at
random angles, 5-30 samples per pose, noise 1-5 um (the sensors' stated repeatability), beams drawn
as above or given.

Rod scans (:func:`~borescan.synthetic.rod_scenarios.draw_rod_scan`, :data:`ROD_CONTRACT`): 2-3
coaxial holes of 100-200 mm, 8-40 poses at random angles, 5-30 readings per pose, noise 2-20 um,
eccentricity up to 2.5 mm, deflection up to 1 deg, real layer geometry (phi, d, gamma); half in
ring-gauge sets with certified diameters (verification), half in parts with nominal ones
(measurement).

:func:`~borescan.synthetic.battery.write_battery` writes a battery of such scans deterministically
(``kinds``): scan i is drawn from its own child seed ``SeedSequence(seed, spawn_key=(i,))``, so
adding scans never changes the earlier ones. Command: ``borescan simulate contract --n N --seed S
--out DIR``.
"""

from __future__ import annotations

import math

import numpy as np

from borescan.geometry import Beams

__all__ = [
    "TRI_CONTRACT",
    "STATIC_CONTRACT",
    "ROD_CONTRACT",
    "draw_beam_directions",
    "draw_speed_profile",
    "spindle_tick_s",
    "reading_span_mm",
    "artifact_of",
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


def artifact_of(kind: str, ident: str, diameters_mm, z_mm, cte_per_k: float, u_mm: float = 0.0015) -> dict:
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
