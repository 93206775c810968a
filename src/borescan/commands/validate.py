"""``borescan validate RAW_ROOT``: check every scan against ``borescan-raw/1``."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from borescan import rawio

NAME = "validate"
HELP = "check scans under RAW_ROOT against borescan-raw/1 (one line per problem, exit 1 if any)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add ``RAW_ROOT`` and ``--warnings``."""
    parser.add_argument("raw_root", metavar="RAW_ROOT", type=Path, help="root of night=*/scan=* folders")
    parser.add_argument(
        "--warnings",
        action="store_true",
        help="also print non-fatal warnings (readings outside [0, range_mm]) to stderr",
    )


def run(args: argparse.Namespace) -> int:
    """Print ``scan_id: file: problem`` lines; exit 1 if any, else a summary and exit 0."""
    warnings: list[str] = []
    errors = rawio.validate_root(args.raw_root, warnings=warnings)
    n_scans = len(rawio.discover_scans(args.raw_root))
    for e in errors:
        print(e)
    if args.warnings:
        for w in warnings:
            print(f"warning: {w}", file=sys.stderr)
    if errors:
        bad = len({e.scan_id for e in errors if e.scan_id != "-"})
        print(f"{len(errors)} problems; {bad} of {n_scans} scans invalid", file=sys.stderr)
        return 1
    print(f"{n_scans} scans, all valid")
    return 0
