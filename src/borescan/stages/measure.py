"""Stage ``measure_night``: verify calibrations on certified gauges, then measure the night's parts.

Each scan uses the calibration :func:`borescan.calibrations.choose_calibration` allows; a scan
without one is quarantined with the reason. Verifications run first and in order (a failed one
bars its calibration from the rest of the night); measurements are spread over processes.

Every diameter carries its GUM budget (:func:`borescan.measure.tri_diameter_with_budget`) and
is given at the scan's temperature (``diameter_mm``) and at 20 degC (``diameter_20_mm``, ISO 1);
a scan without a temperature is refused or flagged ``temperature_assumed`` as the
``uncertainty`` section says. A verification compares the diameter at 20 degC with the gauge's
certificate and decides by the ``laboratory`` section's decision rule.
"""

from __future__ import annotations


import numpy as np
import polars as pl

from borescan import measure, rawio, readings, rod
from borescan.artifacts import MissingTemperature, artifact_row
from borescan.calibrate.result import CalibrationError
from borescan.calibrations import (
    choose_calibration,
    choose_rod_calibration,
    failed_calibration_ids,
    tri_calibration,
)
from borescan.config import schema_defaults
from borescan.parallel import map_timed, workers_for
from borescan.stages._common import night_scans, quarantine, read_tables
from borescan.workflow_log import compute_line

__all__ = ["stage_measure", "measure_one", "section"]


def section(cfg: dict, name: str) -> dict:
    """Return config section ``name``, else its schema defaults.

    Config section ``name`` from ``cfg``, else its schema defaults (callers that pass only some
    sections).
    """
    return cfg[name] if cfg.get(name) is not None else schema_defaults()[name]


def stage_measure(
    raw_root,
    night: str,
    results_root,
    scans_table,
    calibration_tables,
    verification_tables_before,
    cfg: dict,
    log=print,
    workers: int = 1,
):
    """Verification scans first, then measurements, each with the calibration it may use.

    ``cfg`` holds the config's ``verification``, ``measurement`` and ``calibration`` sections, and
    ``uncertainty``, ``laboratory`` and ``signal`` (the readings' spike policy; their schema
    defaults where absent).
    Returns (diameters, verifications, artifacts, quarantined). ``verification_tables_before``
    are the verifications of earlier nights (a calibration that failed one is refused).
    """
    tol = float(cfg["verification"]["tolerance_mm"])
    allow = bool(cfg["measurement"]["allow_unverified_calibration"])
    validity = int(cfg["calibration"]["validity_days"])
    unc, lab, clean = (
        section(cfg, "uncertainty"),
        section(cfg, "laboratory"),
        readings.cleaning_policy(section(cfg, "signal")),
    )
    part = {
        "default_tolerance_mm": cfg["measurement"].get("part_tolerance_mm"),
        "rule": lab["decision_rule"],
        "guard_band_factor": float(lab["guard_band_factor"]),
    }
    cals = read_tables(calibration_tables, "calibrations")
    failed = failed_calibration_ids(read_tables(verification_tables_before, "verifications"))
    diam, ver, arts, bad = [], [], {}, []
    items = night_scans(results_root, night, scans_table)
    rod_policy = cfg["measurement"]["rod_without_calibration"]

    def job(row, d):
        if row["device_type"] == "rod":
            cal_id, why = choose_rod_calibration(
                cals, failed, row["device_id"], night, validity, allow, rod_policy
            )
        else:
            cal_id, why = choose_calibration(cals, failed, row["device_id"], night, validity, allow)
        cal = cals.filter(pl.col("calibration_id") == cal_id) if cal_id is not None else None
        return (raw_root, night, results_root, row, d, cal_id, why, cal, tol, unc, lab, part, clean)

    def take(out):
        diam.extend(out["diameters"])
        ver.extend(out["verifications"])
        bad.extend(out["quarantined"])
        if out["artifact"]:
            arts[out["artifact"]["artifact_id"]] = out["artifact"]
        if out["log"]:
            log(out["log"])

    def of_kind(kind):
        return sorted((it for it in items if it[0]["kind"] == kind), key=lambda it: it[0]["scan_id"])

    for row, d in of_kind("verification"):
        ((out, cpu_s),) = map_timed(measure_one, [job(row, d)])
        log(compute_line(row["scan_id"], cpu_s))
        take(out)
        failed.update(v["calibration_id"] for v in out["verifications"] if not v["passed"])
    jobs = [job(row, d) for row, d in of_kind("measurement")]
    log(f"{len(jobs)} measurements on {workers_for(len(jobs), workers)} process(es)")
    ids = [row["scan_id"] for row, _ in of_kind("measurement")]
    for (out, cpu_s), scan_id in zip(map_timed(measure_one, jobs, workers), ids):
        log(compute_line(scan_id, cpu_s))
        take(out)
    frame = lambda rows: pl.DataFrame(rows, infer_schema_length=None) if rows else pl.DataFrame()  # noqa: E731
    return frame(diam), frame(ver), frame(list(arts.values())), bad


