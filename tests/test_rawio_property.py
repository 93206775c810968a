"""Property test of the reader (issue 8): mutate a valid scan; read_scan either accepts a scan that
re-validates or raises ScanError, never another exception, and never accepts an invalid mutation.
"""

from __future__ import annotations

import json
import shutil
import tempfile
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import polars as pl
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

from borescan.rawio import lds as raw_lds
from borescan.rawio import meta as raw_meta
from borescan.rawio import ScanError, lds_matrix, read_scan, validate_root, write_scan

N, CHANS = 24, (1, 2, 3)

META = {
    "format": "borescan-raw/1",
    "scan_id": "P1",
    "night": "2026-11-21",
    "started_at": "2026-11-21T22:14:03Z",
    "kind": "measurement",
    "device": {"id": "TRI-01", "type": "tri_lds"},
    "sample_rate_hz": 625.0,
    "sensors": [{"channel": c, "range_mm": 10.0} for c in CHANS],
    "artifact": {"id": "RG-275", "type": "ring_gauge"},
}
# required key -> JSON kind it must have
REQUIRED = {
    ("format",): str,
    ("scan_id",): str,
    ("night",): str,
    ("started_at",): str,
    ("kind",): str,
    ("device",): dict,
    ("device", "id"): str,
    ("device", "type"): str,
    ("sample_rate_hz",): float,
    ("sensors",): list,
    ("artifact",): dict,
    ("artifact", "id"): str,
    ("artifact", "type"): str,
}
LDS_DTYPES = {
    "sample": [pl.Int32, pl.Int16, pl.UInt64, pl.Float64],
    "t_ns": [pl.Int32, pl.UInt64, pl.Float64],
    "sensor": [pl.Int8, pl.Int32, pl.Int64, pl.Float64],
    "value_mm": [pl.Float32, pl.String],
    "pose": [pl.Int16, pl.Int64, pl.Float64],
}


def _base_lds() -> pl.DataFrame:
    rng = np.random.default_rng(7)
    v = rng.uniform(1, 9, N * len(CHANS))
    v[::5] = np.nan
    return pl.DataFrame(
        {
            "sample": np.repeat(np.arange(N, dtype=np.int64), len(CHANS)),
            "t_ns": np.repeat(np.arange(N, dtype=np.int64) * 1_600_000, len(CHANS)),
            "sensor": np.tile(np.array(CHANS, dtype=np.int16), N),
            "value_mm": pl.Series(v, nan_to_null=True),
            "pose": pl.Series([None] * (N * len(CHANS)), dtype=pl.Int32),
        }
    )


def _base_spindle() -> pl.DataFrame:
    t = np.arange(N, dtype=np.int64) * 1_600_000
    return pl.DataFrame(
        {
            "t_ns": t,
            "angle_rad": t * 6.283e-9,
            "x_mm": np.ones(N),
            "y_mm": np.ones(N),
            "rpm": np.full(N, 60.0),
        }
    )


@pytest.fixture(scope="module")
def base(tmp_path_factory):
    root = tmp_path_factory.mktemp("base")
    scan_dir = write_scan(root, META, _base_lds(), _base_spindle())
    return scan_dir, read_scan(scan_dir)


def _not_kind(kind):
    """JSON values that are not of the given kind (bool is never a number here)."""
    by_kind = {
        type(None): st.none(),
        bool: st.booleans(),
        int: st.integers(-5, 5),
        float: st.floats(allow_nan=False, allow_infinity=False),
        str: st.text(max_size=4),
        list: st.lists(st.integers(), max_size=2),
        dict: st.dictionaries(st.text(max_size=3), st.integers(), max_size=2),
    }
    excluded = {float, int} if kind is float else {kind}
    return st.one_of([v for k, v in by_kind.items() if k not in excluded])


json_values = st.recursive(
    st.one_of(
        st.none(),
        st.booleans(),
        st.integers(),
        st.floats(allow_nan=False, allow_infinity=False),
        st.text(max_size=6),
    ),
    lambda inner: st.one_of(
        st.lists(inner, max_size=3), st.dictionaries(st.text(max_size=4), inner, max_size=3)
    ),
    max_leaves=6,
)

