"""Whether two results roots hold the same results: the catalog table by table, certificates byte for byte.

For a change that moves a whole-night number (issue 38): run the same night with the old and the new
code into two results roots, then

    python -m bench.compare_results RESULTS_OLD RESULTS_NEW [--ignore scans.raw_path]

Every table of the catalog (``catalog.duckdb``: each table's columns and its rows in key order, and
each saved query's rows) and every file of a certificate (``calibration/night=*/**``: json, dcc.xml,
pdf, png) are compared. A table that differs is named with its differing rows' count and, per
column, the largest difference of its numbers (absolute and relative to the larger magnitude) or
the count of other values that differ. Exit status 0 when everything is the same, 1 otherwise.
"""

from __future__ import annotations

import argparse
import math
import sys
from dataclasses import dataclass
from pathlib import Path

import duckdb


@dataclass(frozen=True)
class ColumnDifference:
    """How one column of a table differs between two roots (rows paired in key order)."""

    column: str
    rows: int
    max_abs: float
    max_rel: float


@dataclass(frozen=True)
class TableDifference:
    """A catalog table (or saved query) that is not the same in both roots."""

    table: str
    reason: str
    columns: tuple[ColumnDifference, ...] = ()


def catalog_snapshot(results: Path) -> dict[str, tuple[list[str], list[tuple]]]:
    """Every catalog table's columns and rows in key order, and every saved query's sorted rows."""
    from borescan import catalog

    con = duckdb.connect(str(results / "catalog.duckdb"), read_only=True)
    try:
        present = {r[0] for r in con.execute("SELECT table_name FROM information_schema.tables").fetchall()}
        out = {}
        for t in sorted(set(catalog.SCHEMA) & present):
            cols = [r[0] for r in con.execute(f"DESCRIBE {t}").fetchall()]
            key_first = list(catalog.KEYS[t]) + [c for c in cols if c not in catalog.KEYS[t]]
            out[t] = (key_first, catalog.table_rows(con, t))
        for q in sorted(set(catalog.saved_queries()) & present):
            cur = con.execute(f"SELECT * FROM {q}")
            out[f"query {q}"] = ([d[0] for d in cur.description], sorted(cur.fetchall(), key=repr))
        return out
    finally:
        con.close()


def _column_differences(cols: list[str], old: list[tuple], new: list[tuple]) -> tuple[ColumnDifference, ...]:
    diffs = []
    for j, col in enumerate(cols):
        pairs = [(a[j], b[j]) for a, b in zip(old, new) if a[j] != b[j]]
        if not pairs:
            continue
        nums = [
            (float(a), float(b))
            for a, b in pairs
            if isinstance(a, int | float)
            and isinstance(b, int | float)
            and math.isfinite(a)
            and math.isfinite(b)
        ]
        abs_d = [abs(a - b) for a, b in nums]
        rel_d = [abs(a - b) / max(abs(a), abs(b)) for a, b in nums]
        diffs.append(
            ColumnDifference(col, len(pairs), max(abs_d, default=math.nan), max(rel_d, default=math.nan))
        )
    return tuple(diffs)


def _without(snapshot: dict, ignore: set[str]) -> dict:
    """Drop the columns named ``table.column`` in ``ignore`` from a :func:`catalog_snapshot`."""
    out = {}
    for t, (cols, rows) in snapshot.items():
        keep = [j for j, c in enumerate(cols) if f"{t}.{c}" not in ignore]
        out[t] = ([cols[j] for j in keep], sorted((tuple(r[j] for j in keep) for r in rows), key=repr))
    return out


def compare_catalogs(old: Path, new: Path, ignore: set[str] = frozenset()) -> list[TableDifference]:
    """Return the tables and saved queries that differ between the catalogs of two results roots.

    ``ignore``: columns left out, as ``table.column`` (``scans.raw_path`` when the two runs read the
    same scans from two raw roots).
    """
    a, b = catalog_snapshot(old), catalog_snapshot(new)
    if ignore:
        a, b = _without(a, ignore), _without(b, ignore)
    out = []
    for t in sorted(set(a) | set(b)):
        if t not in a or t not in b:
            out.append(TableDifference(t, f"only in {'new' if t in b else 'old'}"))
            continue
        (cols_a, rows_a), (cols_b, rows_b) = a[t], b[t]
        if cols_a != cols_b:
            out.append(TableDifference(t, f"columns differ: {cols_a} / {cols_b}"))
        elif len(rows_a) != len(rows_b):
            out.append(TableDifference(t, f"{len(rows_a)} rows / {len(rows_b)} rows"))
        elif rows_a != rows_b:
            n = sum(x != y for x, y in zip(rows_a, rows_b))
            out.append(
                TableDifference(
                    t, f"{n} of {len(rows_a)} rows differ", _column_differences(cols_a, rows_a, rows_b)
                )
            )
    return out


def certificate_files(results: Path) -> dict[str, bytes]:
    """Every certificate file under ``calibration/night=*`` (device links point there), by relative path."""
    root = results / "calibration"
    return {
        str(p.relative_to(root)): p.read_bytes()
        for p in sorted(root.glob("night=*/**/*"))
        if p.is_file() and not p.is_symlink() and not p.name.startswith(".")
    }


def compare_certificates(old: Path, new: Path) -> tuple[int, list[str]]:
    """Return the number of certificate files in ``old`` and the paths that differ or are in one root only."""
    a, b = certificate_files(old), certificate_files(new)
    differ = [p for p in sorted(set(a) | set(b)) if a.get(p) != b.get(p)]
    return len(a), differ


def main(argv: list[str] | None = None) -> int:
    """Compare two results roots; print what differs; return 0 when nothing does."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("old", type=Path)
    ap.add_argument("new", type=Path)
    ap.add_argument(
        "--ignore",
        action="append",
        default=[],
        metavar="TABLE.COLUMN",
        help="leave a column out (e.g. scans.raw_path when the runs read two copies of the raw root)",
    )
    a = ap.parse_args(argv)
    for root in (a.old, a.new):
        if not (root / "catalog.duckdb").is_file():
            raise SystemExit(f"{root}: no catalog.duckdb (not a results root, or the night did not finish)")
    tables = compare_catalogs(a.old, a.new, set(a.ignore))
    n_tables = len(catalog_snapshot(a.old))
    n_files, files = compare_certificates(a.old, a.new)
    print(f"catalog: {n_tables - len(tables)} of {n_tables} tables and saved queries the same")
    for d in tables:
        print(f"  {d.table}: {d.reason}")
        for c in d.columns:
            print(f"    {c.column}: {c.rows} rows, max |diff| {c.max_abs:.3g}, max relative {c.max_rel:.3g}")
    print(f"certificates: {n_files - len(files)} of {n_files} files byte for byte the same")
    for p in files:
        print(f"  differs: {p}")
    return 0 if not tables and not files else 1


if __name__ == "__main__":
    sys.exit(main())
