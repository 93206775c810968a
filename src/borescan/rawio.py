"""Reader, writer and validator of ``borescan-raw/1`` (``shared/spec/raw-scan-format.md``).

This module is the only place that touches raw files. Layout::

    <raw_root>/night=<YYYY-MM-DD>/scan=<scan_id>/
        scan.json        required   metadata
        lds.parquet      required   long table: sample, t_ns, sensor, value_mm, pose
        spindle.parquet  optional   t_ns, angle_rad, x_mm, y_mm, rpm

Raw files are opened read-only and never modified; :func:`write_scan` writes a new scan folder
atomically (temporary folder beside it, then a rename) and refuses to replace an existing folder
with different content. A bad scan raises :class:`ScanError` naming the scan, the file and the
problem; :func:`validate_root` collects every problem of every scan.

Decisions the spec leaves open (documented here, enforced by the reader):

- all five ``lds.parquet`` columns are required, with exactly the listed Arrow types;
  ``sample``, ``t_ns``, ``sensor`` are never null; ``sample`` and ``t_ns`` are >= 0;
- rows are sorted by ``(sample, sensor)`` with no duplicate pair; all rows of one ``sample`` share
  one ``t_ns``, and ``t_ns`` strictly increases with ``sample``;
- ``value_mm`` null means "no reading"; NaN or +-inf is an error; every channel listed in
  ``sensors`` needs at least one non-null reading; readings outside ``[0, range_mm]`` are
  physical and only counted in :attr:`RawScan.warnings`;
- ``pose`` is non-null and >= 0 (and constant within a sample) on ``rod`` scans, and null on
  ``tri_lds`` scans that carry a ``spindle.parquet``;
- ``spindle.parquet``: ``t_ns`` non-null, >= 0, strictly increasing; ``x_mm``, ``y_mm``, ``rpm``
  non-null and finite; ``angle_rad`` null or finite; at least one row;
- ``started_at`` must carry an explicit UTC designator (``Z`` or ``+00:00``);
- scan folders (or files in them) that resolve outside ``raw_root`` are rejected.
"""

from __future__ import annotations

import datetime as _dt
import hashlib
import json
import math
import os
import re
import shutil
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import polars as pl
import pyarrow as pa
import pyarrow.parquet as pq

__all__ = [
    "FORMAT",
    "ScanError",
    "RawScan",
    "LdsMatrix",
    "read_scan",
    "inspect_scan",
    "read_scan_meta",
    "write_scan",
    "discover_scans",
    "nights",
    "night_scan_dirs",
    "night_raw_files",
    "night_manifest",
    "earlier_duplicate_ids",
    "clock_jump",
    "validate_root",
    "tree_problems",
    "check_scan_data",
    "lds_matrix",
    "sha256_file",
    "LDS_SCHEMA",
    "SPINDLE_SCHEMA",
]

FORMAT = "borescan-raw/1"
SCAN_JSON = "scan.json"
LDS_FILE = "lds.parquet"
SPINDLE_FILE = "spindle.parquet"

KINDS = ("calibration", "centering", "verification", "measurement")
DEVICE_TYPES = ("tri_lds", "rod")
ARTIFACT_TYPES = ("ring_gauge", "part")
#: ``spindle.direction`` seen from +z (spec "Units and frames"): counter-clockwise or clockwise.
DIRECTIONS = ("ccw", "cw")

SCAN_ID_RE = re.compile(r"[A-Za-z0-9_-]{1,64}")
NIGHT_RE = re.compile(r"\d{4}-\d{2}-\d{2}")

LDS_SCHEMA = pa.schema(
    [
        ("sample", pa.int64()),
        ("t_ns", pa.int64()),
        ("sensor", pa.int16()),
        ("value_mm", pa.float64()),
        ("pose", pa.int32()),
    ]
)
LDS_NULLABLE = frozenset({"value_mm", "pose"})
SPINDLE_SCHEMA = pa.schema(
    [
        ("t_ns", pa.int64()),
        ("angle_rad", pa.float64()),
        ("x_mm", pa.float64()),
        ("y_mm", pa.float64()),
        ("rpm", pa.float64()),
    ]
)
SPINDLE_NULLABLE = frozenset({"angle_rad"})

_NO_SCAN = "-"


class ScanError(Exception):
    """A raw scan that breaks ``borescan-raw/1``.

    Parameters
    ----------
    scan_id : str
        Scan the problem belongs to (``"-"`` when no scan can be named).
    file : str
        File (or folder, relative to the raw root) with the problem.
    problem : str
        What is wrong, in words.
    """

    def __init__(self, scan_id: str, file: str, problem: str):
        self.scan_id = str(scan_id)
        self.file = str(file)
        self.problem = str(problem)
        super().__init__(f"{self.scan_id}: {self.file}: {self.problem}")

    def __reduce__(self):
        return (type(self), (self.scan_id, self.file, self.problem))


@dataclass
class RawScan:
    """One validated raw scan.

    Attributes
    ----------
    scan_id, night : str
        From the folder names (equal to ``scan.json``).
    path : Path
        The scan folder.
    meta : dict
        Parsed ``scan.json`` (unknown keys kept as read).
    lds : pl.DataFrame
        The five ``lds.parquet`` columns (extra columns are not read).
    spindle : pl.DataFrame or None
        The five ``spindle.parquet`` columns, or None when the file is absent.
    files : dict
        File name -> the path it was read from.
    warnings : list of str
        Non-fatal findings (readings outside ``[0, range_mm]``, counted per channel).
    sha256 : dict (property)
        File name -> hex SHA-256 digest of the raw bytes. ``scan.json`` is hashed as it is read;
        the Parquet files on first use of ``sha256`` (stages that only use the data do not pay
        for hashing megabytes; raw files are never modified).
    """

    scan_id: str
    night: str
    path: Path
    meta: dict
    lds: pl.DataFrame
    spindle: pl.DataFrame | None
    files: dict[str, Path]
    warnings: list[str] = field(default_factory=list)
    _digests: dict[str, str] = field(default_factory=dict, repr=False)
    # (the ``lds`` frame, its wide matrix) when validation built the matrix on the way: see lds_matrix
    _matrix: tuple[pl.DataFrame, LdsMatrix] | None = field(default=None, repr=False, compare=False)

    @property
    def sha256(self) -> dict[str, str]:
        """File name -> hex SHA-256 of the raw bytes (computed once per file, on first use)."""
        for name, path in self.files.items():
            if name not in self._digests:
                self._digests[name] = sha256_file(path)
        return dict(self._digests)

    @property
    def device_type(self) -> str:
        """``meta["device"]["type"]`` (``tri_lds`` or ``rod``)."""
        return self.meta["device"]["type"]

    @property
    def channels(self) -> tuple[int, ...]:
        """Channels listed in ``sensors``, ascending."""
        return tuple(sorted(int(s["channel"]) for s in self.meta["sensors"]))


