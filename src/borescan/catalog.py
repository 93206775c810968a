"""The history catalog: ``<results_root>/catalog.duckdb``, rebuilt from the stage tables.

The pipeline writes one Parquet file per stage table and night
(``<results_root>/stage/<table>/night=<night>.parquet``). :func:`build_catalog` loads those
tables (as polars frames) into a fresh DuckDB file ``catalog.duckdb.tmp`` with the fixed schema
below (:data:`SCHEMA`, the columns of ``shared/spec/outputs.md`` plus extensions), fills the
columns that follow from other tables (a diameter's night and raw digest from its scan, ...),
creates one view per saved query (``workflow/queries/<name>.sql``) and renames the file to
``catalog.duckdb``. Nothing in a row comes from the wall clock, and rows are inserted in key
order, so rebuilding from the same stage files gives the same table contents.

Reading the history
-------------------
- ``borescan sql "SELECT ..."`` or ``borescan sql --query verification_drift`` (read-only).
- Plain DuckDB, also on shared storage while the pipeline runs:
  ``duckdb -readonly results/catalog.duckdb`` (the file is replaced by a rename, so an open
  reader keeps a consistent snapshot).
- Without the catalog, straight from the stage Parquet files:
  ``SELECT * FROM read_parquet('results/stage/diameters/night=*.parquet', union_by_name=true)``;
  the quarantine rows are hive-partitioned by stage:
  ``read_parquet('results/stage/quarantine/*/*.parquet', hive_partitioning=true)``.
"""

from __future__ import annotations

import datetime as _dt
import json
import os
import re
from collections.abc import Mapping
from pathlib import Path

import duckdb
import polars as pl

from borescan.rawio import combined_sha256, sha256_file
from borescan.tables import TABLES, polars_schema

__all__ = [
    "CATALOG_NAME",
    "SCHEMA",
    "KEYS",
    "DEFAULT_QUERIES_DIR",
    "STAGE_TABLES",
    "STAGE_ORDER",
    "assemble_history",
    "build_catalog",
    "open_catalog",
    "read_quarantine",
    "read_stage_table",
    "catalog_path",
    "combined_sha256",
    "saved_queries",
    "upsert_rows",
    "table_rows",
]

CATALOG_NAME = "catalog.duckdb"

#: Saved queries shipped with the project (``workflow/queries/*.sql``), one view each.
DEFAULT_QUERIES_DIR = Path(__file__).resolve().parents[2] / "workflow" / "queries"

#: Column name -> DuckDB type of every catalog table, in column order (from :mod:`borescan.tables`,
#: the one definition of the history tables). Input frames may carry more columns: they are kept
#: after these, with the type DuckDB infers.
SCHEMA: dict[str, dict[str, str]] = {name: t.duckdb_types() for name, t in TABLES.items()}

#: Key columns of each table: rows are inserted in this order (and unique where ``primary``).
KEYS: dict[str, tuple[str, ...]] = {name: t.key for name, t in TABLES.items()}

_IDENT = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")


def catalog_path(results_root: str | os.PathLike) -> Path:
    """``<results_root>/catalog.duckdb``."""
    return Path(results_root) / CATALOG_NAME


def certificate_json_path(results_root: str | os.PathLike, certificate_path: str) -> Path:
    """The ``certificate.json`` belonging to a ``certificate_path`` (a certificate file or its folder).

    Relative paths are relative to ``results_root``.
    """
    p = Path(certificate_path)
    if not p.is_absolute():
        p = Path(results_root) / p
    folder = p if p.suffix == "" else p.parent
    return folder / "certificate.json"


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
    return df


def _q(name: str) -> str:
    return '"' + name.replace('"', '""') + '"'


