"""Digital twin: scan generators (``borescan-raw/1``) on the scenes of :mod:`borescan.synthetic.scenes`.

The noise-free readings are the scene's (:func:`borescan.synthetic.scenes.tri_readings`, the one
forward model of each device); the generators add noise, then ``quantization``, ``outliers``, and
null the readings outside [0, range_mm].

What the simulated machine reports (``spindle.parquet``): ``angle_rad`` is the true device
angle phi(t) (the spec: the device frame is the machine frame at encoder angle 0; it shows
``speed_error``/``speed_ripple``), or null with ``encoder=False``; ``x_mm``/``y_mm`` are the
commanded position S0 (the machine does not see its own ``spindle_error_motion``); ``rpm`` is
the commanded speed (``TriScene.rpm_profile``, else ``rpm_nominal``).
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field, replace
from datetime import datetime, timedelta, timezone
from pathlib import Path

import numpy as np
import polars as pl

from borescan import __version__, rawio
from borescan.atomic import json_ready
from borescan.effects import Effect, apply_effects, as_effects, effects_to_dicts, sort_effects
from borescan.geometry import Beams, RodLayer, layer_dict
from borescan.physics.rod import rod_holes_with_effects
from borescan.physics.tri import bore_with_effects
from borescan.synthetic.scenes import (
    ROD_NOISE_MM,
    TRI_NOISE_MM,
    RodScene,
    TriScene,
    default_rod_scene,
    default_tri_scene,
    rod_readings_with_effects,
    tri_phi,
    tri_readings,
    tri_static_readings_with_effects,
)

__all__ = [
    "SimulatedScan",
    "simulate_tri_spindle",
    "simulate_tri_static",
    "simulate_rod",
    "write_simulated",
    "load_truth",
    "started_at_plus",
]


# --------------------------------------------------------------------------- generators


@dataclass
class SimulatedScan:
    """A simulated scan: meta, readings, spindle stream and truth.

    A simulated scan: ``meta`` (scan.json), ``lds`` and ``spindle`` frames per
    ``raw-scan-format.md``, and the ground ``truth`` (written outside the raw tree).
    """

    meta: dict
    lds: pl.DataFrame
    spindle: pl.DataFrame | None
    truth: dict = field(default_factory=dict)

    @property
    def scan_id(self) -> str:
        """The scan's id."""
        return self.meta["scan_id"]


def _t_ns(sample: np.ndarray, rate_hz: float) -> np.ndarray:
    return np.round(sample.astype(np.float64) * (1e9 / rate_hz)).astype(np.int64)


def _finish_readings(
    v: np.ndarray,
    channels,
    effects: list[Effect],
    device_type: str,
    range_mm,
    noise_mm: float,
    rng: np.random.Generator,
) -> np.ndarray:
    """Noise, then quantization and outliers, then null (NaN) outside [0, range_mm]."""
    v = v + rng.normal(0.0, noise_mm, v.shape) if noise_mm > 0 else v.copy()
    v = apply_effects(
        v,
        np.zeros(v.shape[0]),
        channels,
        effects,
        device_type=device_type,
        range_mm=range_mm,
        stages=("output",),
        rng=rng,
    )
    rng_arr = np.asarray(range_mm, dtype=float)
    with np.errstate(invalid="ignore"):
        v[(v < 0.0) | (v > rng_arr)] = np.nan
    return v


def _lds_frame(
    sample: np.ndarray, t_ns: np.ndarray, channels, values: np.ndarray, pose: np.ndarray | None
) -> pl.DataFrame:
    """Long lds frame sorted by sample, then sensor, with the spec's dtypes."""
    n, c = values.shape
    vals = values.reshape(-1)
    cols = {
        "sample": pl.Series("sample", np.repeat(sample, c), dtype=pl.Int64),
        "t_ns": pl.Series("t_ns", np.repeat(t_ns, c), dtype=pl.Int64),
        "sensor": pl.Series("sensor", np.tile(np.asarray(channels, dtype=np.int16), n), dtype=pl.Int16),
        "value_mm": pl.Series("value_mm", vals, dtype=pl.Float64, nan_to_null=True),
    }
    if pose is None:
        cols["pose"] = pl.Series("pose", [None] * (n * c), dtype=pl.Int32)
    else:
        cols["pose"] = pl.Series("pose", np.repeat(pose, c), dtype=pl.Int32)
    return pl.DataFrame(cols)


