"""Stage ``ingest_night``: validate and register every scan of a night.

Stage ``ingest_night``: validate and register every scan of a night, record checksums, quarantine bad
ones.
"""

from __future__ import annotations

from pathlib import Path

import polars as pl

from borescan import rawio, tables, validation
from borescan.parallel import map_in_order
from borescan.artifacts import certificate_conflicts, certificate_fields
from borescan.stages._common import Quarantined, frames_or_empty, write_quarantine_record

__all__ = ["stage_ingest", "scan_row"]

DUPLICATE_REASON = validation.DUPLICATE_REASON


def stage_ingest(
    raw_root: str | Path,
    night: str,
    results_root: str | Path,
    duplicate_ids: list[str] = (),
    workers: int = 1,
    earlier_scans=(),
    on_conflict: str = "quarantine",
    log=None,
    plausibility: dict | None = None,
) -> tuple[pl.DataFrame, pl.DataFrame, list[Quarantined]]:
    """Validate and register every scan of one night (spread over ``workers`` processes).

    A scan is quarantined for the first problem :func:`borescan.validation.scan_problems` finds
    (the checks ``borescan validate`` runs): the format, readings outside the sensor's range,
    the sample clock of spindle scans, a scan id used by an earlier night.

    Returns the ``scans`` rows (status ``ok`` or ``quarantined`` with the reason), the
    ``scan_files`` rows (SHA-256 and size of every raw file, bad scans included) and the
    quarantine records (also written as ``quarantine/<scan_id>.json``). Each valid scan's readings
    and ``ScanMeta`` go to the night's readings store (:mod:`borescan.rawio.store`,
    ``<results_root>/stage/readings/night=<night>/``), which every later stage reads instead of raw.
    ``duplicate_ids`` (:func:`borescan.rawio.earlier_duplicate_ids`) are quarantined: an earlier
    night has them.

    ``earlier_scans``: the ``scans`` tables (paths or frames) of earlier nights. A scan whose
    artifact certificate contradicts an earlier record of the same certificate
    (:func:`borescan.artifacts.certificate_conflicts`) is quarantined (``on_conflict:
    quarantine``) or kept with a log line (``flag``); the conflict is named either way.
    ``plausibility``: the config's section of that name (:class:`borescan.validation.Plausibility`).
    """
    dup = set(duplicate_ids)
    limits = validation.Plausibility.from_config(plausibility)
    rawio.clear_readings_dir(results_root, night)  # the night's store holds the scans this run accepts
    jobs = [
        (raw_root, night, results_root, d, d.name[5:] in dup, limits)
        for d in rawio.night_scan_dirs(raw_root, night)
    ]
    rows, file_rows, bad = [], [], []
    for row, files, problem in map_in_order(_ingest_one, jobs, workers):
        rows.append(row)
        file_rows += files
        if problem is not None:
            bad.append(problem)
    before = frames_or_empty(
        [e if isinstance(e, pl.DataFrame) else pl.read_parquet(e) for e in earlier_scans]
    )
    conflicts = certificate_conflicts(
        before.to_dicts() if before.height and "artifact_certificate" in before.columns else [], rows
    )
    for row in rows:
        why = conflicts.get(row["scan_id"])
        if why is None:
            continue
        if log is not None:
            log(f"CERTIFICATE CONFLICT {row['scan_id']}: {why}")
        if on_conflict == "quarantine":
            problem = Quarantined(row["scan_id"], night, "ingest", "scan.json", why)
            write_quarantine_record(results_root, problem)
            row.update(status="quarantined", reason=f"scan.json: {why}")
            bad.append(problem)
    return tables.frame("scans", rows), tables.frame("scan_files", file_rows), bad


def _meta_field(meta: dict, *keys: str) -> str | None:
    cur: object = meta
    for k in keys:
        if not isinstance(cur, dict) or k not in cur:
            return None
        cur = cur[k]
    return None if cur is None else str(cur)


def scan_row(
    scan_id: str, night: str, scan_dir: Path, meta: dict, hashes: dict[str, str], problem: Quarantined | None
) -> dict:
    """Return the ``scans`` row of one scan folder (whatever of ``scan.json`` could be read, else nulls)."""
    acq = meta.get("acquisition")
    return {
        "scan_id": scan_id,
        "night": night,
        "device_id": _meta_field(meta, "device", "id"),
        "device_type": _meta_field(meta, "device", "type"),
        "kind": _meta_field(meta, "kind"),
        "artifact_id": _meta_field(meta, "artifact", "id"),
        "started_at": _meta_field(meta, "started_at"),
        "status": "quarantined" if problem else "ok",
        "reason": f"{problem.file}: {problem.reason}" if problem else None,
        "raw_sha256": rawio.combined_sha256(hashes),
        "raw_path": str(scan_dir),
        "simulated": bool(acq.get("simulated", False)) if isinstance(acq, dict) else False,
        **certificate_fields(meta),
    }


def _ingest_one(job) -> tuple[dict, list[dict], Quarantined | None]:
    """Hash, validate and describe one scan folder: (scans row, scan_files rows, quarantine or None)."""
    raw_root, night, results_root, d, duplicate, limits = job
    scan_id = d.name[5:]
    hashes, file_rows = {}, []
    inside = not d.is_symlink() and d.resolve().is_relative_to(Path(raw_root).resolve())
    try:
        entries = sorted(d.iterdir()) if inside else []
    except OSError:  # an unreadable folder: scan_problems below names it, the scan is quarantined
        entries = []
    for f in entries:
        try:
            if f.is_file() and not f.is_symlink():
                digest, size = rawio.sha256_file(f), f.stat().st_size
            else:
                continue
        except OSError:  # an unreadable file (e.g. umask 077 of another user): named by scan_problems
            continue
        hashes[f.name] = digest
        file_rows.append(
            {"scan_id": scan_id, "night": night, "file": f.name, "sha256": digest, "bytes": size}
        )
    # the one validator, shared with `borescan validate`: the first problem is the reason
    earlier = validation.earlier_night_of(raw_root, night, scan_id) if duplicate else None
    scan, problems = validation.scan_problems(
        d, raw_root, duplicate=duplicate, earlier_night=earlier, limits=limits
    )
    meta: dict = scan.meta if scan is not None else {}
    if scan is None:  # a scan that cannot be read whole: its row gets what scan.json gives
        try:
            meta = rawio.read_scan_meta(d)
        except rawio.ScanError:
            pass
    # the folder's own id (a ScanError shortens an id that is no valid id to name it)
    problem = (
        Quarantined(scan_id, night, "ingest", problems[0].file, problems[0].problem) if problems else None
    )
    if problem is not None:
        write_quarantine_record(results_root, problem)
    else:  # what later stages read instead of the raw files (borescan.rawio.store)
        rawio.write_stored_scan(rawio.stored_scan_dir(results_root, night, scan_id), scan, hashes)
    return scan_row(scan_id, night, d, meta, hashes, problem), file_rows, problem