def _create_table(con: duckdb.DuckDBPyConnection, name: str, df: pl.DataFrame | None) -> None:
    schema = SCHEMA[name]
    if df is not None and df.width == 0:
        df = None
    extra: dict[str, str] = {}
    if df is not None:
        con.register("_in", df)
        in_types = {row[0]: row[1] for row in con.execute("DESCRIBE SELECT * FROM _in").fetchall()}
        extra = {c: in_types[c] for c in df.columns if c not in schema}
    keys = KEYS[name]
    con.execute(TABLES[name].ddl(extra))
    if df is None or df.height == 0:
        if df is not None:
            con.unregister("_in")
        return
    select = []
    for c, t in schema.items():
        select.append(f"CAST({_q(c)} AS {t})" if c in df.columns else f"CAST(NULL AS {t})")
    select += [_q(c) for c in extra]
    # keys first, then every other column: a total, input-order-independent insertion order
    order_cols = [k for k in keys if k in df.columns] + [c for c in schema if c in df.columns and c not in keys]
    order = ", ".join(f"{_q(c)} NULLS FIRST" for c in order_cols)
    try:
        con.execute(f"INSERT INTO {_q(name)} SELECT {', '.join(select)} FROM _in ORDER BY {order}")
    except duckdb.ConstraintException as err:
        raise ValueError(f"catalog table {name}: duplicate key {keys}: {err}") from err
    except duckdb.ConversionException as err:
        raise ValueError(f"catalog table {name}: a column does not convert to its catalog type: {err}") from err
    finally:
        con.unregister("_in")


_FILL_SQL = [
    # diameters: id, night, raw digest and device from the scan
    "UPDATE diameters SET diameter_id = scan_id || '/' || coalesce(feature, '') WHERE diameter_id IS NULL",
    """UPDATE diameters SET night = coalesce(diameters.night, s.night),
                            raw_sha256 = coalesce(diameters.raw_sha256, s.raw_sha256),
                            device_id = coalesce(diameters.device_id, s.device_id),
                            artifact_id = coalesce(diameters.artifact_id, s.artifact_id)
       FROM scans s WHERE s.scan_id = diameters.scan_id""",
    # calibrations: night/raw digest of the (first) calibration scan; valid from that night
    """UPDATE calibrations SET night = coalesce(calibrations.night, s.night),
                               raw_sha256 = coalesce(calibrations.raw_sha256, s.raw_sha256),
                               device_type = coalesce(calibrations.device_type, s.device_type)
       FROM scans s WHERE s.scan_id = calibrations.scan_id""",
    "UPDATE calibrations SET valid_from = night WHERE valid_from IS NULL",
    "UPDATE calibrations SET status = 'valid' WHERE status IS NULL",
    """INSERT INTO calibration_scans
       SELECT DISTINCT c.calibration_id, c.scan_id FROM calibrations c
       WHERE c.scan_id IS NOT NULL AND NOT EXISTS (
           SELECT 1 FROM calibration_scans cs WHERE cs.calibration_id = c.calibration_id)
       ORDER BY 1, 2""",
    # verifications: night from the scan, error and verdict from the numbers
    """UPDATE verifications SET night = coalesce(verifications.night, s.night),
                                device_id = coalesce(verifications.device_id, s.device_id),
                                artifact_id = coalesce(verifications.artifact_id, s.artifact_id)
       FROM scans s WHERE s.scan_id = verifications.scan_id""",
    "UPDATE verifications SET error_mm = measured_mm - certified_mm WHERE error_mm IS NULL",
    "UPDATE verifications SET passed = abs(error_mm) <= tolerance_mm WHERE passed IS NULL",
    "UPDATE findings SET night = s.night FROM scans s WHERE s.scan_id = findings.scan_id AND findings.night IS NULL",
    "UPDATE quarantine SET night = s.night FROM scans s WHERE s.scan_id = quarantine.scan_id AND quarantine.night IS NULL",
]


# --------------------------------------------------------------------------- saved queries