@dataclass(frozen=True)
class LdsMatrix:
    """Wide view of ``lds.parquet``: one row per sample, one column per channel.

    Attributes
    ----------
    sample : ndarray, shape (n,), int64
    t_s : ndarray, shape (n,), float64
        Time since scan start [s] (``t_ns / 1e9``, correctly rounded).
    channels : tuple of int
        Column order of ``values_mm`` (ascending channel).
    values_mm : ndarray, shape (n, c), float64
        Readings [mm]; NaN where null or where a channel has no row for the sample.
    pose : ndarray, shape (n,), int64
        Rod pose index, -1 where null.
    """

    sample: np.ndarray
    t_s: np.ndarray
    channels: tuple[int, ...]
    values_mm: np.ndarray
    pose: np.ndarray

    def channel(self, ch: int) -> np.ndarray:
        """Return readings [mm] of channel ``ch`` (1-based)."""
        return self.values_mm[:, self.channels.index(ch)]


# ---------------------------------------------------------------------------------------------
# helpers


def sha256_file(path: Path) -> str:
    """Hex SHA-256 of a file's bytes (read-only, streamed)."""
    with open(path, "rb") as f:
        return hashlib.file_digest(f, "sha256").hexdigest()


def combined_sha256(file_hashes: dict[str, str]) -> str:
    r"""One digest for a scan: SHA-256 over the sorted ``"name:sha256\n"`` lines of its raw files."""
    lines = "".join(f"{name}:{digest}\n" for name, digest in sorted(file_hashes.items()))
    return hashlib.sha256(lines.encode()).hexdigest()


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


# ---------------------------------------------------------------------------------------------
# table checks (vectorised, on Arrow / numpy)


def _check_schema(schema: pa.Schema, want: pa.Schema, p: _Problems, file: str) -> bool:
    ok = True
    names = schema.names
    for f in want:
        if names.count(f.name) > 1:
            p.add(file, f"column '{f.name}' appears {names.count(f.name)} times")
            ok = False
        elif f.name not in names:
            p.add(file, f"missing column '{f.name}' ({f.type})")
            ok = False
        else:
            got = schema.field(f.name).type
            if got != f.type:
                p.add(file, f"column '{f.name}' has dtype {got}, expected {f.type}")
                ok = False
    return ok


#: numpy dtype of the primitive Arrow types a raw column may have. Their values are read straight from
#: the Arrow buffers (:func:`_arrow_numpy`): pyarrow's own ``to_numpy`` and ``fill_null`` import pandas on
#: first use, ~0.35 s in every process that reads a scan (each stage job and worker), for nothing we use.
_NUMPY_DTYPE = {
    pa.int8(): np.int8,
    pa.int16(): np.int16,
    pa.int32(): np.int32,
    pa.int64(): np.int64,
    pa.uint8(): np.uint8,
    pa.uint16(): np.uint16,
    pa.uint32(): np.uint32,
    pa.uint64(): np.uint64,
    pa.float32(): np.float32,
    pa.float64(): np.float64,
}


def _arrow_numpy(arr: pa.Array, fill=None) -> np.ndarray:
    """Return one Arrow array as numpy.

    One Arrow array as numpy: a view of its value buffer (a copy with ``fill`` where null, in the
    array's dtype) for the types of :data:`_NUMPY_DTYPE`; any other type, or nulls without ``fill``, by
    pyarrow's conversion.
    """
    dtype = _NUMPY_DTYPE.get(arr.type)
    n = len(arr)
    if dtype is None or (arr.null_count and fill is None):
        if arr.null_count and fill is not None:
            arr = arr.fill_null(fill)
        return arr.to_numpy(zero_copy_only=False)
    if n == 0:
        return np.zeros(0, dtype=dtype)
    vals = np.frombuffer(arr.buffers()[1], dtype=dtype, count=arr.offset + n)[arr.offset :]
    if not arr.null_count:
        return vals
    valid = np.unpackbits(np.frombuffer(arr.buffers()[0], dtype=np.uint8), bitorder="little")
    out = vals.copy()
    out[valid[arr.offset : arr.offset + n] == 0] = fill
    return out


def _np(col: pa.ChunkedArray | pa.Array, fill) -> np.ndarray:
    """Column as numpy, nulls replaced by ``fill``."""
    if isinstance(col, pa.ChunkedArray):
        col = col.combine_chunks()
    return _arrow_numpy(col, fill)


def _check_nonnull(table: pa.Table, nullable: frozenset, p: _Problems, file: str) -> bool:
    ok = True
    for name in table.column_names:
        if name not in nullable and table.column(name).null_count:
            p.add(file, f"column '{name}' has {table.column(name).null_count} null values (not nullable)")
            ok = False
    return ok


def _first(mask: np.ndarray) -> int:
    return int(np.flatnonzero(mask)[0])


def _listed_sensors(meta: dict | None) -> dict[int, dict] | None:
    """``scan.json`` sensors by channel (entries with an integer channel), None when not a list."""
    if meta is None or not isinstance(meta.get("sensors"), list):
        return None
    return {
        int(s["channel"]): s for s in meta["sensors"] if isinstance(s, dict) and _is_int(s.get("channel"))
    }


def _device_type(meta: dict | None) -> Any:
    """``meta["device"]["type"]`` when ``scan.json`` has it (any JSON value), else None."""
    dev = meta.get("device") if isinstance(meta, dict) else None
    return dev.get("type") if isinstance(dev, dict) else None


def _range_warning(file: str, ch: int, count: int, rng: float) -> str:
    return f"{file}: channel {ch}: {count} readings outside [0, {rng:g}] mm"


def _range_of(sensor: dict) -> float | None:
    rng = sensor.get("range_mm")
    return rng if _is_number(rng) and math.isfinite(rng) and rng > 0 else None


def _aligned_chunks(table: pa.Table, names: tuple[str, ...]) -> list[tuple[np.ndarray, ...]]:
    """Return numpy arrays of the columns ``names``, chunk by chunk.

    Numpy arrays of the columns ``names``, chunk by chunk: zero-copy views of the chunks as read
    (nulls of a float column as NaN, which costs a copy of that chunk), or one combined chunk per
    column when the columns are chunked differently.
    """
    cols = [table.column(k) for k in names]
    lengths = [[len(ch) for ch in c.chunks] for c in cols]
    if any(ln != lengths[0] for ln in lengths[1:]):
        return [tuple(_chunk_numpy(c.combine_chunks()) for c in cols)]
    return [tuple(_chunk_numpy(c.chunk(i)) for c in cols) for i in range(cols[0].num_chunks) if lengths[0][i]]


def _chunk_numpy(arr: pa.Array) -> np.ndarray:
    """One chunk as numpy: zero-copy without nulls; nulls of a float chunk as NaN."""
    return _arrow_numpy(arr, np.nan if pa.types.is_floating(arr.type) else None)


def _lds_fast_check(
    table: pa.Table, meta: dict | None, has_spindle: bool, file: str, *, layout: bool = True
) -> tuple[list[str], LdsMatrix | None] | None:
    """:func:`_check_lds` for a table that passes every check, in far fewer passes over the data.

    Returns (the warnings :func:`_check_lds` would return, the wide matrix when the table is in the
    usual layout of :func:`_regular_matrix`, else None) when the table has no problem, and None as
    soon as anything might be one; the caller then runs :func:`_check_lds_full` for the messages.
    A table in the usual layout is checked on its wide matrix (the layout implies the ordering
    checks); any other one (or every one, ``layout=False``) chunk by chunk as Arrow read it
    (:func:`_lds_chunk_warnings`).
    """
    n = table.num_rows
    if n == 0 or any(table.column(k).null_count for k in table.column_names if k not in LDS_NULLABLE):
        return None
    listed = _listed_sensors(meta)
    mat = _regular_matrix(table, tuple(sorted(listed))) if listed and layout else None
    if mat is not None:
        warnings = _matrix_warnings(mat, table.column("value_mm").null_count, listed, file)
    else:
        warnings = _lds_chunk_warnings(table, listed, file)
    if warnings is None or not _pose_ok(table, meta, has_spindle):
        return None
    return warnings, mat


