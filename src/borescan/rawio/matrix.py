"""The wide view of ``lds.parquet`` (``LdsMatrix``: a row per sample, a column per channel)."""

from __future__ import annotations


import numpy as np
import polars as pl
import pyarrow as pa

from borescan.rawio.format import LDS_SCHEMA, LdsMatrix, RawScan

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
