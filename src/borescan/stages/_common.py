"""What every stage shares: quarantine records, a night's ``ok`` scans, reading and writing stage tables."""

from __future__ import annotations

import hashlib
import io
import json
import os
import shutil
from pathlib import Path

import polars as pl

from borescan import rawio, tables
from borescan.atomic import atomic_write_bytes
from borescan.stages.quarantine import (
    Quarantined,
    quarantine,
    quarantine_frame,
    quarantine_record_name,
    quarantined_text,
    sync_quarantine_records,
    write_quarantine_record,
)

__all__ = [
    "Quarantined",
    "write_quarantine_record",
    "quarantine",
    "quarantine_frame",
    "quarantined_text",
    "write_table",
    "write_stage_outputs",
    "quarantine_record_name",
    "sync_quarantine_records",
    "ok_scans",
    "night_scans",
    "read_tables",
    "frames_or_empty",
    "config_hash",
    "night_folder",
    "clear_night_folder",
    "link_into_night",
]


def config_hash(cfg: dict) -> str:
    """SHA-256 (hex, 16 chars) of config sections, for certificates and provenance."""
    return hashlib.sha256(json.dumps(cfg, sort_keys=True, default=str).encode()).hexdigest()[:16]


def write_table(df: pl.DataFrame, path: str | Path) -> None:
    """Write a stage table as Parquet atomically (temp file + rename)."""
    buf = io.BytesIO()
    df.write_parquet(buf, statistics=False)
    atomic_write_bytes(path, buf.getvalue())  # a unique temporary name: two runs never meet


def write_stage_outputs(output, quarantined: list[Quarantined] | None = None, **frames: pl.DataFrame) -> None:
    """Write a stage's tables to the rule's outputs.

    Write a stage's tables to the rule's outputs of the same names (``output.<name>``), and
    its quarantine records as ``output.quarantine`` when given.
    """
    if quarantined is not None:
        frames["quarantine"] = quarantine_frame(quarantined)
    for name, df in frames.items():
        write_table(tables.conform(name, df) if name in tables.TABLES else df, getattr(output, name))


def ok_scans(scans_table: str | Path | pl.DataFrame) -> pl.DataFrame:
    """Return the rows of a ``scans`` stage table whose status is ``ok``, by scan id."""
    df = scans_table if isinstance(scans_table, pl.DataFrame) else pl.read_parquet(scans_table)
    return tables.conform("scans", df).filter(pl.col("status") == "ok").sort("scan_id")


def night_scans(
    results_root: str | Path, night: str, scans_table: str | Path | pl.DataFrame, **where: str
) -> list[tuple[dict, Path]]:
    """Return the ``ok`` rows of a night's ``scans`` table with their folders in the readings store.

    Optionally filtered (e.g. kind=...); each folder is read by :func:`borescan.rawio.load_stored_scan`
    (ingest's validated readings and ``ScanMeta``: later stages never read raw files).
    """
    df = ok_scans(scans_table)
    for col, value in where.items():
        df = df.filter(pl.col(col) == value)
    return [
        (row, rawio.stored_scan_dir(results_root, night, row["scan_id"])) for row in df.iter_rows(named=True)
    ]


def frames_or_empty(frames: list[pl.DataFrame]) -> pl.DataFrame:
    """Return the non-empty frames stacked (columns united by name); an empty frame when there are none."""
    frames = [f for f in frames if f.height]
    return pl.concat(frames, how="diagonal_relaxed") if frames else pl.DataFrame()


def read_tables(paths, table: str | None = None) -> pl.DataFrame:
    """Return stage table files (one path or a list) stacked.

    Stacked as :func:`frames_or_empty` does; with every column of history table ``table`` when named
    (:func:`borescan.tables.conform`: no rows, or rows of one kind only, still give the table's columns).
    """
    frames = [pl.read_parquet(p) for p in (paths if isinstance(paths, (list, tuple)) else [paths])]
    df = frames_or_empty([f for f in frames if f.width])
    return tables.conform(table, df) if table is not None else df


# --------------------------------------------------------------------------- per-night folders
# Files whose set depends on the data (certificates, findings and gap plots) are written into one
# folder per night, ``<area>/night=<night>/...``, which the rule declares (so Snakemake empties it
# before a rerun and `snakemake --report` lists its files); the path people and the catalog use
# (``calibration/<device>/<id>/``, ``discrepancy/<scan_id>/``, outputs.md) is a relative symbolic
# link into it (a copy where the filesystem has none).


def night_folder(results_root, area: str, night: str) -> Path:
    """``<results_root>/<area>/night=<night>``: the night's declared folder of ``area``."""
    return Path(results_root) / area / f"night={night}"


def clear_night_folder(results_root, area: str, night: str) -> Path:
    """Empty the night's folder of ``area`` and drop the links into it.

    Empty the night's folder of ``area`` and drop the links into it (up to two levels below
    ``area``): what a rerun no longer writes leaves nothing behind. Returns the (empty) folder.
    """
    folder = night_folder(results_root, area, night)
    shutil.rmtree(folder, ignore_errors=True)
    folder.mkdir(parents=True, exist_ok=True)
    mark = f"night={night}"

    def drop_links(d: Path, depth: int) -> None:
        with os.scandir(d) as entries:
            for e in entries:
                if e.is_symlink():
                    if mark in Path(os.readlink(e.path)).parts:
                        os.unlink(e.path)
                elif depth > 1 and e.is_dir() and not e.name.startswith("night="):
                    drop_links(Path(e.path), depth - 1)

    drop_links(folder.parent, 2)
    return folder


def link_into_night(link: Path, target: Path) -> None:
    """Make ``link`` a relative symbolic link to ``target``.

    Make ``link`` a relative symbolic link to ``target`` (a folder inside a night folder),
    replacing what was there (a link, or a folder of the layout before night folders); a copy
    where symbolic links cannot be made.
    """
    link = Path(link)
    link.parent.mkdir(parents=True, exist_ok=True)
    if link.is_symlink() or link.is_file():
        link.unlink()
    elif link.is_dir():
        shutil.rmtree(link)
    try:
        os.symlink(os.path.relpath(target, link.parent), link, target_is_directory=True)
    except OSError:
        shutil.copytree(target, link)
