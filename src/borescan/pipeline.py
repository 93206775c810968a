"""Glue between the Snakemake rules and the library: one ``stage_*`` function per rule.

Every stage works on one night at a time (batching keeps Snakemake's per-job overhead small),
reads raw scans only through :mod:`borescan.rawio`, writes its tables as Parquet under
``<results_root>/stage/<table>/night=<night>.parquet`` (hive layout, so DuckDB and polars read
all nights at once) and never stops for one bad scan: the scan is quarantined with its reason
(``<results_root>/quarantine/<scan_id>.json`` and a row in the stage's quarantine table) and the
stage goes on with the others.
"""

from __future__ import annotations

import hashlib
import json
import re
from dataclasses import dataclass
from pathlib import Path

import polars as pl

from borescan import rawio

NIGHT_RE = re.compile(r"^night=(\d{4}-\d{2}-\d{2})$")
SCAN_RE = re.compile(r"^scan=(.+)$")

QUARANTINE_SCHEMA = {
    "scan_id": pl.Utf8,
    "night": pl.Utf8,
    "stage": pl.Utf8,
    "file": pl.Utf8,
    "reason": pl.Utf8,
}


# --------------------------------------------------------------------------- discovery


def nights(raw_root: str | Path) -> list[str]:
    """Nights (YYYY-MM-DD) present under ``raw_root``, sorted; [] when it does not exist."""
    root = Path(raw_root)
    if not root.is_dir():
        return []
    out = []
    for p in root.iterdir():
        m = NIGHT_RE.match(p.name)
        if m and p.is_dir():
            out.append(m.group(1))
    return sorted(out)


def scan_dirs(raw_root: str | Path, night: str) -> list[Path]:
    """Scan folders of one night, sorted by folder name."""
    night_dir = Path(raw_root) / f"night={night}"
    if not night_dir.is_dir():
        return []
    return sorted(p for p in night_dir.iterdir() if p.is_dir() and SCAN_RE.match(p.name))


def night_raw_files(raw_root: str | Path, night: str) -> list[str]:
    """Every regular file of a night's scans (the inputs whose change must rerun that night)."""
    files = []
    for d in scan_dirs(raw_root, night):
        for f in sorted(d.iterdir()):
            if f.is_file():
                files.append(str(f))
    return files


def earlier_duplicate_ids(raw_root: str | Path, night: str) -> list[str]:
    """Scan ids of ``night`` that already occur in an earlier night (the earlier one wins).

    Depends only on this and earlier nights, so adding a later night changes nothing here.
    """
    ids_here = {SCAN_RE.match(d.name).group(1) for d in scan_dirs(raw_root, night)}
    seen: set[str] = set()
    for n in nights(raw_root):
        if n >= night:
            break
        seen.update(SCAN_RE.match(d.name).group(1) for d in scan_dirs(raw_root, n))
    return sorted(ids_here & seen)


# --------------------------------------------------------------------------- quarantine


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
    payload = {
        "scan_id": q.scan_id,
        "night": q.night,
        "stage": q.stage,
        "file": q.file,
        "reason": q.reason,
        "message": f"{q.scan_id}: {q.file}: {q.reason}",
    }
    _atomic_write_text(path, json.dumps(payload, indent=2, sort_keys=True) + "\n")
    return path


def quarantine_frame(records: list[Quarantined]) -> pl.DataFrame:
    """Quarantine rows as a polars frame (empty frame with the schema when none)."""
    if not records:
        return pl.DataFrame(schema=QUARANTINE_SCHEMA)
    return pl.DataFrame([r.__dict__ for r in records], schema=QUARANTINE_SCHEMA, orient="row")


def _atomic_write_text(path: Path, text: str) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text(text)
    tmp.replace(path)


