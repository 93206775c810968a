"""The pipeline's configuration: ``config/config.yaml`` completed from its schema.

Defaults live in one place, the schema the package ships (``workflow/schemas/config.schema.yaml`` in
a checkout, :func:`borescan.resources.shipped`); this module reads them
from there (as the Snakefile's ``validate`` does) so that library callers outside Snakemake
(benchmarks, scripts run by hand) see exactly the settings a night job sees.
"""

from __future__ import annotations

import copy
import functools
from pathlib import Path
from typing import Any

import yaml

from borescan.resources import shipped

__all__ = [
    "SCHEMA_PATH",
    "ConfigError",
    "schema_defaults",
    "schema_default",
    "check_config",
    "load_config",
    "load_configs",
]

#: the config schema the package ships (``workflow/schemas/config.schema.yaml`` of a checkout links to it)
SCHEMA_PATH = shipped("config.schema.yaml")


def _defaults(node: dict) -> Any:
    if node.get("type") == "object" and "properties" in node:
        out = dict(node.get("default") or {})
        for key, sub in node["properties"].items():
            d = _defaults(sub)
            if d is not None or "default" in sub:  # a stated null default is a value (no tolerance, ...)
                out[key] = d
        return out
    return node.get("default")


#: The loader of the shipped schema: PyYAML's safe loader on libyaml's parser where the installed PyYAML
#: has it (the same objects in a tenth of the time: 3 ms instead of 30 ms for the schema, read by every
#: stage job and worker, several times). A user's file keeps the pure-Python loader and its messages.
_SCHEMA_LOADER = getattr(yaml, "CSafeLoader", yaml.SafeLoader)


@functools.lru_cache(maxsize=4)
def _parsed(schema_path: str, mtime_ns: int) -> dict:
    return yaml.load(Path(schema_path).read_text(), Loader=_SCHEMA_LOADER)


def _read_schema(schema_path: Path | str) -> dict:
    """Return the schema at ``schema_path``, parsed once per process while the file stays (read only)."""
    return _parsed(str(schema_path), Path(schema_path).stat().st_mtime_ns)


def schema_defaults(schema_path: Path | str = SCHEMA_PATH) -> dict:
    """Every key's default from the schema, nested as the config is (the caller's own copy)."""
    return copy.deepcopy(_defaults(_read_schema(schema_path)))


@functools.lru_cache(maxsize=4)
def _defaults_of(schema_path: str) -> dict:
    return schema_defaults(schema_path)


def schema_default(*keys: str) -> Any:
    """Return the schema's default of one setting (read once per process).

    E.g. ``schema_default("uncertainty", "coverage_probability")``: what a library function uses for a keyword
    its caller leaves unset, so that the default lives in the schema only (read once per process).

    Raises
    ------
    KeyError naming the path when the schema has no such setting.
    """
    node: Any = _defaults_of(str(SCHEMA_PATH))
    for i, k in enumerate(keys):
        if not isinstance(node, dict) or k not in node:
            raise KeyError(f"the config schema has no default for {'.'.join(keys[: i + 1])}")
        node = node[k]
    return copy.deepcopy(node)


def _merge(base: dict, over: dict) -> dict:
    out = dict(base)
    for k, v in (over or {}).items():
        out[k] = _merge(base[k], v) if isinstance(v, dict) and isinstance(base.get(k), dict) else v
    return out


class ConfigError(ValueError):
    """A config that is not YAML or breaks the schema.

    ``str()`` names the file, the key and the problem in one line (a mistyped key, a wrong type, a value out
    of range), never the schema itself.
    """


def _key_path(err) -> str:
    return ".".join(str(p) for p in err.absolute_path) or "(top level)"


#: keys an earlier version had, with what says it now (docs/migration.md)
REMOVED_KEYS = {
    "stage_workers": "removed: a night job's processes are its rule's threads, "
    "--set-threads <rule>=N (or set-threads: in a profile)",
}


def _one_line(err) -> str:
    """Return a jsonschema error as ``key: problem``, the schema left out."""
    if err.validator == "additionalProperties":
        allowed = sorted((err.schema.get("properties") or {}).keys())
        extra = sorted(set(err.instance) - set(allowed)) if isinstance(err.instance, dict) else []
        where = _key_path(err)
        removed = [k for k in extra if where == "(top level)" and k in REMOVED_KEYS]
        parts = [f"{k}: {REMOVED_KEYS[k]}" for k in removed]
        unknown = [k for k in extra if k not in removed]
        if unknown:
            names = ", ".join(f"{where}.{k}" if where != "(top level)" else k for k in unknown)
            known = f" (known here: {', '.join(allowed)})" if allowed else ""
            parts.append(f"{names}: unknown key{known}")
        return "; ".join(parts)
    if err.validator in (
        "type",
        "minimum",
        "maximum",
        "exclusiveMinimum",
        "exclusiveMaximum",
        "enum",
        "pattern",
    ):
        return f"{_key_path(err)}: {err.instance!r} is not allowed ({err.validator} {err.validator_value!r})"
    return f"{_key_path(err)}: {err.message[:200]}"


def check_config(config: dict, source: str = "config", schema_path: Path | str = SCHEMA_PATH) -> None:
    """Check ``config`` against the schema; :class:`ConfigError` listing each problem in one line."""
    import jsonschema

    validator = jsonschema.Draft202012Validator(_read_schema(schema_path))
    errors = sorted(validator.iter_errors(config), key=lambda e: [str(p) for p in e.absolute_path])
    if errors:
        lines = "; ".join(_one_line(e) for e in errors[:10])
        more = f" (and {len(errors) - 10} more)" if len(errors) > 10 else ""
        raise ConfigError(
            f"{source}: {lines}{more} (every key is described in workflow/schemas/config.schema.yaml)"
        )


def load_config(path: Path | str | None = None, schema_path: Path | str = SCHEMA_PATH) -> dict:
    """Return the config at ``path`` with every missing key defaulted, checked against the schema.

    No ``path``: the schema's defaults alone. Raise :class:`ConfigError` when it is not YAML or breaks the
    schema.
    """
    source = str(path) if path is not None else "schema defaults"
    try:
        user = yaml.safe_load(Path(path).read_text()) if path is not None else {}
    except yaml.YAMLError as err:
        raise ConfigError(f"{source}: not YAML: {str(err).splitlines()[0]}") from None
    if user is not None and not isinstance(user, dict):
        raise ConfigError(f"{source}: a config is a mapping of keys, got {type(user).__name__}")
    cfg = _merge(schema_defaults(schema_path), user or {})
    check_config(cfg, source, schema_path)
    return cfg


def load_configs(paths, schema_path: Path | str = SCHEMA_PATH) -> dict:
    """Return the config files merged in order over the schema's defaults.

    Merged as the Snakefile's ``configfile:`` lines are.
    """
    out = schema_defaults(schema_path)
    for path in paths:
        out = _merge(out, yaml.safe_load(Path(path).read_text()) or {})
    return out
