"""Stage ``build_catalog``: ``catalog.duckdb`` rebuilt from every night's stage tables."""

from __future__ import annotations

from pathlib import Path

from borescan import catalog

__all__ = ["stage_catalog"]


def stage_catalog(results_root: str | Path, catalog_file: str | Path | None = None) -> dict[str, int]:
    """Rebuild ``<results_root>/catalog.duckdb`` (:func:`borescan.catalog.assemble_history`); rows per table.

    ``catalog_file``, when given, must be where the catalog is written (the rule's output).
    """
    tables = catalog.assemble_history(results_root)
    path = catalog.build_catalog(results_root, tables)
    if catalog_file is not None and Path(catalog_file).resolve() != Path(path).resolve():
        raise RuntimeError(f"catalog written to {path}, rule expected {catalog_file}")
    return {name: df.height for name, df in sorted(tables.items())}
