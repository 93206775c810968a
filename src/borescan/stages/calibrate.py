"""Stage ``calibrate_night``: calibrate each device from the night's ring-gauge scans; write certificates.

Each three-sensor device (:mod:`borescan.stages.calibrate_tri`) and each rod calibration scan
(:mod:`borescan.stages.calibrate_rod`) is one job: the jobs are spread over the rule's processes and
their rows come back in the order of the device ids, so the tables do not depend on the number of
processes.
"""

from __future__ import annotations


from pathlib import Path

import polars as pl

from borescan import rawio
from borescan.calibrations import rod_nominal_calibration_rows
from borescan.config import schema_defaults
from borescan.parallel import map_timed, workers_for
from borescan.stages._common import clear_night_folder, config_hash, night_scans
from borescan.stages.calibrate_rod import calibrate_rod_scan
from borescan.stages.calibrate_jobs import (
    CalibrationJob,
    CalibrationJobResult,
    CalibrationOutcome,
    CalibrationSettings,
    RodCalibrationContext,
    TriCalibrationContext,
    TriDeviceJob,
)
from borescan.stages.calibrate_tri import calibrate_tri_device
from borescan.workflow_log import compute_line

__all__ = ["stage_calibrate", "calibrate_device", "config_hash"]


def stage_calibrate(
    raw_root,
    night: str,
    results_root,
    scans_table,
    summary_table,
    cfg: dict,
    log=print,
    *,
    uncertainty: dict | None = None,
    laboratory: dict | None = None,
    verification: dict | None = None,
    devices: dict | None = None,
    pooled_tables=(),
    auto_nights: int = 0,
    signal: dict | None = None,
    workers: int = 1,
    certificates: list | None = None,
):
    """Calibrate every tri_lds device from its calibration scans of the night; write certificates.

    ``uncertainty``, ``laboratory``, ``verification``, ``devices``, ``signal`` (the readings' spike
    policy, :mod:`borescan.readings`): those config sections (schema defaults if None); ``pooled_tables``:
    earlier nights' pooled findings (a device model's values); ``auto_nights``:
    ``discrepancy.device_model_auto_nights``. ``cfg["method"]``: ``full_lsq`` (every sample, exact forward
    model, all calibration scans of the device together) or ``yang2017`` (the paper's extrema method, one
    calibration per scan). A rod's ring-gauge calibration scan calibrates its layers' base lengths
    (:mod:`borescan.rod_calibration`). Devices are calibrated on up to ``workers`` processes. Returns
    (calibrations rows, calibration_scans rows, quarantined). A scan with too few revolutions, or a
    calibration that does not converge, is quarantined with the reason; the other devices and nights go
    on. ``certificates``, when given, receives the ``stage/certificate_issues`` rows of the certificates
    written (:func:`borescan.certificate_issue.issue_row`).
    """
    dflt = schema_defaults()
    settings = CalibrationSettings(
        uncertainty=uncertainty or dflt["uncertainty"],
        laboratory=laboratory or dflt["laboratory"],
        verification=verification or dflt["verification"],
        signal=signal or dflt["signal"],
        raw_root=Path(raw_root),
        scans_table=scans_table,
        devices=devices,
        night=night,
        pooled_rows=tuple(r for t in pooled_tables or () for r in pl.read_parquet(t).to_dicts()),
        auto_nights=auto_nights,
    )
    summary = pl.read_parquet(summary_table) if not isinstance(summary_table, pl.DataFrame) else summary_table
    clear_night_folder(results_root, "calibration", night)  # certificates of a rerun replace the night's
    by_device: dict[str, list] = {}
    for row, d in night_scans(results_root, night, scans_table, kind="calibration", device_type="tri_lds"):
        by_device.setdefault(row["device_id"], []).append((row, d))
    groups = [("tri", tuple(items)) for _, items in sorted(by_device.items())]
    groups += [
        ("rod", (item,))
        for item in night_scans(results_root, night, scans_table, kind="calibration", device_type="rod")
    ]
    jobs = [CalibrationJob(kind, items, Path(results_root), summary, cfg, settings) for kind, items in groups]
    if jobs:
        log(f"{len(jobs)} calibration job(s) on {workers_for(len(jobs), workers)} process(es)")
    made = {"tri": CalibrationOutcome(), "rod": CalibrationOutcome()}
    for (res, cpu_s), job in zip(map_timed(calibrate_device, jobs, workers), jobs):
        if certificates is not None:
            certificates.extend(res.outcome.certificate_rows)
        made[res.kind] = made[res.kind] + res.outcome
        for line in res.log_lines:
            log(line)
        log(compute_line(job.name, cpu_s))
    cal_rows, link_rows = list(made["tri"].calibration_rows), list(made["tri"].calibration_scan_rows)
    for row, d in night_scans(results_root, night, scans_table, device_type="rod"):
        rows = rod_nominal_calibration_rows(rawio.load_scan_json(d), night, row["scan_id"])
        if rows and rows[0]["calibration_id"] not in {r["calibration_id"] for r in cal_rows}:
            cal_rows += rows
            link_rows.append({"calibration_id": rows[0]["calibration_id"], "scan_id": row["scan_id"]})
    cal_rows += made["rod"].calibration_rows
    link_rows += made["rod"].calibration_scan_rows
    cals = pl.DataFrame(cal_rows, infer_schema_length=None) if cal_rows else pl.DataFrame()
    links = pl.DataFrame(link_rows) if link_rows else pl.DataFrame()
    return cals, links, list(made["tri"].quarantined + made["rod"].quarantined)


def calibrate_device(job: CalibrationJob) -> CalibrationJobResult:
    """Run one job of :func:`stage_calibrate` (in a worker process): its outcome and its log lines."""
    ctx, lines = job.settings.context(), []
    night = job.settings.night
    if job.kind == "tri":
        outcome = calibrate_tri_device(
            TriDeviceJob(job.items, night, job.results_root, job.summary, job.cfg, ctx, lines.append)
        )
    else:
        outcome = _calibrate_rod(job, ctx, lines.append)
    return CalibrationJobResult(job.kind, outcome, tuple(lines))


def _calibrate_rod(job: CalibrationJob, ctx: TriCalibrationContext, log) -> CalibrationOutcome:
    """Calibrate a rod job's scan (:func:`borescan.stages.calibrate_rod.calibrate_rod_scan`)."""
    ((_row, d),) = job.items
    rod_ctx = RodCalibrationContext(
        ctx.uncertainty, ctx.laboratory, ctx.verification, ctx.scans_table, ctx.cleaning
    )
    return calibrate_rod_scan(
        rawio.load_stored_scan(d), job.settings.night, job.results_root, rod_ctx, job.cfg, log
    )
