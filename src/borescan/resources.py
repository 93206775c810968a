"""Files the package ships (package data, :mod:`importlib.resources`).

The config schema, the catalog's saved queries and the papers' transcribed tables.

They live in ``src/borescan/shipped/`` (one copy); the workflow's usual paths
(``workflow/schemas/config.schema.yaml``, ``workflow/queries/``, ``data/papers/``) are links to them in
a checkout, and an installed wheel carries them, so the library finds them without a checkout.
"""

from __future__ import annotations

from importlib.resources import files
from pathlib import Path

__all__ = ["shipped"]


def shipped(*parts: str) -> Path:
    """Path of a shipped file or folder, e.g. ``shipped("config.schema.yaml")``, ``shipped("queries")``.

    Raises
    ------
    FileNotFoundError naming the path when the package does not ship it.
    """
    path = Path(str(files("borescan").joinpath("shipped", *parts)))
    if not path.exists():
        raise FileNotFoundError(f"borescan ships no {'/'.join(parts)} (looked at {path})")
    return path
