"""``borescan trace ID``: the chain behind a diameter, scan, part, calibration or certificate."""

from __future__ import annotations

import argparse
import datetime as _dt
import json
import sys
from pathlib import Path

from borescan.commands._common import CommandFailed, utc_text

NAME = "trace"
HELP = "show the chain behind a diameter, scan, part, calibration or certificate (down to raw SHA-256)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the command's options to ``parser``."""
    parser.add_argument(
        "id",
        help="diameter id (SCAN/FEATURE), scan id, part id, calibration id or certificate "
        "path (relative to the current folder or the results folder, or absolute)",
    )
    parser.add_argument(
        "--results",
        default="results",
        help="results folder holding catalog.duckdb, relative or absolute (default: results)",
    )
    parser.add_argument("--json", action="store_true", help="print the chain as JSON instead of text")


def _ident(text: str, results: str) -> str:
    """Return an id that is a path, made absolute.

    Return a path from the current folder into the results folder, made absolute (``borescan.trace``
    relates absolute paths to the results folder; the catalog's are relative to it), so that
    ``results/calibration/.../certificate.pdf`` works as well as ``calibration/.../certificate.pdf``
    and an absolute path; any other id as given.
    """
    p = Path(text.strip())
    if p.is_absolute() or len(p.parts) < 2:
        return text
    here = p.resolve()
    return str(here) if here.is_relative_to(Path(results).resolve()) else text


def _zoned(node: object) -> object:
    """Return the chain with every time as ISO 8601 UTC with its zone (the catalog's TIMESTAMPs are UTC)."""
    if isinstance(node, dict):
        return {k: _zoned(v) for k, v in node.items()}
    if isinstance(node, list):
        return [_zoned(v) for v in node]
    if isinstance(node, _dt.datetime):
        return utc_text(node)
    if isinstance(node, _dt.date):
        return node.isoformat()
    return node


def run(args: argparse.Namespace) -> int:
    """Print the chain from an id down to the raw files; return the exit status."""
    from borescan import trace as _trace

    ident = _ident(args.id, args.results)
    try:
        chain = _trace.trace(args.results, ident)
    except _trace.UnknownId as err:  # named as the user wrote it
        raise CommandFailed(err.args[0].replace(repr(ident), repr(args.id), 1)) from None
    except FileNotFoundError as err:
        raise CommandFailed(str(err)) from None
    chain["id"] = args.id  # as the user wrote it
    if args.json:
        print(json.dumps(_zoned(chain), indent=2, sort_keys=True, default=str))
    else:
        sys.stdout.write(_trace.format_trace(chain))
    return 0
