"""``borescan sql``: run SQL (or a saved query) on the history catalog, read-only."""

from __future__ import annotations

import argparse
import csv
import datetime as _dt
import json
import math
import sys
from decimal import Decimal

import duckdb

from borescan import catalog

NAME = "sql"
HELP = "run SQL on the history catalog (results/catalog.duckdb), read-only"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("query", nargs="?", help='SQL text, e.g. "SELECT * FROM scans"')
    parser.add_argument("--results", default="results", help="results folder holding catalog.duckdb (default: results)")
    parser.add_argument("--query", dest="saved", metavar="NAME",
                        help="run a saved query of workflow/queries (see --list)")
    parser.add_argument("--list", action="store_true", help="list the saved queries and what they answer")
    parser.add_argument("--format", choices=("table", "csv", "json"), default="table",
                        help="output format (default: aligned table)")
    parser.epilog = (
        "The catalog is opened read-only. Saved queries are also views: "
        "SELECT * FROM verification_drift WHERE device_id = 'TRI-01'."
    )


def _cell(v: object) -> str:
    if v is None:
        return ""
    if isinstance(v, float):
        return "" if math.isnan(v) else repr(v)
    if isinstance(v, bool):
        return "true" if v else "false"
    return str(v)


def _jsonable(v: object) -> object:
    if isinstance(v, float):
        return v if math.isfinite(v) else None
    if isinstance(v, (_dt.date, _dt.datetime, _dt.time)):
        return v.isoformat().replace("T", " ") if isinstance(v, _dt.datetime) else v.isoformat()
    if isinstance(v, Decimal):
        return float(v)
    if isinstance(v, (list, tuple)):
        return [_jsonable(x) for x in v]
    if isinstance(v, dict):
        return {str(k): _jsonable(x) for k, x in v.items()}
    if v is None or isinstance(v, (str, int, bool)):
        return v
    return str(v)


def format_table(columns: list[str], rows: list[tuple]) -> str:
    """Aligned text table: header, a rule, one line per row; numbers right-aligned."""
    cells = [[_cell(v) for v in r] for r in rows]
    numeric = [
        all(isinstance(r[i], (int, float, Decimal)) and not isinstance(r[i], bool) for r in rows if r[i] is not None)
        and any(r[i] is not None for r in rows)
        for i in range(len(columns))
    ]
    widths = [max([len(c)] + [len(r[i]) for r in cells]) for i, c in enumerate(columns)]

    def line(values: list[str]) -> str:
        parts = [v.rjust(w) if num else v.ljust(w) for v, w, num in zip(values, widths, numeric, strict=True)]
        return "  ".join(parts).rstrip()

    out = [line(list(columns)), "  ".join("-" * w for w in widths)]
    out += [line(r) for r in cells]
    return "\n".join(out) + "\n"


def run_query(results: str, sql: str) -> tuple[list[str], list[tuple]]:
    """Run ``sql`` on the read-only catalog under ``results``; return (column names, rows)."""
    con = catalog.open_catalog(results, read_only=True)
    try:
        cur = con.execute(sql)
        if cur.description is None:
            return [], []
        columns = [d[0] for d in cur.description]
        return columns, cur.fetchall()
    finally:
        con.close()


def _catalog_views(results: str) -> set[str]:
    """Names of the saved-query views inside the catalog (empty when there is no catalog)."""
    try:
        con = catalog.open_catalog(results, read_only=True)
    except FileNotFoundError:
        return set()
    try:
        return {r[0] for r in con.execute("SELECT view_name FROM duckdb_views() WHERE NOT internal").fetchall()}
    finally:
        con.close()


def run(args: argparse.Namespace) -> int:
    queries = catalog.saved_queries()
    if args.list:
        for name, (desc, _sql) in queries.items():
            first = desc.splitlines()[0] if desc else ""
            print(f"{name:24s} {first}")
        return 0
    if args.saved and args.query:
        print("borescan sql: give either SQL text or --query NAME, not both", file=sys.stderr)
        return 2
    if args.saved:
        if args.saved in queries:
            sql = queries[args.saved][1]
        elif args.saved in _catalog_views(args.results):  # installed without the workflow folder
            sql = f'SELECT * FROM "{args.saved}"'
        else:
            valid = ", ".join(sorted(queries)) or "none found"
            print(f"borescan sql: unknown saved query {args.saved!r}; valid: {valid}", file=sys.stderr)
            return 1
    elif args.query:
        sql = args.query
    else:
        print('borescan sql: give SQL text (borescan sql "SELECT * FROM scans") or --query NAME', file=sys.stderr)
        return 2
    try:
        columns, rows = run_query(args.results, sql)
    except FileNotFoundError as err:
        print(f"borescan sql: {err}", file=sys.stderr)
        return 1
    except duckdb.Error as err:
        print(f"borescan sql: {err}", file=sys.stderr)
        return 1
    if args.format == "csv":
        w = csv.writer(sys.stdout, lineterminator="\n")
        w.writerow(columns)
        for r in rows:
            w.writerow([_cell(v) for v in r])
    elif args.format == "json":
        data = [{c: _jsonable(v) for c, v in zip(columns, r, strict=True)} for r in rows]
        print(json.dumps(data, indent=2))
    else:
        sys.stdout.write(format_table(columns, rows))
    return 0
