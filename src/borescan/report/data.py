"""The catalog rows a page shows: tables, months, their fingerprints (what changed)."""

from __future__ import annotations

import contextlib
import datetime as dt
import functools
import hashlib
import json
import os
from pathlib import Path
from typing import Any

import duckdb
import numpy as np
import polars as pl

from borescan import catalog
from borescan.tables import TABLES


def load_tables(results_root: str | os.PathLike) -> dict[str, pl.DataFrame]:
    """Return the catalog tables (and the ``suspect_measurements`` view when present) as polars frames."""
    con = catalog.open_catalog(results_root, read_only=True)
    try:
        out = {}
        for t in catalog.SCHEMA:
            out[t] = con.sql(f"SELECT * FROM {t} ORDER BY {_ORDER.get(t, '1')}").pl()
        if "verifications" in out and "scans" in out:
            # time order within a night: by the scan's start
            out["verifications"] = (
                out["verifications"]
                .join(out["scans"].select("scan_id", "started_at"), on="scan_id", how="left")
                .sort("device_id", "night", "started_at", "scan_id", nulls_last=True)
            )
        views = {
            r[0] for r in con.execute("SELECT view_name FROM duckdb_views() WHERE NOT internal").fetchall()
        }
        if "suspect_measurements" in views:
            out["suspect_measurements"] = con.sql("SELECT * FROM suspect_measurements").pl()
        return out
    finally:
        con.close()


# --------------------------------------------------------------------------- what changed


@functools.lru_cache(maxsize=1)
def _code_fingerprint() -> str:
    """Return the digest of the report package's source and the plotting libraries.

    A change of any module of ``borescan.report`` or of the libraries re-renders every page.
    """
    import matplotlib

    h = hashlib.sha256()
    for module in sorted(Path(__file__).parent.glob("*.py")):
        h.update(module.name.encode() + b"\0" + module.read_bytes())
    h.update(f"matplotlib {matplotlib.__version__} polars {pl.__version__}".encode())
    return h.hexdigest()[:16]


def frame_fingerprint(df: pl.DataFrame) -> str:
    """SHA-256 (16 hex) of a frame's columns, types and rows in order (same polars version)."""
    h = hashlib.sha256(repr([(c, str(t)) for c, t in df.schema.items()]).encode())
    if df.height and df.width:
        h.update(df.hash_rows().to_numpy().tobytes())
    return h.hexdigest()[:16]


def group_fingerprints(df: pl.DataFrame | None, by: str) -> dict[str | None, str]:
    """Value of column ``by`` (as text) -> SHA-256 (16 hex) of the frame's rows with it.

    The digest is of the rows as a multiset (their hashes sorted): a page's row order follows
    from the rows' contents (:data:`_ORDER`), and rows that tie in it come in any order from
    DuckDB. The frame's schema is part of every digest; one row hash over the whole frame, so a
    month's nights (or scans) are fingerprinted at the cost of one pass, whatever their number.
    """
    if df is None or df.height == 0 or df.width == 0:
        return {}
    schema = repr([(c, str(t)) for c, t in df.schema.items()]).encode()
    groups = (
        pl.DataFrame({"k": df[by].cast(pl.Utf8), "h": df.hash_rows()})
        .group_by("k", maintain_order=True)
        .agg(pl.col("h").sort())
    )
    return {
        k: hashlib.sha256(schema + np.asarray(h, dtype=np.uint64).tobytes()).hexdigest()[:16]
        for k, h in groups.iter_rows()
    }


_MONTH = "coalesce(strftime(CAST({t}night AS DATE), '%Y-%m'), 'undated')"


def _month_sql(alias: str = "") -> str:
    return _MONTH.format(t=f"{alias}." if alias else "")