def _matrix_warnings(mat: LdsMatrix, nulls: int, listed: dict[int, dict], file: str) -> list[str] | None:
    """Return the range warnings of a usual-layout table, or None.

    Range warnings of a table in the usual layout from its wide matrix (NaN = null); None when
    something might be a problem: a negative first sample or time, NaN or infinite readings, a
    listed channel without valid readings.
    """
    if mat.sample[0] < 0 or mat.t_s[0] < 0:
        return None
    vals = mat.values_mm.reshape(-1)
    lo, hi = float(np.fmin.reduce(vals)), float(np.fmax.reduce(vals))  # NaN (null) ignored
    if not (math.isfinite(lo) and math.isfinite(hi)):
        return None  # infinite readings, or no valid reading at all
    nan_at = np.flatnonzero(np.isnan(vals))
    if nan_at.size != nulls:
        return None  # NaN readings
    c = len(mat.channels)
    if (np.bincount(nan_at % c, minlength=c) >= mat.values_mm.shape[0]).any():
        return None  # a listed channel without valid readings
    return _range_warnings(
        lo,
        hi,
        listed,
        file,
        lambda j, rng: int(np.count_nonzero((mat.values_mm[:, j] < 0) | (mat.values_mm[:, j] > rng))),
    )


def _range_warnings(lo: float, hi: float, listed: dict[int, dict], file: str, count_out) -> list[str]:
    """Return warnings for readings outside [0, range] per listed channel.

    Warnings for readings outside [0, range] per listed channel, counted (``count_out(j, range)``
    for the j-th channel ascending) only when the extreme readings ``lo``, ``hi`` leave [0, range].
    """
    chans = sorted(listed)
    ranges = [_range_of(listed[ch]) for ch in chans]
    limit = min((r for r in ranges if r is not None), default=np.inf)
    warnings: list[str] = []
    if lo < 0 or hi > limit:
        for j, (ch, rng) in enumerate(zip(chans, ranges)):
            out = count_out(j, rng) if rng is not None else 0
            if out:
                warnings.append(_range_warning(file, ch, out, rng))
    return warnings


def _pose_ok(table: pa.Table, meta: dict | None, has_spindle: bool) -> bool:
    """Return whether the pose checks of :func:`_check_lds_full` pass.

    Return the pose checks of :func:`_check_lds_full` pass (rod: every pose set, >= 0, one per sample;
    tri_lds with a spindle stream: no pose).
    """
    pcol = table.column("pose")
    dtype = _device_type(meta)
    if dtype == "rod":
        if pcol.null_count:
            return False
        sample = _arrow_numpy(table.column("sample").combine_chunks())
        pose = _arrow_numpy(pcol.combine_chunks())
        return not (pose.min() < 0 or ((sample[1:] == sample[:-1]) & (pose[1:] != pose[:-1])).any())
    return not (dtype == "tri_lds" and has_spindle and pcol.null_count != table.num_rows)


def _lds_chunk_warnings(  # noqa: C901 (one branch per checked rule of the raw format)
    table: pa.Table, listed: dict[int, dict] | None, file: str
) -> list[str] | None:
    """Return the checks' warnings on the Arrow chunks as read, or None.

    Ordering, finiteness, channel and range checks of any table without nulls where they are not
    allowed, on the Arrow chunks as they were read (no concatenation): sorting is tested by
    comparing neighbours (no int64 differences), readings per channel by one comparison per listed
    channel. Returns the range warnings, None when something might be a problem.
    """
    n = table.num_rows
    chunks = _aligned_chunks(table, ("sample", "t_ns", "sensor", "value_mm"))
    chans = sorted(listed) if listed is not None else []
    per_ch = np.zeros(len(chans), dtype=np.int64)
    lo, hi, non_finite = np.inf, -np.inf, 0
    prev = None  # last (sample, t_ns, sensor) of the previous chunk
    for sample, t_ns, sensor, value in chunks:
        if sample.min() < 0 or t_ns.min() < 0:
            return None
        if prev is not None:  # the pair across the chunk boundary
            s0, t0, e0 = prev
            if not (sample[0] > s0 and t_ns[0] > t0 or sample[0] == s0 and sensor[0] > e0 and t_ns[0] == t0):
                return None
        same = sample[1:] == sample[:-1]
        if not (same | (sample[1:] > sample[:-1])).all():
            return None  # decreasing sample
        if not np.where(
            same, (sensor[1:] > sensor[:-1]) & (t_ns[1:] == t_ns[:-1]), t_ns[1:] > t_ns[:-1]
        ).all():
            # unsorted or duplicate (sample, sensor), t_ns differing within a sample or not increasing
            return None
        prev = (sample[-1], t_ns[-1], sensor[-1])
        finite = np.isfinite(value)
        k_fin = int(np.count_nonzero(finite))
        non_finite += value.size - k_fin
        if k_fin:
            lo = min(lo, float(np.min(value, where=finite, initial=np.inf)))
            hi = max(hi, float(np.max(value, where=finite, initial=-np.inf)))
        for j, ch in enumerate(chans):
            per_ch[j] += np.count_nonzero(sensor == ch)
    vcol = table.column("value_mm")
    if non_finite != vcol.null_count:
        return None  # NaN/inf readings
    if listed is None:
        return []
    if per_ch.sum() != n:
        return None  # an unlisted channel
    if vcol.null_count:  # readings per channel less its nulls (few): every listed channel needs one
        sensor_all = _arrow_numpy(table.column("sensor").filter(vcol.is_null()).combine_chunks())
        per_ch = per_ch - np.array([np.count_nonzero(sensor_all == ch) for ch in chans], dtype=np.int64)
    if not (per_ch > 0).all():
        return None  # a listed channel without valid readings
    return _range_warnings(
        lo,
        hi,
        listed,
        file,
        lambda j, rng: sum(
            int(np.count_nonzero((sensor == chans[j]) & ((value < 0) | (value > rng))))
            for _, _, sensor, value in chunks
        ),
    )


def _check_lds(
    table: pa.Table, meta: dict | None, has_spindle: bool, p: _Problems, file: str
) -> tuple[list[str], LdsMatrix | None]:
    """Check the data of an ``lds.parquet`` table with the right schema.

    Check the data of an ``lds.parquet`` table with the right schema; return (warnings, the wide
    matrix when the fast check built it on the way, else None).
    """
    fast = _lds_fast_check(table, meta, has_spindle, file)
    return fast if fast is not None else (_check_lds_full(table, meta, has_spindle, p, file), None)


