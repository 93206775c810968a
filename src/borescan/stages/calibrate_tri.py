"""Stage ``calibrate_night``, three-sensor devices: one device's calibration from its ring-gauge scans.

The device's scans of the night are fitted together (``full_lsq``) or one by one (``yang2017``);
each calibration carries its GUM budget (:mod:`borescan.calibrate.budget`), its covariance the
budget's combined one, and gets its certificate (ISO/IEC 17025 7.8) with the night's verifications
of the device made with it; its dates come from the data and the night's record
(:func:`certificate.certificate_dates`).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import polars as pl

from borescan import __version__, certificate, certificate_issue, device_model, measure, night_config, rawio
from borescan.artifacts import MissingTemperature
from borescan.calibrate.budget import with_budget
from borescan.calibrate.result import CalibrationError
from borescan.calibrate.sensitivities import full_residuals
from borescan.calibrations import calibration_rows
from borescan.geometry import Beams
from borescan.preconditions import (
    CALIBRATE_STAGE,
    CALIBRATION_NEEDS_BEAMS,
    NO_SPINDLE_REASON,
    calibration_revolutions_problem,
    design_beams,
    summary_period_source,
    summary_revolutions,
)
from borescan.stages._common import config_hash, link_into_night, night_scans, ok_scans
from borescan.stages.calibrate_jobs import (
    CalibrationOutcome,
    FitBlame,
    SpindleInputs,
    TriCalibrationContext,
    TriDeviceJob,
    UsableScans,
)
from borescan.stages.calibration_fit import (
    budget_of,
    fit_device_calibration,
    scan_conditions,
    spindle_inputs,
    yang_from_summary,
)

__all__ = ["calibrate_tri_device"]


def calibrate_tri_device(job: TriDeviceJob) -> CalibrationOutcome:
    """Calibrate one three-sensor device from its calibration scans of the night.

    Write the certificates and return the rows; a scan that cannot be used, or a calibration that fails,
    is quarantined with the reason.
    """
    usable = _usable_scans(job)
    out = CalibrationOutcome(quarantined=usable.quarantined)
    if not usable.scans:
        return out
    # full_lsq fits all calibration scans of the device together; the paper's method
    # calibrates from one scan's extrema, so each scan gives its own calibration.
    pairs = list(zip(usable.scans, usable.inputs))
    groups = [pairs] if job.cfg["method"] != "yang2017" else [[p] for p in pairs]
    for group in groups:
        out = out + _calibrate_group(
            job, [s for s, _ in group], [x for _, x in group], usable.nominal, usable.lost
        )
    return out


def _usable_scans(job: TriDeviceJob) -> UsableScans:
    """Read the job's scans; set aside those a calibration cannot use, each with its reason."""
    min_rev = int(job.cfg["min_revolutions"])
    scans, inputs, nominal, bad = [], [], None, []
    lost = _set_aside_at_ingest(job.ctx.scans_table, job.items[0][0]["device_id"])
    for _row, d in job.items:
        scan = rawio.load_stored_scan(d)
        problem = _unusable(scan, job.summary, min_rev, job.cfg["method"])
        if problem == "":
            lost.append(f"{scan.scan_id} (set aside by the signal stage)")
            continue
        if problem is None:
            try:
                beams = design_beams(scan.meta, CALIBRATION_NEEDS_BEAMS)
                inputs.append(spindle_inputs(scan, job.ctx.uncertainty, job.ctx.cleaning))
                scans.append(scan)
                nominal = nominal or beams  # the first scan's design geometry starts the device's fit
                continue
            except ValueError as err:  # MissingDesignGeometry is one
                problem = ("scan.json", str(err))
        bad.append(job.set_aside(scan.scan_id, *problem))
        lost.append(f"{scan.scan_id} ({problem[0]}: {problem[1]})")
    return UsableScans(tuple(scans), tuple(inputs), nominal, tuple(lost), tuple(bad))


def _unusable(
    scan: rawio.RawScan, summary: pl.DataFrame, min_rev: int, method: str
) -> tuple[str, str] | str | None:
    """Why ``method`` cannot use a scan: (file, reason); "" if the signal stage set it aside; None."""
    s = summary.filter(pl.col("scan_id") == scan.scan_id) if summary.height else summary
    if scan.spindle is None:
        return ("spindle.parquet", NO_SPINDLE_REASON)
    if s.height == 0:
        return ""
    return calibration_revolutions_problem(*summary_revolutions(s, method), min_rev, summary_period_source(s))