#: What a month's page shows, per source: (SQL of its rows with a ``_m`` month column).
_MONTH_ROWS = {
    "scans": "SELECT {m} AS _m, t.* FROM scans t",
    "calibrations": "SELECT {m} AS _m, t.* FROM calibrations t",
    # a calibration's links to scans of its own month (a rod's nominal geometry is linked to the
    # rod's scans of every later night: those would make its month's page change every night)
    "calibration_scans": (
        "SELECT c._m, t.* FROM calibration_scans t JOIN (SELECT DISTINCT calibration_id, {mc} AS _m "
        "FROM calibrations c) c USING (calibration_id) LEFT JOIN (SELECT scan_id, min({ms}) AS _sm "
        "FROM scans s GROUP BY scan_id) s USING (scan_id) WHERE s._sm IS NULL OR s._sm = c._m"
    ),
    "verifications": "SELECT {m} AS _m, t.* FROM verifications t",
    "pooled_findings": "SELECT {m} AS _m, t.* FROM pooled_findings t",
    "calibration_drift": "SELECT {m} AS _m, t.* FROM calibration_drift t",
    # with the part's nominal (artifacts.nominal_diameter_mm) when the part has one feature:
    # the catalog does not hold feature nominals
    "diameters": (
        "SELECT {m} AS _m, t.*, a.nominal_mm AS artifact_nominal_mm FROM diameters t LEFT JOIN "
        "(SELECT artifact_id, any_value(nominal_diameter_mm) AS nominal_mm FROM artifacts "
        "WHERE artifact_id IN (SELECT artifact_id FROM diameters GROUP BY artifact_id "
        "HAVING count(DISTINCT feature) <= 1) GROUP BY artifact_id) a ON a.artifact_id = t.artifact_id"
    ),
    # the lifecycle's events of measured calibrations (saved query calibration_status_history: one
    # definition for the report, `borescan trace` and the user's queries); valid -> "made"
    "calibration_events": (
        "SELECT {m} AS _m, t.night, CASE t.status WHEN 'valid' THEN 'made' ELSE t.status END AS event, "
        "t.calibration_id, t.device_id, t.other_id FROM calibration_status_history t "
        "WHERE t.calibration_id IS NOT NULL AND coalesce(t.method, '') <> 'nominal' "
        "AND t.status IN ('valid', 'superseded', 'expired')"
    ),
    "findings": "SELECT {m} AS _m, t.* FROM findings t",
    "quarantine": "SELECT {m} AS _m, t.* FROM quarantine t",
    "suspect_measurements": "SELECT {m} AS _m, t.* FROM suspect_measurements t",
}

#: Sources whose month is the month of their own ``night`` column (a DATE).
_OWN_NIGHT = frozenset(_MONTH_ROWS) - {"calibration_scans"}

#: Row order of each table on a page.
_ORDER = {
    "scans": "night, started_at, scan_id",
    "calibration_events": "night, device_id, event, calibration_id",
    "calibrations": "device_id, valid_from, calibration_id, channel",
    "calibration_scans": "calibration_id, scan_id",
    "diameters": "artifact_id, feature, night, scan_id",
    "verifications": "device_id, night, scan_id",
    "findings": "scan_id, effect, channel",
    "pooled_findings": "device_id, night, term",
    "calibration_drift": "device_id, night, channel, parameter",
    "quarantine": "scan_id, stage",
    "suspect_measurements": "device_id, night, scan_id, feature",
    "artifacts": "artifact_id",
    "scan_files": "scan_id, file",
}


def _sources(con) -> dict[str, str]:
    """Source name -> SQL of its rows with a ``_m`` month column, for the sources the catalog has."""
    have = {
        r[0]
        for r in con.execute(
            "SELECT table_name FROM duckdb_tables() WHERE schema_name = 'main' UNION "
            "SELECT view_name FROM duckdb_views() WHERE NOT internal AND schema_name = 'main'"
        ).fetchall()
    }
    needs = {"calibration_events": {"calibration_status_history"}, "diameters": {"diameters", "artifacts"}}
    return {
        name: sql.format(m=_month_sql("t"), mc=_month_sql("c"), ms=_month_sql("s"))
        for name, sql in _MONTH_ROWS.items()
        if needs.get(name, {name}) <= have
    }


def _fingerprint_sources(con) -> dict[str, str]:
    """:func:`_sources`, with each calibration's record (``calibration_json``) stood for by its digest.

    Where the catalog keeps ``calibration_json_sha256`` beside ``calibration_json`` (its catalog, in which
    the two are written together) the digest is hashed instead of the record: the same changes are seen
    without reading, and decompressing, every calibration's record of the history (about 24 kB each).
    """
    srcs = _sources(con)
    if "calibrations" in srcs:
        cols = {r[0] for r in con.execute("DESCRIBE calibrations").fetchall()}
        if {"calibration_json", catalog.RECORD_DIGEST} <= cols:
            srcs["calibrations"] = (
                f"SELECT {_month_sql('t')} AS _m, t.* EXCLUDE (calibration_json) FROM calibrations t"
            )
    return srcs


def month_fingerprints(con) -> dict[str, str]:
    """Month (``YYYY-MM`` of the night, or ``undated``) -> fingerprint of every row its page shows.

    One aggregate query per table (row count and the sum of DuckDB row hashes per month), so
    finding which months changed costs milliseconds even for years of nights.
    """
    parts: dict[str, list] = {}
    for name, sql in _fingerprint_sources(con).items():
        for m, n, h in con.execute(
            f"SELECT _m, count(*), sum(hash(q)::HUGEINT) FROM ({sql}) q GROUP BY _m"
        ).fetchall():
            parts.setdefault(m, []).append((name, n, str(h)))
    code = _code_fingerprint()
    return {
        m: hashlib.sha256(json.dumps([code, sorted(v)]).encode()).hexdigest()[:16]
        for m, v in sorted(parts.items())
    }


