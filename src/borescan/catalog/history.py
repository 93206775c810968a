"""The history from the stage tables: their files per night, read, normalised and assembled into rows."""

from __future__ import annotations

import datetime as _dt
import hashlib
import json
import os
from collections.abc import Mapping
from pathlib import Path

import polars as pl

from borescan.rawio import sha256_file
from borescan.tables import polars_schema
from borescan.catalog.names import SCHEMA, STAGE_ORDER, STAGE_TABLES, _NIGHT_COL, certificate_json_path

# --------------------------------------------------------------------------- normalisation


def _utc_naive(value: object) -> _dt.datetime | None:
    """ISO 8601 text or datetime -> naive UTC datetime (the catalog's TIMESTAMP convention)."""
    if value is None:
        return None
    if isinstance(value, _dt.datetime):
        dt = value
    else:
        try:
            dt = _dt.datetime.fromisoformat(str(value))
        except ValueError:  # an unreadable time stamp: such a scan is quarantined, its row keeps null
            return None
    if dt.tzinfo is not None:
        dt = dt.astimezone(_dt.timezone.utc).replace(tzinfo=None)
    return dt


def _prepare(name: str, df: pl.DataFrame, results_root: Path) -> pl.DataFrame:
    """Python-side conversions DuckDB cannot do by a cast."""
    cols = df.columns
    if "started_at" in cols and df.schema["started_at"] == pl.Utf8:
        df = df.with_columns(
            pl.col("started_at").map_elements(_utc_naive, return_dtype=pl.Datetime("us")).alias("started_at")
        )
    if "parameters" in cols and df.schema["parameters"] != pl.Utf8:
        df = df.with_columns(
            pl.Series(
                "parameters",
                [None if v is None else json.dumps(v, sort_keys=True) for v in df["parameters"].to_list()],
                dtype=pl.Utf8,
            )
        )
    if name == "calibrations" and "certificate_path" in cols:
        have = df["certificate_sha256"].to_list() if "certificate_sha256" in cols else [None] * df.height
        shas = []
        for path, sha in zip(df["certificate_path"].to_list(), have, strict=True):
            if sha is None and path:
                cj = certificate_json_path(results_root, path)
                sha = sha256_file(cj) if cj.is_file() else None
            shas.append(sha)
        df = df.with_columns(pl.Series("certificate_sha256", shas, dtype=pl.Utf8))
    if name == "calibrations":
        df = with_record_digest(df)
    return df


#: the catalog's column with the SHA-256 of each calibration's record (``calibration_json``)
RECORD_DIGEST = "calibration_json_sha256"


def with_record_digest(calibrations: pl.DataFrame) -> pl.DataFrame:
    """Return calibration rows with :data:`RECORD_DIGEST`, the SHA-256 (hex) of their ``calibration_json``.

    Rows without a record get None; a frame without the column is returned as it is.
    """
    if "calibration_json" not in calibrations.columns:
        return calibrations
    records = calibrations["calibration_json"]
    digests = [None if j is None else hashlib.sha256(j.encode()).hexdigest() for j in records]
    return calibrations.with_columns(pl.Series(RECORD_DIGEST, digests, dtype=pl.Utf8))


def _scan_stage(results_root: Path) -> dict[str, dict[str, tuple[str, str, int, int]]]:
    """Night -> {source: (path, path relative to results_root, bytes, mtime_ns)} of the stage files."""
    out: dict[str, dict[str, tuple[str, str, int, int]]] = {}
    folders = [(name, f"stage/{name}") for name in STAGE_TABLES]
    qdir = results_root / "stage" / "quarantine"
    if qdir.is_dir():
        folders += [
            (f"quarantine/{e.name}", f"stage/quarantine/{e.name}")
            for e in os.scandir(qdir)
            if e.is_dir() and e.name.startswith("stage=")
        ]
    for source, rel in folders:
        try:
            entries = list(os.scandir(results_root / rel))
        except FileNotFoundError:
            continue
        for e in entries:
            if e.name.startswith("night=") and e.name.endswith(".parquet"):
                st = e.stat()
                out.setdefault(e.name[len("night=") : -len(".parquet")], {})[source] = (
                    e.path,
                    f"{rel}/{e.name}",
                    st.st_size,
                    st.st_mtime_ns,
                )
    return {n: dict(sorted(v.items())) for n, v in sorted(out.items())}


def stage_files(results_root: str | os.PathLike) -> dict[str, dict[str, Path]]:
    """Night -> {source: path} of every stage file the catalog reads.

    A source is a table name of :data:`STAGE_TABLES` or ``quarantine/stage=<stage>``.
    """
    return {n: {s: Path(v[0]) for s, v in d.items()} for n, d in _scan_stage(Path(results_root)).items()}