def _sensors_meta(
    device_id: str, channels, range_mm, model: str, linearity_fs: float, repeatability_mm: float
) -> list[dict]:
    return [
        {
            "channel": int(c),
            "model": model,
            "serial": f"{device_id}-S{int(c)}",
            "range_mm": float(r),
            "linearity_fs": linearity_fs,
            "repeatability_mm": repeatability_mm,
        }
        for c, r in zip(channels, range_mm)
    ]


def _temperature(scene_t: float, effects: list[Effect]) -> float:
    for e in effects:
        if e.name == "thermal_expansion":
            return e.params["temperature_c"]
    return scene_t


def _base_meta(
    scan_id, night, kind, started_at, device, sample_rate_hz, sensors, artifact, temperature_c, seed, extra
) -> dict:
    if started_at is None:
        started_at = f"{night}T22:00:00Z"
    meta = {
        "format": "borescan-raw/1",
        "scan_id": scan_id,
        "night": night,
        "started_at": started_at,
        "kind": kind,
        "device": device,
        "sample_rate_hz": float(sample_rate_hz),
        "sensors": sensors,
        "artifact": artifact,
        "environment": {"temperature_c": float(temperature_c)},
        "operator": "night-shift",
        "acquisition": {"software": f"borescan-simulate {__version__}", "simulated": True, "seed": seed},
    }
    meta.update(extra or {})
    return meta


def _default_artifact(diameter_mm: float, cte_per_k: float) -> dict:
    """Return a ring gauge of the scene's diameter.

    Return a ring gauge of the scene's diameter: RG-275 (certificate RG-275/2026-03) for the default
    275.029 mm, else one gauge per diameter (its certificate id names the value, so two simulated
    gauges never share a certificate with different values: ingest quarantines that).
    """
    if abs(diameter_mm - 275.029) < 1e-9:
        ident, cert = "RG-275", "RG-275/2026-03"
    else:
        ident = f"RG-{round(diameter_mm)}"
        cert = f"{ident}/{diameter_mm:.6f}"
    return {
        "id": ident,
        "type": "ring_gauge",
        "nominal_diameter_mm": diameter_mm,
        "certified_diameter_mm": diameter_mm,
        "u_diameter_mm": 0.0015,
        "k": 2,
        "certificate": cert,
        "cte_per_k": cte_per_k,
    }


def _tri_device(device_id: str, nominal_beams: Beams | None, truth_beams: Beams) -> dict:
    return {
        "id": device_id,
        "type": "tri_lds",
        "nominal": {"beams": (nominal_beams or truth_beams).to_nominal()},
    }


