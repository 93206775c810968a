"""The validated readings store: what ingest accepted of each scan, read by every later stage.

Ingest (:mod:`borescan.stages.ingest`) reads and validates each raw scan folder once a night and
writes what it accepted into the night's store, an internal stage folder (not a contract table)::

    <results_root>/stage/readings/night=<night>/scan=<scan_id>/
        lds.parquet      the five lds columns as the raw file gave them (validated)
        spindle.parquet  the five spindle columns (only when the raw scan has one)
        scan_meta.json   ScanMeta, the raw scan.json as parsed, the raw files' paths and SHA-256,
                         the reader's warnings

Only scans ingest found valid are stored. Later stages (signal, calibrate, measure, discrepancy,
pooled) read :func:`load_stored_scan` and never parse or validate a raw file again; the raw files'
paths and SHA-256 digests (computed by ingest) travel with the scan, so provenance still names
them. One Parquet pair per scan keeps a stage's memory to the scans it holds at once.
"""

from __future__ import annotations

import io
import json
import shutil
from pathlib import Path

import polars as pl

from borescan.atomic import atomic_write_bytes, atomic_write_text
from borescan.rawio.format import LDS_FILE, SCAN_JSON, SPINDLE_FILE, RawScan, ScanMeta

__all__ = [
    "STORE_META",
    "readings_dir",
    "stored_scan_dir",
    "clear_readings_dir",
    "write_stored_scan",
    "load_stored_scan",
    "load_scan_meta",
    "load_scan_json",
]

#: the store's metadata file of one scan
STORE_META = "scan_meta.json"
_STORE_VERSION = 1


def readings_dir(results_root: str | Path, night: str) -> Path:
    """``<results_root>/stage/readings/night=<night>``: the night's store (ingest's declared folder)."""
    return Path(results_root) / "stage" / "readings" / f"night={night}"


def stored_scan_dir(results_root: str | Path, night: str, scan_id: str) -> Path:
    """Return the store folder of one scan of the night."""
    return readings_dir(results_root, night) / f"scan={scan_id}"


def clear_readings_dir(results_root: str | Path, night: str) -> Path:
    """Empty the night's store (a rerun of ingest leaves no scan it no longer accepts); return it."""
    folder = readings_dir(results_root, night)
    shutil.rmtree(folder, ignore_errors=True)
    folder.mkdir(parents=True, exist_ok=True)
    return folder


def _parquet_bytes(df: pl.DataFrame) -> bytes:
    buf = io.BytesIO()
    df.write_parquet(buf, statistics=False)
    return buf.getvalue()


def write_stored_scan(folder: str | Path, scan: RawScan, raw_sha256: dict[str, str]) -> ScanMeta:
    """Store one validated scan (its readings, ``ScanMeta``, the raw files' paths and digests).

    ``raw_sha256``: file name -> SHA-256 of every raw file the scan was read from (ingest hashes
    them for ``scan_files``); each file ingest read must have one. Returns the scan's ``ScanMeta``.
    """
    missing = sorted(set(scan.files) - set(raw_sha256))
    if missing:
        raise ValueError(f"{scan.scan_id}: no SHA-256 of raw file(s) {', '.join(missing)} to store")
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    meta = ScanMeta.from_scan_json(scan.meta)
    atomic_write_bytes(folder / LDS_FILE, _parquet_bytes(scan.lds))
    if scan.spindle is not None:
        atomic_write_bytes(folder / SPINDLE_FILE, _parquet_bytes(scan.spindle))
    record = {
        "version": _STORE_VERSION,
        "scan_meta": meta.to_dict(),
        "scan_json": scan.meta,
        "raw_files": {
            name: {"path": str(path), "sha256": raw_sha256[name]} for name, path in sorted(scan.files.items())
        },
        "warnings": list(scan.warnings),
    }
    # meta last: a folder with its scan_meta.json has its readings
    atomic_write_text(folder / STORE_META, json.dumps(record, sort_keys=True, indent=1) + "\n")
    return meta


def _record(folder: Path) -> dict:
    path = folder / STORE_META
    try:
        record = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise FileNotFoundError(
            f"{folder.name.removeprefix('scan=')}: {path}: not in the readings store "
            "(ingest_night writes it; rerun the night's ingest)"
        ) from None
    if record.get("version") != _STORE_VERSION:
        raise ValueError(
            f"{path}: readings store version {record.get('version')!r}, expected {_STORE_VERSION}"
        )
    return record


def load_scan_meta(folder: str | Path) -> ScanMeta:
    """Return the ``ScanMeta`` of one stored scan (no readings read)."""
    return ScanMeta.from_dict(_record(Path(folder))["scan_meta"])


def load_scan_json(folder: str | Path) -> dict:
    """Return the raw ``scan.json`` of one stored scan as ingest parsed it (for functions taking it whole)."""
    return _record(Path(folder))["scan_json"]


def load_stored_scan(folder: str | Path) -> RawScan:
    """Return one stored scan as ingest accepted it, without touching its raw files.

    ``meta`` is the raw ``scan.json`` as parsed, ``files`` the raw files' paths and ``sha256``
    their digests computed by ingest (provenance names the raw files); ``lds`` and ``spindle``
    the validated readings.
    """
    folder = Path(folder)
    record = _record(folder)
    meta = record["scan_json"]
    raw = record["raw_files"]
    spindle_path = folder / SPINDLE_FILE
    return RawScan(
        scan_id=str(meta["scan_id"]),
        night=str(meta["night"]),
        path=Path(raw[SCAN_JSON]["path"]).parent,
        meta=meta,
        lds=pl.read_parquet(folder / LDS_FILE),
        spindle=pl.read_parquet(spindle_path) if SPINDLE_FILE in raw else None,
        files={name: Path(v["path"]) for name, v in raw.items()},
        warnings=list(record["warnings"]),
        _digests={name: v["sha256"] for name, v in raw.items()},
    )
