"""Stage ``calibrate_night``: calibrate each device from the night's ring-gauge scans; write certificates."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np
import polars as pl

from borescan import __version__, calibration, certificate, rawio
from borescan.calibrations import calibration_rows, rod_nominal_calibration_rows
from borescan.geometry import Beams
from borescan.stages._common import night_scans, quarantine
from borescan.stages.calibration_fit import fit_device_calibration, spindle_inputs, yang_from_summary

__all__ = ["stage_calibrate", "config_hash"]


def config_hash(cfg: dict) -> str:
    """SHA-256 (hex, 16 chars) of a config section, for certificates and provenance."""
    return hashlib.sha256(json.dumps(cfg, sort_keys=True, default=str).encode()).hexdigest()[:16]


def stage_calibrate(raw_root, night: str, results_root, scans_table, summary_table, cfg: dict, log=print):
    """Calibrate every tri_lds device from its calibration scans of the night; write certificates.

    ``cfg["method"]``: ``full_lsq`` (every sample, exact forward model, all calibration scans of
    the device together) or ``yang2017`` (the paper's extrema method, one calibration per scan).
    Rods record their nominal layer geometry. Returns (calibrations rows, calibration_scans rows,
    quarantined). A scan with too few revolutions, or a calibration that does not converge, is
    quarantined with the reason; the other devices and nights go on.
    """
    method, min_rev = cfg["method"], int(cfg["min_revolutions"])
    summary = pl.read_parquet(summary_table) if not isinstance(summary_table, pl.DataFrame) else summary_table
    cal_rows, link_rows, bad = [], [], []
    by_device: dict[str, list] = {}
    for row, d in night_scans(raw_root, night, scans_table, kind="calibration", device_type="tri_lds"):
        by_device.setdefault(row["device_id"], []).append((row, d))
    for _device_id, items in sorted(by_device.items()):
        scans, inputs = [], []
        for _row, d in items:
            scan = rawio.read_scan(d, raw_root=Path(raw_root))
            problem = _unusable(scan, summary, min_rev)
            if problem == "":
                continue  # set aside by the signal stage already
            if problem is None:
                try:
                    inputs.append(spindle_inputs(scan))
                    scans.append(scan)
                    continue
                except ValueError as err:
                    problem = ("scan.json", str(err))
            quarantine(results_root, bad, scan.scan_id, night, "calibrate", *problem)
        if not scans:
            continue
        nominal = Beams.from_nominal(scans[0].meta["device"]["nominal"]["beams"])
        # full_lsq fits all calibration scans of the device together; the paper's method
        # calibrates from one scan's extrema, so each scan gives its own calibration.
        groups = [(scans, inputs)] if method != "yang2017" else [([s], [x]) for s, x in zip(scans, inputs)]
        for group_scans, group_inputs in groups:
            _calibrate_group(group_scans, group_inputs, method, nominal, summary, night, results_root, cfg, bad,
                            cal_rows, link_rows, log)
    for row, d in night_scans(raw_root, night, scans_table, device_type="rod"):
        rows = rod_nominal_calibration_rows(rawio.read_scan_meta(d, raw_root=Path(raw_root)), night, row["scan_id"])
        if rows and rows[0]["calibration_id"] not in {r["calibration_id"] for r in cal_rows}:
            cal_rows += rows
            link_rows.append({"calibration_id": rows[0]["calibration_id"], "scan_id": row["scan_id"]})
    cals = pl.DataFrame(cal_rows, infer_schema_length=None) if cal_rows else pl.DataFrame()
    links = pl.DataFrame(link_rows) if link_rows else pl.DataFrame()
    return cals, links, bad


def _unusable(scan: rawio.RawScan, summary: pl.DataFrame, min_rev: int) -> tuple[str, str] | str | None:
    """Why a calibration scan cannot be used, as (file, reason); "" when the signal stage set it aside; None if usable."""
    s = summary.filter(pl.col("scan_id") == scan.scan_id) if summary.height else summary
    if scan.spindle is None:
        return ("spindle.parquet", "calibration scan has no spindle stream (a ring-gauge calibration turns on a spindle)")
    if s.height == 0:
        return ""
    spr = float(s["period_samples_per_rev"][0])
    recorded = int(s["n_samples_recorded"][0] // spr) if "n_samples_recorded" in s.columns else None
    with_extrema = int(s["n_revolutions_min"].min())
    if recorded is not None and recorded < min_rev:
        return ("lds.parquet", f"too few revolutions to calibrate: {recorded} whole revolutions recorded, "
                               f"at least {min_rev} needed")
    if with_extrema < min_rev:
        return ("lds.parquet", f"calibration failed: a once-per-revolution extremum was found in only {with_extrema} "
                               f"revolutions (at least {min_rev} needed); the readings barely vary with rotation, "
                               "is the spindle at the gauge centre?")
    return None




def _calibrate_group(scans, inputs, method, nominal, summary, night, results_root, cfg, bad, cal_rows, link_rows, log):
    """Calibrate one device from ``scans`` (already checked), write the certificate, add rows.

    A calibration that fails (no convergence, rank deficiency, no real solution) quarantines
    the scans it was made from, with the reason.
    """
    device_id = scans[0].meta["device"]["id"]
    ids = [s.scan_id for s in scans]
    raw_files = {f"{s.scan_id}/{k}": v for s in scans for k, v in sorted(s.sha256.items())}
    try:
        if method == "yang2017":
            cal = yang_from_summary(scans[0], inputs[0], summary, nominal, night, log=log)
        else:
            cal = fit_device_calibration(scans, inputs, nominal, cfg, night=night)
    except (calibration.CalibrationError, ValueError, np.linalg.LinAlgError) as err:
        for s in scans:
            quarantine(results_root, bad, s.scan_id, night, "calibrate", "lds.parquet", f"calibration failed: {err}")
        return
    out_dir = certificate.certificate_dir(results_root, cal)
    scan0, first = scans[0], inputs[0]
    art = scan0.meta.get("artifact") or {}
    if cal.method == "full_lsq":
        residual_mm = calibration.full_residuals(cal, first["t_s"], first["readings"], first["R"], scan0.scan_id,
                                                 angle_model=first["angle_model"])
        residuals = {"t_s": first["t_s"], "residual_mm": residual_mm}
    else:
        residuals = {"t_s": np.zeros(0), "residual_mm": np.zeros((0, len(cal.beams.channels)))}
    revolutions = int(summary.filter(pl.col("scan_id") == scan0.scan_id)["n_revolutions_min"].min())
    certificate.write_certificate(
        cal, out_dir,
        device={"id": device_id, "type": "tri_lds", "sensors": scan0.meta.get("sensors", [])},
        artifact={"id": art.get("id"), "certificate": art.get("certificate"),
                  "certified_diameter_mm": art.get("certified_diameter_mm"),
                  "u_diameter_mm": art.get("u_diameter_mm"), "k": art.get("k", 2)},
        conditions={"temperature_c": (scan0.meta.get("environment") or {}).get("temperature_c"),
                    "spindle_position": (scan0.meta.get("spindle") or {}).get("position"),
                    "rpm": first["rpm"], "revolutions": revolutions, "gauge_radius_at_temperature_mm": first["R"]},
        residuals=residuals, raw_files=raw_files, software_version=__version__, config_hash=config_hash(cfg),
    )
    rel_cert = str((Path(out_dir) / "certificate.pdf").relative_to(Path(results_root)))
    cal_rows += calibration_rows(cal, "tri_lds", night, rel_cert, rawio.combined_sha256(raw_files))
    link_rows += [{"calibration_id": cal.calibration_id, "scan_id": sid} for sid in ids]
    log(f"{device_id}: {cal.calibration_id} ({cal.method}) from {', '.join(ids)}; "
        f"residual rms {cal.residual_rms_mm * 1e3:.2f} um")