def simulate_tri_spindle(
    scene: TriScene | None = None,
    *,
    scan_id: str = "SIM-TRI-SPINDLE",
    night: str = "2026-11-20",
    kind: str = "calibration",
    n_rev: float = 60.0,
    effects: Iterable[Effect] = (),
    noise_mm: float = TRI_NOISE_MM,
    seed: int = 0,
    device_id: str = "TRI-01",
    nominal_beams: Beams | None = None,
    artifact: dict | None = None,
    spindle_label: str = "P1",
    center_xy_mm: tuple[float, float] | None = None,
    encoder: bool = True,
    spindle_rate_hz: float = 50.0,
    started_at: str | None = None,
    extra_meta: dict | None = None,
) -> SimulatedScan:
    """Simulate a spindle scan (``n_rev`` revolutions at ``scene.rpm_nominal``).

    Samples k = 0..n-1 at t = k / sample_rate_hz, n = round(n_rev 60 / rpm * rate); readings
    from :func:`tri_readings`, then noise N(0, noise_mm^2), quantization, outliers, nulls.
    The spindle stream runs on its own clock at ``spindle_rate_hz``.

    Returns
    -------
    SimulatedScan
    """
    scene = scene or default_tri_scene()
    effects = as_effects(effects)
    rng = np.random.default_rng(seed)
    channels = scene.beams.channels
    n = int(round(_duration_s(scene, n_rev) * scene.sample_rate_hz))
    sample = np.arange(n, dtype=np.int64)
    t_ns = _t_ns(sample, scene.sample_rate_hz)
    t_s = t_ns * 1e-9
    v_true = tri_readings(scene, t_s, effects)
    v = _finish_readings(v_true, channels, effects, "tri_lds", scene.range_mm, noise_mm, rng)
    lds = _lds_frame(sample, t_ns, channels, v, None)

    duration_s = n / scene.sample_rate_hz
    m = int(math.floor(duration_s * spindle_rate_hz)) + 1
    ts_ns = _t_ns(np.arange(m, dtype=np.int64), spindle_rate_hz)
    kinematic = [e for e in effects if e.spec.stage == "kinematics"]
    angle = tri_phi(scene, ts_ns * 1e-9, kinematic)  # the spec: phi(t) is the encoder angle itself
    spindle = pl.DataFrame(
        {
            "t_ns": pl.Series("t_ns", ts_ns, dtype=pl.Int64),
            "angle_rad": pl.Series("angle_rad", angle if encoder else [None] * m, dtype=pl.Float64),
            "x_mm": pl.Series("x_mm", np.full(m, float(scene.spindle_xy_mm[0])), dtype=pl.Float64),
            "y_mm": pl.Series("y_mm", np.full(m, float(scene.spindle_xy_mm[1])), dtype=pl.Float64),
            "rpm": pl.Series("rpm", scene.commanded_rpm(ts_ns * 1e-9), dtype=pl.Float64),
        }
    )
    extra = {
        "spindle": {
            "rpm_nominal": float(scene.rpm_nominal),
            "direction": scene.direction,
            "position": {
                "label": spindle_label,
                "x_mm": float(scene.spindle_xy_mm[0]),
                "y_mm": float(scene.spindle_xy_mm[1]),
            },
        }
    }
    if center_xy_mm is not None:
        extra["center"] = {
            "x_mm": float(center_xy_mm[0]),
            "y_mm": float(center_xy_mm[1]),
            "method": "centring scan",
        }
    extra.update(extra_meta or {})
    meta = _base_meta(
        scan_id,
        night,
        kind,
        started_at,
        _tri_device(device_id, nominal_beams, scene.beams),
        scene.sample_rate_hz,
        _sensors_meta(device_id, channels, scene.range_mm, "HG-C1030", 0.001, 0.010),
        artifact or _default_artifact(2 * scene.bore_radius_20_mm, scene.cte_per_k),
        _temperature(scene.temperature_c, effects),
        seed,
        extra,
    )
    bore = bore_with_effects(
        scene.bore(), sort_effects(effects, "tri_lds", channels)["bore"], scene.cte_per_k
    )
    truth = _truth(
        meta,
        scene.to_dict(),
        effects,
        noise_mm,
        seed,
        n_samples=n,
        extra={
            "encoder": encoder,
            "n_rev": n_rev,
            "bore_radius_mm": bore.radius_mm,
            "reading_mean_mm": np.nanmean(v_true, axis=0).tolist(),
        },
    )
    return SimulatedScan(meta, lds, spindle, truth)


def _duration_s(scene: TriScene, n_rev: float) -> float:
    """Time the commanded profile needs for ``n_rev`` revolutions [s]."""
    if not scene.rpm_profile:
        return n_rev * 60.0 / scene.rpm_nominal
    target = 2.0 * math.pi * n_rev
    hi = 1.0
    while scene.commanded_angle_rad(hi) < target:
        hi *= 2.0
        if hi > 1e7:
            raise ValueError("the rpm profile never completes the requested revolutions")
    lo = 0.0
    for _ in range(80):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if scene.commanded_angle_rad(mid) < target else (lo, mid)
    return hi


def _pose_samples(n_poses: int, samples_per_pose: int, pose_interval_s: float, rate_hz: float):
    """Sample ticks: pose p occupies ticks p * round(interval * rate) + 0..samples_per_pose-1."""
    stride = max(int(round(pose_interval_s * rate_hz)), samples_per_pose)
    pose = np.repeat(np.arange(n_poses, dtype=np.int64), samples_per_pose)
    sample = pose * stride + np.tile(np.arange(samples_per_pose, dtype=np.int64), n_poses)
    return sample, pose