def _check_lds_full(  # noqa: C901 (one branch per checked rule of the raw format)
    table: pa.Table, meta: dict | None, has_spindle: bool, p: _Problems, file: str
) -> list[str]:
    """Every check of :func:`_check_lds` with its message (the path for tables with problems)."""
    warnings: list[str] = []
    n = table.num_rows
    if n == 0:
        p.add(file, "no rows")
        return warnings
    if not _check_nonnull(table, LDS_NULLABLE, p, file):
        return warnings
    sample = _np(table.column("sample"), 0)
    t_ns = _np(table.column("t_ns"), 0)
    sensor = _np(table.column("sensor"), 0).astype(np.int64)
    vcol = table.column("value_mm")
    value = _np(vcol, np.nan)
    valid = _np(vcol.is_valid(), False) if vcol.null_count else np.ones(n, dtype=bool)

    if sample.min() < 0:
        p.add(file, f"negative sample at row {_first(sample < 0)} (sample is 0-based)")
    if t_ns.min() < 0:
        p.add(file, f"negative t_ns at row {_first(t_ns < 0)} (time since scan start)")

    ds = np.diff(sample)
    dsen = np.diff(sensor)
    dt = np.diff(t_ns)
    sorted_ok = True
    if (ds < 0).any():
        i = _first(ds < 0) + 1
        p.add(file, f"sample is non-monotonic: decreases at row {i} ({sample[i - 1]} -> {sample[i]})")
        sorted_ok = False
    same = ds == 0
    bad = same & (dsen < 0)
    if bad.any():
        i = _first(bad) + 1
        p.add(
            file,
            f"rows not sorted by (sample, sensor): row {i} has sensor {sensor[i]} after {sensor[i - 1]}",
        )
        sorted_ok = False
    dup = same & (dsen == 0)
    if dup.any():
        i = _first(dup) + 1
        p.add(file, f"duplicate (sample, sensor) = ({sample[i]}, {sensor[i]}) at row {i}")
        sorted_ok = False
    if sorted_ok:
        bad = same & (dt != 0)
        if bad.any():
            i = _first(bad) + 1
            p.add(file, f"t_ns differs within sample {sample[i]} ({t_ns[i - 1]} vs {t_ns[i]})")
        bad = (ds > 0) & (dt <= 0)
        if bad.any():
            i = _first(bad) + 1
            p.add(
                file,
                f"t_ns is non-monotonic: sample {sample[i - 1]} -> {sample[i]} has t_ns "
                f"{t_ns[i - 1]} -> {t_ns[i]}",
            )

    nonfinite = valid & ~np.isfinite(value)
    if nonfinite.any():
        i = _first(nonfinite)
        p.add(
            file,
            f"value_mm has {int(nonfinite.sum())} NaN/inf values (first at row {i}); "
            "use null for 'no reading'",
        )

    # channels (bincount over the int16 channel numbers: one pass each)
    listed = _listed_sensors(meta)
    if listed is not None:
        smin = int(sensor.min())
        nbin = int(sensor.max()) - smin + 1
        offset = sensor - smin
        present = np.flatnonzero(np.bincount(offset, minlength=nbin)) + smin
        for ch in sorted(set(present.tolist()) - set(listed)):
            p.add(file, f"channel {ch} is not listed in scan.json sensors")
        good = valid & np.isfinite(value)
        n_good = np.bincount(offset[good], minlength=nbin)
        # readings outside [0, range_mm] are physical: warnings only
        rng_of = np.full(nbin, np.inf)
        for ch, s in listed.items():
            rng = _range_of(s)
            if 0 <= ch - smin < nbin and rng is not None:
                rng_of[ch - smin] = rng
        outside = good & ((value < 0) | (value > rng_of[offset]))
        n_out = np.bincount(offset[outside], minlength=nbin)
        for ch in sorted(listed):
            k = ch - smin
            if not (0 <= k < nbin and n_good[k] > 0):
                p.add(file, f"channel {ch} has no valid readings")
            elif n_out[k]:
                warnings.append(_range_warning(file, ch, int(n_out[k]), listed[ch]["range_mm"]))

    # pose
    pcol = table.column("pose")
    dtype = _device_type(meta)
    if dtype == "rod":
        if pcol.null_count:
            pv = _np(pcol.is_null(), False)
            p.add(
                file, f"pose is null in {pcol.null_count} rows (first at row {_first(pv)}); rod scans need it"
            )
        else:
            pose = _np(pcol, 0)
            if pose.min() < 0:
                p.add(file, f"negative pose at row {_first(pose < 0)}")
            if sorted_ok:
                bad = same & (np.diff(pose) != 0)
                if bad.any():
                    i = _first(bad) + 1
                    p.add(file, f"pose differs within sample {sample[i]}")
    elif dtype == "tri_lds" and has_spindle and pcol.null_count != n:
        i = _first(_np(pcol.is_valid(), False))
        p.add(file, f"pose must be null on tri_lds spindle scans (non-null at row {i})")
    return warnings


def _check_spindle(table: pa.Table, p: _Problems, file: str) -> None:
    if table.num_rows == 0:
        p.add(file, "no rows")
        return
    if not _check_nonnull(table, SPINDLE_NULLABLE, p, file):
        return
    t_ns = _np(table.column("t_ns"), 0)
    if t_ns.min() < 0:
        p.add(file, f"negative t_ns at row {_first(t_ns < 0)}")
    dt = np.diff(t_ns)
    if (dt <= 0).any():
        i = _first(dt <= 0) + 1
        p.add(file, f"t_ns is non-monotonic at row {i} ({t_ns[i - 1]} -> {t_ns[i]})")
    for name in ("angle_rad", "x_mm", "y_mm", "rpm"):
        col = table.column(name)
        v = _np(col, 0.0)
        bad = ~np.isfinite(v)
        if bad.any():
            p.add(file, f"{name} has {int(bad.sum())} NaN/inf values (first at row {_first(bad)})")


def _lds_to_arrow(lds: pl.DataFrame | pa.Table, p: _Problems, file: str) -> pa.Table | None:
    """In-memory frame -> Arrow table with exactly the schema columns (cast losslessly)."""
    return _frame_to_arrow(lds, LDS_SCHEMA, p, file)


def _frame_to_arrow(df: Any, schema: pa.Schema, p: _Problems, file: str) -> pa.Table | None:
    if isinstance(df, pl.DataFrame):
        t = df.to_arrow()
    elif isinstance(df, pa.Table):
        t = df
    else:
        p.add(file, f"expected a polars DataFrame or Arrow table, got {type(df).__name__}")
        return None
    missing = [f.name for f in schema if f.name not in t.column_names]
    if missing:
        for name in missing:
            p.add(file, f"missing column '{name}'")
        return None
    cols = []
    for f in schema:
        c = t.column(f.name)
        if c.type != f.type:
            castable = (
                pa.types.is_null(c.type)
                or pa.types.is_integer(c.type)
                or (pa.types.is_floating(c.type) and pa.types.is_floating(f.type))
            )
            if castable:
                try:
                    c = c.cast(f.type, safe=True)
                except (pa.ArrowInvalid, pa.ArrowNotImplementedError) as e:
                    p.add(file, f"column '{f.name}' cannot be stored as {f.type}: {e}")
                    return None
            else:
                p.add(file, f"column '{f.name}' has dtype {c.type}, expected {f.type}")
                return None
        cols.append(c)
    return pa.Table.from_arrays(cols, schema=schema)