def _read_nights(results_root: Path, files: Mapping[str, Mapping[str, Path]]) -> dict[str, pl.DataFrame]:
    """Return the stage rows of the given nights, per table (quarantine: every stage), in night order.

    Each row keeps its source night in ``_night``; a table with a ``night`` column gets the
    file's night where the stage left it out, and a row of another night is an error.
    """
    frames: dict[str, list[pl.DataFrame]] = {}
    sources: dict[str, list[tuple[str, int, Path]]] = {}
    for night in sorted(files):
        for source, f in files[night].items():
            table = "quarantine" if source.startswith("quarantine/") else source
            df = pl.read_parquet(f)
            if df.width == 0 or (table == "quarantine" and df.height == 0):
                continue
            frames.setdefault(table, []).append(df)
            sources.setdefault(table, []).append((night, df.height, f))
    out = {}
    for table, fs in frames.items():
        df = pl.concat(fs, how="diagonal_relaxed") if len(fs) > 1 else fs[0]
        src = sources[table]
        df = df.with_columns(pl.Series(_NIGHT_COL, [n for n, h, _ in src for _ in range(h)], dtype=pl.Utf8))
        if "night" in SCHEMA.get(table, {}):
            if "night" not in df.columns:
                df = df.with_columns(pl.col(_NIGHT_COL).alias("night"))
            elif df.schema["night"] == pl.Utf8:
                bad = df.filter(pl.col("night").is_not_null() & (pl.col("night") != pl.col(_NIGHT_COL)))
                if bad.height:
                    night = bad[_NIGHT_COL][0]
                    f = next(f for n, _, f in src if n == night)
                    raise ValueError(
                        f"{f}: rows of night {bad['night'][0]} in the stage file of night {night}"
                    )
                df = df.with_columns(pl.col("night").fill_null(pl.col(_NIGHT_COL)))
        out[table] = df
    if "quarantine" not in out:
        out["quarantine"] = pl.DataFrame(schema={**polars_schema("quarantine"), _NIGHT_COL: pl.Utf8})
    out["quarantine"] = out["quarantine"].sort("scan_id", "stage", maintain_order=True)
    return out


def _assemble(tables: dict[str, pl.DataFrame]) -> dict[str, pl.DataFrame]:
    """Return the history rules within a batch of nights (rows keep their source night in ``_night``).

    The ``scans`` reason is the first stage's reason (:data:`STAGE_ORDER`), prefixed with the
    file, so ``SELECT reason FROM scans`` answers "why" without a join. A calibration's first
    night's row wins; an artifact keeps its latest record (``artifacts`` holds each night's last
    record per artifact, the catalog keeps the latest of them).
    """
    quarantine = tables["quarantine"]
    if "scans" in tables and quarantine.height:
        order = {stage: i for i, stage in enumerate(STAGE_ORDER)}
        first = (
            quarantine.with_columns(pl.col("stage").replace_strict(order, default=9).alias("_o"))
            .sort("scan_id", "night", "_o")
            .group_by("scan_id", "night", maintain_order=True)
            .first()
            .select("scan_id", "night", (pl.col("file") + ": " + pl.col("reason")).alias("_reason"))
        )
        scans = tables["scans"].join(first, on=["scan_id", "night"], how="left")
        tables["scans"] = scans.with_columns(
            pl.when(pl.col("_reason").is_not_null())
            .then(pl.lit("quarantined"))
            .otherwise(pl.col("status"))
            .alias("status"),
            pl.coalesce("reason", "_reason").alias("reason"),
        ).drop("_reason")
    if "scans" in tables:
        tables["scans"] = tables["scans"].sort("night", "scan_id")
    if "calibrations" in tables:
        tables["calibrations"] = (
            tables["calibrations"]
            .sort(_NIGHT_COL, maintain_order=True)
            .unique(["calibration_id", "channel"], keep="first", maintain_order=True)
        )
    if "calibration_scans" in tables:
        tables["calibration_scans"] = tables["calibration_scans"].unique(maintain_order=True)
    if "artifacts" in tables:
        tables["artifacts"] = tables["artifacts"].unique(
            ["artifact_id", _NIGHT_COL], keep="last", maintain_order=True
        )
    return tables


def read_stage_table(results_root: str | os.PathLike, table: str) -> pl.DataFrame | None:
    """All nights of one stage table (``stage/<table>/night=*.parquet``); None when there are none."""
    files = sorted((Path(results_root) / "stage" / table).glob("night=*.parquet"))
    frames = [f for f in (pl.read_parquet(f) for f in files) if f.width > 0]
    return pl.concat(frames, how="diagonal_relaxed") if frames else None


def read_quarantine(results_root: str | os.PathLike) -> pl.DataFrame:
    """Every stage's quarantine rows (``stage/quarantine/stage=*/night=*.parquet``), by scan and stage."""
    files = sorted((Path(results_root) / "stage" / "quarantine").glob("stage=*/night=*.parquet"))
    frames = [f for f in (pl.read_parquet(f) for f in files) if f.height > 0]
    if not frames:
        return pl.DataFrame(schema=polars_schema("quarantine"))
    return pl.concat(frames, how="diagonal_relaxed").sort("scan_id", "stage")


def assemble_history(
    results_root: str | os.PathLike, nights: list[str] | None = None
) -> dict[str, pl.DataFrame]:
    """Return the catalog's tables from the stage tables of ``nights`` (default: every night).

    A scan any stage set aside is ``quarantined`` (first stage's reason); a row's night comes
    from its stage file where the stage leaves it out; a calibration's first night's row wins
    and an artifact keeps its latest record.
    """
    files = stage_files(results_root)
    if nights is not None:
        files = {n: files[n] for n in nights if n in files}
    tables = _assemble(_read_nights(Path(results_root), files))
    if "artifacts" in tables:
        tables["artifacts"] = tables["artifacts"].unique("artifact_id", keep="last", maintain_order=True)
    return {name: df.drop(_NIGHT_COL, strict=False) for name, df in tables.items()}
