"""Stage ``build_catalog``: ``catalog.duckdb`` extended by the nights whose stage tables are new."""

from __future__ import annotations

from pathlib import Path

from borescan import catalog

__all__ = ["stage_catalog"]


def stage_catalog(results_root: str | Path, catalog_file: str | Path | None = None,
                  full: bool = False) -> catalog.CatalogUpdate:
    """Bring ``<results_root>/catalog.duckdb`` up to date (:func:`borescan.catalog.update_catalog`).

    Only new nights' stage files are read; ``full=True`` rebuilds from every night. ``catalog_file``,
    when given, must be where the catalog is written (the rule's output).
    """
    update = catalog.update_catalog(results_root, full=full)
    if catalog_file is not None and Path(catalog_file).resolve() != Path(update.path).resolve():
        raise RuntimeError(f"catalog written to {update.path}, rule expected {catalog_file}")
    return update
