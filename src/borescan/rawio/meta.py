"""The checks of ``scan.json``: JSON parsing (duplicate keys and constants refused) and every key."""

from __future__ import annotations

import datetime as _dt
import json
import math
from typing import Any


from borescan.rawio.format import (
    ARTIFACT_TYPES,
    DEVICE_TYPES,
    DIRECTIONS,
    FORMAT,
    KINDS,
    NIGHT_RE,
    SCAN_ID_RE,
    ScanError,
)


class _Problems:
    """Collects :class:`ScanError` for one scan."""

    def __init__(self, scan_id: str):
        self.scan_id = scan_id
        self.errors: list[ScanError] = []

    def add(self, file: str, problem: str) -> None:
        self.errors.append(ScanError(self.scan_id, file, problem))

    def __bool__(self) -> bool:
        return bool(self.errors)


def _is_number(x: Any) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool)


def _is_int(x: Any) -> bool:
    return isinstance(x, int) and not isinstance(x, bool)


def _jtype(x: Any) -> str:
    return {
        dict: "object",
        list: "array",
        str: "string",
        bool: "boolean",
        int: "integer",
        float: "number",
        type(None): "null",
    }.get(type(x), type(x).__name__)


def _valid_night(s: Any) -> bool:
    if not isinstance(s, str) or not NIGHT_RE.fullmatch(s):
        return False
    try:
        _dt.date.fromisoformat(s)
    except ValueError:
        return False
    return True


def _valid_scan_id(s: Any) -> bool:
    return isinstance(s, str) and SCAN_ID_RE.fullmatch(s) is not None


def _reject_constant(name: str):
    raise ValueError(f"non-standard JSON constant {name}")


def _no_duplicate_keys(pairs):
    out = {}
    for k, v in pairs:
        if k in out:
            raise ValueError(f"duplicate key {k!r}")
        out[k] = v
    return out


def _parse_json_bytes(data: bytes) -> Any:
    return json.loads(
        data.decode("utf-8"),
        parse_constant=_reject_constant,
        object_pairs_hook=_no_duplicate_keys,
    )


# ---------------------------------------------------------------------------------------------
# scan.json checks

_NUM, _STR, _DICT, _LIST, _BOOL, _INT = "number", "string", "object", "array", "boolean", "integer"

# Optional keys the pipeline uses: checked for type when present.
_OPTIONAL_TYPES: dict[tuple[str, ...], str] = {
    ("device", "nominal"): _DICT,
    ("spindle",): _DICT,
    ("spindle", "rpm_nominal"): _NUM,
    ("spindle", "direction"): _STR,
    ("spindle", "position"): _DICT,
    ("spindle", "position", "label"): _STR,
    ("spindle", "position", "x_mm"): _NUM,
    ("spindle", "position", "y_mm"): _NUM,
    ("artifact", "nominal_diameter_mm"): _NUM,
    ("artifact", "certified_diameter_mm"): _NUM,
    ("artifact", "u_diameter_mm"): _NUM,
    ("artifact", "k"): _NUM,
    ("artifact", "certificate"): _STR,
    ("artifact", "cte_per_k"): _NUM,
    ("artifact", "features"): _LIST,
    ("center",): _DICT,
    ("center", "x_mm"): _NUM,
    ("center", "y_mm"): _NUM,
    ("center", "method"): _STR,
    ("rod",): _DICT,
    ("rod", "layers"): _LIST,
    ("environment",): _DICT,
    ("environment", "temperature_c"): _NUM,
    ("operator",): _STR,
    ("acquisition",): _DICT,
    ("acquisition", "software"): _STR,
    ("acquisition", "simulated"): _BOOL,
}
_SENSOR_OPTIONAL: dict[str, str] = {
    "model": _STR,
    "serial": _STR,
    "range_mm": _NUM,
    "linearity_fs": _NUM,
    "repeatability_mm": _NUM,
}


def _type_ok(x: Any, want: str) -> bool:
    if want == _NUM:
        return _is_number(x) and math.isfinite(x)
    if want == _INT:
        return _is_int(x)
    if want == _STR:
        return isinstance(x, str)
    if want == _DICT:
        return isinstance(x, dict)
    if want == _LIST:
        return isinstance(x, list)
    if want == _BOOL:
        return isinstance(x, bool)
    raise AssertionError(want)  # pragma: no cover


