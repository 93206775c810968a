"""``borescan import-csv``: a vendor CSV export + metadata file -> one ``borescan-raw/1`` scan."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from borescan import importcsv

NAME = "import-csv"
HELP = "convert a vendor CSV export plus a metadata JSON/YAML file into a borescan-raw/1 scan"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add ``CSV``, ``--meta``, ``--raw-root``, ``--separator``."""
    parser.add_argument(
        "csv", metavar="CSV", type=Path, help="vendor export, one row per tick (docs/import-csv.md)"
    )
    parser.add_argument(
        "--meta", required=True, type=Path, help="metadata file (.json/.yaml) with scan.json fields"
    )
    parser.add_argument("--raw-root", required=True, type=Path, help="raw root to write night=*/scan=* into")
    parser.add_argument("--separator", default=",", help="CSV field separator (default ',')")


def run(args: argparse.Namespace) -> int:
    """Import; print the scan folder (exit 0) or the problems (stderr, exit 1)."""
    try:
        vendor = importcsv.read_vendor_csv(args.csv, separator=args.separator)
        if vendor.ignored_columns:
            print(f"note: ignored columns {', '.join(vendor.ignored_columns)}", file=sys.stderr)
        out = importcsv.import_csv(args.csv, args.meta, args.raw_root, separator=args.separator)
    except (importcsv.CsvImportError, FileExistsError) as e:
        print(f"borescan import-csv: {e}", file=sys.stderr)
        return 1
    print(out)
    return 0
