"""The history tables are defined once: the stage tables' polars schema and the catalog's DDL agree."""

import duckdb
import polars as pl
import pytest

from borescan import catalog, tables


def test_polars_schema_and_ddl_come_from_the_same_columns():
    for name, t in tables.TABLES.items():
        stage = t.polars_schema()
        ddl = t.duckdb_types()
        assert [c for c in ddl if c in stage] == list(stage), name  # same order
        only_catalog = [c.name for c in t.columns if not c.stage]
        assert set(ddl) - set(stage) == set(only_catalog), name
        assert set(t.key) <= set(ddl), name


def test_catalog_uses_the_definitions():
    assert catalog.SCHEMA == {n: t.duckdb_types() for n, t in tables.TABLES.items()}
    assert catalog.KEYS == {n: t.key for n, t in tables.TABLES.items()}
    assert tables.polars_schema("findings").get("night") is None  # filled in the catalog from scans
    assert tables.TABLES["findings"].duckdb_types()["night"] == "DATE"
    assert (
        tables.polars_schema("scans")["night"] == pl.Utf8
        and tables.polars_schema("scans")["simulated"] == pl.Boolean
    )


def test_ddl_creates_the_table_with_key_and_extra_columns():
    con = duckdb.connect()
    con.execute(tables.TABLES["scan_files"].ddl({"note": "VARCHAR"}))
    cols = [r[0] for r in con.execute("DESCRIBE scan_files").fetchall()]
    assert cols == ["scan_id", "file", "sha256", "bytes", "night", "note"]
    con.execute("INSERT INTO scan_files VALUES ('S', 'lds.parquet', 'ab', 1, '2026-11-20', NULL)")
    with pytest.raises(duckdb.ConstraintException):
        con.execute("INSERT INTO scan_files VALUES ('S', 'lds.parquet', 'cd', 2, '2026-11-20', NULL)")
    assert "PRIMARY KEY" not in tables.TABLES["diameters"].ddl()


def test_frame_builds_rows_by_name_and_empty_frames_keep_the_schema():
    df = tables.frame(
        "quarantine", [{"reason": "r", "file": "f", "stage": "ingest", "night": "2026-11-20", "scan_id": "S"}]
    )
    assert df.columns == ["scan_id", "night", "stage", "file", "reason"] and df.row(0) == (
        "S",
        "2026-11-20",
        "ingest",
        "f",
        "r",
    )
    empty = tables.frame("findings", [])
    assert empty.height == 0 and empty.schema == tables.polars_schema("findings")


def test_unknown_names_list_the_valid_ones():
    with pytest.raises(ValueError, match=r"unknown history table 'nope'; valid: \['artifacts'"):
        tables.polars_schema("nope")
    with pytest.raises(ValueError, match="unknown type 'decimal'"):
        tables.Column("x", "decimal")