def _set_aside_at_ingest(scans_table, device_id: str) -> list[str]:
    """Return the device's calibration scans of the night that ingest set aside, each with its reason."""
    df = pl.read_parquet(scans_table) if not isinstance(scans_table, pl.DataFrame) else scans_table
    if not df.height or "device_id" not in df.columns:
        return []
    ok = set(ok_scans(df)["scan_id"])
    rows = df.filter(
        (pl.col("device_id") == device_id) & (pl.col("kind") == "calibration") & ~pl.col("scan_id").is_in(ok)
    )
    return [f"{r['scan_id']} (set aside at ingest: {r['reason']})" for r in rows.sort("scan_id").to_dicts()]


def _calibrate_group(
    job: TriDeviceJob, scans: list, inputs: list[SpindleInputs], nominal: Beams, lost: tuple[str, ...]
) -> CalibrationOutcome:
    """Calibrate one device from ``scans`` (already checked), budget it, write the certificate, add rows.

    A calibration that fails (no convergence, rank deficiency, no real solution, no budget)
    quarantines the scans it was made from, with the reason; when some of a joint fit's scans
    calibrate alone, the others are set aside and the rest calibrated again without them.
    """
    method, device_id = job.cfg["method"], scans[0].meta["device"]["id"]
    try:
        if method == "yang2017":
            if job.ctx.device_model(device_id, inputs[0].channels):
                job.log(
                    f"{device_id}: its device model is not carried by yang2017 (extrema of the recorded "
                    "readings)"
                )
            fit = yang_from_summary(scans[0], inputs[0], job.summary, nominal, job.night, log=job.log)
        else:
            model = job.ctx.device_model(device_id, inputs[0].channels)
            inputs = device_model.carry(model, device_id, inputs, job.log)
            fit = fit_device_calibration(scans, inputs, nominal, job.cfg, night=job.night, model=model)
        budget = budget_of(
            fit,
            scans,
            inputs,
            job.ctx.uncertainty,
            summary=job.summary,
            nominal=nominal,
            night=job.night,
            position_accuracy_mm=float(job.cfg["position_accuracy_mm"]),
        )
    except (CalibrationError, ValueError, np.linalg.LinAlgError) as err:
        blame = _blame_failed_fit(job, scans, inputs, err, nominal, lost)
        out = CalibrationOutcome(quarantined=blame.quarantined)
        if blame.kept:
            kept = blame.kept
            out = out + _calibrate_group(
                job, [scans[i] for i in kept], [inputs[i] for i in kept], nominal, lost + blame.lost
            )
        return out
    return _certify(job, scans, inputs, with_budget(fit, budget), budget)


def _certify(job: TriDeviceJob, scans: list, inputs: list[SpindleInputs], cal, budget) -> CalibrationOutcome:
    """Write the certificate of calibration ``cal`` (with its GUM ``budget``) and return its rows."""
    ctx, cfg, night, results_root = job.ctx, job.cfg, job.night, job.results_root
    device_id, ids = cal.device_id, [s.scan_id for s in scans]
    raw_files = {f"{s.scan_id}/{k}": v for s in scans for k, v in sorted(s.sha256.items())}
    p = float(ctx.uncertainty["coverage_probability"])
    out_dir = certificate.certificate_night_dir(results_root, cal, night)
    first = inputs[0]
    residuals = {"t_s": np.zeros(0), "residual_mm": np.zeros((0, len(cal.beams.channels)))}
    if cal.method == "full_lsq":
        residuals = {
            "t_s": first.t_s,
            "residual_mm": full_residuals(
                cal, first.t_s, first.readings_mm, first.radius_mm, ids[0], angle_model=first.angle_model
            ),
        }
    ver_rows = _night_verifications(cal, night, job.results_root, ctx, job.log)
    conditions = certificate.calibration_conditions(
        first.temperature,
        first.cte,
        first.radius_mm,
        float(cfg["position_accuracy_mm"]),
        p,
        [scan_conditions(s, x, job.summary) for s, x in zip(scans, inputs)],
    )
    dates = certificate.certificate_dates(
        [s.meta for s in scans],
        night,
        int(cfg["validity_days"]),
        night_config.first_processed(results_root, night),
    )
    art = scans[0].meta.get("artifact") or {}
    cert_paths = certificate.write_certificate(
        cal,
        out_dir,
        device={"id": device_id, "type": "tri_lds", "sensors": scans[0].meta.get("sensors", [])},
        artifact=dict(art, k=art.get("k", 2)),
        conditions=conditions,
        residuals=residuals,
        raw_files=raw_files,
        software_version=__version__,
        budget=budget,
        laboratory=ctx.laboratory,
        coverage_probability=p,
        dates=dates,
        config_hash=config_hash(job.config_sections()),
        verifications=ver_rows,
    )
    link = certificate.certificate_dir(results_root, cal)
    link_into_night(link, out_dir)
    rel_cert = str((link / "certificate.pdf").relative_to(Path(results_root)))
    rows = calibration_rows(cal, "tri_lds", night, rel_cert, rawio.combined_sha256(raw_files))
    issue = certificate_issue.issue_row(cert_paths, results_root, night, residuals)
    for row in rows:
        j = list(cal.beams.channels).index(row["channel"])
        for k, name in enumerate(("beta_rad", "rho_mm", "d_b_mm")):
            comb = budget.combined(3 * j + k, p)
            row[f"expanded_u_{name}"], row[f"k_{name.rsplit('_', 1)[0]}"] = comb.U, comb.k
        row.update(
            coverage_probability=p,
            temperature_c=first.temperature.temperature_c,
            certificate_sha256=json.loads(issue["files_sha256"])["certificate.json"],
            temperature_assumed=first.temperature.assumed,
            recalibration_due=dates["recalibration_due"],
        )
    job.log(
        f"{device_id}: {cal.calibration_id} ({cal.method}) from {', '.join(ids)}; residual rms "
        f"{cal.residual_rms_mm * 1e3:.2f} um; U(d_b) "
        + ", ".join(f"{budget.combined(3 * j + 2, p).U * 1e3:.1f}" for j in range(len(cal.beams.channels)))
        + f" um; {len(ver_rows)} verification(s) in the certificate"
        + (" [gauge temperature ASSUMED 20 degC]" if first.temperature.assumed else "")
    )
    return CalibrationOutcome(
        calibration_rows=tuple(rows),
        calibration_scan_rows=tuple({"calibration_id": cal.calibration_id, "scan_id": sid} for sid in ids),
        certificate_rows=(issue,),
    )


