"""What every stage shares: quarantine records, a night's ``ok`` scans, reading and writing stage tables."""

from __future__ import annotations

import hashlib
import io
import json
from dataclasses import asdict, dataclass
from pathlib import Path

import polars as pl

from borescan import rawio, tables
from borescan.atomic import atomic_write_bytes, atomic_write_text

__all__ = ["Quarantined", "write_quarantine_record", "quarantine", "quarantine_frame", "write_table",
           "write_stage_outputs", "ok_scans", "night_scans", "read_tables", "frames_or_empty", "config_hash"]


def config_hash(cfg: dict) -> str:
    """SHA-256 (hex, 16 chars) of config sections, for certificates and provenance."""
    return hashlib.sha256(json.dumps(cfg, sort_keys=True, default=str).encode()).hexdigest()[:16]


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
        return cls(err.scan_id, night, stage, err.file, err.problem)


def write_quarantine_record(results_root: str | Path, q: Quarantined) -> Path:
    """Write ``<results_root>/quarantine/<scan_id>.json`` (atomic, deterministic bytes)."""
    path = Path(results_root) / "quarantine" / f"{q.scan_id}.json"
    payload = dict(asdict(q), message=f"{q.scan_id}: {q.file}: {q.reason}")
    atomic_write_text(path, json.dumps(payload, indent=2, sort_keys=True) + "\n")
    return path


def quarantine(results_root, records: list[Quarantined], scan_id: str, night: str, stage: str, file: str,
               reason: str) -> None:
    """Set a scan aside: append its record to ``records`` and write its quarantine file."""
    q = Quarantined(scan_id, night, stage, file, reason)
    records.append(q)
    write_quarantine_record(results_root, q)


def quarantine_frame(records: list[Quarantined]) -> pl.DataFrame:
    """Quarantine rows as a polars frame (empty frame with the schema when none)."""
    return tables.frame("quarantine", [asdict(r) for r in records])


def write_table(df: pl.DataFrame, path: str | Path) -> None:
    """Write a stage table as Parquet atomically (temp file + rename)."""
    buf = io.BytesIO()
    df.write_parquet(buf, statistics=False)
    atomic_write_bytes(path, buf.getvalue())  # a unique temporary name: two runs never meet


def write_stage_outputs(output, quarantined: list[Quarantined] | None = None, **frames: pl.DataFrame) -> None:
    """Write a stage's tables to the rule's outputs of the same names (``output.<name>``), and
    its quarantine records as ``output.quarantine`` when given."""
    if quarantined is not None:
        frames["quarantine"] = quarantine_frame(quarantined)
    for name, df in frames.items():
        write_table(df, getattr(output, name))


def ok_scans(scans_table: str | Path | pl.DataFrame) -> pl.DataFrame:
    """The rows of a ``scans`` stage table whose status is ``ok``, by scan id."""
    df = scans_table if isinstance(scans_table, pl.DataFrame) else pl.read_parquet(scans_table)
    return df.filter(pl.col("status") == "ok").sort("scan_id")


def night_scans(raw_root: str | Path, night: str, scans_table: str | Path | pl.DataFrame,
                **where: str) -> list[tuple[dict, Path]]:
    """The ``ok`` rows of a night's ``scans`` table (optionally filtered, e.g. kind=...) with their folders."""
    df = ok_scans(scans_table)
    for col, value in where.items():
        df = df.filter(pl.col(col) == value)
    return [(row, Path(raw_root) / f"night={night}" / f"scan={row['scan_id']}") for row in df.iter_rows(named=True)]


def frames_or_empty(frames: list[pl.DataFrame]) -> pl.DataFrame:
    """The non-empty frames stacked (columns united by name); an empty frame when there are none."""
    frames = [f for f in frames if f.height]
    return pl.concat(frames, how="diagonal_relaxed") if frames else pl.DataFrame()


def read_tables(paths) -> pl.DataFrame:
    """Stage table files (one path or a list) stacked, see :func:`frames_or_empty`."""
    frames = [pl.read_parquet(p) for p in (paths if isinstance(paths, (list, tuple)) else [paths])]
    return frames_or_empty([f for f in frames if f.width])
