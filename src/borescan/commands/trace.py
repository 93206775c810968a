"""``borescan trace ID``: the chain behind a diameter, scan, part, calibration or certificate."""

from __future__ import annotations

import argparse
import json
import sys

from borescan import trace as _trace

NAME = "trace"
HELP = "show the chain behind a diameter, scan, part, calibration or certificate (down to raw SHA-256)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("id", help="diameter id (SCAN/FEATURE), scan id, part id, calibration id or certificate path")
    parser.add_argument("--results", default="results", help="results folder holding catalog.duckdb (default: results)")
    parser.add_argument("--json", action="store_true", help="print the chain as JSON instead of text")


def run(args: argparse.Namespace) -> int:
    try:
        chain = _trace.trace(args.results, args.id)
    except (_trace.UnknownId, FileNotFoundError) as err:
        msg = err.args[0] if isinstance(err, _trace.UnknownId) else str(err)
        print(f"borescan trace: {msg}", file=sys.stderr)
        return 1
    if args.json:
        print(json.dumps(chain, indent=2, sort_keys=True, default=str))
    else:
        sys.stdout.write(_trace.format_trace(chain))
    return 0