def _blame_failed_fit(
    job: TriDeviceJob,
    scans: list,
    inputs: list[SpindleInputs],
    err: Exception,
    nominal: Beams,
    lost: tuple[str, ...],
) -> FitBlame:
    """Quarantine the scans of a failed calibration, each with the cause; say which are still usable.

    A joint fit of several scans that fails is tried scan by scan: when some scans calibrate alone and others
    do not, only those that do not are set aside (their own failure and the joint one named), and the indices
    of the others are returned to be calibrated without them. Otherwise every scan is set aside with the fit's
    failure. The record names the stage (:data:`CALIBRATE_STAGE`), not a raw file, and lists the partner
    scans set aside before the fit (``lost``): a scan that cannot be calibrated alone says it lost them.
    """
    alone: list[str | None] = []
    if len(scans) > 1 and job.cfg["method"] != "yang2017":
        for s, x in zip(scans, inputs):
            try:
                fit_device_calibration([s], [x], nominal, job.cfg, night=job.night)
                alone.append(None)
            except (CalibrationError, ValueError, np.linalg.LinAlgError) as own:
                alone.append(str(own))
    kept = tuple(i for i, why in enumerate(alone) if why is None)
    if kept and len(kept) < len(scans):
        others = ", ".join(scans[i].scan_id for i in kept)
        bad, gone = [], []
        for s, why in zip(scans, alone):
            if why is not None:
                reason = f"calibration failed on its own: {why} (the joint fit with {others} failed too)"
                bad.append(job.set_aside(s.scan_id, CALIBRATE_STAGE, reason))
                gone.append(f"{s.scan_id} ({CALIBRATE_STAGE}: {reason})")
        return FitBlame(tuple(bad), kept, tuple(gone))
    tail = (
        f"; calibrated without its partner scan(s) set aside before the fit: {'; '.join(lost)}"
        if lost
        else ""
    )
    bad = tuple(job.set_aside(s.scan_id, CALIBRATE_STAGE, f"calibration failed: {err}{tail}") for s in scans)
    return FitBlame(bad, (), ())


def _night_verifications(cal, night: str, results_root, ctx: TriCalibrationContext, log) -> list[dict]:
    """Return the night's ring-gauge verifications of the calibration's device.

    Return the night's ring-gauge verifications of the calibration's device, made with it
    (:func:`borescan.measure.verification_for_certificate`). A scan that cannot be measured is left
    out with a log line (the measure stage quarantines it).
    """
    rows = []
    for _row, d in night_scans(
        results_root, night, ctx.scans_table, kind="verification", device_id=cal.device_id
    ):
        scan = rawio.load_stored_scan(d)
        try:
            row = measure.verification_for_certificate(
                scan,
                cal,
                ctx.uncertainty,
                ctx.laboratory,
                float(ctx.verification["tolerance_mm"]),
                ctx.cleaning,
            )
        except (MissingTemperature, ValueError, np.linalg.LinAlgError) as err:
            log(f"{scan.scan_id}: verification left out of the certificate of {cal.calibration_id}: {err}")
            continue
        if row is not None:
            rows.append(row)
    return rows