# each mutation: (target file, is_valid_after, description, payload)
mutation = st.one_of(
    st.sampled_from(sorted(REQUIRED)).map(lambda k: ("scan.json", False, "drop", k)),
    st.sampled_from(sorted(REQUIRED)).flatmap(
        lambda k: _not_kind(REQUIRED[k]).map(lambda v: ("scan.json", False, "retype", (k, v)))
    ),
    st.tuples(st.text(min_size=1, max_size=6), json_values).map(
        lambda kv: ("scan.json", True, "extra_key", kv)
    ),
    st.binary(max_size=60).map(lambda b: ("scan.json", False, "garbage", b)),
    st.sampled_from(sorted(LDS_DTYPES)).map(lambda c: ("lds.parquet", False, "drop_col", c)),
    st.sampled_from(sorted(LDS_DTYPES)).flatmap(
        lambda c: st.sampled_from(LDS_DTYPES[c]).map(lambda d: ("lds.parquet", False, "dtype", (c, d)))
    ),
    st.just(("lds.parquet", True, "extra_col", None)),
    st.just(("scan.json", True, "reorder_keys", None)),
    st.tuples(st.integers(0, N * len(CHANS) - 1), st.sampled_from([-0.5, 10.5, 1e6])).map(
        lambda rv: ("lds.parquet", True, "out_of_range", rv)
    ),
    st.integers(0, 2**32 - 1).map(lambda seed: ("lds.parquet", None, "shuffle", seed)),
    st.tuples(st.integers(0, N * len(CHANS) - 1), st.integers(0, N * len(CHANS) - 1)).map(
        lambda ij: ("lds.parquet", None, "swap", ij)
    ),
    st.tuples(st.integers(0, N * len(CHANS) - 1), st.sampled_from([np.nan, np.inf, -np.inf])).map(
        lambda rv: ("lds.parquet", False, "inject", rv)
    ),
    st.floats(0.0, 0.999).map(lambda f: ("lds.parquet", False, "truncate", f)),
    st.sampled_from(["t_ns", "angle_rad", "x_mm", "y_mm", "rpm"]).map(
        lambda c: ("spindle.parquet", False, "drop_col", c)
    ),
    st.floats(0.0, 0.999).map(lambda f: ("spindle.parquet", False, "truncate", f)),
)


def _apply(  # noqa: C901 (one branch per kind of mutation of the property test)
    scan_dir: Path, muts
) -> tuple[bool, set[str]]:
    """Apply mutations; return (still valid, files whose content is invalid now)."""
    meta = json.loads((scan_dir / "scan.json").read_text())
    tables = {f: pl.from_arrow(pq.read_table(scan_dir / f)) for f in ("lds.parquet", "spindle.parquet")}
    raw_bytes: dict[str, bytes] = {}
    bad_files: set[str] = set()
    order = np.arange(tables["lds.parquet"].height)
    injected: set[int] = set()  # original rows now holding NaN / inf
    for file, valid, what, payload in muts:
        if what == "drop":
            node = meta
            for k in payload[:-1]:
                node = node.get(k) if isinstance(node, dict) else None
            if isinstance(node, dict):
                node.pop(payload[-1], None)
        elif what == "retype":
            key, value = payload
            node = meta
            for k in key[:-1]:
                if not isinstance(node.get(k), dict):
                    node[k] = {}
                node = node[k]
            node[key[-1]] = value
        elif what == "extra_key":
            meta["x_" + payload[0]] = payload[1]
        elif what == "garbage":
            raw_bytes[file] = payload
        elif what == "drop_col":
            tables[file] = tables[file].drop(payload, strict=False)
        elif what == "dtype":
            col, dtype = payload
            if col in tables[file].columns:
                tables[file] = tables[file].with_columns(pl.col(col).cast(dtype))
        elif what == "extra_col":
            tables[file] = tables[file].with_columns(intensity=pl.lit(1.0))
        elif what in ("shuffle", "swap"):
            df = tables[file]
            if what == "shuffle":
                perm = np.random.default_rng(payload).permutation(df.height)
            else:
                perm = np.arange(df.height)
                i, j = (k % max(df.height, 1) for k in payload)
                perm[[i, j]] = perm[[j, i]]
            tables[file] = df[perm]
            order = order[perm]
            valid = True  # judged below on the final order
        elif what == "inject":
            row, value = payload
            df = tables[file]
            if "value_mm" in df.columns and df["value_mm"].dtype == pl.Float64:
                vals = df["value_mm"].to_list()
                vals[row] = float(value)
                tables[file] = df.with_columns(pl.Series("value_mm", vals, dtype=pl.Float64))
                injected.add(int(order[row]))  # judged at the end: a later write may overwrite it
            valid = True
        elif what == "reorder_keys":
            meta = dict(reversed(list(meta.items())))
        elif what == "out_of_range":
            row, value = payload
            df = tables[file]
            if "value_mm" in df.columns and df["value_mm"].dtype == pl.Float64:
                vals = df["value_mm"].to_list()
                vals[row] = value
                tables[file] = df.with_columns(pl.Series("value_mm", vals, dtype=pl.Float64))
                injected.discard(int(order[row]))
        elif what == "truncate":
            raw_bytes[file] = None, payload
        if not valid:
            bad_files.add(file)
    if injected:
        bad_files.add("lds.parquet")
    # rows are distinct (sample, sensor) pairs: any net reordering breaks the sort
    if not np.array_equal(order, np.arange(len(order))):
        bad_files.add("lds.parquet")
    (scan_dir / "scan.json").write_text(json.dumps(meta))
    for f, df in tables.items():
        pq.write_table(df.to_arrow(), scan_dir / f)
    for f, b in raw_bytes.items():
        if isinstance(b, tuple):
            data = (scan_dir / f).read_bytes()
            b = data[: int(len(data) * b[1])]
        (scan_dir / f).write_bytes(b)
    return not bad_files, bad_files


