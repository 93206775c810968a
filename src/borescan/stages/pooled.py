"""Stage ``pooled_night``: examine each device's scans of a window together.

Stage ``pooled_night``: examine each three-sensor device's spindle scans of a window of nights
together, and flag the drift of its calibrations (issue 22).

Per device with at least two spindle scans of kind ``calibration`` or ``verification`` that
ingest accepted (``ok`` in ``scans``; a scan a later stage set aside, e.g. a calibration the
acceptance rule refused, is examined too: the pooled examination may say why) in the window
(the night and the ``discrepancy.pooled_window_nights - 1`` nights before it),
:func:`borescan.discrepancy.pooled.examine_pooled` starts from the device's latest calibration
on or before the night (else ``device.nominal``) and writes
``discrepancy/pooled/night=<night>/<device_id>.json``; its named effects and device-model
terms are the ``pooled_findings`` rows.
The ``calibration_drift`` rows are :func:`borescan.calibrations.calibration_drift` of the
calibrations up to the night, for the pairs whose later calibration is the night's, each
flagged one with the pooled examination's explanation
(:func:`borescan.discrepancy.pooled.drift_explanations`).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import polars as pl

from borescan import rawio, tables
from borescan.atomic import atomic_write_text
from borescan.calibrations import calibration_drift
from borescan.config import schema_defaults
from borescan.discrepancy.examine import _clean, discrepancy_settings
from borescan.discrepancy.pooled import drift_explanations, examine_pooled, pooled_scan
from borescan.effects import device_model_effects
from borescan.discrepancy.reference import discrepancy_reference
from borescan.parallel import map_timed, workers_for
from borescan.stages._common import ok_scans, read_tables
from borescan.workflow_log import compute_line

__all__ = ["POOLED_KINDS", "stage_pooled", "pooled_rows", "drift_rows", "pooled_device", "pooled_dir"]

#: Scan kinds pooled: the gauge scans of a calibration and of a verification (certified artifacts).
POOLED_KINDS = ("calibration", "verification")


def pooled_dir(results_root, night: str) -> Path:
    """Folder of a night's pooled findings (``<device_id>.json``)."""
    return Path(results_root) / "discrepancy" / "pooled" / f"night={night}"


def pooled_rows(findings: dict, night: str, path: str) -> list[dict]:
    """Return the ``pooled_findings`` rows of one device's findings.

    Return the ``pooled_findings`` rows of one device's findings: one per named entry and one per term
    of the device model (``in_device_model``); one row with a null effect when there is neither.
    """
    absorbed = "; ".join(a["advice"] for a in findings.get("absorbed") or []) or None
    base = {
        "night": night,
        "device_id": findings["device_id"],
        "nights": ",".join(findings["nights"]),
        "scan_ids": ",".join(findings["scan_ids"]),
        "verdict": findings["verdict"],
        "gap_before_mm": (findings.get("gap_before") or {}).get("rms_mm"),
        "gap_after_mm": (findings.get("gap_after") or {}).get("rms_mm"),
        "noise_floor_mm": findings.get("noise_floor_mm"),
        "absorbed": absorbed,
        "device_model": ",".join(findings.get("device_model") or []) or None,
        "findings_path": path,
    }
    named = [(n, False) for n in findings.get("named") or []] + [
        (n, True) for n in findings.get("in_device_model") or []
    ]
    if not named:
        return [dict(base, effect=None, channel=None, term=None, in_device_model=False)]
    return [
        dict(
            base,
            effect=n.get("effect"),
            channel=n.get("channel"),
            term=n.get("term", n.get("effect")),
            group=n.get("group"),
            parameters=json.dumps(n.get("parameters") or {}, sort_keys=True),
            uncertainties=json.dumps(n.get("uncertainties") or {}, sort_keys=True),
            evidence_scans=",".join(n.get("scans") or []) or None,
            in_device_model=model,
        )
        for n, model in named
    ]


def drift_rows(
    calibrations: pl.DataFrame, night: str, multiple: float, findings: dict[str, dict]
) -> list[dict]:
    """Return the ``calibration_drift`` rows of ``night``.

    Return the ``calibration_drift`` rows of ``night`` (pairs whose later calibration is valid from
    it), each flagged one explained by its device's pooled ``findings`` (device id -> findings).
    """
    drift = calibration_drift(calibrations, multiple).filter(pl.col("valid_from_after") == night)
    why = {}
    for f in findings.values():
        for e in drift_explanations(drift, f):
            why[(e["device_id"], e["channel"], e["parameter"], e["calibration_id_after"])] = e
    rows = []
    for r in drift.iter_rows(named=True):
        e = why.get((r["device_id"], r["channel"], r["parameter"], r["calibration_id_after"]))
        if r["flagged"] and e is None:
            e = {
                "explained_by": [],
                "explanation": (
                    f"{r['parameter']} of channel {r['channel']} moved by {r['change']:+.4g} "
                    f"({r['change_over_u']:+.1f} "
                    f"combined u); device {r['device_id']} has no pooled examination on night {night} "
                    "(fewer than two spindle scans of a certified gauge)"
                ),
            }
        rows.append(
            dict(
                r,
                night=night,
                explained_by=",".join(e["explained_by"]) if e else None,
                explanation=e["explanation"] if e else None,
            )
        )
    return rows


