"""The history catalog: ``<results_root>/catalog.duckdb``, extended night by night from the stage tables.

The pipeline writes one Parquet file per stage table and night
(``<results_root>/stage/<table>/night=<night>.parquet``). :func:`update_catalog` (what the
``build_catalog`` rule runs) adds the nights whose stage files are new to the catalog: it reads
only those files, fills the columns that follow from other tables within the night (a
diameter's raw digest from its scan, ...) and appends the rows. Its cost depends on the night,
not on the history. A night whose files changed or disappeared is replaced the same way when it
is newer than every unchanged night (a re-run of the latest nights); any other change (an older
night re-run, a catalog written by another version) rebuilds the whole catalog, as does
:func:`rebuild_catalog` (``borescan rebuild-catalog``). Both paths give the same tables
(``tests/test_catalog_incremental.py``).

Each table has the fixed schema of :mod:`borescan.tables` (:data:`SCHEMA`, the columns of
``shared/spec/outputs.md`` plus extensions); one view per saved query
(``workflow/queries/<name>.sql``) is created on every update. Nothing in a row comes from the
wall clock, so building from the same stage files gives the same table contents. Cross-night
rules: a calibration's first night's row wins (a rod's nominal geometry recurs every night), an
artifact keeps its latest night's record, and statuses that a later night changes (a
measurement put in doubt by a failed verification) are views, always current.

Bookkeeping lives in the DuckDB schema ``build`` (``build.sources``: the stage files each night
was built from, with size and modification time; ``build.info``; the per-night records behind
``calibration_scans`` and ``artifacts``, so the latest nights can be replaced).

The new catalog is written to ``catalog.duckdb.tmp`` (a copy of the old one, extended) and
renamed over ``catalog.duckdb``, so readers never see a half-built history.

Modules: :mod:`~borescan.catalog.names` (file, tables, keys, stage order),
:mod:`~borescan.catalog.history` (the stage tables read and assembled), :mod:`~borescan.catalog.rows`
(rows written), :mod:`~borescan.catalog.queries` (saved queries as views), :mod:`~borescan.catalog.seal`
(damage), :mod:`~borescan.catalog.build` (update, rebuild, open); the public names are importable from
``borescan.catalog``.

Reading the history
-------------------
- ``borescan sql "SELECT ..."`` or ``borescan sql --query verification_drift`` (read-only).
- Plain DuckDB, also on shared storage while the pipeline runs:
  ``duckdb -readonly results/catalog.duckdb`` (the file is replaced by a rename, so an open
  reader keeps a consistent snapshot).
- Without the catalog, straight from the stage Parquet files:
  ``SELECT * FROM read_parquet('results/stage/diameters/night=*.parquet', union_by_name=true)``;
  the quarantine rows are hive-partitioned by stage:
  ``read_parquet('results/stage/quarantine/*/*.parquet', hive_partitioning=true)``.
"""

from __future__ import annotations

from borescan.catalog.build import (
    CatalogUpdate,
    build_catalog,
    open_catalog,
    rebuild_catalog,
    table_rows,
    update_catalog,
    upsert_rows,
)
from borescan.catalog.history import (
    RECORD_DIGEST,
    assemble_history,
    read_quarantine,
    read_stage_table,
    stage_files,
    with_record_digest,
)
from borescan.catalog.names import (
    BUILD_SCHEMA,
    CATALOG_NAME,
    FORMAT_VERSION,
    KEYS,
    NIGHT_TABLES,
    SCHEMA,
    STAGE_ORDER,
    STAGE_TABLES,
    catalog_path,
    certificate_json_path,
)
from borescan.catalog.queries import DEFAULT_QUERIES_DIR, _q, _view_sql, saved_queries
from borescan.catalog.seal import CatalogDamaged, catalog_damage, set_aside_damaged

__all__ = [
    "BUILD_SCHEMA",
    "CATALOG_NAME",
    "CatalogUpdate",
    "FORMAT_VERSION",
    "NIGHT_TABLES",
    "SCHEMA",
    "KEYS",
    "DEFAULT_QUERIES_DIR",
    "STAGE_TABLES",
    "STAGE_ORDER",
    "assemble_history",
    "RECORD_DIGEST",
    "with_record_digest",
    "build_catalog",
    "rebuild_catalog",
    "stage_files",
    "update_catalog",
    "open_catalog",
    "read_quarantine",
    "read_stage_table",
    "catalog_path",
    "certificate_json_path",
    "catalog_damage",
    "set_aside_damaged",
    "CatalogDamaged",
    "saved_queries",
    "upsert_rows",
    "table_rows",
    "_q",  # quoting of an identifier and a saved query's view text, as the report's own views use them
    "_view_sql",
]
