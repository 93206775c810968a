"""The catalog's names: its file, the tables' columns and keys, the stage tables and their order."""

from __future__ import annotations

import os
import re
from pathlib import Path


from borescan.resources import shipped
from borescan.tables import TABLES

CATALOG_NAME = "catalog.duckdb"

#: Saved queries shipped with the project (``workflow/queries/*.sql``), one view each.
DEFAULT_QUERIES_DIR = shipped("queries")

#: Column name -> DuckDB type of every catalog table, in column order (from :mod:`borescan.tables`,
#: the one definition of the history tables). Input frames may carry more columns: they are kept
#: after these, with the type DuckDB infers.
SCHEMA: dict[str, dict[str, str]] = {name: t.duckdb_types() for name, t in TABLES.items()}

#: Key columns of each table: rows are inserted in this order (and unique where ``primary``).
KEYS: dict[str, tuple[str, ...]] = {name: t.key for name, t in TABLES.items()}

_IDENT = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")


def catalog_path(results_root: str | os.PathLike) -> Path:
    """``<results_root>/catalog.duckdb``."""
    return Path(results_root) / CATALOG_NAME


def certificate_json_path(results_root: str | os.PathLike, certificate_path: str) -> Path:
    """Return the ``certificate.json`` belonging to a ``certificate_path`` (a certificate file or its folder).

    Relative paths are relative to ``results_root``.
    """
    p = Path(certificate_path)
    if not p.is_absolute():
        p = Path(results_root) / p
    folder = p if p.suffix == "" else p.parent
    return folder / "certificate.json"


# --------------------------------------------------------------------------- stage tables

#: History tables the catalog is built from, each the union of ``stage/<table>/night=*.parquet``.
STAGE_TABLES = (
    "scans",
    "scan_files",
    "calibrations",
    "calibration_scans",
    "diameters",
    "verifications",
    "findings",
    "artifacts",
    "pooled_findings",
    "calibration_drift",
    "night_config",
    "config_changes",
)

#: The stages in the order a night runs them: a scan's reason in ``scans`` is its earliest stage's.
STAGE_ORDER = ("ingest", "signal", "calibrate", "measure", "discrepancy")

#: Tables whose rows carry their night (from the stage file's name where the stage leaves it out):
#: a night's rows are found, and replaced, by it.
NIGHT_TABLES = tuple(name for name, cols in SCHEMA.items() if "night" in cols)

#: Bump when the way rows are derived changes: a catalog of another version is rebuilt, not extended.
FORMAT_VERSION = 2

#: DuckDB schema of the bookkeeping tables (see the module docstring).
BUILD_SCHEMA = "build"

_NIGHT_COL = "_night"  # source night of a row while a batch is assembled (never in the catalog)
