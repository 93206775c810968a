"""The scenarios of the pooled-examination bench: a device over the contract and its scans, calibrated.

Drawn as :mod:`bench.bench_pooled` describes them (module doc there); :mod:`bench.bench_loop` draws its
devices and scans the same way.
"""

from __future__ import annotations

import math

import numpy as np

from borescan.config import schema_defaults

#: Hidden effects and the design each is drawn with ("*": any of speeds, eccentricities, nights).
CASES = (
    ("channel_delay", "speeds"),
    ("sensor_nonlinearity", "eccentricities"),
    ("sensor_offset", "eccentricities"),
    ("channel_delay", "one_speed"),
    ("sensor_gain", "*"),
    ("sensor_drift", "*"),
    ("beam_tilt", "*"),
    ("thermal_expansion", "*"),
    ("bore_lobing", "*"),
    ("axis_tilt", "*"),
    ("speed_ripple", "*"),
    ("spindle_error_motion", "*"),
    ("sensor_nonlinearity", "*"),
    ("channel_delay", "speeds"),
)
RUN_EFFECTS = ("speed_ripple", "spindle_error_motion")
#: samples per scan, examined on four blocks (as one scan is): the night's setting (rule pooled_night)
MAX_SAMPLES = int(schema_defaults()["discrepancy"]["pooled_max_samples"])


# ------------------------------------------------------------------------------------ scenario


def draw_device(rng):
    """Beams, gauge radius, sensor ranges of one device (the contract's ranges)."""
    from borescan.geometry import Beams
    from borescan.synthetic.contract import TRI_CONTRACT, draw_beam_directions, reading_span_mm

    R = float(rng.uniform(*TRI_CONTRACT["bore_radius_mm"]))
    beta = draw_beam_directions(rng, 3, TRI_CONTRACT["min_beam_separation_rad"])
    rho = rng.uniform(-TRI_CONTRACT["rho_max_mm"], TRI_CONTRACT["rho_max_mm"], 3)
    # readings must stay in range for every direction of an eccentricity up to 3 mm
    spans = np.concatenate(
        [
            reading_span_mm(beta, rho, 3.0 * np.array([math.cos(a), math.sin(a)]), R, 512)
            for a in np.linspace(0, 2 * math.pi, 8, endpoint=False)
        ]
    )
    s_min, s_max = spans.min(axis=0), spans.max(axis=0)
    range_mm = np.array([max(float(rng.uniform(6.0, 10.0)), s_max[j] - s_min[j] + 0.6) for j in range(3)])
    d_b = np.array([rng.uniform(s_max[j] - range_mm[j] + 0.2, s_min[j] - 0.2) for j in range(3)])
    return Beams((1, 2, 3), beta, rho, d_b), R, range_mm


def scan_designs(rng, design: str) -> list[dict]:
    """Per scan: night index, rpm, direction, eccentricity [mm]."""
    base_rpm = float(rng.uniform(30.0, 90.0))
    d0 = "ccw" if rng.random() < 0.5 else "cw"
    other = "cw" if d0 == "ccw" else "ccw"
    if design == "speeds":
        rpms = [base_rpm, base_rpm * float(rng.uniform(1.5, 2.0)), base_rpm]
        dirs = [d0, d0, other]
        ecc = rng.uniform(1.0, 2.5, 3)
        nights = [0, 0, 0]
    elif design == "eccentricities":
        rpms, dirs, nights = [base_rpm] * 3, [d0] * 3, [0, 0, 0]
        ecc = np.array([0.2, 1.2, 2.6]) * rng.uniform(0.9, 1.1, 3)
    elif design == "one_speed":
        rpms, dirs, nights = [base_rpm] * 3, [d0] * 3, [0, 0, 0]
        ecc = rng.uniform(0.8, 2.5, 3)
    elif design == "nights":
        rpms, dirs, nights = [base_rpm] * 4, [d0] * 4, [0, 0, 1, 1]
        ecc = rng.uniform(1.0, 2.5, 4)
    else:
        raise ValueError(f"unknown design {design!r}")
    return [
        {"night": n, "rpm": r, "direction": d, "ecc_mm": float(e)}
        for n, r, d, e in zip(nights, rpms, dirs, ecc)
    ]


def gauge_artifact(R: float) -> dict:
    """Return the certified ring gauge of radius ``R`` [mm] a scenario's device turns in."""
    return {
        "id": f"RG-{round(2 * R)}",
        "type": "ring_gauge",
        "nominal_diameter_mm": float(round(2 * R)),
        "certified_diameter_mm": 2 * R,
        "u_diameter_mm": 0.0015,
        "k": 2,
        "certificate": "RG/2027",
        "cte_per_k": 11.5e-6,
    }


