"""Calibration records of the history: their ``calibrations`` rows, and which one a result may use.

A calibration is recorded as one row per channel (``calibrations`` table of ``outputs.md``); a
tri_lds row carries the whole :class:`~borescan.calibration.TriCalibration` as
``calibration_json``, so a measurement rebuilds the exact object. A rod's layer geometry
(Wang 2017 calibrates nothing) is recorded as a calibration with method ``nominal`` so that its
diameters, too, name the geometry they used.

Which calibration applies (README "A measurement never uses a calibration that failed its
verification or has expired"): the device's latest calibration made on or before the night,
refused when it is older than the validity or has failed a verification, unless the config
allows unverified calibrations.
"""

from __future__ import annotations

import datetime as _dt
import hashlib
import json
import math

import polars as pl

from borescan.calibration import TriCalibration
from borescan.geometry import RodLayer

__all__ = ["choose_calibration", "failed_calibration_ids", "days_between", "calibration_rows",
           "rod_nominal_calibration_rows", "tri_calibration", "rod_layers"]


def days_between(first_night: str, night: str) -> int:
    """Whole days from ``first_night`` to ``night`` (ISO dates)."""
    return (_dt.date.fromisoformat(night) - _dt.date.fromisoformat(first_night)).days


def failed_calibration_ids(verifications: pl.DataFrame) -> set[str]:
    """Calibration ids that failed a verification in ``verifications`` (rows with ``passed`` false)."""
    if verifications.height == 0:
        return set()
    return set(verifications.filter(~pl.col("passed"))["calibration_id"].drop_nulls())


def choose_calibration(calibrations: pl.DataFrame, failed_ids: set[str], device_id: str, night: str,
                       validity_days: int, allow_unverified: bool) -> tuple[str | None, str | None]:
    """The calibration a device's result of ``night`` must use, or the reason there is none.

    The latest calibration of the device made on or before the night (same night included;
    ties broken by calibration id), if it is at most ``validity_days`` old and has not failed a
    verification. A failed or expired latest calibration is refused (never silently replaced by
    an older one) unless ``allow_unverified``.

    Returns
    -------
    (calibration_id, None) or (None, reason)
    """
    none = f"no calibration of device {device_id} on or before night {night}"
    if calibrations.height == 0 or "device_id" not in calibrations.columns:
        return None, none
    c = calibrations.filter((pl.col("device_id") == device_id) & (pl.col("valid_from") <= night))
    if c.height == 0:
        return None, none
    c = c.sort("valid_from", "calibration_id")
    cal_id, valid_from = c["calibration_id"][-1], c["valid_from"][-1]
    if allow_unverified:
        return cal_id, None
    if cal_id in failed_ids:
        return None, f"latest calibration {cal_id} of device {device_id} failed its verification; recalibrate"
    age = days_between(valid_from, night)
    if age > validity_days:
        return None, f"latest calibration {cal_id} of device {device_id} expired ({age} days old, validity {validity_days} days)"
    return cal_id, None


def calibration_rows(cal: TriCalibration, device_type: str, night: str, certificate_path: str | None,
                     raw_sha256: str) -> list[dict]:
    """The ``calibrations`` rows of a three-sensor calibration: one per channel, valid from ``night``."""
    rows = []
    u_beta, u_rho, u_db = cal.u_beta_rad, cal.u_rho_mm, cal.u_d_b_mm
    cal_json = json.dumps(cal.to_dict(), sort_keys=True)
    for i, ch in enumerate(cal.beams.channels):
        rows.append({
            "calibration_id": cal.calibration_id, "device_id": cal.device_id, "device_type": device_type,
            "scan_id": cal.scan_ids[0], "channel": int(ch),
            "rho_mm": float(cal.beams.rho_mm[i]), "d_b_mm": float(cal.beams.d_b_mm[i]), "beta_rad": float(cal.beams.beta_rad[i]),
            "u_rho_mm": float(u_rho[i]), "u_d_b_mm": float(u_db[i]), "u_beta_rad": float(u_beta[i]),
            "method": cal.method, "certificate_path": certificate_path, "night": night, "valid_from": night,
            "status": "valid", "raw_sha256": raw_sha256, "residual_rms_mm": float(cal.residual_rms_mm),
            "calibration_json": cal_json,
        })
    return rows


def rod_nominal_calibration_rows(meta: dict, night: str, scan_id: str) -> list[dict]:
    """The rod's layer geometry from ``device.nominal`` as a calibration record (method ``nominal``).

    The id is ``<device>-nominal-<8 hex of the layers' SHA-256>``, so the same geometry on
    another night is the same calibration. [] when the device lists no layers.
    """
    layers = sorted(((meta.get("device") or {}).get("nominal") or {}).get("layers") or [], key=lambda l: int(l["channel"]))
    if not layers:
        return []
    digest = hashlib.sha256(json.dumps(layers, sort_keys=True).encode()).hexdigest()[:8]
    cal_id = f"{meta['device']['id']}-nominal-{digest}"
    return [{
        "calibration_id": cal_id, "device_id": meta["device"]["id"], "device_type": "rod", "scan_id": scan_id,
        "channel": int(l["channel"]), "l0_mm": float(l["l0"]), "h_mm": float(l.get("h", float("nan"))),
        "phi_rad": float(l.get("phi", 0.0)), "d_mm": float(l.get("d", 0.0)), "gamma_rad": float(l.get("gamma", 0.0)),
        "method": "nominal", "certificate_path": None, "night": night, "valid_from": night, "status": "valid",
    } for l in layers]


def tri_calibration(calibrations: pl.DataFrame, cal_id: str) -> TriCalibration:
    """The :class:`TriCalibration` recorded as ``cal_id`` in ``calibrations`` rows."""
    row = calibrations.filter(pl.col("calibration_id") == cal_id).row(0, named=True)
    return TriCalibration.from_dict(json.loads(row["calibration_json"]))


def rod_layers(layer_rows: pl.DataFrame, channels) -> list[RodLayer]:
    """The rod layers of ``channels`` from a rod calibration's rows (missing or NaN phi, d, gamma, h: 0)."""
    rows = {int(r["channel"]): r for r in layer_rows.iter_rows(named=True)}

    def num(r: dict, k: str) -> float:
        v = r.get(k)
        return float(v) if v is not None and math.isfinite(float(v)) else 0.0

    return [RodLayer(int(ch), num(rows[int(ch)], "h_mm"), float(rows[int(ch)]["l0_mm"]), num(rows[int(ch)], "phi_rad"),
                     num(rows[int(ch)], "d_mm"), num(rows[int(ch)], "gamma_rad")) for ch in channels]
