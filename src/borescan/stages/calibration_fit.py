"""How a three-sensor device is calibrated from a night's scans: the full-data fit from raw
spindle scans, and Yang 2017 (Eq. 8-15) from the signal stage's per-channel extrema summary.

Used by the calibrate stage (:mod:`borescan.stages.calibrate`) and by benchmarks that calibrate
raw scans the way a night does (:func:`calibrate_raw_scans`).
"""

from __future__ import annotations

import numpy as np
import polars as pl

from borescan import calibration, kinematics, rawio, signal
from borescan.artifacts import gauge_radius_mm
from borescan.geometry import Beams

__all__ = ["spindle_inputs", "acceptance_rule", "fit_device_calibration", "calibrate_raw_scans", "yang_from_summary"]


def spindle_inputs(scan: rawio.RawScan) -> dict:
    """Times, despiked readings, rotation angle model and positions of a spindle scan for the full fit.

    Raises ``ValueError`` naming ``spindle.parquet`` when its angle/rpm columns give no angle.
    """
    mat = rawio.lds_matrix(scan)
    clean, _ = signal.remove_spikes(np.asarray(mat.values_mm, dtype=float))
    meta, sp = scan.meta, scan.spindle
    sp_meta = meta.get("spindle") or {}
    pos = sp_meta.get("position") or {}
    if pos.get("x_mm") is not None and pos.get("y_mm") is not None:
        spindle_xy = (float(pos["x_mm"]), float(pos["y_mm"]))
    else:
        spindle_xy = (float(sp["x_mm"].mean()), float(sp["y_mm"].mean()))
    center = meta.get("center")
    try:
        angle_model = kinematics.angle_model_of_scan(meta, sp)
    except ValueError as err:
        raise ValueError(f"{scan.scan_id}: spindle.parquet: {err}") from None
    sensors = {int(s["channel"]): s for s in meta.get("sensors", [])}
    return {
        "t_s": np.asarray(mat.t_s, dtype=float), "readings": clean, "channels": tuple(mat.channels),
        "spindle_xy": spindle_xy, "center_xy": None if not center else (float(center["x_mm"]), float(center["y_mm"])),
        "rpm": float(abs(angle_model.mean_omega_rad_s()) * 60.0 / (2.0 * np.pi)),
        "direction": sp_meta.get("direction", "ccw"), "angle_model": angle_model,
        "range_mm": [float((sensors.get(ch) or {}).get("range_mm") or 10.0) for ch in mat.channels],
        "R": gauge_radius_mm(meta),
    }


def acceptance_rule(cal_cfg: dict) -> calibration.AcceptanceRule:
    """The calibration section's acceptance settings as a :class:`calibration.AcceptanceRule`."""
    return calibration.AcceptanceRule(
        max_residual_to_noise=float(cal_cfg["max_residual_to_noise"]), head_radius_mm=float(cal_cfg["head_radius_mm"]),
        position_accuracy_mm=float(cal_cfg["position_accuracy_mm"]),
        speed_scale_range=(float(cal_cfg["speed_scale_min"]), float(cal_cfg["speed_scale_max"])),
    )


def fit_device_calibration(scans, inputs, nominal: Beams, cal_cfg: dict, night: str | None = None):
    """Full-data calibration of one device from its spindle scans (:func:`spindle_inputs` of each).

    Raises ``calibration.CalibrationError`` (naming the scans and the reason) when the fit fails or is refused.
    """
    raw_files = {f"{s.scan_id}/{k}": v for s in scans for k, v in sorted(s.sha256.items())}
    return calibration.fit_full_calibration(
        [x["t_s"] for x in inputs], [x["readings"] for x in inputs], inputs[0]["channels"], nominal,
        inputs[0]["R"], [x["spindle_xy"] for x in inputs], center_xy_mm=[x["center_xy"] for x in inputs],
        angle_models=[x["angle_model"] for x in inputs], range_mm=inputs[0]["range_mm"],
        rule=acceptance_rule(cal_cfg), scan_ids=[s.scan_id for s in scans],
        device_id=scans[0].meta["device"]["id"], raw_sha256=raw_files, night=night,
    )


def calibrate_raw_scans(scans, cal_cfg: dict, night: str | None = None):
    """Full-data calibration of the calibration scans ``scans`` (``rawio.RawScan``, one device).

    The same path as the night's calibrate stage; ``cal_cfg`` is the config's ``calibration``
    section with its schema defaults. Raises ``calibration.CalibrationError``.
    """
    inputs = [spindle_inputs(s) for s in scans]
    nominal = Beams.from_nominal(scans[0].meta["device"]["nominal"]["beams"])
    return fit_device_calibration(scans, inputs, nominal, cal_cfg, night=night or scans[0].night)


def yang_from_summary(scan: rawio.RawScan, inputs: dict, summary: pl.DataFrame, nominal: Beams, night: str, log=print):
    """Yang 2017 (Eq. 8-15) from the signal stage's per-channel means of one scan.

    Where a channel's status (advanced/backward) is not significant (|n - m| within its
    uncertainty), the beam's side is taken from ``nominal`` and logged. Raises ``ValueError``
    when the scan has no gauge centre (``scan.json`` ``center``, needed for oe, Eq. 9).
    """
    s = summary.filter(pl.col("scan_id") == scan.scan_id).sort("channel")
    statuses = list(s["status"])
    if "status_significant" in s.columns:
        sgn = 1.0 if inputs["direction"] == "ccw" else -1.0
        for i, (ch, ok) in enumerate(zip(s["channel"], s["status_significant"])):
            if not ok:
                statuses[i] = "advanced" if sgn * nominal.rho_mm[i] > 0 else "backward"
                log(f"{scan.scan_id}: channel {ch}: status not significant (|n - m| within its uncertainty); "
                    f"side of the beam taken from device.nominal (rho {nominal.rho_mm[i]:+.3f} mm): {statuses[i]}")
    if inputs["center_xy"] is None:
        raise ValueError("yang2017 needs scan.json center (the gauge centre from a centring scan) for oe (Eq. 9)")
    oe = calibration.yang_oe(inputs["spindle_xy"], inputs["center_xy"])
    spr = float(s["period_samples_per_rev"][0])
    return calibration.yang_calibration(
        s["d_max_mm"].to_numpy(), s["d_min_mm"].to_numpy(), statuses, s["feature_sample"].to_numpy(), spr, inputs["R"], oe,
        channels=tuple(int(c) for c in s["channel"]), device_id=scan.meta["device"]["id"], scan_ids=[scan.scan_id],
        raw_sha256=dict(scan.sha256), beta_ref_rad=float(nominal.beta_rad[0]), beta_nominal_rad=nominal.beta_rad,
        direction=inputs["direction"], u_d_max_mm=s["u_d_max_mm"].to_numpy(), u_d_min_mm=s["u_d_min_mm"].to_numpy(),
        u_feature_sample=s["u_feature_sample"].to_numpy(), night=night,
    )