def check_scan_data(
    meta: dict,
    lds: pl.DataFrame | pa.Table,
    spindle: pl.DataFrame | pa.Table | None = None,
    *,
    meta_file: str = SCAN_JSON,
    lds_file: str = LDS_FILE,
    spindle_file: str = SPINDLE_FILE,
) -> list[ScanError]:
    """Every ``borescan-raw/1`` problem of in-memory scan data (no folder checks).

    Integer/float columns are cast losslessly to the format's dtypes first (as
    :func:`write_scan` does). File labels name the files in the messages.

    Returns
    -------
    list of ScanError
        Empty when the data would make a valid scan.
    """
    sid = meta.get("scan_id") if isinstance(meta, dict) else None
    p = _Problems(sid if _valid_scan_id(sid) else _NO_SCAN)
    _check_meta(meta, p, meta_file)
    meta_ok = not p
    lt = _lds_to_arrow(lds, p, lds_file)
    if lt is not None:
        _check_lds(lt, meta if meta_ok else None, spindle is not None, p, lds_file)
    if spindle is not None:
        st = _frame_to_arrow(spindle, SPINDLE_SCHEMA, p, spindle_file)
        if st is not None:
            _check_spindle(st, p, spindle_file)
    return p.errors


# ---------------------------------------------------------------------------------------------
# reading


def _scan_id_from_dir(scan_dir: Path) -> str:
    name = scan_dir.name
    sid = name[5:] if name.startswith("scan=") else name
    return sid if _valid_scan_id(sid) else (sid[:64] or _NO_SCAN)


def _check_folder(scan_dir: Path, raw_root: Path | None, p: _Problems) -> tuple[str | None, str | None]:
    """Folder-name and containment checks; return (scan_id, night) from the names."""
    name, parent = scan_dir.name, scan_dir.parent.name
    sid = name[5:] if name.startswith("scan=") else None
    night = parent[6:] if parent.startswith("night=") else None
    rel = f"{parent}/{name}"
    if sid is None or night is None:
        p.add(rel, "folder is not <raw_root>/night=<YYYY-MM-DD>/scan=<scan_id>")
    if sid is not None and not _valid_scan_id(sid):
        p.add(rel, f"folder scan_id {sid!r:.80} does not match [A-Za-z0-9_-]{{1,64}}")
        sid = None
    if night is not None and not _valid_night(night):
        p.add(rel, f"folder night {night!r:.40} is not a date YYYY-MM-DD")
        night = None
    root = Path(raw_root) if raw_root is not None else scan_dir.parent.parent
    try:
        real_root = root.resolve(strict=True)
        real = scan_dir.resolve(strict=True)
    except (OSError, RuntimeError) as e:
        p.add(rel, f"cannot resolve folder: {e}")
        return sid, night
    if not real.is_relative_to(real_root) or real == real_root:
        p.add(rel, f"folder resolves to {real}, outside the raw root {real_root}")
    elif not real.is_dir():
        p.add(rel, "not a directory")
    else:
        try:
            os.listdir(real)
        except OSError as e:  # e.g. written with umask 077 by another user
            p.add(rel, f"cannot list the scan folder: {e.strerror or e}")
    return sid, night


def _open_file(
    scan_dir: Path, fname: str, real_root: Path | None, p: _Problems, required: bool
) -> Path | None:
    path = scan_dir / fname
    try:
        if not os.path.lexists(path):
            if required:
                p.add(fname, "missing (required)")
            return None
        real = path.resolve(strict=True)
    except (OSError, RuntimeError) as e:
        p.add(fname, f"cannot resolve: {e}")
        return None
    if real_root is not None and not real.is_relative_to(real_root):
        p.add(fname, f"resolves to {real}, outside the raw root")
        return None
    if not real.is_file():
        p.add(fname, "not a regular file")
        return None
    return path


def _read_meta_file(path: Path, p: _Problems) -> tuple[Any, str | None]:
    try:
        with open(path, "rb") as f:
            data = f.read()
    except OSError as e:
        p.add(SCAN_JSON, f"unreadable: {e.strerror or e}")
        return None, None
    digest = hashlib.sha256(data).hexdigest()
    try:
        return _parse_json_bytes(data), digest
    except UnicodeDecodeError as e:
        p.add(SCAN_JSON, f"not UTF-8 text: {e.reason} at byte {e.start}")
    except (ValueError, RecursionError) as e:
        p.add(SCAN_JSON, f"invalid JSON: {e}")
    return None, digest


def _read_parquet(path: Path, fname: str, schema: pa.Schema, p: _Problems) -> pa.Table | None:
    """Read only the schema's columns of a Parquet file; None after a problem."""
    # An Arrow-native file, never a Python file object: column decoding runs on Arrow's thread
    # pool, and its tasks drop their page readers after the read has returned. Over a Python file
    # object those hold Python-owned buffers whose release needs the GIL; a worker that asks for it
    # while the interpreter is shutting down is terminated inside a C++ destructor, and the process
    # aborts after its output ("terminate called without an active exception", exit 134).
    try:
        with pa.OSFile(str(path)) as f:
            pf = pq.ParquetFile(f)
            if not _check_schema(pf.schema_arrow, schema, p, fname):
                return None
            table = pf.read(columns=schema.names)  # Arrow's pool: OMP_NUM_THREADS threads
    except OSError as e:
        if e.errno is not None:
            p.add(fname, f"unreadable: {os.strerror(e.errno)}")
        else:
            p.add(fname, f"not a readable Parquet file (truncated or corrupt): {e}")
        return None
    except Exception as e:  # noqa: BLE001 - any decoder failure means a corrupt file
        p.add(fname, f"not a readable Parquet file (truncated or corrupt): {type(e).__name__}: {e}")
        return None
    return table.select(schema.names)


def _meta_folder_checks(meta: dict, sid: str | None, night: str | None, p: _Problems) -> None:
    msid = meta.get("scan_id")
    if sid is not None and isinstance(msid, str) and msid != sid:
        p.add(SCAN_JSON, f"scan_id {msid!r:.80} differs from the folder name scan={sid}")
    mnight = meta.get("night")
    if night is not None and isinstance(mnight, str) and mnight != night:
        p.add(SCAN_JSON, f"night {mnight!r:.40} differs from the folder name night={night}")