def saved_queries(queries_dir: str | os.PathLike | None = None) -> dict[str, tuple[str, str]]:
    """Saved queries: name -> (description, SQL text).

    The description is the leading ``--`` comment block of ``<name>.sql`` (comment markers
    stripped). Names are the file stems, which must be SQL identifiers.
    """
    qdir = Path(queries_dir) if queries_dir is not None else DEFAULT_QUERIES_DIR
    out: dict[str, tuple[str, str]] = {}
    if not qdir.is_dir():
        return out
    for f in sorted(qdir.glob("*.sql")):
        if not _IDENT.match(f.stem):
            raise ValueError(f"saved query {f}: the file name must be an SQL identifier")
        text = f.read_text()
        desc = []
        for line in text.splitlines():
            s = line.strip()
            if s.startswith("--"):
                desc.append(s[2:].strip())
            elif s:
                break
        out[f.stem] = ("\n".join(desc).strip(), text)
    return out


def _view_sql(sql: str) -> str:
    body = sql.strip()
    while body.endswith(";"):
        body = body[:-1].rstrip()
    return body


# --------------------------------------------------------------------------- stage tables

#: History tables the catalog is built from, each the union of ``stage/<table>/night=*.parquet``.
STAGE_TABLES = ("scans", "scan_files", "calibrations", "calibration_scans", "diameters", "verifications", "findings",
                "artifacts")

#: The stages in the order a night runs them: a scan's reason in ``scans`` is its earliest stage's.
STAGE_ORDER = ("ingest", "signal", "calibrate", "measure", "discrepancy")


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


def assemble_history(results_root: str | os.PathLike) -> dict[str, pl.DataFrame]:
    """The catalog's tables from the stage tables; a scan any stage set aside is ``quarantined``.

    The ``scans`` reason is the first stage's reason (:data:`STAGE_ORDER`), prefixed with the
    file, so ``SELECT reason FROM scans`` answers "why" without a join. A rod's nominal geometry
    recurs every night (its first night's row wins); an artifact seen on many nights keeps its
    latest record.
    """
    tables: dict[str, pl.DataFrame] = {}
    for name in STAGE_TABLES:
        df = read_stage_table(results_root, name)
        if df is not None:
            tables[name] = df
    quarantine = read_quarantine(results_root)
    tables["quarantine"] = quarantine
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
            pl.when(pl.col("_reason").is_not_null()).then(pl.lit("quarantined")).otherwise(pl.col("status")).alias("status"),
            pl.coalesce("reason", "_reason").alias("reason"),
        ).drop("_reason")
    if "scans" in tables:
        tables["scans"] = tables["scans"].sort("night", "scan_id")
    if "calibrations" in tables:
        tables["calibrations"] = tables["calibrations"].sort("night").unique(["calibration_id", "channel"], keep="first",
                                                                             maintain_order=True)
    if "calibration_scans" in tables:
        tables["calibration_scans"] = tables["calibration_scans"].unique(maintain_order=True)
    if "artifacts" in tables:
        tables["artifacts"] = tables["artifacts"].unique("artifact_id", keep="last", maintain_order=True)
    return tables


# --------------------------------------------------------------------------- build / open


