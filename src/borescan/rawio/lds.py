"""The checks of ``lds.parquet`` and ``spindle.parquet`` (vectorised) and of in-memory scan data."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import polars as pl
import pyarrow as pa

from borescan.rawio.format import (
    LDS_FILE,
    LDS_NULLABLE,
    LDS_SCHEMA,
    LdsMatrix,
    SCAN_JSON,
    SPINDLE_FILE,
    SPINDLE_NULLABLE,
    SPINDLE_SCHEMA,
    ScanError,
    _NO_SCAN,
)
from borescan.rawio.matrix import _arrow_numpy, _np, _regular_matrix
from borescan.rawio.meta import _Problems, _check_meta, _is_int, _is_number, _valid_scan_id

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