def write_table(df: pl.DataFrame, path: str | Path) -> None:
    """Write a stage table as Parquet atomically (temp file + rename)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp")
    df.write_parquet(tmp, statistics=False)
    tmp.replace(path)


# --------------------------------------------------------------------------- ingest

SCANS_SCHEMA = {
    "scan_id": pl.Utf8,
    "night": pl.Utf8,
    "device_id": pl.Utf8,
    "device_type": pl.Utf8,
    "kind": pl.Utf8,
    "artifact_id": pl.Utf8,
    "started_at": pl.Utf8,
    "status": pl.Utf8,
    "reason": pl.Utf8,
    "raw_sha256": pl.Utf8,
    "raw_path": pl.Utf8,
    "simulated": pl.Boolean,
}
SCAN_FILES_SCHEMA = {"scan_id": pl.Utf8, "night": pl.Utf8, "file": pl.Utf8, "sha256": pl.Utf8, "bytes": pl.Int64}


def combined_sha256(file_hashes: dict[str, str]) -> str:
    """One digest for a scan: SHA-256 over the sorted ``name:sha256`` lines of its raw files."""
    lines = "".join(f"{name}:{digest}\n" for name, digest in sorted(file_hashes.items()))
    return hashlib.sha256(lines.encode()).hexdigest()


def _meta_field(meta: dict, *keys: str) -> str | None:
    cur: object = meta
    for k in keys:
        if not isinstance(cur, dict) or k not in cur:
            return None
        cur = cur[k]
    return None if cur is None else str(cur)


def stage_ingest(raw_root: str | Path, night: str, results_root: str | Path, duplicate_ids: list[str] = ()) -> tuple[pl.DataFrame, pl.DataFrame, list[Quarantined]]:
    """Validate and register every scan of one night.

    Returns the ``scans`` rows (status ``ok`` or ``quarantined`` with the reason), the
    ``scan_files`` rows (SHA-256 and size of every raw file, bad scans included) and the
    quarantine records (also written as ``quarantine/<scan_id>.json``).
    """
    rows, file_rows, bad = [], [], []
    dup = set(duplicate_ids)
    for d in scan_dirs(raw_root, night):
        scan_id = SCAN_RE.match(d.name).group(1)
        hashes = {}
        inside = not d.is_symlink() and d.resolve().is_relative_to(Path(raw_root).resolve())
        for f in sorted(d.iterdir()) if inside else []:
            if f.is_file() and not f.is_symlink():
                digest = rawio.sha256_file(f)
                hashes[f.name] = digest
                file_rows.append({"scan_id": scan_id, "night": night, "file": f.name, "sha256": digest, "bytes": f.stat().st_size})
        meta: dict = {}
        try:
            meta = rawio.read_scan_meta(d)
        except rawio.ScanError:
            pass
        problem: Quarantined | None = None
        if scan_id in dup:
            problem = Quarantined(scan_id, night, "ingest", "scan.json", "scan_id already used by a scan of an earlier night (scan ids are unique across nights)")
        else:
            try:
                scan = rawio.read_scan(d, raw_root=Path(raw_root))
            except rawio.ScanError as err:
                problem = Quarantined.from_error(err, night, "ingest")
            else:
                # The sensor reports null when out of range (raw-scan-format.md), so a logged value
                # outside [0, range_mm] is a mislabelled or corrupt export, not a measurement.
                out_of_range = [w for w in scan.warnings if "outside" in w]
                if out_of_range:
                    file, _, msg = out_of_range[0].partition(": ")
                    problem = Quarantined(scan_id, night, "ingest", file, msg + " (a sensor reports null when out of range)")
        if problem is not None:
            bad.append(problem)
            write_quarantine_record(results_root, problem)
        rows.append(
            {
                "scan_id": scan_id,
                "night": night,
                "device_id": _meta_field(meta, "device", "id"),
                "device_type": _meta_field(meta, "device", "type"),
                "kind": _meta_field(meta, "kind"),
                "artifact_id": _meta_field(meta, "artifact", "id"),
                "started_at": _meta_field(meta, "started_at"),
                "status": "quarantined" if problem else "ok",
                "reason": f"{problem.file}: {problem.reason}" if problem else None,
                "raw_sha256": combined_sha256(hashes),
                "raw_path": str(d),
                "simulated": bool(meta.get("acquisition", {}).get("simulated", False)) if isinstance(meta.get("acquisition"), dict) else False,
            }
        )
    scans = pl.DataFrame(rows, schema=SCANS_SCHEMA, orient="row") if rows else pl.DataFrame(schema=SCANS_SCHEMA)
    files = pl.DataFrame(file_rows, schema=SCAN_FILES_SCHEMA, orient="row") if file_rows else pl.DataFrame(schema=SCAN_FILES_SCHEMA)
    return scans, files, bad


def ok_scans(scans_table: str | Path | pl.DataFrame) -> pl.DataFrame:
    """The rows of a ``scans`` stage table whose status is ``ok``."""
    df = scans_table if isinstance(scans_table, pl.DataFrame) else pl.read_parquet(scans_table)
    return df.filter(pl.col("status") == "ok").sort("scan_id")


# --------------------------------------------------------------------------- catalog

#: History tables the catalog is built from, each the union of ``stage/<table>/night=*.parquet``.
CATALOG_TABLES = ("scans", "scan_files", "calibrations", "calibration_scans", "diameters", "verifications", "findings", "artifacts")


def read_stage_table(results_root: str | Path, table: str) -> pl.DataFrame | None:
    """All nights of one stage table (hive partition column ``night`` dropped if duplicated)."""
    files = sorted((Path(results_root) / "stage" / table).glob("night=*.parquet"))
    if not files:
        return None
    frames = [pl.read_parquet(f) for f in files]
    frames = [f for f in frames if f.width > 0]
    if not frames:
        return None
    return pl.concat(frames, how="diagonal_relaxed")


def read_quarantine(results_root: str | Path) -> pl.DataFrame:
    """Every stage's quarantine rows."""
    files = sorted((Path(results_root) / "stage" / "quarantine").glob("stage=*/night=*.parquet"))
    frames = [pl.read_parquet(f) for f in files]
    frames = [f for f in frames if f.height > 0]
    if not frames:
        return pl.DataFrame(schema=QUARANTINE_SCHEMA)
    return pl.concat(frames, how="diagonal_relaxed").sort("scan_id", "stage")


