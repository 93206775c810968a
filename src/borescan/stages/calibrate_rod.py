"""Stage ``calibrate_night``, rods: a rod's base lengths from its ring-gauge scan, with certificate.

Each rod calibration scan (kind ``calibration``, device type ``rod``, in certified ring gauges)
gives one calibration (:mod:`borescan.rod_calibration`); its certificate reports the night's gauge
verifications of the rod made with it, as a three-sensor certificate does.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from borescan import __version__, certificate, certificate_issue, night_config, rawio, rod_calibration
from borescan.artifacts import MissingTemperature
from borescan import measure
from borescan.stages._common import config_hash, link_into_night, night_scans, quarantine
from borescan.stages.calibrate_jobs import CalibrationOutcome, RodCalibrationContext

__all__ = ["calibrate_rod_scan"]


def calibrate_rod_scan(
    scan: rawio.RawScan, night: str, results_root, ctx: RodCalibrationContext, cfg: dict, log
) -> CalibrationOutcome:
    """Calibrate a rod's base lengths from one ring-gauge scan.

    Calibrate a rod's base lengths from one ring-gauge scan (:mod:`borescan.rod_calibration`), write
    its certificate and return its rows; a scan that cannot give a calibration is quarantined with the
    reason (in the outcome's ``quarantined``).
    """
    unc, lab = ctx.uncertainty, ctx.laboratory
    bad: list = []
    p = float(unc["coverage_probability"])
    meta, sid = scan.meta, scan.scan_id
    try:
        hold = rod_calibration.calibrate_hold(scan, unc, night=night, cleaning=ctx.cleaning)
    except rod_calibration.RodCalibrationInputError as err:  # what scan.json must give
        quarantine(results_root, bad, sid, night, "calibrate", "scan.json", f"rod calibration: {err}")
        return CalibrationOutcome(quarantined=tuple(bad))
    except ValueError as err:  # the readings: a solve (a RodSolveError says what hold would do) that settles
        quarantine(
            results_root, bad, sid, night, "calibrate", "lds.parquet", f"rod calibration failed: {err}"
        )
        return CalibrationOutcome(quarantined=tuple(bad))
    cal, temp, cte, budget = hold.calibration, hold.temperature, hold.cte, hold.calibration.budget
    out_dir = certificate.certificate_night_dir(results_root, cal, night)
    link = certificate.certificate_dir(results_root, cal)
    rel_cert = str((link / "certificate.pdf").relative_to(Path(results_root)))
    raw_files = hold.raw_files
    rows = hold.rows(night, rel_cert, p)
    ver_rows, _ = _night_rod_verifications(cal, rows, night, results_root, ctx, log)
    dates = certificate.certificate_dates(
        [meta], night, int(cfg["validity_days"]), night_config.first_processed(results_root, night)
    )
    for row in rows:
        row.update(
            temperature_c=temp.temperature_c,
            temperature_assumed=temp.assumed,
            recalibration_due=dates["recalibration_due"],
        )
    cert_paths = certificate.write_rod_certificate(
        cal,
        out_dir,
        device={"id": cal.device_id, "type": "rod", "sensors": meta.get("sensors", [])},
        artifact=dict(meta.get("artifact") or {}),
        temperature=temp,
        cte=cte,
        raw_files=raw_files,
        software_version=__version__,
        laboratory=lab,
        coverage_probability=p,
        dates=dates,
        verifications=ver_rows,
        residuals=certificate.rod_pose_residuals(cal.solution, hold.means_mm),
        config_hash=config_hash(
            {"calibration": cfg, "uncertainty": unc, "laboratory": lab, "verification": ctx.verification}
        ),
    )
    link_into_night(link, out_dir)
    issue = certificate_issue.issue_row(cert_paths, results_root, night)
    for row in rows:
        row["certificate_sha256"] = json.loads(issue["files_sha256"])["certificate.json"]
    log(
        f"{cal.device_id}: {cal.calibration_id} (rod on ring gauges) from {sid}; l0 - nominal "
        + ", ".join(
            f"ch {ch} {1e3 * (a - b):+.2f} um" for ch, a, b in zip(cal.channels, cal.l0_mm, cal.l0_nominal_mm)
        )
        + "; U(l0) "
        + ", ".join(f"{budget.combined(j, p).U * 1e3:.2f}" for j in range(len(cal.channels)))
        + " um"
        + f"; {len(ver_rows)} layer verification(s) in the certificate"
        + (" [gauge temperature ASSUMED 20 degC]" if temp.assumed else "")
    )
    return CalibrationOutcome(
        calibration_rows=tuple(rows),
        calibration_scan_rows=({"calibration_id": cal.calibration_id, "scan_id": sid},),
        certificate_rows=(issue,),
    )


def _night_rod_verifications(
    cal, rows: list[dict], night: str, results_root, ctx: RodCalibrationContext, log
) -> tuple[list[dict], list[dict]]:
    """Return the night's gauge verifications of the rod.

    Return the night's gauge verifications of the rod made with the new calibration (one row per layer,
    :func:`borescan.measure.rod_verifications`) and their scan.json; a scan that cannot be
    measured is left out with a log line (the measure stage quarantines it).
    """
    out, metas = [], []
    for _row, d in night_scans(
        results_root, night, ctx.scans_table, kind="verification", device_id=cal.device_id
    ):
        scan = rawio.load_stored_scan(d)
        try:
            res = measure.rod_diameters_with_budget(
                scan, rows, ctx.uncertainty, cal.calibration_id, ctx.cleaning
            )
            out += measure.rod_verifications(
                scan,
                res,
                cal.calibration_id,
                ctx.uncertainty,
                ctx.laboratory,
                float(ctx.verification["tolerance_mm"]),
            )
            metas.append(scan.meta)
        except (MissingTemperature, ValueError, np.linalg.LinAlgError) as err:
            log(f"{scan.scan_id}: verification left out of the certificate of {cal.calibration_id}: {err}")
    return out, metas