def _month_tables(con, month: str) -> dict[str, pl.DataFrame]:
    """Return the rows of one month, per table, in page order (verifications with their scan's start)."""
    out = {}
    srcs = _sources(con)
    for name, sql in srcs.items():
        order, drop = _ORDER[name], "_m"
        if name == "verifications" and "scans" in srcs:  # time order within a night: by the scan's start
            sql = (
                "SELECT "
                + _month_sql("t")
                + " AS _m, t.*, s.started_at AS _start FROM verifications t LEFT JOIN "
                "(SELECT DISTINCT ON (scan_id, night) scan_id, night, started_at FROM scans) s "
                "ON s.scan_id = t.scan_id AND s.night IS NOT DISTINCT FROM t.night"
            )
            order, drop = "device_id, night, _start NULLS LAST, scan_id", "_m, _start"
        where, params = "_m = ?", [month]
        if name in _OWN_NIGHT and month != "undated":  # the same rows, found without reading the others
            first = dt.date.fromisoformat(f"{month}-01")
            where += " AND CAST(q.night AS DATE) >= ? AND CAST(q.night AS DATE) < ?"
            params += [first, (first + dt.timedelta(days=31)).replace(day=1)]
        out[name] = con.sql(
            f"SELECT * EXCLUDE ({drop}) FROM ({sql}) q WHERE {where} ORDER BY {order}", params=params
        ).pl()
    return out


def _totals(con) -> dict[str, Any]:
    """Return counts over the whole history for the page header."""
    first, last, n_scans, n_q = con.execute(
        "SELECT min(night)::VARCHAR, max(night)::VARCHAR, count(*), count(*) FILTER (status = 'quarantined') "
        "FROM scans"
    ).fetchone()
    return {
        "first": first,
        "last": last,
        "scans": n_scans,
        "quarantined": n_q,
        "calibrations": con.execute("SELECT count(DISTINCT calibration_id) FROM calibrations").fetchone()[0],
        "diameters": con.execute("SELECT count(*) FROM diameters").fetchone()[0],
        "verifications": con.execute("SELECT count(*) FROM verifications").fetchone()[0],
    }


def _counts(t: dict[str, pl.DataFrame]) -> dict[str, Any]:
    """Return the header's counts over one page's rows."""
    sc = t["scans"]
    nights = sorted({str(n) for n in sc["night"].drop_nulls().to_list()})
    return {
        "first": nights[0] if nights else None,
        "last": nights[-1] if nights else None,
        "scans": sc.height,
        "quarantined": sc.filter(pl.col("status") == "quarantined").height,
        "calibrations": t["calibrations"]["calibration_id"].drop_nulls().n_unique(),
        "diameters": t["diameters"].height,
        "verifications": t["verifications"].height,
    }


def _month_summary(con) -> list[tuple[str, int, int, int]]:
    """(month, nights, scans, quarantined) of every month with scans."""
    return con.execute(
        f"SELECT {_month_sql()} AS m, count(DISTINCT night), count(*), count(*) FILTER (status = "
        "'quarantined') "
        "FROM scans GROUP BY m ORDER BY m"
    ).fetchall()


def _memory_catalog(tables: dict[str, pl.DataFrame]):
    """Return an in-memory DuckDB with the given frames as catalog tables (missing ones empty, typed)."""
    con = duckdb.connect()
    con.execute("SET TimeZone = 'UTC'")
    for name, cols in catalog.SCHEMA.items():
        df = tables.get(name)
        if df is None or df.width == 0:
            con.execute(TABLES[name].ddl())
            continue
        if name == "calibrations" and catalog.RECORD_DIGEST not in df.columns:
            df = catalog.with_record_digest(df)  # as the catalog writes them (_fingerprint_sources reads it)
        con.register("_in", df)
        select = [
            f"CAST({catalog._q(c)} AS {t}) AS {catalog._q(c)}"
            if c in df.columns
            else f"CAST(NULL AS {t}) AS {catalog._q(c)}"
            for c, t in cols.items()
        ]
        select += [catalog._q(c) for c in df.columns if c not in cols]
        con.execute(f"CREATE TABLE {name} AS SELECT {', '.join(select)} FROM _in")
        con.unregister("_in")
    for name, df in tables.items():
        if name not in catalog.SCHEMA and df is not None:
            con.register("_in", df)
            con.execute(f"CREATE TABLE {catalog._q(name)} AS SELECT * FROM _in")
            con.unregister("_in")
    for qname, (_desc, sql) in catalog.saved_queries().items():
        if qname not in tables:
            with contextlib.suppress(duckdb.Error):  # a query over tables not given: no view
                con.execute(f"CREATE VIEW {catalog._q(qname)} AS {catalog._view_sql(sql)}")
    return con