def assemble_history(results_root: str | Path) -> dict[str, pl.DataFrame]:
    """The catalog's tables from the stage tables; a scan any stage set aside is ``quarantined``.

    The ``scans`` reason is the first stage's reason (ingest before later stages), prefixed with
    the file, so ``SELECT reason FROM scans`` answers "why" without a join.
    """
    tables: dict[str, pl.DataFrame] = {}
    for name in CATALOG_TABLES:
        df = read_stage_table(results_root, name)
        if df is not None:
            tables[name] = df
    quarantine = read_quarantine(results_root)
    tables["quarantine"] = quarantine
    if "scans" in tables and quarantine.height:
        order = {"ingest": 0, "signal": 1, "calibrate": 2, "measure": 3, "discrepancy": 4}
        first = (
            quarantine.with_columns(pl.col("stage").replace_strict(order, default=9).alias("_o"))
            .sort("scan_id", "night", "_o")
            .group_by("scan_id", "night", maintain_order=True)
            .first()
            .select("scan_id", "night", (pl.col("file") + ": " + pl.col("reason")).alias("_reason"))
        )
        scans = tables["scans"].join(first, on=["scan_id", "night"], how="left")
        tables["scans"] = scans.with_columns(
            pl.when(pl.col("_reason").is_not_null()).then(pl.lit("quarantined")).otherwise(pl.col("status")).alias("status"),
            pl.coalesce("reason", "_reason").alias("reason"),
        ).drop("_reason")
    if "scans" in tables:
        tables["scans"] = tables["scans"].sort("night", "scan_id")
    if "artifacts" in tables:  # the same gauge is seen on many nights: its latest record wins
        tables["artifacts"] = tables["artifacts"].unique("artifact_id", keep="last", maintain_order=True)
    return tables


def stage_catalog(results_root: str | Path, catalog_file: str | Path | None = None) -> dict[str, int]:
    """Rebuild ``catalog.duckdb`` from every stage table; returns rows per table."""
    from borescan import catalog

    tables = assemble_history(results_root)
    path = catalog.build_catalog(results_root, tables)
    if catalog_file is not None and Path(catalog_file).resolve() != Path(path).resolve():
        raise RuntimeError(f"catalog written to {path}, rule expected {catalog_file}")
    return {name: df.height for name, df in sorted(tables.items())}
