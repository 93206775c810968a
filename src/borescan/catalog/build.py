"""Bringing the catalog up to date (appended night by night or rebuilt), opening it, upserting rows."""

from __future__ import annotations

import os
import shutil
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import duckdb
import polars as pl

from borescan.catalog.history import _assemble, _prepare, _read_nights, _scan_stage
from borescan.catalog.names import BUILD_SCHEMA, FORMAT_VERSION, KEYS, SCHEMA, catalog_path
from borescan.catalog.queries import _q, _view_sql, saved_queries
from borescan.catalog.rows import _append, _columns, _create_tables, _remove_nights, _schema_fingerprint
from borescan.catalog.seal import CatalogDamaged, _write_seal, catalog_damage

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
        have = _columns(con, table)  # the defined columns and the extra ones kept (calibration_json)
        cols = [c for c in have if c in df.columns]
        casts = ", ".join(f"CAST({_q(c)} AS {have[c]})" for c in cols)
        con.execute(f"INSERT INTO {_q(table)} ({', '.join(_q(c) for c in cols)}) SELECT {casts} FROM _up")
    finally:
        con.unregister("_up")
    return df.height
