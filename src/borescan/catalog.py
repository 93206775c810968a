"""The history catalog: ``<results_root>/catalog.duckdb``, extended night by night from the stage tables.

The pipeline writes one Parquet file per stage table and night
(``<results_root>/stage/<table>/night=<night>.parquet``). :func:`update_catalog` (what the
``build_catalog`` rule runs) adds the nights whose stage files are new to the catalog: it reads
only those files, fills the columns that follow from other tables within the night (a
diameter's raw digest from its scan, ...) and appends the rows. Its cost depends on the night,
not on the history. A night whose files changed or disappeared is replaced the same way when it
is newer than every unchanged night (a re-run of the latest nights); any other change (an older
night re-run, a catalog written by another version) rebuilds the whole catalog, as does
:func:`rebuild_catalog` (``borescan rebuild-catalog``). Both paths give the same tables
(``tests/test_catalog_incremental.py``).

Each table has the fixed schema of :mod:`borescan.tables` (:data:`SCHEMA`, the columns of
``shared/spec/outputs.md`` plus extensions); one view per saved query
(``workflow/queries/<name>.sql``) is created on every update. Nothing in a row comes from the
wall clock, so building from the same stage files gives the same table contents. Cross-night
rules: a calibration's first night's row wins (a rod's nominal geometry recurs every night), an
artifact keeps its latest night's record, and statuses that a later night changes (a
measurement put in doubt by a failed verification) are views, always current.

Bookkeeping lives in the DuckDB schema ``build`` (``build.sources``: the stage files each night
was built from, with size and modification time; ``build.info``; the per-night records behind
``calibration_scans`` and ``artifacts``, so the latest nights can be replaced).

The new catalog is written to ``catalog.duckdb.tmp`` (a copy of the old one, extended) and
renamed over ``catalog.duckdb``, so readers never see a half-built history.

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
import hashlib
import json
import os
import re
import shutil
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import duckdb
import polars as pl

from borescan.resources import shipped
from borescan.atomic import atomic_write_text
from borescan.rawio import combined_sha256, sha256_file
from borescan.tables import TABLES, polars_schema

__all__ = [
    "BUILD_SCHEMA",
    "CATALOG_NAME",
    "CatalogUpdate",
    "FORMAT_VERSION",
    "NIGHT_TABLES",
    "SCHEMA",
    "KEYS",
    "DEFAULT_QUERIES_DIR",
    "STAGE_TABLES",
    "STAGE_ORDER",
    "assemble_history",
    "build_catalog",
    "rebuild_catalog",
    "stage_files",
    "update_catalog",
    "open_catalog",
    "read_quarantine",
    "read_stage_table",
    "catalog_path",
    "catalog_damage",
    "set_aside_damaged",
    "CatalogDamaged",
    "combined_sha256",
    "saved_queries",
    "upsert_rows",
    "table_rows",
]

CATALOG_NAME = "catalog.duckdb"

#: Saved queries shipped with the project (``workflow/queries/*.sql``), one view each.
DEFAULT_QUERIES_DIR = shipped("queries")

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
    """Return the ``certificate.json`` belonging to a ``certificate_path`` (a certificate file or its folder).

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


# --------------------------------------------------------------------------- saved queries


