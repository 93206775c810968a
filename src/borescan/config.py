"""The pipeline's configuration: ``config/config.yaml`` completed from its schema.

Defaults live in one place, ``workflow/schemas/config.schema.yaml``; this module reads them
from there (as the Snakefile's ``validate`` does) so that library callers outside Snakemake
(benchmarks, scripts run by hand) see exactly the settings a night job sees.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml

__all__ = ["SCHEMA_PATH", "schema_defaults", "load_config"]

#: the config schema of the checkout this package is installed from (editable install)
SCHEMA_PATH = Path(__file__).resolve().parents[2] / "workflow" / "schemas" / "config.schema.yaml"


def _defaults(node: dict) -> Any:
    if node.get("type") == "object" and "properties" in node:
        out = dict(node.get("default") or {})
        for key, sub in node["properties"].items():
            d = _defaults(sub)
            if d is not None or "default" in sub:  # a stated null default is a value (no tolerance, ...)
                out[key] = d
        return out
    return node.get("default")


def schema_defaults(schema_path: Path | str = SCHEMA_PATH) -> dict:
    """Every key's default from the schema, nested as the config is."""
    return _defaults(yaml.safe_load(Path(schema_path).read_text()))


def _merge(base: dict, over: dict) -> dict:
    out = dict(base)
    for k, v in (over or {}).items():
        out[k] = _merge(base[k], v) if isinstance(v, dict) and isinstance(base.get(k), dict) else v
    return out


def load_config(path: Path | str | None = None, schema_path: Path | str = SCHEMA_PATH) -> dict:
    """Return the config at ``path`` (none: the schema's defaults alone) with every missing key defaulted."""
    user = yaml.safe_load(Path(path).read_text()) if path is not None else {}
    return _merge(schema_defaults(schema_path), user or {})