def build_catalog(
    results_root: str | os.PathLike,
    tables: Mapping[str, pl.DataFrame | None] | None = None,
    queries_dir: str | os.PathLike | None = None,
) -> Path:
    """(Re)build ``<results_root>/catalog.duckdb`` from the history tables; return its path.

    Parameters
    ----------
    results_root
        Results folder; certificate paths in ``calibrations`` are relative to it.
    tables
        Table name -> polars frame with (a subset of) the columns of :data:`SCHEMA`; missing
        tables are created empty, missing columns are null, extra columns are kept. ``None``
        reads the stage tables with :func:`assemble_history`.
    queries_dir
        Folder of saved ``*.sql`` queries, one view each (default: the project's
        ``workflow/queries``).

    The database is written to ``catalog.duckdb.tmp`` and renamed over ``catalog.duckdb``, so
    readers never see a half-built history. Unknown table names raise ``ValueError``.
    """
    root = Path(results_root)
    root.mkdir(parents=True, exist_ok=True)
    if tables is None:
        tables = assemble_history(root)
    unknown = sorted(set(tables) - set(SCHEMA))
    if unknown:
        raise ValueError(f"unknown catalog table(s) {unknown}; valid: {sorted(SCHEMA)}")
    final = catalog_path(root)
    tmp = final.with_name(final.name + ".tmp")
    for leftover in (tmp, tmp.with_name(tmp.name + ".wal")):
        if leftover.exists():
            leftover.unlink()
    con = duckdb.connect(str(tmp))
    try:
        con.execute("SET TimeZone = 'UTC'")
        for name in SCHEMA:
            df = tables.get(name)
            _create_table(con, name, None if df is None else _prepare(name, df, root))
        for stmt in _FILL_SQL:
            con.execute(stmt)
        for qname, (_desc, sql) in saved_queries(queries_dir).items():
            try:
                con.execute(f"CREATE VIEW {_q(qname)} AS {_view_sql(sql)}")
            except duckdb.Error as err:
                raise ValueError(f"saved query {qname}: {err}") from err
        con.execute("CHECKPOINT")
    finally:
        con.close()
    os.replace(tmp, final)
    return final


def open_catalog(results_root: str | os.PathLike, read_only: bool = True) -> duckdb.DuckDBPyConnection:
    """Connect to ``<results_root>/catalog.duckdb`` (read-only by default).

    Raises ``FileNotFoundError`` naming the expected file when the catalog has not been built.
    """
    path = catalog_path(results_root)
    if not path.is_file():
        raise FileNotFoundError(
            f"no history catalog at {path}; run `snakemake catalog` (or pass --results DIR)"
        )
    con = duckdb.connect(str(path), read_only=read_only)
    con.execute("SET TimeZone = 'UTC'")
    return con


def table_rows(con: duckdb.DuckDBPyConnection, table: str) -> list[tuple]:
    """All rows of a catalog table in key order (handy for comparisons and tests)."""
    if table not in SCHEMA:
        raise ValueError(f"unknown catalog table {table!r}; valid: {sorted(SCHEMA)}")
    order = ", ".join(f"{_q(k)} NULLS FIRST" for k in KEYS[table])
    return con.execute(f"SELECT * FROM {_q(table)} ORDER BY {order}").fetchall()


def upsert_rows(con: duckdb.DuckDBPyConnection, table: str, df: pl.DataFrame) -> int:
    """Replace the rows of ``table`` whose key matches a row of ``df``, then insert ``df``.

    For interactive repairs on a writable connection; the pipeline rebuilds the whole catalog
    with :func:`build_catalog` instead. Returns the number of rows inserted.
    """
    if table not in SCHEMA:
        raise ValueError(f"unknown catalog table {table!r}; valid: {sorted(SCHEMA)}")
    keys = [k for k in KEYS[table] if k in df.columns]
    if not keys:
        raise ValueError(f"upsert into {table} needs the key column(s) {KEYS[table]}")
    df = _prepare(table, df, Path("."))
    con.register("_up", df)
    try:
        cond = " AND ".join(f"t.{_q(k)} IS NOT DISTINCT FROM u.{_q(k)}" for k in keys)
        con.execute(f"DELETE FROM {_q(table)} t WHERE EXISTS (SELECT 1 FROM _up u WHERE {cond})")
        cols = [c for c in SCHEMA[table] if c in df.columns]
        casts = ", ".join(f"CAST({_q(c)} AS {SCHEMA[table][c]})" for c in cols)
        con.execute(f"INSERT INTO {_q(table)} ({', '.join(_q(c) for c in cols)}) SELECT {casts} FROM _up")
    finally:
        con.unregister("_up")
    return df.height