def _inspect(  # noqa: C901 (one branch per raw file and problem of a scan folder)
    scan_dir: Path, raw_root: Path | None = None, meta_only: bool = False
) -> tuple[RawScan | dict | None, list[ScanError]]:
    scan_dir = Path(scan_dir)
    p = _Problems(_scan_id_from_dir(scan_dir))
    sid, night = _check_folder(scan_dir, raw_root, p)
    if p:
        return None, p.errors
    root = Path(raw_root) if raw_root is not None else scan_dir.parent.parent
    real_root = root.resolve()
    meta_path = _open_file(scan_dir, SCAN_JSON, real_root, p, required=True)
    lds_path = _open_file(scan_dir, LDS_FILE, real_root, p, required=True) if not meta_only else None
    sp_path = _open_file(scan_dir, SPINDLE_FILE, real_root, p, required=False) if not meta_only else None
    meta, meta_digest = (None, None)
    if meta_path is not None:
        meta, meta_digest = _read_meta_file(meta_path, p)
    meta_ok = False
    if meta is not None:
        n0 = len(p.errors)
        _check_meta(meta, p, SCAN_JSON)
        if isinstance(meta, dict):
            _meta_folder_checks(meta, sid, night, p)
        meta_ok = len(p.errors) == n0
    if meta_only:
        return (meta if not p else None), p.errors
    has_spindle_file = os.path.lexists(scan_dir / SPINDLE_FILE)
    lds_tab = _read_parquet(lds_path, LDS_FILE, LDS_SCHEMA, p) if lds_path is not None else None
    sp_tab = _read_parquet(sp_path, SPINDLE_FILE, SPINDLE_SCHEMA, p) if sp_path is not None else None
    warnings: list[str] = []
    matrix = None
    if lds_tab is not None:
        warnings, matrix = _check_lds(lds_tab, meta if meta_ok else None, has_spindle_file, p, LDS_FILE)
    if sp_tab is not None:
        _check_spindle(sp_tab, p, SPINDLE_FILE)
    if p:
        return None, p.errors
    files = {SCAN_JSON: meta_path, LDS_FILE: lds_path}
    if sp_tab is not None:
        files[SPINDLE_FILE] = sp_path
    lds = pl.from_arrow(lds_tab)
    if matrix is not None:
        for a in (matrix.sample, matrix.t_s, matrix.values_mm, matrix.pose):
            a.flags.writeable = False  # shared by every lds_matrix(scan) call
    scan = RawScan(
        scan_id=sid,
        night=night,
        path=scan_dir,
        meta=meta,
        lds=lds,
        spindle=pl.from_arrow(sp_tab) if sp_tab is not None else None,
        files=files,
        warnings=warnings,
        _digests={SCAN_JSON: meta_digest},
        _matrix=(lds, matrix) if matrix is not None else None,
    )
    return scan, []


def read_scan(scan_dir: Path, raw_root: Path | None = None) -> RawScan:
    """Read and fully validate one scan folder.

    Parameters
    ----------
    scan_dir : Path
        ``<raw_root>/night=<YYYY-MM-DD>/scan=<scan_id>``.
    raw_root : Path, optional
        The raw root; defaults to ``scan_dir.parent.parent``. The folder and its files must
        resolve inside it (symlinks that leave it are rejected).

    Returns
    -------
    RawScan

    Raises
    ------
    ScanError
        The first problem found (:func:`validate_root` lists them all).
    """
    scan, errors = _inspect(scan_dir, raw_root)
    if errors:
        raise errors[0]
    return scan


def inspect_scan(scan_dir: Path, raw_root: Path | None = None) -> tuple[RawScan | None, list[ScanError]]:
    """Read and validate one scan folder, returning every problem.

    Read and validate one scan folder like :func:`read_scan`, returning every problem instead of
    raising the first: ``(scan, [])`` when valid, ``(None, problems)`` otherwise.
    """
    return _inspect(scan_dir, raw_root)


def read_scan_meta(scan_dir: Path, raw_root: Path | None = None) -> dict:
    """Read and check only ``scan.json`` of a scan folder (fast path for listings).

    Raises
    ------
    ScanError
        First problem of the folder names or of ``scan.json``.
    """
    meta, errors = _inspect(scan_dir, raw_root, meta_only=True)
    if errors:
        raise errors[0]
    return meta


def _listing(folder: Path) -> list[Path]:
    """Return the entries of ``folder``; [] when it cannot be listed.

    Unlistable means unreadable, e.g. written with umask 077 by another user: the scan's own check
    (:func:`_check_folder`) or :func:`tree_problems` names it.
    """
    try:
        return list(Path(folder).iterdir())
    except OSError:
        return []


def _is_dir(path: Path) -> bool:
    try:
        return path.is_dir()
    except OSError:
        return False


def _sort_key(scan_dir: Path) -> tuple[str, str]:
    return (scan_dir.parent.name[6:], scan_dir.name[5:])


def discover_scans(raw_root: Path) -> list[Path]:
    """Scan folders ``<raw_root>/night=*/scan=*``, sorted by (night, scan_id).

    Hidden entries (names starting with ``.``, e.g. unfinished temporary folders) are skipped.
    Folders are listed, not validated.
    """
    raw_root = Path(raw_root)
    out = []
    if not raw_root.is_dir():
        return out
    for night_dir in _listing(raw_root):
        if not night_dir.name.startswith("night=") or not _is_dir(night_dir):
            continue
        for scan_dir in _listing(night_dir):
            if scan_dir.name.startswith("scan=") and _is_dir(scan_dir):
                out.append(scan_dir)
    return sorted(out, key=_sort_key)


def nights(raw_root: str | Path) -> list[str]:
    """Return the nights with a ``night=<date>`` folder under ``raw_root``.

    Nights (``YYYY-MM-DD``) with a ``night=<date>`` folder under ``raw_root``, sorted; [] when it does not
    exist.

    The unit of work of the pipeline: each stage runs once per night. Folders whose name is not
    ``night=`` + a calendar date (``night=2026-02-30`` is not one) are never processed
    (:func:`tree_problems` names them, and the catalog step reports them as skipped).
    """
    root = Path(raw_root)
    if not root.is_dir():
        return []
    return sorted(
        p.name[6:]
        for p in _listing(root)
        if p.name.startswith("night=") and _valid_night(p.name[6:]) and _is_dir(p)
    )


def night_scan_dirs(raw_root: str | Path, night: str) -> list[Path]:
    """Return the scan folders of one night, sorted.

    Scan folders ``scan=<scan_id>`` (non-empty id) of one night, sorted by folder name; listed, not
    validated.
    """
    night_dir = Path(raw_root) / f"night={night}"
    return sorted(
        p for p in _listing(night_dir) if p.name.startswith("scan=") and len(p.name) > 5 and _is_dir(p)
    )


def night_raw_files(raw_root: str | Path, night: str) -> list[str]:
    """Every regular file of a night's scan folders (the inputs whose change must rerun that night).

    Files this user cannot read are left out, and a scan folder that cannot be listed contributes
    none (Snakemake hashes a job's inputs; ingest quarantines the scan, naming the file or folder).
    """
    return [
        str(f)
        for d in night_scan_dirs(raw_root, night)
        for f in sorted(_listing(d))
        if _is_file(f) and os.access(f, os.R_OK)
    ]


def _is_file(path: Path) -> bool:
    try:
        return path.is_file()
    except OSError:
        return False


def night_manifest(raw_root: str | Path, night: str) -> str:
    """Return what a night of the raw root holds, as text.

    One line per scan folder and per file in it (``scan=<id>/<file> <bytes> <mtime_ns>``; a folder that cannot
    be listed: ``scan=<id>/ unlistable``).

    Equal text means the night's scans are the ones last processed, whatever the files' times
    say about their order: a scan added with old times (``cp -a``, ``rsync -a``), removed, or a
    file replaced changes the text (the workflow's ``raw_index``, an input of every night job).
    """
    lines = []
    for d in night_scan_dirs(raw_root, night):
        try:
            entries = sorted(d.iterdir())
        except OSError:
            lines.append(f"{d.name}/ unlistable")
            continue
        for f in entries:
            try:
                st = f.stat()
            except OSError:
                lines.append(f"{d.name}/{f.name} unreadable")
                continue
            if f.is_file():
                lines.append(f"{d.name}/{f.name} {st.st_size} {st.st_mtime_ns}")
    return "".join(line + "\n" for line in lines)


