"""``borescan validate RAW_ROOT``: the checks ingest runs, over every scan the pipeline would ingest.

One validator (:func:`borescan.validation.validate_tree`, the function the ingest stage calls
per scan): a scan this command calls valid is never quarantined at ingest, and the reverse.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from borescan.commands._common import Progress, UsageError

NAME = "validate"
HELP = ("check scans under RAW_ROOT exactly as the pipeline's ingest does: format, sensor range, "
        "sample clock, unique ids (one line per problem, exit 1 if any)")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add ``RAW_ROOT``."""
    parser.add_argument("raw_root", metavar="RAW_ROOT", type=Path,
                        help="root of night=*/scan=* folders (relative or absolute)")
    # Before the checks were one, readings outside the sensor range were warnings shown by this
    # flag; they are problems now (ingest quarantines them). Accepted so old scripts keep working.
    parser.add_argument("--warnings", action="store_true", help=argparse.SUPPRESS)
    parser.epilog = ("Problems go to stdout as 'scan_id: file: problem' ('-' for folders that are not "
                     "scans), the summary to stderr. Exit 0: all valid; 1: problems; 2: RAW_ROOT missing.")


def _plausibility():
    """The plausibility bounds of the project's config/config.yaml (run from the project folder), else the schema's."""
    from borescan import validation
    from borescan.config import load_configs

    cfg = Path("config/config.yaml")
    return validation.Plausibility.from_config(load_configs([cfg])["plausibility"] if cfg.is_file() else None)


def run(args: argparse.Namespace) -> int:
    """Print ``scan_id: file: problem`` lines; exit 1 if any, else a summary and exit 0."""
    from borescan import validation

    progress = None
    if sys.stderr.isatty():  # a person waiting; cron logs get only the result
        bar: list[Progress] = []

        def progress(i: int, n: int) -> None:
            if not bar:
                bar.append(Progress(n, "validated", min_interval_s=2.0))
            bar[0].update(i)

    try:
        report = validation.validate_tree(args.raw_root, progress=progress, limits=_plausibility())
    except validation.RawRootError as err:
        raise UsageError(str(err)) from None
    for e in report.problems:
        print(e)
    if report.problems:
        print(f"{len(report.problems)} problems; {len(report.bad_scan_ids)} of {report.n_scans} scans invalid",
              file=sys.stderr)
        return 1
    print(f"{report.n_scans} scans, all valid")
    return 0
