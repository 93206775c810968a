"""``borescan sql``: run SQL (or a saved query) on the history catalog, read-only.

Output formats: ``table`` (default; numbers rounded to ``--digits`` significant digits and aligned
on the decimal point, long text but no id cut at ``--max-width`` characters), ``csv`` and ``json`` (full
precision, for programs). Times are shown with their zone: the catalog's TIMESTAMP values are
UTC (:mod:`borescan.catalog`) and print as ``2026-11-21T22:14:03Z``.
"""

from __future__ import annotations

import argparse
import csv
import datetime as _dt
import json
import math
import sys
from decimal import Decimal

from borescan.atomic import json_ready
from borescan.commands._common import CommandFailed, UsageError, int_at_least, nonnegative_int, utc_text

NAME = "sql"
HELP = "run SQL on the history catalog (results/catalog.duckdb), read-only"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the command's options to ``parser``."""
    parser.add_argument("query", nargs="?", help='SQL text, e.g. "SELECT * FROM scans"')
    parser.add_argument(
        "--results",
        default="results",
        help="results folder holding catalog.duckdb, relative or absolute (default: results)",
    )
    parser.add_argument(
        "--query", dest="saved", metavar="NAME", help="run a saved query of workflow/queries (see --list)"
    )
    parser.add_argument("--list", action="store_true", help="list the saved queries and what they answer")
    parser.add_argument(
        "--format",
        choices=("table", "csv", "json"),
        default="table",
        help="table: aligned and rounded (default); csv, json: full precision",
    )
    parser.add_argument(
        "--digits",
        type=int_at_least(1),
        default=7,
        help="significant digits of numbers in the table (default 7)",
    )
    parser.add_argument(
        "--max-width",
        type=nonnegative_int,
        default=40,
        help="cut text cells longer than this, 0 = never (default 40); ids (id, *_id) are never cut",
    )
    parser.epilog = (
        "The catalog is opened read-only, and queries cannot read or write other files (COPY, ATTACH, "
        "read_csv) or load extensions: export with --format csv > file.csv. Saved queries are also views: "
        "SELECT * FROM verification_drift WHERE device_id = 'TRI-01'. "
        "Times are UTC and shown with a Z."
    )


# --------------------------------------------------------------------------- cells


def _text(v: object) -> str:
    """Full-precision text of a value (csv)."""
    if v is None:
        return ""
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float):
        return "" if math.isnan(v) else repr(v)
    if isinstance(v, _dt.datetime):
        return utc_text(v)
    if isinstance(v, (_dt.date, _dt.time)):
        return v.isoformat()
    return str(v)


def _jsonable(v: object) -> object:
    """Return a query result's value for JSON.

    Times as the CLI prints them, decimals as floats, the rest through :func:`borescan.atomic.json_ready`
    (non-finite floats null), anything else as text.
    """
    if isinstance(v, _dt.datetime):
        return utc_text(v)
    if isinstance(v, (_dt.date, _dt.time)):
        return v.isoformat()
    if isinstance(v, Decimal):
        return float(v)
    if isinstance(v, (list, tuple)):
        return [_jsonable(x) for x in v]
    if isinstance(v, dict):
        return {str(k): _jsonable(x) for k, x in v.items()}
    try:
        return json_ready(v)
    except TypeError:
        return str(v)


def _is_number(v: object) -> bool:
    return isinstance(v, (int, float, Decimal)) and not isinstance(v, bool)


def _round(x: float, digits: int) -> str:
    """Return ``x`` rounded to ``digits`` significant digits as text.

    ``x`` to ``digits`` significant digits, positional (``0.0004214``, not ``4.214e-04``) unless tiny
    or huge; trailing zeros dropped.
    """
    if x == 0 or not math.isfinite(x):
        return f"{x:g}"
    if not 1e-9 <= abs(x) < 1e15:
        return f"{x:.{digits}g}"
    decimals = max(digits - 1 - math.floor(math.log10(abs(x))), 0)
    text = f"{x:.{decimals}f}"
    return text.rstrip("0").rstrip(".") if "." in text else text


def _number_cells(values: list[object], digits: int) -> list[str]:
    """Return a numeric column's cells: floats to ``digits`` significant digits, decimal points aligned."""
    raw = []
    for v in values:
        if v is None or (isinstance(v, float) and math.isnan(v)):
            raw.append("")
        elif isinstance(v, int):
            raw.append(str(v))
        else:
            raw.append(_round(float(v), digits))
    plain = [c for c in raw if c and "e" not in c and c not in ("inf", "-inf")]
    frac = max((len(c) - c.index(".") if "." in c else 0) for c in plain) if plain else 0
    out = []
    for c in raw:
        if c in plain:
            pad = frac - (len(c) - c.index(".") if "." in c else 0)
            c = c + " " * pad
        out.append(c)
    return out


def _cut(text: str, width: int) -> str:
    """Return ``text`` on one line, cut to ``width`` characters.

    ``text`` on one line, at most ``width`` characters (0: any): the middle gives way to an
    ellipsis, so a path keeps its file name and a digest both ends.
    """
    text = text.replace("\n", " ")
    if width <= 0 or len(text) <= width:
        return text
    head = (width - 1) // 3
    return text[:head] + "\u2026" + text[len(text) - (width - 1 - head) :]