@settings(max_examples=100, deadline=None, database=None, suppress_health_check=[HealthCheck.too_slow])
@given(muts=st.lists(mutation, min_size=1, max_size=2))
def test_mutated_scans_are_accepted_only_when_valid(base, muts):
    base_dir, base_scan = base
    with tempfile.TemporaryDirectory() as d:
        scan_dir = Path(d) / base_dir.parent.name / base_dir.name
        shutil.copytree(base_dir, scan_dir)
        valid, bad_files = _apply(scan_dir, muts)
        try:
            scan = read_scan(scan_dir)
        except ScanError as e:
            event("rejected")
            assert not valid, f"valid mutation rejected: {e}"
            assert e.scan_id == "P1"
            assert e.file in bad_files
            assert str(e).startswith(f"P1: {e.file}: ")
            assert validate_root(Path(d)), "read_scan rejects but validate_root finds nothing"
            return
        event("accepted")
        assert valid, f"invalid mutation {[(m[2], m[0]) for m in muts]} accepted"
        # accepted: the data are the original ones (bar out-of-range readings, which warn) and re-validate
        changed = scan.lds["value_mm"].ne_missing(base_scan.lds["value_mm"])
        assert scan.lds.filter(~changed).equals(base_scan.lds.filter(~changed), null_equal=True)
        n_out = int(((scan.lds["value_mm"] < 0) | (scan.lds["value_mm"] > 10)).sum())
        assert sum(int(w.split(": ")[2].split()[0]) for w in scan.warnings) == n_out
        assert n_out == int(changed.sum())
        assert scan.spindle.equals(base_scan.spindle, null_equal=True)
        np.testing.assert_array_equal(lds_matrix(scan).sample, lds_matrix(base_scan).sample)
        assert validate_root(Path(d)) == []
        assert read_scan(scan_dir).sha256 == scan.sha256


@settings(max_examples=200, deadline=None, database=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    muts=st.lists(mutation, min_size=1, max_size=3),
    rod=st.booleans(),
    spindle=st.booleans(),
    cuts=st.lists(st.integers(1, N * len(CHANS) - 1), max_size=4),
)
def test_fast_lds_check_agrees_with_the_full_check(base, muts, rod, spindle, cuts):
    """The fast path of the lds check returns exactly the full check's warnings when the table
    has no problem, and declines (None) whenever the full check finds one, both on the wide matrix
    (tables in the usual layout) and chunk by chunk; the table is cut into chunks at random rows
    (both paths work on the chunks as read, pairs across a cut included).
    """
    from borescan import rawio

    base_dir, _ = base
    with tempfile.TemporaryDirectory() as d:
        scan_dir = Path(d) / base_dir.parent.name / base_dir.name
        shutil.copytree(base_dir, scan_dir)
        _apply(scan_dir, muts)
        try:
            pf = pq.ParquetFile(scan_dir / "lds.parquet")
        except Exception:  # noqa: BLE001 - a truncated file never reaches the data checks
            return
        p = raw_meta._Problems("P1")
        if not raw_lds._check_schema(pf.schema_arrow, rawio.LDS_SCHEMA, p, "lds.parquet"):
            return
        table = pf.read(columns=rawio.LDS_SCHEMA.names)
        bounds = [0, *sorted({c for c in cuts if c < table.num_rows}), table.num_rows]
        table = pa.concat_tables([table.slice(a, b - a) for a, b in zip(bounds, bounds[1:])])
        if rod:  # a rod scan: poses per sample (valid) or null (invalid)
            pose = pl.Series(
                np.repeat(np.arange(table.num_rows // 3 + 1), 3)[: table.num_rows], dtype=pl.Int32
            )
            table = table.set_column(table.column_names.index("pose"), "pose", pose.to_arrow())
        meta = {**META, "device": {"id": "R", "type": "rod" if rod else "tri_lds"}}
        full = raw_lds._check_lds_full(table, meta, spindle, p, "lds.parquet")
        fast = raw_lds._lds_fast_check(table, meta, spindle, "lds.parquet")
        if p.errors:
            event("problem")
            assert fast is None
            assert raw_lds._lds_fast_check(table, meta, spindle, "lds.parquet", layout=False) is None
        else:
            event("clean, with warnings" if full else "clean")
            assert fast is not None and fast[0] == full
            assert raw_lds._lds_fast_check(table, meta, spindle, "lds.parquet", layout=False) == (full, None)
            if fast[1] is not None:  # checked on the wide matrix: it is the general long -> wide one
                event("usual layout")
                # a channel listed without rows forces the general scatter (its column all NaN)
                general = rawio.lds_matrix(SimpleNamespace(lds=pl.from_arrow(table), channels=(*CHANS, 99)))
                np.testing.assert_array_equal(fast[1].values_mm, general.values_mm[:, : len(CHANS)])
                for k in ("sample", "t_s", "pose"):
                    np.testing.assert_array_equal(getattr(fast[1], k), getattr(general, k))
