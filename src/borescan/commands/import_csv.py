"""``borescan import-csv``: a vendor CSV export + metadata file -> one ``borescan-raw/1`` scan."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from borescan.commands._common import CommandFailed, UsageError

NAME = "import-csv"
HELP = "convert a vendor CSV export plus a metadata JSON/YAML file into a borescan-raw/1 scan"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add ``CSV``, ``--meta``, ``--raw-root``, ``--separator``, ``--decimal``."""
    parser.add_argument(
        "csv", metavar="CSV", type=Path, help="vendor export, one row per tick (docs/import-csv.md)"
    )
    parser.add_argument(
        "--meta", required=True, type=Path, help="metadata file (.json/.yaml) with scan.json fields"
    )
    parser.add_argument("--raw-root", required=True, type=Path, help="raw root to write night=*/scan=* into")
    parser.add_argument("--separator", default=",", help="CSV field separator (default ',')")
    parser.add_argument(
        "--decimal",
        default=".",
        choices=(".", ","),
        help="decimal mark of the numbers (default '.'; with ',' give --separator ';')",
    )
    parser.epilog = (
        "Times with a UTC offset (started_at, a timestamp column) are stored converted to UTC. "
        "The scan is checked as the pipeline's ingest checks it before anything is written. "
        "Exit 0: written (the folder is printed); 1: the data were refused (every problem on "
        "stderr); 2: a file is missing or the scan id exists with other data."
    )


def run(args: argparse.Namespace) -> int:
    """Import; print the scan folder (exit 0) or the problems (stderr, exit 1)."""
    from borescan import importcsv

    for path, what in ((args.csv, "CSV file"), (args.meta, "metadata file")):
        if not path.is_file():
            raise UsageError(f"{what} {path} {'is not a file' if path.exists() else 'does not exist'}")
    if len(args.separator) != 1:
        raise UsageError(f"--separator must be one character, got {args.separator!r}")
    try:
        vendor = importcsv.read_vendor_csv(args.csv, separator=args.separator, decimal=args.decimal)
        if vendor.ignored_columns:
            print(f"note: ignored columns {', '.join(vendor.ignored_columns)}", file=sys.stderr)
        out = importcsv.import_csv(
            args.csv, args.meta, args.raw_root, separator=args.separator, decimal=args.decimal
        )
    except importcsv.CsvImportError as e:
        raise CommandFailed(str(e)) from None
    except FileExistsError as e:
        raise UsageError(f"{e}; import under another scan_id") from None
    print(out)
    return 0