#: ``diameters.method`` of a rod hole (rod.solve_rod: Wang 2017 Eq. 16 generalised)
ROD_METHOD = "rod joint solve (Wang Eq. 16 with layer geometry and axis deflection)"


def measure_one(job) -> dict:
    """Measure (and for a verification scan, verify) one scan with the calibration chosen for it.

    Returns {"diameters", "verifications", "quarantined": lists, "artifact": row or None, "log": str}.
    """
    raw_root, night, results_root, row, d, cal_id, why, cals, tol, unc, lab, part, clean = job
    out = {"diameters": [], "verifications": [], "quarantined": [], "artifact": None, "log": None}
    bad = out["quarantined"]
    scan = rawio.load_stored_scan(d)
    meta, sid, dev = scan.meta, scan.scan_id, row["device_id"]
    out["artifact"] = artifact_row(meta)
    if cal_id is None:
        quarantine(results_root, bad, sid, night, "measure", "scan.json", why)
        return out
    try:
        if row["device_type"] == "rod":
            return _measure_rod(out, scan, row, cal_id, cals, tol, unc, lab, part, results_root, night, clean)
        cal = tri_calibration(cals, cal_id)
        res, du = measure.tri_diameter_with_budget(scan, cal, unc, clean)
    except MissingTemperature as err:
        quarantine(results_root, bad, sid, night, "measure", "scan.json", str(err))
        return out
    except (rod.RodSolveError, CalibrationError, ValueError, np.linalg.LinAlgError) as err:
        quarantine(results_root, bad, sid, night, "measure", "lds.parquet", f"measurement failed: {err}")
        return out
    try:
        return _verdicts(out, meta, row, sid, dev, cal_id, res, du, tol, unc, lab, part, results_root, night)
    except ValueError as err:  # no NaN or inf verdict (measure.decide): the scan is set aside, named
        quarantine(results_root, bad, sid, night, "measure", "scan.json", str(err))
        return dict(out, diameters=[], verifications=[])


def _verdicts(out, meta, row, sid, dev, cal_id, res, du, tol, unc, lab, part, results_root, night) -> dict:
    bad = out["quarantined"]  # the diameter with its part verdict, and a gauge scan's verification
    feature = measure.only_feature_id(dict(meta.get("artifact") or {}))  # the bore of a one-bore part
    out["diameters"].append(
        _with_part(
            measure.diameter_row(
                sid,
                dev,
                row["artifact_id"],
                feature,
                res["diameter_mm"],
                du.combined_t.u,
                cal_id,
                res["method"],
                du,
            ),
            meta,
            feature,
            du,
            part,
        )
    )
    msg = (
        f"{sid}: D = {res['diameter_mm']:.4f} mm at {du.temperature.temperature_c:g} degC, "
        f"D20 = {du.diameter_20_mm:.4f} mm +- {du.combined_20.U * 1e3:.2f} um (k = {du.combined_20.k:.2f}) "
        f"({res['method']}, {cal_id})" + _temperature_note(du.temperature)
    )
    if row["kind"] == "verification":
        a = meta.get("artifact") or {}
        if a.get("type") != "ring_gauge" or a.get("certified_diameter_mm") is None:
            quarantine(
                results_root,
                bad,
                sid,
                night,
                "measure",
                "scan.json",
                "verification scan needs a ring_gauge artifact with certified_diameter_mm",
            )
            return out
        v = measure.verify_budget(
            du,
            a,
            tol,
            float(unc["coverage_probability"]),
            lab["decision_rule"],
            float(lab["guard_band_factor"]),
        )
        vrow = measure.verification_row(sid, dev, a["id"], v)
        vrow["calibration_id"] = cal_id
        vrow["temperature_assumed"] = du.temperature.assumed
        out["verifications"].append(vrow)
        msg += (
            f"; error at 20 degC {v.error_mm * 1e3:+.2f} um vs {a['certified_diameter_mm']}: {v.conformity}"
        )
    out["log"] = msg
    return out