def simulate_tri_static(
    scene: TriScene | None = None,
    device_xy_mm: np.ndarray | None = None,
    device_angle_rad: np.ndarray | None = None,
    *,
    scan_id: str = "SIM-TRI-STATIC",
    night: str = "2026-11-20",
    kind: str = "verification",
    samples_per_pose: int = 20,
    pose_interval_s: float = 5.0,
    effects: Iterable[Effect] = (),
    noise_mm: float = TRI_NOISE_MM,
    seed: int = 0,
    device_id: str = "TRI-01",
    nominal_beams: Beams | None = None,
    artifact: dict | None = None,
    started_at: str | None = None,
    extra_meta: dict | None = None,
) -> SimulatedScan:
    """Simulate static three-sensor measurements: one block of samples per device pose.

    Pose p (device rotation axis at ``device_xy_mm[p]``, angle ``device_angle_rad[p]``) gives
    ``samples_per_pose`` samples; the ``pose`` column carries p; no spindle stream. By default
    10 poses like Yang 2017 Table 3: within 1.5 mm of the bore centre, random angles.

    Returns
    -------
    SimulatedScan
    """
    scene = scene or default_tri_scene()
    effects = as_effects(effects)
    rng = np.random.default_rng(seed)
    channels = scene.beams.channels
    if device_xy_mm is None or device_angle_rad is None:
        n_poses = 10
        r = 1.5 * np.sqrt(rng.uniform(0, 1, n_poses))
        a = rng.uniform(0, 2 * np.pi, n_poses)
        device_xy_mm = np.asarray(scene.bore_center_xy_mm) + np.stack([r * np.cos(a), r * np.sin(a)], -1)
        device_angle_rad = rng.uniform(0, 2 * np.pi, n_poses)
    xy = np.atleast_2d(np.asarray(device_xy_mm, dtype=float))
    ang = np.atleast_1d(np.asarray(device_angle_rad, dtype=float))
    sample, pose = _pose_samples(len(ang), samples_per_pose, pose_interval_s, scene.sample_rate_hz)
    t_ns = _t_ns(sample, scene.sample_rate_hz)
    v_true = tri_static_readings_with_effects(scene, xy[pose], ang[pose], t_ns * 1e-9, effects)
    v = _finish_readings(v_true, channels, effects, "tri_lds", scene.range_mm, noise_mm, rng)
    lds = _lds_frame(sample, t_ns, channels, v, pose)
    meta = _base_meta(
        scan_id,
        night,
        kind,
        started_at,
        _tri_device(device_id, nominal_beams, scene.beams),
        scene.sample_rate_hz,
        _sensors_meta(device_id, channels, scene.range_mm, "HG-C1030", 0.001, 0.010),
        artifact or _default_artifact(2 * scene.bore_radius_20_mm, scene.cte_per_k),
        _temperature(scene.temperature_c, effects),
        seed,
        extra_meta,
    )
    bore = bore_with_effects(
        scene.bore(), sort_effects(effects, "tri_lds", channels)["bore"], scene.cte_per_k
    )
    poses = [
        {"pose": p, "device_xy_mm": xy[p].tolist(), "device_angle_rad": float(ang[p])}
        for p in range(len(ang))
    ]
    truth = _truth(
        meta,
        scene.to_dict(),
        effects,
        noise_mm,
        seed,
        n_samples=len(sample),
        extra={"poses": poses, "bore_radius_mm": bore.radius_mm, "diameter_mm": 2 * bore.radius_mm},
    )
    return SimulatedScan(meta, lds, None, truth)