def earlier_duplicate_ids(raw_root: str | Path, night: str) -> list[str]:
    """Scan ids of ``night`` that already occur in an earlier night (the earlier scan keeps the id).

    Scan ids are unique across nights. Depends only on this and earlier nights, so adding a
    later night changes nothing here.
    """
    ids_here = {d.name[5:] for d in night_scan_dirs(raw_root, night)}
    seen: set[str] = set()
    for n in nights(raw_root):
        if n >= night:
            break
        seen.update(d.name[5:] for d in night_scan_dirs(raw_root, n))
    return sorted(ids_here & seen)


def clock_jump(sample: np.ndarray, t_s: np.ndarray, sample_rate_hz: float) -> str | None:
    """Describe the first tick whose time step disagrees with the sample step by more than half a period.

    On a spindle scan one clock drives every channel, so ``t`` must advance by
    ``(sample step) / sample_rate_hz``; a larger error means the logger's clock or counter
    slipped. Returns None when every step agrees (or there are fewer than two samples).

    Parameters
    ----------
    sample : (n,) sample numbers, increasing.
    t_s : (n,) times of the samples [s].
    sample_rate_hz : the scan's nominal sample rate [Hz].
    """
    sample = np.asarray(sample)
    t_s = np.asarray(t_s, dtype=float)
    if sample.size < 2:
        return None
    expected = np.diff(sample) / sample_rate_hz
    step = np.diff(t_s)
    bad = np.flatnonzero(np.abs(step - expected) > 0.5 / sample_rate_hz)
    if bad.size == 0:
        return None
    i = int(bad[0])
    return (
        f"clock jump: t_ns advances {step[i]:.6g} s between samples {int(sample[i])} and "
        f"{int(sample[i + 1])}, expected {expected[i]:.6g} s at {sample_rate_hz:g} Hz"
    )


def validate_root(raw_root: Path, *, warnings: list[str] | None = None) -> list[ScanError]:
    """Every problem of every scan under ``raw_root``, plus stray folders and duplicate ids.

    Parameters
    ----------
    raw_root : Path
    warnings : list, optional
        If given, non-fatal warnings of valid scans are appended as ``"scan_id: file: text"``.

    Returns
    -------
    list of ScanError
        Empty when every scan is valid. Entries that are not ``night=<date>/scan=<id>``
        folders are reported with scan_id ``"-"``.
    """
    raw_root = Path(raw_root)
    if not raw_root.is_dir():
        return [ScanError(_NO_SCAN, str(raw_root), "raw root does not exist or is not a folder")]
    errors = tree_problems(raw_root)
    seen: dict[str, str] = {}
    for scan_dir in discover_scans(raw_root):
        if not _valid_night(scan_dir.parent.name[6:]):
            continue  # reported by tree_problems
        scan, errs = _inspect(scan_dir, raw_root)
        errors.extend(errs)
        sid = scan_dir.name[5:]
        if sid in seen:
            errors.append(
                ScanError(
                    sid,
                    f"{scan_dir.parent.name}/{scan_dir.name}",
                    f"scan_id also used in {seen[sid]} (scan ids are unique across nights)",
                )
            )
        else:
            seen[sid] = scan_dir.parent.name
        if scan is not None and warnings is not None:
            warnings.extend(f"{scan.scan_id}: {w}" for w in scan.warnings)
    return errors


def tree_problems(raw_root: Path) -> list[ScanError]:
    """Entries of an existing raw root that are not ``night=<date>/scan=<id>`` folders (scan_id ``"-"``).

    Hidden entries are skipped. A night folder whose name is not a date is reported here, and
    its scans are not checked further.
    """
    errors: list[ScanError] = []
    for entry in sorted(_listing(raw_root)):
        if entry.name.startswith("."):
            continue
        if not (entry.name.startswith("night=") and _is_dir(entry)):
            errors.append(ScanError(_NO_SCAN, entry.name, "not a night=<YYYY-MM-DD> folder"))
            continue
        if not _valid_night(entry.name[6:]):
            errors.append(
                ScanError(
                    _NO_SCAN, entry.name, "folder night is not a date YYYY-MM-DD; its scans are not processed"
                )
            )
        try:
            subs = sorted(entry.iterdir())
        except OSError as e:
            errors.append(ScanError(_NO_SCAN, entry.name, f"cannot list the night folder: {e.strerror or e}"))
            continue
        for sub in subs:
            if sub.name.startswith("."):
                continue
            if not (sub.name.startswith("scan=") and _is_dir(sub)):
                errors.append(ScanError(_NO_SCAN, f"{entry.name}/{sub.name}", "not a scan=<scan_id> folder"))
    return errors


# ---------------------------------------------------------------------------------------------
# writing


def _json_bytes(meta: dict) -> bytes:
    return (json.dumps(meta, indent=2, ensure_ascii=False, allow_nan=False) + "\n").encode("utf-8")


def _write_parquet(table: pa.Table, path: Path) -> None:
    pq.write_table(table, path, compression="zstd", use_dictionary=False, write_statistics=True)


def _fsync(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _same_content(a: Path, b: Path) -> bool:
    fa = sorted(x.name for x in a.iterdir())
    fb = sorted(x.name for x in b.iterdir())
    return fa == fb and all(sha256_file(a / n) == sha256_file(b / n) for n in fa)


def write_scan(  # noqa: C901 (checks, staging and atomic rename of a scan's raw files)
    raw_root: Path, meta: dict, lds: pl.DataFrame, spindle: pl.DataFrame | None = None
) -> Path:
    """Write one scan as ``<raw_root>/night=<night>/scan=<scan_id>/`` (atomic, write-once).

    Columns are cast losslessly to the format dtypes (e.g. int64 -> int16 for ``sensor``);
    extra columns are dropped. The data are validated before anything is written. The files go
    to a temporary folder beside the target, which is then renamed into place. Writing the
    same content again is a no-op.

    Parameters
    ----------
    raw_root : Path
    meta : dict
        ``scan.json`` content.
    lds : pl.DataFrame
        Long table: sample, t_ns, sensor, value_mm, pose.
    spindle : pl.DataFrame, optional
        t_ns, angle_rad, x_mm, y_mm, rpm.

    Returns
    -------
    Path
        The scan folder.

    Raises
    ------
    ScanError
        The data would not make a valid scan (first problem; all are in ``problems``).
    FileExistsError
        The folder exists with different content, or the scan_id exists under another night.
    """
    raw_root = Path(raw_root)
    errors = check_scan_data(meta, lds, spindle)
    if errors:
        err = errors[0]
        err.problems = errors  # type: ignore[attr-defined]
        raise err
    p = _Problems(meta["scan_id"])
    lds_t = _lds_to_arrow(lds, p, LDS_FILE)
    sp_t = _frame_to_arrow(spindle, SPINDLE_SCHEMA, p, SPINDLE_FILE) if spindle is not None else None
    sid, night = meta["scan_id"], meta["night"]
    night_dir = raw_root / f"night={night}"
    final = night_dir / f"scan={sid}"
    if raw_root.is_dir():
        for other in raw_root.glob(f"night=*/scan={sid}"):
            if other.parent.name != night_dir.name:
                raise FileExistsError(
                    f"{sid}: {other.parent.name}/{other.name}: scan_id already used under another night"
                )
    night_dir.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".scan={sid}.tmp-", dir=night_dir))
    try:
        (tmp / SCAN_JSON).write_bytes(_json_bytes(meta))
        _write_parquet(lds_t, tmp / LDS_FILE)
        if sp_t is not None:
            _write_parquet(sp_t, tmp / SPINDLE_FILE)
        for f in tmp.iterdir():
            _fsync(f)
        os.chmod(tmp, 0o755)
        if final.exists() or final.is_symlink():
            if final.is_dir() and not final.is_symlink() and _same_content(tmp, final):
                return final
            raise FileExistsError(
                f"{sid}: {night_dir.name}/{final.name}: exists with different content "
                "(raw folders are write-once)"
            )
        try:
            os.rename(tmp, final)
        except OSError:
            if final.is_dir() and _same_content(tmp, final):
                return final
            raise FileExistsError(
                f"{sid}: {night_dir.name}/{final.name}: appeared while writing with different content"
            ) from None
        _fsync(night_dir)
        return final
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)