#: ``diameters.method`` of a rod hole measured with the design geometry (no gauge calibration)
ROD_METHOD_NOMINAL = (
    ROD_METHOD + " with the design base lengths: NOT TRACEABLE (rod never calibrated on ring gauges)"
)


def _measure_rod(out, scan, row, cal_id, cals, tol, unc, lab, part, results_root, night, clean) -> dict:
    """Return the diameters of a rod scan with their GUM budgets.

    Diameters of a rod scan with their GUM budgets
    (:func:`borescan.measure.rod_diameters_with_budget`);
    for a verification scan, each layer's error against its certified gauge.
    """
    meta, sid, dev = scan.meta, scan.scan_id, row["device_id"]
    res = measure.rod_diameters_with_budget(scan, cals.rows(named=True), unc, cal_id, clean)
    vers = {}
    if row["kind"] == "verification":
        try:
            vers = {v["feature"]: v for v in measure.rod_verifications(scan, res, cal_id, unc, lab, tol)}
        except ValueError as err:
            quarantine(
                results_root,
                out["quarantined"],
                sid,
                night,
                "measure",
                "scan.json",
                f"rod verification: {err}",
            )
            return out
    notes = []
    for r in res:
        du = r["du"]
        out["diameters"].append(
            _with_part(
                measure.diameter_row(
                    sid,
                    dev,
                    row["artifact_id"],
                    r["feature"],
                    r["diameter_mm"],
                    du.combined_t.u,
                    cal_id,
                    ROD_METHOD if r["traceable"] else ROD_METHOD_NOMINAL,
                    du,
                ),
                meta,
                r["feature"],
                du,
                part,
            )
        )
        note = f"{r['feature']} {r['diameter_mm']:.4f} +- {du.combined_t.u * 1e3:.1f} um"
        v = vers.get(r["feature"])
        if v is not None:
            for k in ("budget", "certificate", "raw_files"):
                v.pop(k, None)
            out["verifications"].append(v)
            note += (
                f" (error at 20 degC {v['error_mm'] * 1e3:+.2f} um, "
                f"U(E) {v['expanded_u_error_mm'] * 1e3:.1f} um: "
                f"{str(v['conformity']).upper()}, rule {v['decision_rule']})"
            )
        notes.append(note)
    traceable = all(r["traceable"] for r in res)
    out["log"] = (
        f"{sid}: "
        + ", ".join(notes)
        + (f" ({cal_id})" if traceable else " [design geometry, not traceable]")
        + _temperature_note(res[0]["du"].temperature if res else None)
    )
    return out


def _with_part(row: dict, meta: dict, feature, du, part: dict) -> dict:
    """Return the diameter row with its part's nominal, tolerance and verdict.

    Return the diameter row with its part's nominal, tolerance (scan.json, else
    ``measurement.part_tolerance_mm``),
    deviation at 20 degC and verdict by the laboratory's decision rule
    (:func:`borescan.measure.part_conformity`).
    """
    f = measure.part_feature(dict(meta.get("artifact") or {}), feature)
    tol = f["tolerance_mm"] if f["tolerance_mm"] is not None else part["default_tolerance_mm"]
    row.update(
        measure.part_conformity(
            du.diameter_20_mm,
            du.combined_20.U,
            f["nominal_diameter_mm"],
            None if tol is None else float(tol),
            part["rule"],
            part["guard_band_factor"],
        )
    )
    return row


def _temperature_note(temp) -> str:
    return " [temperature ASSUMED 20 degC: none in scan.json]" if temp is not None and temp.assumed else ""