def simulate_rod(
    scene: RodScene | None = None,
    alpha_rad: np.ndarray | None = None,
    *,
    n_poses: int = 24,
    samples_per_pose: int = 5,
    pose_interval_s: float = 3.0,
    scan_id: str = "SIM-ROD",
    night: str = "2026-11-20",
    kind: str = "measurement",
    effects: Iterable[Effect] = (),
    noise_mm: float = ROD_NOISE_MM,
    seed: int = 0,
    device_id: str = "ROD-01",
    nominal_layers: Sequence[RodLayer] | None = None,
    artifact: dict | None = None,
    features: Sequence[str] | None = None,
    started_at: str | None = None,
    extra_meta: dict | None = None,
) -> SimulatedScan:
    """Simulate a hand-turned measuring rod: ``n_poses`` stationary rotations, a few samples each.

    Rotations alpha_p = alpha_0 + 2 pi (p + U(-0.3, 0.3)) / n_poses (Wang 2017: turned "randomly
    and discretely"); readings from :func:`rod_readings_with_effects`, noise, quantization,
    outliers, nulls. The nominal layers in scan.json have d = gamma = 0 and phi = 0 (Wang §3.5).

    Returns
    -------
    SimulatedScan
    """
    scene = scene or default_rod_scene()
    effects = as_effects(effects)
    rng = np.random.default_rng(seed)
    channels = scene.channels
    if alpha_rad is None:
        jitter = rng.uniform(-0.3, 0.3, n_poses)
        alpha_rad = rng.uniform(0, 2 * np.pi) + 2 * np.pi * (np.arange(n_poses) + jitter) / n_poses
    alpha = np.atleast_1d(np.asarray(alpha_rad, dtype=float))
    sample, pose = _pose_samples(len(alpha), samples_per_pose, pose_interval_s, scene.sample_rate_hz)
    t_ns = _t_ns(sample, scene.sample_rate_hz)
    v_true = rod_readings_with_effects(scene, alpha[pose], effects, t_ns * 1e-9)
    v = _finish_readings(v_true, channels, effects, "rod", scene.range_mm, noise_mm, rng)
    lds = _lds_frame(sample, t_ns, channels, v, pose)
    features = list(features or [f"H{c}" for c in channels])
    if nominal_layers is None:
        nominal_layers = [replace(lay, d_mm=0.0, gamma_rad=0.0, phi_rad=0.0) for lay in scene.layers]
    if artifact is None:
        artifact = {
            "id": "PART-2H",
            "type": "part",
            "nominal_diameter_mm": 150.0,
            "cte_per_k": scene.cte_per_k,
            "features": [
                {"id": f, "z_mm": float(lay.h_mm), "nominal_diameter_mm": 150.0}
                for f, lay in zip(features, scene.layers)
            ],
        }
    device = {
        "id": device_id,
        "type": "rod",
        "nominal": {"layers": [layer_dict(lay) for lay in nominal_layers]},
    }
    extra = {
        "rod": {
            "layers": [
                {"channel": int(lay.channel), "feature": f, "h_mm": float(lay.h_mm)}
                for f, lay in zip(features, scene.layers)
            ]
        }
    }
    extra.update(extra_meta or {})
    meta = _base_meta(
        scan_id,
        night,
        kind,
        started_at,
        device,
        scene.sample_rate_hz,
        _sensors_meta(device_id, channels, scene.range_mm, "OD2-P30W04", 0.0025, 0.020),
        artifact,
        _temperature(scene.temperature_c, effects),
        seed,
        extra,
    )
    radii = [
        h.radius_mm
        for h in rod_holes_with_effects(
            scene.holes, sort_effects(effects, "rod", channels)["bore"], scene.cte_per_k
        )
    ]
    truth = _truth(
        meta,
        scene.to_dict(),
        effects,
        noise_mm,
        seed,
        n_samples=len(sample),
        extra={"alpha_rad": alpha.tolist(), "diameters_mm": {f: 2 * r for f, r in zip(features, radii)}},
    )
    return SimulatedScan(meta, lds, None, truth)


def _truth(
    meta: dict, scene: dict, effects: list[Effect], noise_mm: float, seed: int, n_samples: int, extra: dict
) -> dict:
    return {
        "scan_id": meta["scan_id"],
        "night": meta["night"],
        "device_id": meta["device"]["id"],
        "device_type": meta["device"]["type"],
        "kind": meta["kind"],
        "scene": scene,
        "effects": effects_to_dicts(effects),
        "noise_sigma_mm": noise_mm,
        "seed": seed,
        "n_samples": n_samples,
        **extra,
    }


# --------------------------------------------------------------------------- writing


def write_simulated(sim: SimulatedScan, raw_root: Path | str, truth_root: Path | str) -> Path:
    """Write the scan in ``borescan-raw/1`` under ``raw_root`` and its truth outside it.

    The scan goes through :func:`borescan.rawio.write_scan` (validated, atomic, write-once); truth goes to
    ``<truth_root>/<scan_id>.truth.json``.

    Returns
    -------
    Path of the scan folder.
    """
    raw_root, truth_root = Path(raw_root), Path(truth_root)
    path = rawio.write_scan(raw_root, sim.meta, sim.lds, sim.spindle)
    truth_root.mkdir(parents=True, exist_ok=True)
    tmp = truth_root / f".{sim.scan_id}.truth.json.tmp"
    tmp.write_text(json.dumps(json_ready(sim.truth), indent=2, sort_keys=True) + "\n")
    os.replace(tmp, truth_root / f"{sim.scan_id}.truth.json")
    return Path(path)


def load_truth(truth_root: Path | str, scan_id: str) -> dict:
    """Read ``<truth_root>/<scan_id>.truth.json`` (evaluation code only; the pipeline never reads truth).

    ``truth["scene"]`` rebuilds with :meth:`TriScene.from_dict` / :meth:`RodScene.from_dict`,
    ``truth["effects"]`` with :func:`borescan.effects.effects_from_dicts`.
    """
    return json.loads((Path(truth_root) / f"{scan_id}.truth.json").read_text())


def started_at_plus(night: str, hour: int, minute: int) -> str:
    """ISO 8601 UTC timestamp ``night`` + hh:mm (hours >= 24 roll into the next day)."""
    t = datetime.fromisoformat(night).replace(tzinfo=timezone.utc) + timedelta(hours=hour, minutes=minute)
    return t.strftime("%Y-%m-%dT%H:%M:%SZ")
