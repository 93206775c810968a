"""Writing rows into the catalog: tables created, a night's rows staged, merged, appended or removed."""

from __future__ import annotations

import hashlib
from collections.abc import Mapping
from pathlib import Path

import duckdb
import polars as pl

from borescan.tables import TABLES
from borescan.catalog.history import _prepare
from borescan.catalog.names import BUILD_SCHEMA, FORMAT_VERSION, KEYS, NIGHT_TABLES, SCHEMA, _NIGHT_COL
from borescan.catalog.queries import _q

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
