"""``borescan rebuild-catalog``: rebuild the history catalog from every night's stage tables."""

from __future__ import annotations

import argparse
import sys
import time

from borescan import catalog

NAME = "rebuild-catalog"
HELP = "rebuild results/catalog.duckdb from every night's stage tables (the nightly run only adds new nights)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the command's options to ``parser``."""
    parser.add_argument(
        "--results",
        default="results",
        help="results folder holding stage/ and catalog.duckdb (default: results)",
    )
    parser.epilog = (
        "The pipeline's build_catalog step reads only the nights that are new since the last build; "
        "this command reads them all and gives the same tables. The old catalog is replaced only "
        "when the new one is complete."
    )


def run(args: argparse.Namespace) -> int:
    """Rebuild the catalog from every night's stage tables; return the exit status."""
    nights = catalog.stage_files(args.results)
    if not nights:
        print(
            f"borescan rebuild-catalog: no stage tables under {args.results}/stage (run the pipeline first)",
            file=sys.stderr,
        )
        return 1
    t0 = time.perf_counter()
    try:
        update = catalog.rebuild_catalog(args.results)
    except ValueError as err:
        print(f"borescan rebuild-catalog: {err}", file=sys.stderr)
        return 1
    print(
        f"full rebuild of {update.path} from {len(update.added)} night(s) in {time.perf_counter() - t0:.1f} s"
    )
    for table, n in update.rows.items():
        print(f"{table}: {n} rows")
    return 0
