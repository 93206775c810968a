"""Saved queries (``workflow/queries/*.sql``), one view each in the catalog."""

from __future__ import annotations

import os
from pathlib import Path


from borescan.catalog.names import DEFAULT_QUERIES_DIR, _IDENT

# --------------------------------------------------------------------------- saved queries


def saved_queries(queries_dir: str | os.PathLike | None = None) -> dict[str, tuple[str, str]]:
    """Return the saved queries: name -> (description, SQL text).

    The description is the leading ``--`` comment block of ``<name>.sql`` (comment markers
    stripped). Names are the file stems, which must be SQL identifiers.
    """
    qdir = Path(queries_dir) if queries_dir is not None else DEFAULT_QUERIES_DIR
    out: dict[str, tuple[str, str]] = {}
    if not qdir.is_dir():
        return out
    for f in sorted(qdir.glob("*.sql")):
        if not _IDENT.match(f.stem):
            raise ValueError(f"saved query {f}: the file name must be an SQL identifier")
        text = f.read_text()
        desc = []
        for line in text.splitlines():
            s = line.strip()
            if s.startswith("--"):
                desc.append(s[2:].strip())
            elif s:
                break
        out[f.stem] = ("\n".join(desc).strip(), text)
    return out


def _view_sql(sql: str) -> str:
    body = sql.strip()
    while body.endswith(";"):
        body = body[:-1].rstrip()
    return body


def _q(name: str) -> str:
    return '"' + name.replace('"', '""') + '"'