# ---------------------------------------------------------------------------------------------
# wide view


def _chunk_views(col: pa.ChunkedArray) -> list[np.ndarray] | None:
    """Zero-copy numpy views of the chunks of a null-free primitive column; None if it has nulls."""
    if col.null_count:
        return None
    return [_arrow_numpy(ch) for ch in col.chunks if len(ch)]


def _residue_views(views: list[np.ndarray], k: int, c: int):
    """Rows r = k (mod c) of a chunked column: yields (those rows of one chunk, r // c of the first)."""
    r0 = 0
    for a in views:
        j = (k - r0) % c
        yield a[j::c], (r0 + j) // c
        r0 += a.size


def _residue_column(views: list[np.ndarray], k: int, c: int, n: int, dtype) -> np.ndarray:
    """Rows r = k (mod c) of a chunked column gathered into one array of length ``n``."""
    out = np.empty(n, dtype=dtype)
    for v, g in _residue_views(views, k, c):
        out[g : g + v.size] = v
    return out


def _wide_values(col: pa.ChunkedArray, c: int, n: int) -> np.ndarray:
    """Return a float column of a long table as an (n, c) matrix.

    Float column of a long table, c rows per sample -> (n, c) (row r -> [r // c, r % c], i.e. the
    flat index r of a C-ordered array: one copy of the value buffers); nulls NaN.
    """
    out = np.empty(n * c)
    r0 = 0
    for ch in col.chunks:
        m = len(ch)
        if not m:
            continue
        out[r0 : r0 + m] = _arrow_numpy(ch, np.nan)
        r0 += m
    return out.reshape(n, c)


def _regular_matrix(  # noqa: C901 (one exit per layout that is not the usual one)
    tab: pa.Table, listed: tuple[int, ...]
) -> LdsMatrix | None:
    """Return the wide matrix of an ``lds`` table in the usual layout, or None.

    Return the wide matrix of an ``lds`` Arrow table in the usual layout, straight from its chunks; None
    when the layout does not apply.

    The usual layout: every sample has one row per listed channel (``listed`` ascending) in channel
    order, rows sorted by sample, ``sample`` strictly increasing from one sample to the next and
    ``t_ns`` too, both equal within a sample; no null sample / sensor / t_ns; float64 readings.
    Then row r is sample r // c, channel r % c and the wide matrix is a strided copy of the value
    buffers (no long -> wide scatter). Such a table passes every ordering check of
    :func:`_check_lds_full`, so the validation uses this too (:func:`_lds_fast_check`).
    """
    c, rows = len(listed), tab.num_rows
    if not rows or not c or rows % c or tab.schema.field("value_mm").type != pa.float64():
        return None
    sample, sensor, t_ns = (_chunk_views(tab.column(k)) for k in ("sample", "sensor", "t_ns"))
    if sample is None or sensor is None or t_ns is None:
        return None
    n = rows // c
    s0 = _residue_column(sample, 0, c, n, np.int64)
    t0 = _residue_column(t_ns, 0, c, n, np.int64)
    if not ((s0[1:] > s0[:-1]).all() and (t0[1:] > t0[:-1]).all()):
        return None
    for k in range(c):
        for v, _ in _residue_views(sensor, k, c):
            if not (v == listed[k]).all():
                return None
        if k:
            for col, first in ((sample, s0), (t_ns, t0)):
                for v, g in _residue_views(col, k, c):
                    if not np.array_equal(v, first[g : g + v.size]):
                        return None
    pose = tab.column("pose")
    if pose.null_count == rows:
        pose_s = np.full(n, -1, dtype=np.int64)
    else:
        P = _arrow_numpy(pose.combine_chunks(), -1).astype(np.int64).reshape(-1, c)
        first = np.argmax(P >= 0, axis=1)
        pose_s = P[np.arange(n), first]  # -1 where the whole sample has no pose
    return LdsMatrix(
        sample=s0,
        t_s=t0 / 1e9,
        channels=listed,
        values_mm=_wide_values(tab.column("value_mm"), c, n),
        pose=pose_s,
    )


def _lds_matrix_reshaped(t: pl.DataFrame, listed: tuple[int, ...]) -> LdsMatrix | None:
    """:func:`_regular_matrix` of a polars ``lds`` frame; None when the usual layout does not apply."""
    return _regular_matrix(t.select(*LDS_SCHEMA.names).to_arrow(), listed)


def lds_matrix(scan: RawScan) -> LdsMatrix:
    """Long ``lds`` -> one row per sample, one column per listed channel (ascending).

    NaN where a reading is null or a channel has no row for a sample; ``t_s = t_ns / 1e9``;
    ``pose`` is -1 where null.
    """
    t = scan.lds
    listed = tuple(sorted({int(ch) for ch in scan.channels}))
    built = getattr(scan, "_matrix", None)
    if built is not None and built[0] is t and built[1].channels == listed:
        return built[1]  # built by read_scan's validation (read-only arrays)
    fast = _lds_matrix_reshaped(t, listed)
    if fast is not None:
        return fast
    sample = t["sample"].to_numpy()
    sensor16 = t["sensor"].to_numpy()
    value = _arrow_numpy(t["value_mm"].cast(pl.Float64).to_arrow(), np.nan)
    t_ns = t["t_ns"].to_numpy()
    sensor = sensor16.astype(np.int64)
    pose = t["pose"].fill_null(-1).to_numpy().astype(np.int64)
    present = np.flatnonzero(np.bincount(sensor)) if sensor.size and sensor.min() >= 0 else np.unique(sensor)
    channels = tuple(sorted(set(scan.channels) | set(present.tolist())))
    starts = np.flatnonzero(np.r_[True, np.diff(sample) != 0])
    row = np.cumsum(np.r_[True, np.diff(sample) != 0]) - 1
    lut = np.full(max(channels) + 1, -1, dtype=np.int64)
    lut[list(channels)] = np.arange(len(channels))
    values = np.full((len(starts), len(channels)), np.nan)
    values[row, lut[sensor]] = value
    # pose of a sample: first non-null pose among its rows
    pose_s = np.full(len(starts), -1, dtype=np.int64)
    have = pose >= 0
    pose_s[row[have][::-1]] = pose[have][::-1]
    return LdsMatrix(
        sample=sample[starts].astype(np.int64),
        t_s=t_ns[starts] / 1e9,
        channels=channels,
        values_mm=values,
        pose=pose_s,
    )
