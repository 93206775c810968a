"""Stage ``discrepancy_night``: name the physical effect missing from the model, per scan of a night.

Each scan's ``findings.json`` and ``gap.png`` go to ``discrepancy/night=<night>/<scan_id>/``, one
folder per night that the rule declares (so ``snakemake --report`` shows them);
``discrepancy/<scan_id>`` is a relative symbolic link to the scan's folder, the path the report
page, the README and people use (a copy where the filesystem has no symbolic links).
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import polars as pl

from borescan import discrepancy, rawio, tables
from borescan.discrepancy.calibration_record import calibration_findings, with_calibration_findings
from borescan.discrepancy.examine import discrepancy_settings
from borescan.discrepancy.reference import discrepancy_reference, reference_calibration
from borescan.parallel import map_timed, workers_for
from borescan.stages._common import (
    Quarantined,
    clear_night_folder,
    link_into_night,
    night_folder,
    night_scans,
    quarantine,
    read_tables,
)
from borescan.workflow_log import compute_line

__all__ = ["stage_discrepancy", "findings_rows", "discrepancy_one", "findings_night_dir", "findings_dir"]


def findings_night_dir(results_root, night: str) -> Path:
    """Return the night's folder of per-scan findings (the rule's declared output)."""
    return night_folder(results_root, "discrepancy", night)


def findings_dir(results_root, scan_id: str) -> Path:
    """Return the folder a scan's findings are read from.

    ``discrepancy/<scan_id>``: where a scan's findings.json and gap.png are read (a link into its
    night's folder).
    """
    return Path(results_root) / "discrepancy" / scan_id


def findings_rows(findings: dict) -> list[dict]:
    """Return the ``findings`` rows of one scan's findings.json.

    Return the ``findings`` rows of one scan's findings.json: one per named effect (one row with null
    effect if
    none).
    """
    base = {
        "scan_id": findings["scan_id"],
        "verdict": findings["verdict"],
        "gap_before_mm": (findings.get("gap_before") or {}).get("rms_mm"),
        "gap_after_mm": (findings.get("gap_after") or {}).get("rms_mm"),
        "noise_floor_mm": findings.get("noise_floor_mm"),
        "statement": findings.get("statement"),  # the verdict in one sentence (explained fully or partly)
    }
    named = findings.get("named") or []
    if not named:
        return [dict(base, effect=None, channel=None, parameters=None, uncertainties=None)]
    return [
        dict(
            base,
            effect=n.get("effect"),
            channel=n.get("channel"),
            parameters=json.dumps(n.get("parameters") or {}, sort_keys=True),
            uncertainties=json.dumps(n.get("uncertainties") or {}, sort_keys=True),
        )
        for n in named
    ]


def stage_discrepancy(
    raw_root,
    night: str,
    results_root,
    scans_table,
    calibration_tables,
    cfg: dict,
    log=print,
    workers: int = 1,
    findings_tables=None,
) -> tuple[pl.DataFrame, list[Quarantined]]:
    """Examine every scan of a night for model discrepancy.

    Model-discrepancy examination of every scan of a night (``discrepancy/night=<night>/<scan_id>/``,
    read as ``discrepancy/<scan_id>/``).

    Each scan is compared with its device as :func:`borescan.discrepancy.reference.discrepancy_reference`
    says; the named missing effect, the gap before and after and the noise floor go to
    ``findings.json`` (with ``reference`` naming what the scan was compared with), the residual
    plots to ``gap.png``. ``cfg`` is the config's ``discrepancy`` section. Scans are spread over
    ``workers`` processes. A scan read against a three-sensor calibration then gets what the examinations
    of that calibration's own scans found (``calibration_findings``: this night's, or an earlier night's in
    ``findings_tables``; :mod:`borescan.discrepancy.calibration_record`).
    """
    settings = discrepancy_settings(cfg)
    clear_night_folder(results_root, "discrepancy", night)
    cals = read_tables(calibration_tables or [], "calibrations")
    jobs, read_against = [], {}
    for row, d in night_scans(results_root, night, scans_table):
        ref_kw, ref = discrepancy_reference(cals, row["device_id"], row["device_type"], night)
        jobs.append((raw_root, night, results_root, d, settings, ref_kw, ref))
        read_against[row["scan_id"]] = reference_calibration(
            cals, row["device_id"], row["device_type"], night
        )
    log(f"{len(jobs)} scans on {workers_for(len(jobs), workers)} process(es)")
    rows, bad = [], []
    for (r, q, msg), cpu_s in map_timed(discrepancy_one, jobs, workers):
        rows += r
        bad += q
        log(msg)
        log(compute_line(msg.split(" ", 1)[0].rstrip(":"), cpu_s))
    earlier = read_tables(findings_tables or [], "findings").to_dicts()
    temps = {}
    if cals.height and "temperature_c" in cals.columns:
        temps = {
            r["calibration_id"]: r["temperature_c"]
            for r in cals.select("calibration_id", "temperature_c").to_dicts()
        }
    rows = _with_calibration_records(results_root, night, rows, earlier, read_against, temps)
    return tables.frame("findings", rows), bad


def _with_calibration_records(
    results_root, night: str, rows: list[dict], earlier: list[dict], read_against, cal_temperatures: dict
):
    """Add ``calibration_findings`` to each examined scan's findings.json; return the night's rows updated.

    ``read_against``: scan id -> the calibration it was examined against (None: the design, or a rod). A scan
    of that calibration itself gets ``null`` (it is the record), as does one read against no calibration.
    ``cal_temperatures``: calibration id -> the temperature [degC] it read its gauge at.
    """
    out = []
    for sid in dict.fromkeys(r["scan_id"] for r in rows):
        path = findings_night_dir(results_root, night) / sid
        findings = json.loads((path / "findings.json").read_text())
        cal = read_against.get(sid)
        if cal is None or sid in cal.scan_ids:
            findings["calibration_findings"] = None
        else:
            record = calibration_findings(
                cal.calibration_id, cal.scan_ids, earlier + rows, cal_temperatures.get(cal.calibration_id)
            )
            findings = with_calibration_findings(findings, record)
        discrepancy.write_findings(findings, path)
        out += findings_rows(findings)
    return out


def discrepancy_one(job) -> tuple[list[dict], list[Quarantined], str]:
    """Examine one scan, write findings.json and gap.png: (findings rows, quarantined, log line)."""
    raw_root, night, results_root, d, settings, ref_kw, ref = job
    bad: list[Quarantined] = []
    scan = rawio.load_stored_scan(d)
    out_dir = findings_night_dir(results_root, night) / scan.scan_id
    try:
        ex = discrepancy.analyse_scan(scan, **settings, **ref_kw)
        findings = ex.findings
        findings["reference"] = ref
        discrepancy.write_findings(findings, out_dir)
        discrepancy.plot_gap(ex, out_dir / "gap.png")
        link_into_night(findings_dir(results_root, scan.scan_id), out_dir)
    except (ValueError, KeyError, ArithmeticError) as err:
        shutil.rmtree(out_dir, ignore_errors=True)  # no half-written findings of a scan set aside
        quarantine(
            results_root,
            bad,
            scan.scan_id,
            night,
            "discrepancy",
            getattr(err, "file", "lds.parquet"),
            f"model-discrepancy examination failed: {err}",
        )
        return [], bad, f"{scan.scan_id}: quarantined ({err})"
    named = ", ".join(
        f"{n['effect']}" + (f" ch{n['channel']}" if n.get("channel") else "")
        for n in findings.get("named", [])
    )
    msg = (
        f"{scan.scan_id} vs {ref}: {findings['verdict']}{': ' + named if named else ''} "
        f"(gap {findings['gap_before']['rms_mm'] * 1e3:.2f} -> "
        f"{findings['gap_after']['rms_mm'] * 1e3:.2f} um, "
        f"noise floor {findings['noise_floor_mm'] * 1e3:.2f} um)"
    )
    return findings_rows(findings), bad, msg