def stage_pooled(
    raw_root,
    night: str,
    results_root,
    scans_tables,
    calibration_tables,
    cfg: dict,
    devices: dict | None = None,
    log=print,
    workers: int = 1,
) -> tuple[pl.DataFrame, pl.DataFrame]:
    """Pooled examination of every three-sensor device of the window and the night's drift rows.

    ``scans_tables``: the ``scans`` stage tables of the window's nights (the night's last);
    ``calibration_tables``: the calibrations of every night up to ``night``; ``cfg``: the config's
    ``discrepancy`` section; ``devices``: the config's ``devices`` section (device model). The
    JSON files go to ``<results_root>/discrepancy/pooled/night=<night>/<device_id>.json`` (the
    rows name them relative to ``results_root``). Returns (pooled_findings, calibration_drift).
    """
    section = {**schema_defaults()["discrepancy"], **(cfg or {})}
    settings = {**discrepancy_settings(cfg), "max_samples": int(section["pooled_max_samples"])}
    cals = read_tables(calibration_tables or [], "calibrations")
    scans = ok_scans(read_tables(scans_tables or [], "scans"))
    if scans.height:
        scans = scans.filter((pl.col("device_type") == "tri_lds") & pl.col("kind").is_in(POOLED_KINDS))
    jobs = []
    for (device,), g in scans.sort("night", "scan_id").group_by(["device_id"], maintain_order=True):
        dirs = [
            rawio.stored_scan_dir(results_root, r["night"], r["scan_id"]) for r in g.iter_rows(named=True)
        ]
        ref_kw, ref = discrepancy_reference(cals, device, "tri_lds", night)
        effects = device_model_effects(devices, device, night)
        jobs.append(
            (
                raw_root,
                night,
                str(pooled_dir(results_root, night)),
                device,
                dirs,
                ref_kw,
                ref,
                effects,
                settings,
            )
        )
    log(f"{len(jobs)} device(s) on {workers_for(len(jobs), workers)} process(es)")
    rows, findings = [], {}
    for (device, f, msg), cpu_s in map_timed(pooled_device, jobs, workers):
        log(msg)
        log(compute_line(device, cpu_s))
        if f is not None and "reason" in f:
            rows.append(
                {
                    "night": night,
                    "device_id": device,
                    "verdict": "failed",
                    "reason": f["reason"],
                    "scan_ids": ",".join(f["scan_ids"]),
                }
            )
        elif f is not None:
            findings[device] = f
            rows += pooled_rows(f, night, f"discrepancy/pooled/night={night}/{device}.json")
    drift = drift_rows(cals, night, float(section["drift_multiple"]), findings) if cals.height else []
    for r in drift:
        if r["flagged"]:
            log(f"drift: {r['explanation']}")
    return tables.frame("pooled_findings", rows), tables.frame("calibration_drift", drift)


def pooled_device(job) -> tuple[str, dict | None, str]:
    """Examine one device's pooled spindle scans and write its JSON.

    Examine one device's pooled spindle scans and write its JSON: (device id, findings or None, log
    line).
    """
    raw_root, night, out_dir, device, dirs, ref_kw, ref, effects, settings = job
    scans = [rawio.load_stored_scan(d) for d in dirs]
    spindle = [s for s in scans if "pose" not in s.lds.columns or s.lds["pose"].null_count() == s.lds.height]
    if len(spindle) < 2:
        return device, None, f"{device}: {len(spindle)} spindle scan(s) of a certified gauge: nothing to pool"
    ids = [s.scan_id for s in spindle]
    try:
        pooled = [pooled_scan(s, settings["max_samples"], ref_kw.get("beams")) for s in spindle]
        ex = examine_pooled(pooled, ref_kw.get("beams"), device_effects=effects, **settings)
    except (ValueError, ArithmeticError, np.linalg.LinAlgError) as err:  # the night goes on; the row says why
        reason = f"pooled examination of {', '.join(ids)} failed: {err}"
        return device, {"reason": reason, "scan_ids": ids}, f"{device}: {reason}"
    f = ex.findings
    f["reference"] = ref
    atomic_write_text(
        Path(out_dir) / f"{device}.json", json.dumps(_clean(f), sort_keys=True, indent=2) + "\n"
    )
    named = ", ".join(n.get("term", n["effect"]) for n in f["named"])
    return (
        device,
        f,
        (
            f"{device} ({len(pooled)} scans vs {ref}): {f['verdict']}{': ' + named if named else ''} "
            f"(gap {f['gap_before']['rms_mm'] * 1e3:.2f} -> {f['gap_after']['rms_mm'] * 1e3:.2f} um)"
        ),
    )