def _check_meta(  # noqa: C901 (one branch per checked field of scan.json)
    meta: Any, p: _Problems, file: str
) -> None:
    """Append every ``scan.json`` problem of ``meta`` to ``p`` (no folder checks)."""
    if not isinstance(meta, dict):
        p.add(file, f"top level must be a JSON object, not {_jtype(meta)}")
        return

    def need(key: str, want: str, where: dict = meta, prefix: str = "") -> Any:
        name = prefix + key
        if key not in where:
            p.add(file, f"missing required key '{name}'")
            return None
        v = where[key]
        if not _type_ok(v, want):
            what = "a finite number" if want == _NUM else f"a JSON {want}"
            p.add(file, f"key '{name}' must be {what}, got {_jtype(v)} {v!r:.40}")
            return None
        return v

    fmt = need("format", _STR)
    if fmt is not None and fmt != FORMAT:
        p.add(file, f"unknown format {fmt!r} (this reader knows {FORMAT!r})")
    sid = need("scan_id", _STR)
    if sid is not None and not _valid_scan_id(sid):
        p.add(file, f"scan_id {sid!r:.80} does not match [A-Za-z0-9_-]{{1,64}}")
    night = need("night", _STR)
    if night is not None and not _valid_night(night):
        p.add(file, f"night {night!r:.40} is not a date YYYY-MM-DD")
    started = need("started_at", _STR)
    if started is not None:
        try:
            ts = _dt.datetime.fromisoformat(started)
        except ValueError:
            p.add(file, f"started_at {started!r:.40} is not an ISO 8601 date-time")
        else:
            if ts.tzinfo is None or ts.utcoffset() != _dt.timedelta(0):
                p.add(file, f"started_at {started!r:.40} must be UTC (end in 'Z' or '+00:00')")
    kind = need("kind", _STR)
    if kind is not None and kind not in KINDS:
        p.add(file, f"kind {kind!r:.40} not one of {', '.join(KINDS)}")
    dev = need("device", _DICT)
    if dev is not None:
        devid = need("id", _STR, dev, "device.")
        if devid == "":
            p.add(file, "key 'device.id' is empty")
        dtype = need("type", _STR, dev, "device.")
        if dtype is not None and dtype not in DEVICE_TYPES:
            p.add(file, f"device.type {dtype!r:.40} not one of {', '.join(DEVICE_TYPES)}")
    rate = need("sample_rate_hz", _NUM)
    if rate is not None and not rate > 0:
        p.add(file, f"sample_rate_hz must be > 0, got {rate!r}")
    sensors = need("sensors", _LIST)
    if sensors is not None:
        if not sensors:
            p.add(file, "sensors is empty (one entry per channel needed)")
        seen: set[int] = set()
        for i, s in enumerate(sensors):
            where = f"sensors[{i}]"
            if not isinstance(s, dict):
                p.add(file, f"{where} must be a JSON object, got {_jtype(s)}")
                continue
            ch = need("channel", _INT, s, where + ".")
            if ch is not None:
                if ch < 1 or ch > 32767:
                    p.add(file, f"{where}.channel must be in 1..32767, got {ch}")
                elif ch in seen:
                    p.add(file, f"channel {ch} listed twice in sensors")
                seen.add(ch)
            for key, want in _SENSOR_OPTIONAL.items():
                if key in s and not _type_ok(s[key], want):
                    what = "a finite number" if want == _NUM else f"a JSON {want}"
                    p.add(file, f"key '{where}.{key}' must be {what}, got {_jtype(s[key])}")
            rng = s.get("range_mm")
            if _is_number(rng) and math.isfinite(rng) and not rng > 0:
                p.add(file, f"{where}.range_mm must be > 0, got {rng!r}")
    art = need("artifact", _DICT)
    if art is not None:
        need("id", _STR, art, "artifact.")
        atype = need("type", _STR, art, "artifact.")
        if atype is not None and atype not in ARTIFACT_TYPES:
            p.add(file, f"artifact.type {atype!r:.40} not one of {', '.join(ARTIFACT_TYPES)}")
    for path, want in _OPTIONAL_TYPES.items():
        node: Any = meta
        for k in path[:-1]:
            node = node.get(k) if isinstance(node, dict) else None
        if isinstance(node, dict) and path[-1] in node and not _type_ok(node[path[-1]], want):
            v = node[path[-1]]
            what = "a finite number" if want == _NUM else f"a JSON {want}"
            p.add(file, f"key '{'.'.join(path)}' must be {what}, got {_jtype(v)} {v!r:.40}")
    direction = (
        (meta.get("spindle") or {}).get("direction") if isinstance(meta.get("spindle"), dict) else None
    )
    if isinstance(direction, str) and direction.strip().lower() not in DIRECTIONS:
        p.add(file, f"key 'spindle.direction' must be one of {', '.join(DIRECTIONS)}, got {direction!r:.40}")