def spindle_scans(
    rng,
    rows: list[dict],
    *,
    beams,
    R,
    range_mm,
    C,
    spr,
    noise,
    nominal,
    encoder,
    effect,
    run_scan,
    device_id,
    nights,
    tag,
) -> list:
    """Return the ring-gauge spindle scans of one design.

    Return the ring-gauge spindle scans of one design (:func:`_designs` rows, 12 revolutions each, scan
    ``<tag>-<k>``); the hidden ``effect`` in every scan, or only in scan ``run_scan`` when given.
    """
    from borescan.synthetic.scenes import TriScene
    from borescan.synthetic.simulate import simulate_tri_spindle

    art = gauge_artifact(R)
    sims = []
    for k, s in enumerate(rows):
        a = float(rng.uniform(0, 2 * math.pi))
        S = C + s["ecc_mm"] * np.array([math.cos(a), math.sin(a)])
        scene = TriScene(
            beams=beams,
            bore_center_xy_mm=(float(C[0]), float(C[1])),
            bore_radius_20_mm=R,
            spindle_xy_mm=(float(S[0]), float(S[1])),
            rpm_nominal=s["rpm"],
            phase_rad=float(rng.uniform(0, 2 * math.pi)),
            direction=s["direction"],
            sample_rate_hz=spr * s["rpm"] / 60.0,
            range_mm=tuple(float(x) for x in range_mm),
            cte_per_k=11.5e-6,
            temperature_c=20.0,
        )
        effects = [] if effect is None or (run_scan is not None and k != run_scan) else [effect]
        sims.append(
            simulate_tri_spindle(
                scene,
                scan_id=f"{tag}-{k}",
                night=nights[s["night"]],
                n_rev=12.0,
                effects=effects,
                noise_mm=noise,
                seed=int(rng.integers(0, 2**31 - 1)),
                device_id=device_id,
                nominal_beams=nominal,
                artifact=art,
                center_xy_mm=(float(C[0]), float(C[1])),
                encoder=encoder,
                spindle_rate_hz=200.0,
            )
        )
    return sims


def draw_scenario(seed: int, i: int) -> dict:
    """Scenario ``i`` of battery ``seed``: the simulated scans, the hidden effect, the design."""
    from borescan.discrepancy.battery import random_effect
    from borescan.synthetic.battery import battery_rng
    from borescan.geometry import Beams

    rng = battery_rng(seed + 500_000, i)
    free = i % 4 == 3
    name, design = (None, "*") if free else CASES[(i - i // 4) % len(CASES)]
    if design == "*":
        design = ("speeds", "eccentricities", "nights", "one_speed")[int(rng.integers(0, 4))]
    beams, R, range_mm = draw_device(rng)
    nominal = Beams(
        beams.channels,
        beams.beta_rad + rng.uniform(-0.03, 0.03, 3),
        beams.rho_mm + rng.uniform(-1, 1, 3),
        beams.d_b_mm + rng.uniform(-1, 1, 3),
    )
    scans = scan_designs(rng, design)
    encoder = bool(rng.random() < 0.5) and name not in ("speed_ripple",)
    noise = float(rng.uniform(0.001, 0.004))
    spr = int(rng.integers(300, 501))
    C = rng.uniform(-300, 300, 2)
    effect = None
    if name is not None:
        effect = random_effect(
            name, rng, beams.channels, scans[0]["rpm"] / 60.0, spr * scans[0]["rpm"] / 60.0
        )
    run_scan = int(rng.integers(0, len(scans))) if name in RUN_EFFECTS else None
    nights = ["2027-03-01", "2027-03-02"]
    sims = spindle_scans(
        rng,
        scans,
        beams=beams,
        R=R,
        range_mm=range_mm,
        C=C,
        spr=spr,
        noise=noise,
        nominal=nominal,
        encoder=encoder,
        effect=effect,
        run_scan=run_scan,
        device_id=f"TRI-P{seed}-{i:04d}",
        nights=nights,
        tag=f"P{seed}-{i:04d}",
    )
    return {
        "sims": sims,
        "effect": effect,
        "name": name,
        "design": design,
        "run_scan": run_scan,
        "nights": [nights[s["night"]] for s in scans],
        "beams": beams,
        "noise_mm": noise,
        "encoder": encoder,
    }


def calibrate(sims) -> tuple:
    """Calibrate the scans of one night by the night's method.

    Full-data calibration of the scans of one night (the night's method): (calibration or None,
    accepted). A calibration the acceptance rule refuses only for its residual is used as fitted;
    one that fails otherwise (a diverged fit) is None: the scans are then examined as the pipeline
    examines an uncalibrated device (``device.nominal``, beam lengths and angles free).
    """
    from borescan.calibrate.full_fit import fit_full_calibration
    from borescan.calibrate.result import AcceptanceRule, CalibrationError
    from borescan.discrepancy.examine import scan_arrays
    from borescan.geometry import Beams
    from borescan.kinematics import angle_model_of_scan

    ts, ys, am, S, C = [], [], [], [], []
    for s in sims:
        t, ch, v, _, _ = scan_arrays(s)
        ts.append(t)
        ys.append(v)
        am.append(angle_model_of_scan(s.meta, s.spindle))
        S.append((s.meta["spindle"]["position"]["x_mm"], s.meta["spindle"]["position"]["y_mm"]))
        C.append((s.meta["center"]["x_mm"], s.meta["center"]["y_mm"]))
    meta = sims[0].meta
    nominal = Beams.from_nominal(meta["device"]["nominal"]["beams"])
    R = meta["artifact"]["certified_diameter_mm"] / 2
    rng_mm = [float(x["range_mm"]) for x in sorted(meta["sensors"], key=lambda x: x["channel"])]
    kw = dict(
        center_xy_mm=C,
        angle_models=am,
        range_mm=rng_mm,
        scan_ids=[s.scan_id for s in sims],
        device_id=meta["device"]["id"],
    )
    try:
        return fit_full_calibration(ts, ys, ch, nominal, R, S, **kw), True
    except CalibrationError:
        pass
    try:
        return fit_full_calibration(
            ts, ys, ch, nominal, R, S, rule=AcceptanceRule.defaults(max_residual_to_noise=1e9), **kw
        ), False
    except CalibrationError:
        return None, False


# ------------------------------------------------------------------------------------ scoring
