"""Stage ``calibrate_night``: calibrate each device from the night's ring-gauge scans; write certificates.

Each three-sensor device (:mod:`borescan.stages.calibrate_tri`) and each rod calibration scan
(:mod:`borescan.stages.calibrate_rod`) is one job: the jobs are spread over the rule's processes and
their rows come back in the order of the device ids, so the tables do not depend on the number of
processes.
"""

from __future__ import annotations


import polars as pl

from borescan import device_model, rawio, readings
from borescan.calibrations import rod_nominal_calibration_rows
from borescan.config import schema_defaults
from borescan.effects import device_model_effects
from borescan.parallel import map_timed, workers_for
from borescan.stages._common import clear_night_folder, config_hash, night_scans
from borescan.stages.calibrate_rod import calibrate_rod_scan
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
    ctx_args = {
        "uncertainty": uncertainty or dflt["uncertainty"],
        "laboratory": laboratory or dflt["laboratory"],
        "verification": verification or dflt["verification"],
        "raw_root": raw_root,
        "scans_table": scans_table,
        "signal": signal or dflt["signal"],
        "devices": devices,
        "night": night,
        "pooled_rows": [r for t in pooled_tables or () for r in pl.read_parquet(t).to_dicts()],
        "auto_nights": auto_nights,
    }
    summary = pl.read_parquet(summary_table) if not isinstance(summary_table, pl.DataFrame) else summary_table
    clear_night_folder(results_root, "calibration", night)  # certificates of a rerun replace the night's
    by_device: dict[str, list] = {}
    for row, d in night_scans(results_root, night, scans_table, kind="calibration", device_type="tri_lds"):
        by_device.setdefault(row["device_id"], []).append((row, d))
    jobs = [("tri", items) for _, items in sorted(by_device.items())]
    jobs += [
        ("rod", [item])
        for item in night_scans(results_root, night, scans_table, kind="calibration", device_type="rod")
    ]
    if jobs:
        log(f"{len(jobs)} calibration job(s) on {workers_for(len(jobs), workers)} process(es)")
    common = (night, results_root, summary, cfg, ctx_args)
    made = {"tri": ([], []), "rod": ([], [])}  # kind -> (calibrations rows, calibration_scans rows)
    bad = []
    timed = map_timed(calibrate_device, [(k, it, common) for k, it in jobs], workers)
    for ((kind, rows, links, q, lines, issued), cpu_s), (_, items) in zip(timed, jobs):
        if certificates is not None:
            certificates.extend(issued)
        made[kind][0].extend(rows)
        made[kind][1].extend(links)
        bad += q
        for line in lines:
            log(line)
        log(compute_line(items[0][0]["device_id"] if kind == "tri" else items[0][0]["scan_id"], cpu_s))
    cal_rows, link_rows = made["tri"]
    for row, d in night_scans(results_root, night, scans_table, device_type="rod"):
        rows = rod_nominal_calibration_rows(rawio.load_scan_json(d), night, row["scan_id"])
        if rows and rows[0]["calibration_id"] not in {r["calibration_id"] for r in cal_rows}:
            cal_rows += rows
            link_rows.append({"calibration_id": rows[0]["calibration_id"], "scan_id": row["scan_id"]})
    cal_rows += made["rod"][0]
    link_rows += made["rod"][1]
    cals = pl.DataFrame(cal_rows, infer_schema_length=None) if cal_rows else pl.DataFrame()
    links = pl.DataFrame(link_rows) if link_rows else pl.DataFrame()
    return cals, links, bad


def calibrate_device(job) -> tuple[str, list[dict], list[dict], list, list[str], list[dict]]:
    """Run one job of :func:`stage_calibrate`.

    A three-sensor device's calibration scans of the night (``"tri"``) or one rod calibration scan
    (``"rod"``). Returns (kind, calibrations rows, calibration_scans rows, quarantined, log lines, certificate
    issue rows).
    """
    kind, items, (night, results_root, summary, cfg, ctx_args) = job
    ctx = _context(ctx_args)
    cal_rows, link_rows, bad, lines = [], [], [], []
    if kind == "tri":
        calibrate_tri_device(
            items, night, results_root, summary, cfg, bad, cal_rows, link_rows, lines.append, ctx
        )
    else:
        ((_row, d),) = items
        calibrate_rod_scan(
            rawio.load_stored_scan(d),
            night,
            results_root,
            bad,
            cal_rows,
            link_rows,
            lines.append,
            ctx,
            cfg,
        )
    return kind, cal_rows, link_rows, bad, lines, ctx.get("certificate_rows", [])


def _context(a: dict) -> dict:
    """Return what a calibration job reads besides its scans.

    Return what a calibration job reads besides its scans: the config sections, the readings' cleaning
    policy, and the device model each device carries (:func:`borescan.device_model.lookup`).
    """
    devices, night = a["devices"], a["night"]
    return {
        "uncertainty": a["uncertainty"],
        "laboratory": a["laboratory"],
        "verification": a["verification"],
        "raw_root": a["raw_root"],
        "scans_table": a["scans_table"],
        "cleaning": readings.cleaning_policy(a["signal"]),
        "device_model": device_model.lookup(
            lambda dev: device_model_effects(devices, dev, night), a["pooled_rows"], night, a["auto_nights"]
        ),
    }