def saved_queries(queries_dir: str | os.PathLike | None = None) -> dict[str, tuple[str, str]]:
    """Return the saved queries: name -> (description, SQL text).

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


def _q(name: str) -> str:
    return '"' + name.replace('"', '""') + '"'


# --------------------------------------------------------------------------- stage tables

#: History tables the catalog is built from, each the union of ``stage/<table>/night=*.parquet``.
STAGE_TABLES = (
    "scans",
    "scan_files",
    "calibrations",
    "calibration_scans",
    "diameters",
    "verifications",
    "findings",
    "artifacts",
    "pooled_findings",
    "calibration_drift",
    "night_config",
    "config_changes",
)

#: The stages in the order a night runs them: a scan's reason in ``scans`` is its earliest stage's.
STAGE_ORDER = ("ingest", "signal", "calibrate", "measure", "discrepancy")

#: Tables whose rows carry their night (from the stage file's name where the stage leaves it out):
#: a night's rows are found, and replaced, by it.
NIGHT_TABLES = tuple(name for name, cols in SCHEMA.items() if "night" in cols)

#: Bump when the way rows are derived changes: a catalog of another version is rebuilt, not extended.
FORMAT_VERSION = 2

#: DuckDB schema of the bookkeeping tables (see the module docstring).
BUILD_SCHEMA = "build"

_NIGHT_COL = "_night"  # source night of a row while a batch is assembled (never in the catalog)


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


# --------------------------------------------------------------------------- writing rows

#: Columns filled within a batch from other tables (joined on the scan and, where known, its night).
_FILL_SQL = [
    # diameters: id, night, raw digest and device from the scan
    "UPDATE {diameters} SET diameter_id = scan_id || '/' || coalesce(feature, '') WHERE diameter_id IS NULL",
    """UPDATE {diameters} SET night = coalesce({diameters}.night, s.night),
                              raw_sha256 = coalesce({diameters}.raw_sha256, s.raw_sha256),
                              device_id = coalesce({diameters}.device_id, s.device_id),
                              artifact_id = coalesce({diameters}.artifact_id, s.artifact_id)
       FROM {scans} s WHERE s.scan_id = {diameters}.scan_id
                        AND ({diameters}.night IS NULL OR s.night = {diameters}.night)""",
    # calibrations: night/raw digest of the (first) calibration scan; valid from that night
    """UPDATE {calibrations} SET night = coalesce({calibrations}.night, s.night),
                                 raw_sha256 = coalesce({calibrations}.raw_sha256, s.raw_sha256),
                                 device_type = coalesce({calibrations}.device_type, s.device_type)
       FROM {scans} s WHERE s.scan_id = {calibrations}.scan_id
                        AND ({calibrations}.night IS NULL OR s.night = {calibrations}.night)""",
    "UPDATE {calibrations} SET valid_from = night WHERE valid_from IS NULL",
    "UPDATE {calibrations} SET status = 'valid' WHERE status IS NULL",
    # verifications: night from the scan, error and verdict from the numbers
    """UPDATE {verifications} SET night = coalesce({verifications}.night, s.night),
                                  device_id = coalesce({verifications}.device_id, s.device_id),
                                  artifact_id = coalesce({verifications}.artifact_id, s.artifact_id)
       FROM {scans} s WHERE s.scan_id = {verifications}.scan_id
                        AND ({verifications}.night IS NULL OR s.night = {verifications}.night)""",
    "UPDATE {verifications} SET error_mm = measured_mm - certified_mm WHERE error_mm IS NULL",
    "UPDATE {verifications} SET passed = abs(error_mm) <= tolerance_mm WHERE passed IS NULL",
    "UPDATE {findings} SET night = s.night FROM {scans} s WHERE s.scan_id = {findings}.scan_id AND "
    "{findings}.night IS NULL",
    "UPDATE {quarantine} SET night = s.night FROM {scans} s WHERE s.scan_id = {quarantine}.scan_id AND "
    "{quarantine}.night IS NULL",
]

_STAGING = {name: f"_new_{name}" for name in SCHEMA}


def _columns(con: duckdb.DuckDBPyConnection, table: str) -> dict[str, str]:
    return {r[0]: r[1] for r in con.execute(f"DESCRIBE {table}").fetchall()}


def _create_tables(con: duckdb.DuckDBPyConnection) -> None:
    """Create the empty catalog tables and the bookkeeping tables (a new catalog)."""
    for t in TABLES.values():
        con.execute(t.ddl())
    b = BUILD_SCHEMA
    con.execute(f"CREATE SCHEMA {b}")
    con.execute(f"CREATE TABLE {b}.info (key VARCHAR PRIMARY KEY, value VARCHAR)")
    con.execute(f"CREATE TABLE {b}.sources (night VARCHAR, file VARCHAR, bytes BIGINT, mtime_ns BIGINT)")
    con.execute(
        f"CREATE TABLE {b}.calibration_scan_nights (calibration_id VARCHAR, scan_id VARCHAR, night VARCHAR)"
    )
    con.execute(
        f"CREATE TABLE {b}.artifact_records AS SELECT CAST(NULL AS VARCHAR) AS night, * FROM artifacts "
        "LIMIT 0"
    )


def _schema_fingerprint() -> str:
    text = "\n".join(t.ddl() for t in TABLES.values()) + f"\nformat {FORMAT_VERSION}"
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def _add_columns(con: duckdb.DuckDBPyConnection, table: str, cols: Mapping[str, str]) -> None:
    have = _columns(con, table)
    for c, t in cols.items():
        if c not in have:
            con.execute(f"ALTER TABLE {table} ADD COLUMN {_q(c)} {t}")


def _stage_rows(con: duckdb.DuckDBPyConnection, name: str, df: pl.DataFrame | None, root: Path) -> None:
    """``_new_<name>``: the batch's rows of one table with the catalog's columns and types.

    Columns the catalog does not define are added to it (type as DuckDB infers it), so an extra
    stage column is kept; the source night stays in ``_night`` for the bookkeeping.
    """
    staging = _STAGING[name]
    if df is not None and df.width == 0:
        df = None
    if df is not None:
        df = _prepare(name, df, root)
        con.register("_in", df)
        try:
            in_types = _columns(con, "_in")
        except BaseException:
            con.unregister("_in")
            raise
        extra = {c: t for c, t in in_types.items() if c not in SCHEMA[name] and c != _NIGHT_COL}
        _add_columns(con, name, extra)
        if name == "artifacts":
            _add_columns(con, f"{BUILD_SCHEMA}.artifact_records", extra)
    cols = _columns(con, name)
    con.execute(
        f"CREATE OR REPLACE TEMP TABLE {staging} AS SELECT *, CAST(NULL AS VARCHAR) AS {_NIGHT_COL} "
        f"FROM {name} LIMIT 0"
    )
    if df is None:
        return
    try:
        select = [
            f"CAST({_q(c)} AS {t})" if c in df.columns else f"CAST(NULL AS {t})" for c, t in cols.items()
        ]
        select.append(_q(_NIGHT_COL) if _NIGHT_COL in df.columns else "CAST(NULL AS VARCHAR)")
        con.execute(f"INSERT INTO {staging} SELECT {', '.join(select)} FROM _in")
    except duckdb.ConversionException as err:
        raise ValueError(
            f"catalog table {name}: a column does not convert to its catalog type: {err}"
        ) from err
    finally:
        con.unregister("_in")


def _order_by(name: str, cols: Mapping[str, str]) -> str:
    """Keys first, then every other defined column: a total, input-order-independent order."""
    keys = KEYS[name]
    order_cols = list(keys) + [c for c in SCHEMA[name] if c not in keys and c in cols]
    return ", ".join(f"{_q(c)} NULLS FIRST" for c in order_cols)


def _merge(con: duckdb.DuckDBPyConnection, name: str, source: str | None = None) -> None:
    """Insert the staged rows of ``name`` (or of table ``source``) in key order."""
    cols = _columns(con, name)
    names = ", ".join(_q(c) for c in cols)
    try:
        con.execute(
            f"INSERT INTO {name} ({names}) SELECT {names} FROM {source or _STAGING[name]} "
            f"ORDER BY {_order_by(name, cols)}"
        )
    except duckdb.ConstraintException as err:
        raise ValueError(f"catalog table {name}: duplicate key {KEYS[name]}: {err}") from err


def _append(
    con: duckdb.DuckDBPyConnection,
    tables: Mapping[str, pl.DataFrame | None],
    root: Path,
    direct: bool = False,
) -> None:
    """Add a batch of rows: nights newer than every night in the catalog, or a whole history.

    Within the batch the derived columns are filled (:data:`_FILL_SQL`). Then a calibration
    already in the catalog keeps its row, an artifact takes the batch's latest record, and every
    kept calibration's own scan is linked in ``calibration_scans``. ``direct``: rows given as
    they are (no source nights): duplicate keys are an error in every table.
    """
    b = BUILD_SCHEMA
    for name in SCHEMA:
        _stage_rows(con, name, tables.get(name), root)
    for stmt in _FILL_SQL:
        con.execute(stmt.format(**_STAGING))
    for name in NIGHT_TABLES:
        if name != "calibrations":
            _merge(con, name)
    # calibrations: the first night's row of a (calibration_id, channel) wins
    new_only = (
        ""
        if direct
        else """WHERE NOT EXISTS (SELECT 1 FROM calibrations c
        WHERE c.calibration_id IS NOT DISTINCT FROM n.calibration_id
          AND c.channel IS NOT DISTINCT FROM n.channel)"""
    )
    con.execute(f"CREATE OR REPLACE TEMP TABLE _kept AS SELECT * FROM _new_calibrations n {new_only}")
    _merge(con, "calibrations", "_kept")
    # calibration_scans: the stage's links and each kept calibration's own scan, each night's on record
    con.execute(f"""INSERT INTO _new_calibration_scans (calibration_id, scan_id, {_NIGHT_COL})
                    SELECT DISTINCT calibration_id, scan_id, coalesce({_NIGHT_COL}, CAST(night AS VARCHAR))
                    FROM _kept WHERE scan_id IS NOT NULL""")
    con.execute(f"""INSERT INTO {b}.calibration_scan_nights
                    SELECT DISTINCT calibration_id, scan_id, {_NIGHT_COL} FROM _new_calibration_scans""")
    con.execute("""INSERT INTO calibration_scans
                   SELECT DISTINCT calibration_id, scan_id FROM _new_calibration_scans n WHERE NOT EXISTS (
                       SELECT 1 FROM calibration_scans c WHERE c.calibration_id = n.calibration_id
                                                            AND c.scan_id = n.scan_id)
                   ORDER BY 1, 2""")
    # artifacts: each night's record is kept aside; the catalog holds the latest
    con.execute(
        f"INSERT INTO {b}.artifact_records BY NAME "
        f"SELECT * EXCLUDE ({_NIGHT_COL}), {_NIGHT_COL} AS night FROM _new_artifacts"
    )
    if direct:
        _merge(con, "artifacts")
    else:
        con.execute(f"""CREATE OR REPLACE TEMP TABLE _latest AS SELECT * FROM _new_artifacts
                        QUALIFY row_number()
                                OVER (PARTITION BY artifact_id ORDER BY {_NIGHT_COL} DESC) = 1""")
        con.execute("DELETE FROM artifacts WHERE artifact_id IN (SELECT artifact_id FROM _latest)")
        _merge(con, "artifacts", "_latest")
    for tmp in [*_STAGING.values(), "_kept", "_latest"]:
        con.execute(f"DROP TABLE IF EXISTS {tmp}")


def _remove_nights(con: duckdb.DuckDBPyConnection, nights: list[str]) -> None:
    """Take the rows of the newest ``nights`` out of the catalog.

    Take the rows of ``nights`` (the newest in the catalog) out; artifacts fall back to their
    latest earlier record, links stay while another night still has them.
    """
    b = BUILD_SCHEMA
    con.execute("CREATE OR REPLACE TEMP TABLE _gone_nights AS SELECT unnest(?::VARCHAR[]) AS night", [nights])
    for name in NIGHT_TABLES:
        con.execute(f"DELETE FROM {name} WHERE CAST(night AS VARCHAR) IN (SELECT night FROM _gone_nights)")
    con.execute(f"""CREATE OR REPLACE TEMP TABLE _gone AS SELECT DISTINCT calibration_id, scan_id
                    FROM {b}.calibration_scan_nights WHERE night IN (SELECT night FROM _gone_nights)""")
    con.execute(f"DELETE FROM {b}.calibration_scan_nights WHERE night IN (SELECT night FROM _gone_nights)")
    con.execute(f"""DELETE FROM calibration_scans c
                    WHERE EXISTS (SELECT 1 FROM _gone g
                                  WHERE g.calibration_id = c.calibration_id AND g.scan_id = c.scan_id)
                      AND NOT EXISTS (SELECT 1 FROM {b}.calibration_scan_nights k
                                      WHERE k.calibration_id = c.calibration_id AND k.scan_id = c.scan_id)""")
    con.execute(f"""CREATE OR REPLACE TEMP TABLE _ids AS SELECT DISTINCT artifact_id FROM {b}.artifact_records
                    WHERE night IN (SELECT night FROM _gone_nights)""")
    con.execute(f"DELETE FROM {b}.artifact_records WHERE night IN (SELECT night FROM _gone_nights)")
    con.execute("DELETE FROM artifacts WHERE artifact_id IN (SELECT artifact_id FROM _ids)")
    con.execute(f"""CREATE OR REPLACE TEMP TABLE _latest AS SELECT * EXCLUDE (night) FROM {b}.artifact_records
                    WHERE artifact_id IN (SELECT artifact_id FROM _ids)
                    QUALIFY row_number() OVER (PARTITION BY artifact_id ORDER BY night DESC) = 1""")
    con.execute("INSERT INTO artifacts BY NAME SELECT * FROM _latest")
    for tmp in ("_gone_nights", "_gone", "_ids", "_latest"):
        con.execute(f"DROP TABLE IF EXISTS {tmp}")


# --------------------------------------------------------------------------- build / update


@dataclass(frozen=True)
class CatalogUpdate:
    """What :func:`update_catalog` did.

    ``mode``: ``"append"`` (nights added; ``removed`` lists the newest nights whose rows were
    replaced or dropped first), ``"unchanged"`` (no stage file changed; the saved queries'
    views are refreshed) or ``"full"`` (rebuilt from every stage file, ``reason`` says why).
    ``rows``: rows per catalog table afterwards.
    """

    path: Path
    mode: str
    reason: str
    added: tuple[str, ...]
    removed: tuple[str, ...]
    rows: dict[str, int]


def _read_manifest(
    con: duckdb.DuckDBPyConnection,
) -> tuple[dict[str, str], dict[str, dict[str, tuple[int, int]]]] | None:
    """``build.info`` and ``build.sources`` of a catalog (None when it has none)."""
    try:
        info = dict(con.execute(f"SELECT key, value FROM {BUILD_SCHEMA}.info").fetchall())
        rows = con.execute(f"SELECT night, file, bytes, mtime_ns FROM {BUILD_SCHEMA}.sources").fetchall()
    except duckdb.Error:
        return None
    sources: dict[str, dict[str, tuple[int, int]]] = {}
    for night, file, size, mtime in rows:
        sources.setdefault(night, {})[file] = (size, mtime)
    return info, sources


def _create_views(con: duckdb.DuckDBPyConnection, queries_dir: str | os.PathLike | None) -> None:
    for (view,) in con.execute(
        "SELECT view_name FROM duckdb_views() WHERE NOT internal AND schema_name = 'main'"
    ).fetchall():
        con.execute(f"DROP VIEW {_q(view)}")
    pending = dict(saved_queries(queries_dir))
    while pending:  # a saved query may read another one: create each once what it reads exists
        before, errors = len(pending), {}
        for qname, (_desc, sql) in list(pending.items()):
            try:
                con.execute(f"CREATE VIEW {_q(qname)} AS {_view_sql(sql)}")
                del pending[qname]
            except duckdb.Error as err:
                errors[qname] = err
        if len(pending) == before:  # no view created in this pass: a real error
            qname, err = next(iter(errors.items()))
            raise ValueError("; ".join(f"saved query {q}: {e}" for q, e in errors.items())) from err


def _discard(tmp: Path) -> None:
    for leftover in (tmp, tmp.with_name(tmp.name + ".wal")):
        if leftover.exists():
            leftover.unlink()


def _drop_views(con: duckdb.DuckDBPyConnection) -> None:
    """Drop the views while tables change (created again at the end).

    Drop the views: they bind their columns, so out of the way while tables change (created again at the
    end).
    """
    for (view,) in con.execute(
        "SELECT view_name FROM duckdb_views() WHERE NOT internal AND schema_name = 'main'"
    ).fetchall():
        con.execute(f"DROP VIEW {_q(view)}")


def _write_catalog(final: Path, work, queries_dir, plan=None) -> dict[str, int]:
    """Write ``catalog.duckdb.tmp`` and rename it over ``catalog.duckdb``; return rows per table.

    ``plan(con)``, when given, runs first on a copy of the existing catalog and returns the
    changes to make on it, or None to start from an empty file instead; ``work(con, changes)``
    then writes the rows. The views are created last. On any error the old catalog stays.
    """
    tmp = final.with_name(final.name + ".tmp")
    _discard(tmp)
    con = None
    try:
        changes = None
        if plan is not None and final.is_file():
            shutil.copyfile(final, tmp)
            try:
                con = duckdb.connect(str(tmp))
            except duckdb.Error:
                con = None
            changes = plan(con) if con is not None else None
            if changes is None:
                if con is not None:
                    con.close()
                    con = None
                _discard(tmp)
        if con is None:
            con = duckdb.connect(str(tmp))
        con.execute("SET TimeZone = 'UTC'")
        _drop_views(con)
        work(con, changes)
        _create_views(con, queries_dir)
        rows = {
            name: con.execute(f"SELECT count(*) FROM {_q(name)}").fetchone()[0] for name in sorted(SCHEMA)
        }
        con.execute("CHECKPOINT")
        con.close()
        con = None
    except BaseException:
        if con is not None:
            con.close()
        _discard(tmp)
        raise
    os.replace(tmp, final)
    _write_seal(final)
    return rows


# --------------------------------------------------------------------------- damage


class CatalogDamaged(FileNotFoundError):
    """Raised when ``catalog.duckdb`` is not the file the pipeline wrote (truncated, overwritten).

    A ``FileNotFoundError`` so every command reports it as a missing catalog.
    """


def _seal_path(final: Path) -> Path:
    return final.with_name(final.name + ".sha256")


def _write_seal(final: Path) -> None:
    """``catalog.duckdb.sha256``: the digest and size of the catalog as written."""
    atomic_write_text(_seal_path(final), f"{sha256_file(final)} {final.stat().st_size}\n")


def set_aside_damaged(results_root: str | os.PathLike, dry_run: bool = False) -> str | None:
    """Move a damaged ``catalog.duckdb`` to ``catalog.duckdb.damaged``; return the message, None when intact.

    The workflow then rebuilds the catalog from the stage tables, and the report after it.
    """
    final = catalog_path(results_root)
    why = catalog_damage(final)
    if why is None:
        return None
    if dry_run:
        return f"the history catalog {final} is damaged ({why}); a run rebuilds it from the stage tables"
    os.replace(final, final.with_name(final.name + ".damaged"))
    return (
        f"the history catalog {final} is damaged ({why}): kept as {final.name}.damaged, rebuilt from the "
        "stage tables by this run"
    )


def catalog_damage(path: str | os.PathLike) -> str | None:
    """Return why ``path`` (a ``catalog.duckdb``) is not the catalog the pipeline wrote, or None.

    None also when there is no catalog, or when it was written before catalogs were sealed.
    """
    final = Path(path)
    seal = _seal_path(final)
    if not final.is_file() or not seal.is_file():
        return None
    digest, _, size = seal.read_text().strip().partition(" ")
    now = final.stat().st_size
    if str(now) != size:
        return f"it has {now} bytes, {size} were written (truncated or cut off by a full disk?)"
    if sha256_file(final) != digest:
        return "its content differs from what was written"
    return None


def _set_info(con: duckdb.DuckDBPyConnection, source: str) -> None:
    con.execute(f"DELETE FROM {BUILD_SCHEMA}.info")
    con.execute(
        f"INSERT INTO {BUILD_SCHEMA}.info VALUES ('format_version', ?), ('schema', ?), ('source', ?)",
        [str(FORMAT_VERSION), _schema_fingerprint(), source],
    )


def _record_sources(con: duckdb.DuckDBPyConnection, sig: Mapping[str, Mapping[str, tuple[int, int]]]) -> None:
    rows = [(n, f, size, mtime) for n, files in sig.items() for f, (size, mtime) in files.items()]
    if rows:
        df = pl.DataFrame(
            rows,
            schema={"night": pl.Utf8, "file": pl.Utf8, "bytes": pl.Int64, "mtime_ns": pl.Int64},
            orient="row",
        )
        con.register("_sources", df)
        try:
            con.execute(f"INSERT INTO {BUILD_SCHEMA}.sources SELECT * FROM _sources")
        finally:
            con.unregister("_sources")


def update_catalog(  # noqa: C901 (one branch per way the catalog is brought up to date (new, incremental, rebuilt))
    results_root: str | os.PathLike,
    queries_dir: str | os.PathLike | None = None,
    full: bool = False,
) -> CatalogUpdate:
    """Bring ``<results_root>/catalog.duckdb`` up to date with the stage files; say what was done.

    New nights are appended (only their stage files are read). Nights whose stage files changed
    or disappeared are replaced when they are newer than every unchanged night; otherwise, when
    the catalog was written by another version or from given tables, when it is missing, or with
    ``full=True``, the whole catalog is rebuilt from every stage file. Both give the same tables.
    A night is recognised as unchanged by its stage files' names, sizes and modification times.
    """
    root = Path(results_root)
    root.mkdir(parents=True, exist_ok=True)
    final = catalog_path(root)
    scan = _scan_stage(root)
    files = {n: {s: v[0] for s, v in d.items()} for n, d in scan.items()}
    now = {n: {v[1]: (v[2], v[3]) for v in d.values()} for n, d in scan.items()}
    why = {
        "reason": "full rebuild requested"
        if full
        else "no catalog to extend"
        if not final.exists()
        else "the catalog could not be opened"
    }
    damage = catalog_damage(final)
    if damage is not None:
        full, why["reason"] = True, f"the catalog is damaged ({damage}): rebuilt from the stage tables"

    def plan(con):
        """(nights to take out, nights to read) on the existing catalog, or None to rebuild."""
        old = _read_manifest(con)
        if old is None:
            why["reason"] = "the catalog has no record of its stage files"
            return None
        if old[0].get("schema") != _schema_fingerprint() or old[0].get("source") != "stage":
            why["reason"] = "the catalog was written by another version or from given tables"
            return None
        sources = old[1]
        changed = [n for n in now if sources.get(n) != now[n]]
        gone = [n for n in sources if n not in now]
        unchanged = [n for n in sources if n in now and n not in changed]
        touched = sorted(set(changed) | set(gone))
        if touched and unchanged and min(touched) <= max(unchanged):
            why["reason"] = (
                f"night {min(touched)} changed, and it is not newer than every unchanged night "
                f"(newest unchanged: {max(unchanged)})"
            )
            return None
        return sorted(set(changed) & set(sources) | set(gone)), sorted(changed)

    def work(con, changes):
        if changes is None:
            _create_tables(con)
            _set_info(con, "stage")
            _append(con, _assemble(_read_nights(root, files)), root)
            _record_sources(con, now)
            return
        redo, added = changes
        if redo:
            _remove_nights(con, redo)
            con.execute(
                f"DELETE FROM {BUILD_SCHEMA}.sources WHERE night IN (SELECT unnest(?::VARCHAR[]))", [redo]
            )
        if added:
            _append(con, _assemble(_read_nights(root, {n: files[n] for n in added})), root)
            _record_sources(con, {n: now[n] for n in added})
        done["changes"] = changes

    done: dict = {}
    rows = _write_catalog(final, work, queries_dir, plan=None if full else plan)
    if "changes" not in done:
        return CatalogUpdate(final, "full", why["reason"], tuple(files), (), rows)
    redo, added = done["changes"]
    if not (redo or added):
        return CatalogUpdate(final, "unchanged", "no stage file changed", (), (), rows)
    reason = f"{len(added)} night(s) added" + (f", {len(redo)} replaced or removed" if redo else "")
    return CatalogUpdate(final, "append", reason, tuple(added), tuple(redo), rows)


def rebuild_catalog(
    results_root: str | os.PathLike, queries_dir: str | os.PathLike | None = None
) -> CatalogUpdate:
    """Rebuild ``<results_root>/catalog.duckdb`` from every stage file (``borescan rebuild-catalog``)."""
    return update_catalog(results_root, queries_dir, full=True)


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
        tables are created empty, missing columns are null, extra columns are kept, a duplicate
        key is an error. ``None`` rebuilds from the stage files (:func:`rebuild_catalog`).
    queries_dir
        Folder of saved ``*.sql`` queries, one view each (default: the project's
        ``workflow/queries``).

    The database is written to ``catalog.duckdb.tmp`` and renamed over ``catalog.duckdb``, so
    readers never see a half-built history. Unknown table names raise ``ValueError``. A catalog
    built from given tables is rebuilt, not extended, by the next :func:`update_catalog`.
    """
    root = Path(results_root)
    root.mkdir(parents=True, exist_ok=True)
    if tables is None:
        return rebuild_catalog(root, queries_dir).path
    unknown = sorted(set(tables) - set(SCHEMA))
    if unknown:
        raise ValueError(f"unknown catalog table(s) {unknown}; valid: {sorted(SCHEMA)}")

    def fill(con, _changes):
        _create_tables(con)
        _set_info(con, "tables")
        _append(con, tables, root, direct=True)

    final = catalog_path(root)
    _write_catalog(final, fill, queries_dir)
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
    why = catalog_damage(path)
    if why is not None:
        raise CatalogDamaged(
            f"the history catalog {path} is damaged: {why}. Rebuild it from the stage tables: "
            f"borescan rebuild-catalog --results {Path(results_root)} (the next snakemake run "
            "rebuilds it too)"
        )
    con = duckdb.connect(str(path), read_only=read_only)
    con.execute("SET TimeZone = 'UTC'")
    return con


def table_rows(con: duckdb.DuckDBPyConnection, table: str) -> list[tuple]:
    """Return all rows of a catalog table in key order.

    All rows of a catalog table in key order, ties broken by every other column (handy for
    comparisons and tests: the same rows give the same list).
    """
    if table not in SCHEMA:
        raise ValueError(f"unknown catalog table {table!r}; valid: {sorted(SCHEMA)}")
    cols = list(KEYS[table]) + [c for c in _columns(con, table) if c not in KEYS[table]]
    order = ", ".join(f"{_q(c)} NULLS FIRST" for c in cols)
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