def _is_id(column: str) -> bool:
    """Return whether ``column`` holds identifiers (``id``, ``*_id``, ``*_ids``): shown whole, never cut."""
    name = column.lower()
    return name == "id" or name.endswith(("_id", "_ids"))


def format_table(columns: list[str], rows: list[tuple], digits: int = 7, max_width: int = 40) -> str:
    """Return an aligned text table.

    Aligned text table: header, a rule, one line per row; numbers rounded and right-aligned on
    their decimal point, text left-aligned and cut at ``max_width`` characters (0: never), except
    identifiers (:func:`_is_id`), which are always whole.
    """
    numeric = [
        any(r[i] is not None for r in rows) and all(_is_number(r[i]) for r in rows if r[i] is not None)
        for i in range(len(columns))
    ]
    cols = []
    for i in range(len(columns)):
        values = [r[i] for r in rows]
        if numeric[i]:
            cols.append(_number_cells(values, digits))
        else:
            cols.append([_cut(_text(v), 0 if _is_id(columns[i]) else max_width) for v in values])
    widths = [max([len(c)] + [len(x) for x in col]) for c, col in zip(columns, cols, strict=True)]

    def line(values: list[str]) -> str:
        parts = [v.rjust(w) if num else v.ljust(w) for v, w, num in zip(values, widths, numeric, strict=True)]
        return "  ".join(parts).rstrip()

    out = [
        line([c.rjust(w) if num else c for c, w, num in zip(columns, widths, numeric, strict=True)]),
        "  ".join("-" * w for w in widths),
    ]
    out += [line([col[j] for col in cols]) for j in range(len(rows))]
    return "\n".join(out) + "\n"


# --------------------------------------------------------------------------- queries


#: DuckDB settings of the query connection: no file but the catalog is read or written (COPY ... TO,
#: ATTACH, EXPORT DATABASE, read_csv/read_parquet/glob of any path), no extension installed or loaded,
#: and the settings locked after the time zone is set, so a query cannot undo them.
SANDBOX = {
    "enable_external_access": False,
    "autoinstall_known_extensions": False,
    "autoload_known_extensions": False,
    "allow_community_extensions": False,
}


def query_connection(results: str):
    """Return a connection to ``<results>/catalog.duckdb`` that can only read the catalog.

    The connection is sandboxed (:data:`SANDBOX`), read-only, its configuration locked. FileNotFoundError when
    there is no catalog.
    """
    import duckdb

    from borescan import catalog

    path = catalog.catalog_path(results)
    if not path.is_file() or catalog.catalog_damage(path):
        # its FileNotFoundError (CatalogDamaged for a catalog cut short) names the file and what to run:
        # never an answer from half a file
        catalog.open_catalog(results)
    con = duckdb.connect(str(path), read_only=True, config=dict(SANDBOX))
    con.execute("SET TimeZone = 'UTC'")
    con.execute("SET lock_configuration = true")
    return con


def run_query(results: str, sql: str) -> tuple[list[str], list[tuple]]:
    """Run ``sql`` on the catalog under ``results``; return (column names, rows).

    The connection is :func:`query_connection`'s.
    """
    con = query_connection(results)
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
    import duckdb

    try:
        con = query_connection(results)
    except (FileNotFoundError, duckdb.Error):
        return set()
    try:
        return {
            r[0] for r in con.execute("SELECT view_name FROM duckdb_views() WHERE NOT internal").fetchall()
        }
    finally:
        con.close()


def run(  # noqa: C901 (one branch per option of the sql command)
    args: argparse.Namespace,
) -> int:
    """Run a query (given or saved) on the catalog, or list the saved ones; return the exit status."""
    import duckdb

    from borescan import catalog

    queries = catalog.saved_queries()
    if args.list:
        for name, (desc, _sql) in queries.items():
            first = desc.splitlines()[0] if desc else ""
            print(f"{name:24s} {first}")
        return 0
    if args.saved and args.query:
        raise UsageError("give either SQL text or --query NAME, not both")
    if args.saved:
        if args.saved in queries:
            sql = queries[args.saved][1]
        elif args.saved in _catalog_views(args.results):  # installed without the workflow folder
            sql = f'SELECT * FROM "{args.saved}"'
        else:
            valid = ", ".join(sorted(queries)) or "none found"
            raise CommandFailed(f"unknown saved query {args.saved!r}; valid: {valid}")
    elif args.query:
        sql = args.query
    else:
        raise UsageError('give SQL text (borescan sql "SELECT * FROM scans") or --query NAME')
    try:
        columns, rows = run_query(args.results, sql)
    except FileNotFoundError as err:
        raise CommandFailed(str(err)) from None
    except duckdb.PermissionException as err:
        raise CommandFailed(
            f"borescan sql reads the catalog only (no files, ATTACH or extensions): {err}"
        ) from None
    except duckdb.Error as err:
        raise CommandFailed(str(err)) from None
    if args.format == "csv":
        w = csv.writer(sys.stdout, lineterminator="\n")
        w.writerow(columns)
        for r in rows:
            w.writerow([_text(v) for v in r])
    elif args.format == "json":
        data = [{c: _jsonable(v) for c, v in zip(columns, r, strict=True)} for r in rows]
        print(json.dumps(data, indent=2))
    else:
        sys.stdout.write(format_table(columns, rows, args.digits, args.max_width))
    return 0
