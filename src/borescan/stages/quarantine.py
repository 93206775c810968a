"""Quarantine records of the stages: what set a scan aside, its record file, the night's quarantine table."""

from __future__ import annotations

import hashlib
import json
import re
from dataclasses import asdict, dataclass
from pathlib import Path

import polars as pl

from borescan import rawio, tables
from borescan.atomic import atomic_write_text
from borescan.catalog import STAGE_ORDER

__all__ = [
    "Quarantined",
    "write_quarantine_record",
    "quarantine",
    "quarantine_frame",
    "quarantined_text",
    "quarantine_record_name",
    "sync_quarantine_records",
]


@dataclass(frozen=True)
class Quarantined:
    """A scan set aside by a stage, with the file and the problem."""

    scan_id: str
    night: str
    stage: str
    file: str
    reason: str

    @classmethod
    def from_error(cls, err: rawio.ScanError, night: str, stage: str) -> "Quarantined":
        """Return the quarantine record of ``err`` met in ``stage`` of ``night``."""
        return cls(err.scan_id, night, stage, err.file, err.problem)


_RECORD_NAME = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_-]{0,63}")


def quarantine_record_name(scan_id: str, night: str) -> str:
    """Return the file name of a scan's quarantine record.

    ``<scan_id>.json`` for a valid id that cannot be mistaken for anything else; otherwise (a folder id longer
    than 64 characters, ``..``, ``-``, ...) ``scan-<16 hex of SHA-256 of night/scan_id>.json``, so two folders
    never share a record, no record is hidden and none is named like the ``-`` of problems that name no scan.
    """
    if _RECORD_NAME.fullmatch(scan_id):
        return f"{scan_id}.json"
    return f"scan-{hashlib.sha256(f'{night}/{scan_id}'.encode()).hexdigest()[:16]}.json"


def _record_bytes(q: Quarantined) -> str:  # the record's text (deterministic)
    return (
        json.dumps(dict(asdict(q), message=f"{q.scan_id}: {q.file}: {q.reason}"), indent=2, sort_keys=True)
        + "\n"
    )


def write_quarantine_record(results_root: str | Path, q: Quarantined) -> Path:
    """Write ``<results_root>/quarantine/<name>.json`` (atomic, deterministic bytes).

    The name is :func:`quarantine_record_name`'s. The catalog step rewrites the folder from the catalog
    (:func:`sync_quarantine_records`), so a record outlives neither a rerun nor a recompute.

    The first stage that set the scan aside keeps the file: a record of an earlier stage
    (:data:`borescan.catalog.STAGE_ORDER`) of the same night is left as it is, as the catalog's
    ``scans.reason`` keeps the first stage's reason; the same or a later stage (a rerun) replaces it.
    """
    path = Path(results_root) / "quarantine" / quarantine_record_name(q.scan_id, q.night)
    try:
        old = json.loads(path.read_text())
    except (OSError, ValueError):
        old = None
    if (
        isinstance(old, dict)
        and old.get("night") == q.night
        and _stage_rank(old.get("stage")) < _stage_rank(q.stage)
    ):
        return path
    atomic_write_text(path, _record_bytes(q))
    return path


def _stage_rank(stage) -> int:
    return STAGE_ORDER.index(stage) if stage in STAGE_ORDER else len(STAGE_ORDER)


def sync_quarantine_records(results_root: str | Path, records: list[Quarantined]) -> tuple[int, int]:
    """Make ``<results_root>/quarantine/`` hold exactly ``records``.

    The records are the catalog's, one per scan; a scan id quarantined on two nights gets
    ``<scan_id>.night=<night>.json`` for the later. Returns (written, removed).
    """
    folder = Path(results_root) / "quarantine"
    want: dict[str, str] = {}
    for q in records:
        name = quarantine_record_name(q.scan_id, q.night)
        if name in want:
            name = f"{name[:-5]}.night={q.night}.json"
        want[name] = _record_bytes(q)
    written = removed = 0
    for name, text in want.items():
        if not ((folder / name).is_file() and (folder / name).read_text() == text):
            atomic_write_text(folder / name, text)
            written += 1
    if folder.is_dir():
        for path in folder.iterdir():
            if path.name not in want and path.suffix == ".json" and path.is_file():
                path.unlink()
                removed += 1
    return written, removed


def quarantine(
    results_root, records: list[Quarantined], scan_id: str, night: str, stage: str, file: str, reason: str
) -> None:
    """Set a scan aside: append its record to ``records`` and write its quarantine file."""
    q = Quarantined(scan_id, night, stage, file, reason)
    records.append(q)
    write_quarantine_record(results_root, q)


def quarantined_text(records: list[Quarantined], width: int = 160) -> str:
    """Return a night's log line of who was set aside and why.

    ``n quarantined`` and, per scan, ``scan_id (file: reason)`` with the reason cut at ``width`` characters: a
    night's log line says who was set aside and why (the full reason is in the record).
    """
    if not records:
        return "0 quarantined"
    items = []
    for q in records:
        reason = q.reason if len(q.reason) <= width else q.reason[: width - 3] + "..."
        items.append(f"{q.scan_id} ({q.file}: {reason})")
    return f"{len(records)} quarantined: " + "; ".join(items)


def quarantine_frame(records: list[Quarantined]) -> pl.DataFrame:
    """Quarantine rows as a polars frame (empty frame with the schema when none)."""
    return tables.frame("quarantine", [asdict(r) for r in records])
