"""A damaged catalog: its seal (``catalog.duckdb.sha256``), the damage found, the file set aside."""

from __future__ import annotations

import os
from pathlib import Path


from borescan.atomic import atomic_write_text
from borescan.rawio import sha256_file
from borescan.catalog.names import catalog_path

# --------------------------------------------------------------------------- damage


class CatalogDamaged(FileNotFoundError):
    """Raised when ``catalog.duckdb`` is not the file the pipeline wrote (truncated, overwritten).

    A ``FileNotFoundError`` so every command reports it as a missing catalog.
    """


def _seal_path(final: Path) -> Path:
    return final.with_name(final.name + ".sha256")


def _write_seal(final: Path) -> None:
    """``catalog.duckdb.sha256``: the digest and size of the catalog as written."""
    atomic_write_text(_seal_path(final), f"{sha256_file(final)} {final.stat().st_size}\n")


def set_aside_damaged(results_root: str | os.PathLike, dry_run: bool = False) -> str | None:
    """Move a damaged ``catalog.duckdb`` to ``catalog.duckdb.damaged``; return the message, None when intact.

    The workflow then rebuilds the catalog from the stage tables, and the report after it.
    """
    final = catalog_path(results_root)
    why = catalog_damage(final)
    if why is None:
        return None
    if dry_run:
        return f"the history catalog {final} is damaged ({why}); a run rebuilds it from the stage tables"
    os.replace(final, final.with_name(final.name + ".damaged"))
    return (
        f"the history catalog {final} is damaged ({why}): kept as {final.name}.damaged, rebuilt from the "
        "stage tables by this run"
    )


def catalog_damage(path: str | os.PathLike) -> str | None:
    """Return why ``path`` (a ``catalog.duckdb``) is not the catalog the pipeline wrote, or None.

    None also when there is no catalog, or when it was written before catalogs were sealed.
    """
    final = Path(path)
    seal = _seal_path(final)
    if not final.is_file() or not seal.is_file():
        return None
    digest, _, size = seal.read_text().strip().partition(" ")
    now = final.stat().st_size
    if str(now) != size:
        return f"it has {now} bytes, {size} were written (truncated or cut off by a full disk?)"
    if sha256_file(final) != digest:
        return "its content differs from what was written"
    return None
