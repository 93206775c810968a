"""borescan-raw/1 reader, writer and validator (spec: raw-scan-format.md; issue 2 items 2, 4; issue 8)."""

from __future__ import annotations

import json
import os
import re
import shutil
from pathlib import Path

import numpy as np
import polars as pl
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from borescan import rawio
from borescan.cli import main
from borescan.rawio import ScanError, lds_matrix, read_scan, read_scan_meta, validate_root, write_scan

NIGHT = "2026-11-21"


def make_meta(scan_id="S1", night=NIGHT, device_type="tri_lds", chans=(1, 2, 3), range_mm=10.0):
    return {
        "format": "borescan-raw/1",
        "scan_id": scan_id,
        "night": night,
        "started_at": f"{night}T22:14:03Z",
        "kind": "calibration",
        "device": {"id": "TRI-01" if device_type == "tri_lds" else "ROD-01", "type": device_type},
        "sample_rate_hz": 625.0,
        "sensors": [{"channel": c, "model": "HG-C1030", "range_mm": range_mm} for c in chans],
        "artifact": {"id": "RG-275", "type": "ring_gauge", "certified_diameter_mm": 275.029},
        "acquisition": {"software": "test", "simulated": True},
        "extra_unknown_key": {"kept": [1, 2]},
    }


def make_lds(n=40, chans=(1, 2, 3), seed=0, rod=False, null_every=7):
    """Long lds frame: n samples x channels, some nulls, t_ns = 1.6 ms per sample."""
    rng = np.random.default_rng(seed)
    c = len(chans)
    value = rng.uniform(1.0, 9.0, n * c)
    value[::null_every] = np.nan
    pose = np.repeat(np.arange(n) // 10, c).astype(np.int32) if rod else None
    return pl.DataFrame(
        {
            "sample": np.repeat(np.arange(n, dtype=np.int64), c),
            "t_ns": np.repeat(np.arange(n, dtype=np.int64) * 1_600_000, c),
            "sensor": np.tile(np.array(chans, dtype=np.int16), n),
            "value_mm": pl.Series(value, nan_to_null=True),
            "pose": pl.Series(pose, dtype=pl.Int32) if rod else pl.Series([None] * (n * c), dtype=pl.Int32),
        }
    )


def make_spindle(n=40):
    t = np.arange(n, dtype=np.int64) * 1_600_000
    ang = t * 1e-9 * 2 * np.pi
    return pl.DataFrame(
        {
            "t_ns": t,
            "angle_rad": pl.Series(np.where(np.arange(n) == 3, np.nan, ang), nan_to_null=True),
            "x_mm": np.full(n, 262.955),
            "y_mm": np.full(n, -275.502),
            "rpm": np.full(n, 60.0),
        }
    )


@pytest.fixture
def root(tmp_path):
    r = tmp_path / "raw"
    r.mkdir()
    return r


@pytest.fixture
def scan_dir(root):
    return write_scan(root, make_meta(), make_lds(), make_spindle())


def rewrite_json(scan_dir: Path, fn):
    meta = json.loads((scan_dir / "scan.json").read_text())
    fn(meta)  # mutates in place
    (scan_dir / "scan.json").write_text(json.dumps(meta))


def rewrite_parquet(path: Path, fn):
    df = pl.from_arrow(pq.read_table(path))
    out = fn(df)
    table = out if isinstance(out, pa.Table) else out.to_arrow()
    pq.write_table(table, path)


def expect(scan_dir, file, match):
    with pytest.raises(ScanError, match=match) as ei:
        read_scan(scan_dir)
    e = ei.value
    assert e.scan_id == "S1"
    assert e.file == file
    assert str(e).startswith(f"S1: {file}: ")
    assert e.problem in str(e)
    return e


# --------------------------------------------------------------------------------------------
# round trip


def test_round_trip_every_column_dtype_nulls_and_layout(root):
    meta, lds, sp = make_meta(), make_lds(), make_spindle()
    path = write_scan(root, meta, lds, sp)
    assert path == root / f"night={NIGHT}" / "scan=S1"
    assert sorted(p.name for p in path.iterdir()) == ["lds.parquet", "scan.json", "spindle.parquet"]
    scan = read_scan(path)
    assert (scan.scan_id, scan.night, scan.path) == ("S1", NIGHT, path)
    assert scan.meta == meta  # unknown keys preserved as read
    assert scan.lds.schema == pl.Schema(
        {"sample": pl.Int64, "t_ns": pl.Int64, "sensor": pl.Int16, "value_mm": pl.Float64, "pose": pl.Int32}
    )
    assert scan.lds.equals(lds, null_equal=True)
    assert scan.lds["value_mm"].null_count() == lds["value_mm"].null_count() == 18
    assert scan.lds["pose"].null_count() == 120
    assert scan.spindle.schema == pl.Schema(
        {"t_ns": pl.Int64, "angle_rad": pl.Float64, "x_mm": pl.Float64, "y_mm": pl.Float64, "rpm": pl.Float64}
    )
    assert scan.spindle.equals(sp, null_equal=True)
    assert scan.spindle["angle_rad"].null_count() == 1
    assert scan.sha256 == {
        n: rawio.sha256_file(path / n) for n in ("scan.json", "lds.parquet", "spindle.parquet")
    }
    assert all(len(h) == 64 for h in scan.sha256.values())
    assert scan.warnings == []
    assert not [p for p in path.parent.iterdir() if p.name.startswith(".")]  # no temp folder left


def test_round_trip_rod_without_spindle_and_hive_read(root):
    write_scan(root, make_meta(), make_lds(), make_spindle())
    path = write_scan(root, make_meta("R1", device_type="rod", chans=(1, 2)), make_lds(30, (1, 2), rod=True))
    scan = read_scan(path)
    assert scan.spindle is None and set(scan.sha256) == {"scan.json", "lds.parquet"}
    m = lds_matrix(scan)
    np.testing.assert_array_equal(m.pose, np.arange(30) // 10)
    both = pl.read_parquet(root / "**" / "lds.parquet", hive_partitioning=True)
    assert both.group_by("scan").len().sort("scan").rows() == [("R1", 60), ("S1", 120)]


def test_write_casts_losslessly_and_drops_extra_columns(root):
    lds = make_lds().with_columns(pl.col("sensor").cast(pl.Int64), extra=pl.lit("x"))
    scan = read_scan(write_scan(root, make_meta(), lds))
    assert scan.lds["sensor"].dtype == pl.Int16 and scan.lds.columns == list(rawio.LDS_SCHEMA.names)
    bad = make_lds().with_columns(pl.col("sensor").cast(pl.Int64) * 100_000)
    with pytest.raises(ScanError, match="cannot be stored as int16"):
        write_scan(root, make_meta("S2"), bad)


def test_lds_matrix_wide_nan_and_channel_order(root):
    # sensors listed out of order; sample 2 has no row for channel 3; channel 2 null at sample 0
    lds = pl.DataFrame(
        {
            "sample": [0, 0, 0, 1, 1, 1, 2, 2, 5, 5, 5],
            "t_ns": [0, 0, 0, 10, 10, 10, 25, 25, 90, 90, 90],
            "sensor": [1, 2, 3, 1, 2, 3, 1, 2, 1, 2, 3],
            "value_mm": [1.5, None, 3.25, 4.0, 5.0, 6.0, 7.0, 8.0, 9.0, 10.0, 11.0],
            "pose": pl.Series([None] * 11, dtype=pl.Int32),
        }
    )
    meta = make_meta()
    meta["sensors"] = meta["sensors"][::-1]
    scan = read_scan(write_scan(root, meta, lds))
    m = lds_matrix(scan)
    assert m.channels == (1, 2, 3)
    np.testing.assert_array_equal(m.sample, [0, 1, 2, 5])
    np.testing.assert_array_equal(m.t_s, [0.0, 10e-9, 25e-9, 90e-9])
    expected = np.array([[1.5, np.nan, 3.25], [4, 5, 6], [7, 8, np.nan], [9, 10, 11]])
    np.testing.assert_array_equal(m.values_mm, expected)
    np.testing.assert_array_equal(m.channel(3), expected[:, 2])
    np.testing.assert_array_equal(m.pose, [-1, -1, -1, -1])


def test_lds_matrix_reshape_path_equals_general_path():
    """The usual layout (every channel on every sample, sorted) takes a reshape; it must give
    what the general scatter gives, poses (first non-null of a sample) included.
    """
    from types import SimpleNamespace

    rng = np.random.default_rng(3)
    n, chans = 500, (1, 2, 4)
    pose = np.where(rng.random(n * 3) < 0.3, -1, np.repeat(np.arange(n) // 50, 3))
    full = pl.DataFrame(
        {
            "sample": np.repeat(np.arange(n) * 2, 3),
            "t_ns": np.repeat(np.arange(n) * 2000, 3),
            "sensor": np.tile(chans, n).astype(np.int16),
            "value_mm": pl.Series(rng.uniform(0, 10, n * 3)).fill_nan(None).scatter([5, 77], None),
            "pose": pl.Series(pose, dtype=pl.Int32).set(pl.Series(pose < 0), None),
        }
    )
    fast = lds_matrix(SimpleNamespace(lds=full, channels=chans))
    # one extra row of an unlisted-by-data channel forces the general path; drop its column after
    extra = pl.concat([full, full.tail(1).with_columns(pl.lit(9, dtype=pl.Int16).alias("sensor"))])
    general = lds_matrix(SimpleNamespace(lds=extra, channels=chans))
    assert fast.channels == chans and general.channels == (*chans, 9)
    np.testing.assert_array_equal(fast.values_mm, general.values_mm[:, :3])
    np.testing.assert_array_equal(fast.sample, general.sample)
    np.testing.assert_array_equal(fast.t_s, general.t_s)
    np.testing.assert_array_equal(fast.pose, general.pose)
    assert np.isnan(fast.values_mm).sum() == 2 and (fast.pose >= 0).sum() > 0.9 * n


def test_lds_matrix_from_chunks_not_aligned_to_samples():
    """The reshape path copies straight from the Arrow chunks; chunks that split a sample's rows,
    chunks that start at an offset and nulls in several chunks must give the general path's result,
    and a group whose rows disagree on the sample must fall back to the general path.
    """
    from types import SimpleNamespace

    rng = np.random.default_rng(8)
    n, chans = 700, (2, 3, 5)
    full = pl.DataFrame(
        {
            "sample": np.repeat(np.arange(n) + 10, 3),
            "t_ns": np.repeat(np.arange(n) * 1515, 3),
            "sensor": np.tile(chans, n).astype(np.int16),
            "value_mm": pl.Series(rng.uniform(0, 10, n * 3)).scatter([0, 4, 500, 1000, 2099], None),
            "pose": pl.Series([None] * (n * 3), dtype=pl.Int32),
        }
    )
    big = pl.concat([full.head(7), full], rechunk=True).slice(7)  # one chunk starting at an offset
    cuts = [0, 1, 301, 302, 1000, 1501, 2100]  # 1, 300, 1, 698, 501, 599 rows: no chunk a whole sample
    chunked = pl.concat([big.slice(a, b - a) for a, b in zip(cuts, cuts[1:])], rechunk=False)
    assert chunked["value_mm"].n_chunks() == 6
    extra = pl.concat([full, full.tail(1).with_columns(pl.lit(9, dtype=pl.Int16).alias("sensor"))])
    general = lds_matrix(SimpleNamespace(lds=extra, channels=chans))
    for frame in (full, big, chunked):
        assert rawio.matrix._lds_matrix_reshaped(frame, chans) is not None  # the chunk path applies
        m = lds_matrix(SimpleNamespace(lds=frame, channels=chans))
        np.testing.assert_array_equal(m.values_mm, general.values_mm[:, :3])
        np.testing.assert_array_equal(m.sample, general.sample)
        np.testing.assert_array_equal(m.t_s, general.t_s)
        np.testing.assert_array_equal(m.pose, general.pose)
    assert np.isnan(general.values_mm[:, :3]).sum() == 5
    # channel 5 lags one sample from sample 11 on: every sample still has three rows (2, 3, 5), but
    # their samples disagree; the general scatter must decide (one more sample, with channel 5 only)
    lag = (pl.col("sensor") == 5) & (pl.int_range(pl.len()) >= 5)
    odd = chunked.with_columns(sample=pl.when(lag).then(pl.col("sample") + 1).otherwise(pl.col("sample")))
    assert rawio.matrix._lds_matrix_reshaped(odd, chans) is None
    m = lds_matrix(SimpleNamespace(lds=odd, channels=chans))
    assert m.values_mm.shape == (n + 1, 3)
    assert np.isnan(m.values_mm[1, 2]) and np.isnan(m.values_mm[-1, :2]).all()
    np.testing.assert_array_equal(m.values_mm[2:, 2], general.values_mm[1:, 2])


def test_out_of_range_readings_are_warnings_not_errors(root):
    lds = make_lds(null_every=1000).with_columns(
        value_mm=pl.when((pl.col("sensor") == 2) & (pl.col("sample") < 3))
        .then(10.5)
        .when((pl.col("sensor") == 3) & (pl.col("sample") == 7))
        .then(-0.2)
        .otherwise(pl.col("value_mm"))
    )
    scan = read_scan(write_scan(root, make_meta(), lds))
    assert scan.warnings == [
        "lds.parquet: channel 2: 3 readings outside [0, 10] mm",
        "lds.parquet: channel 3: 1 readings outside [0, 10] mm",
    ]


# --------------------------------------------------------------------------------------------
# write-once and atomicity


def test_write_same_content_is_noop_different_content_refused(root):
    path = write_scan(root, make_meta(), make_lds(), make_spindle())
    before = {p.name: (rawio.sha256_file(p), p.stat().st_mtime_ns) for p in path.iterdir()}
    assert write_scan(root, make_meta(), make_lds(), make_spindle()) == path
    with pytest.raises(FileExistsError, match="write-once"):
        write_scan(root, make_meta(), make_lds(seed=1), make_spindle())
    with pytest.raises(FileExistsError, match="another night"):
        write_scan(root, make_meta(night="2026-11-22"), make_lds())
    assert {p.name: (rawio.sha256_file(p), p.stat().st_mtime_ns) for p in path.iterdir()} == before
    assert [p.name for p in path.parent.iterdir()] == ["scan=S1"]
    assert [p.name for p in root.iterdir()] == [f"night={NIGHT}"]


def test_write_rejects_invalid_data_and_writes_nothing(root):
    with pytest.raises(ScanError, match="channel 4 is not listed") as ei:
        write_scan(root, make_meta(), make_lds(chans=(1, 2, 3, 4)))
    assert ei.value.file == "lds.parquet"
    with pytest.raises(ScanError, match="does not match") as ei:
        write_scan(root, make_meta(scan_id="../evil"), make_lds())
    assert ei.value.file == "scan.json"
    assert list(root.iterdir()) == []
    assert not (root.parent / "evil").exists()


def test_reading_never_changes_raw_bytes(scan_dir):
    before = {
        p.name: (rawio.sha256_file(p), p.stat().st_mtime_ns, p.stat().st_size) for p in scan_dir.iterdir()
    }
    for _ in range(2):
        scan = read_scan(scan_dir)
        lds_matrix(scan)
        read_scan_meta(scan_dir)
    validate_root(scan_dir.parent.parent)
    after = {
        p.name: (rawio.sha256_file(p), p.stat().st_mtime_ns, p.stat().st_size) for p in scan_dir.iterdir()
    }
    assert after == before
    assert scan.sha256 == {k: v[0] for k, v in before.items()}


# --------------------------------------------------------------------------------------------
# every reader error: scan.json


def test_missing_files(scan_dir):
    (scan_dir / "lds.parquet").unlink()
    expect(scan_dir, "lds.parquet", "missing")
    (scan_dir / "scan.json").unlink()
    expect(scan_dir, "scan.json", "missing")


@pytest.mark.parametrize(
    "content, match",
    [
        (b'{"format": "borescan-raw/1",', "invalid JSON"),
        (b"\xff\xfe{}", "not UTF-8"),
        (b"[1, 2]", "top level must be a JSON object, not array"),
        (b'{"sample_rate_hz": NaN}', "invalid JSON: non-standard JSON constant NaN"),
        (b'{"scan_id": "S1", "scan_id": "S1"}', "duplicate key 'scan_id'"),
    ],
)
def test_unreadable_json(scan_dir, content, match):
    (scan_dir / "scan.json").write_bytes(content)
    expect(scan_dir, "scan.json", match)


@pytest.mark.parametrize(
    "path",
    [
        "format",
        "scan_id",
        "night",
        "started_at",
        "kind",
        "device",
        "sample_rate_hz",
        "sensors",
        "artifact",
        "device.id",
        "device.type",
        "artifact.id",
        "artifact.type",
        "sensors.0.channel",
    ],
)
def test_missing_required_key(scan_dir, path):
    def drop(meta):
        *parents, last = path.split(".")
        node = meta
        for k in parents:
            node = node[int(k)] if k.isdigit() else node[k]
        del node[int(last) if last.isdigit() else last]

    rewrite_json(scan_dir, drop)
    name = re.escape(path.replace(".0.", "[0]."))
    expect(scan_dir, "scan.json", f"missing required key '{name}'")


@pytest.mark.parametrize(
    "key, value, match",
    [
        ("format", 1, "key 'format' must be a JSON string, got integer"),
        ("format", "borescan-raw/2", "unknown format 'borescan-raw/2'"),
        ("scan_id", 5, "key 'scan_id' must be a JSON string"),
        ("scan_id", "a/b", r"scan_id 'a/b' does not match \[A-Za-z0-9_-\]\{1,64\}"),
        ("scan_id", "..", "does not match"),
        ("scan_id", "S" * 65, "does not match"),
        ("scan_id", "S2", "scan_id 'S2' differs from the folder name scan=S1"),
        ("night", "2026-11-22", "night '2026-11-22' differs from the folder name night=2026-11-21"),
        ("night", "2026-13-01", "night '2026-13-01' is not a date YYYY-MM-DD"),
        ("night", "21.11.2026", "is not a date YYYY-MM-DD"),
        ("started_at", "yesterday evening", "is not an ISO 8601 date-time"),
        ("started_at", "2026-11-21T22:14:03", "must be UTC"),
        ("started_at", "2026-11-21T22:14:03+01:00", "must be UTC"),
        ("kind", "bogus", "kind 'bogus' not one of calibration, centering, verification, measurement"),
        ("device", "TRI-01", "key 'device' must be a JSON object, got string"),
        ("sample_rate_hz", "625", "key 'sample_rate_hz' must be a finite number, got string"),
        ("sample_rate_hz", True, "must be a finite number, got boolean"),
        ("sample_rate_hz", 0, "sample_rate_hz must be > 0, got 0"),
        ("sample_rate_hz", -625.0, "sample_rate_hz must be > 0"),
        ("sensors", {"channel": 1}, "key 'sensors' must be a JSON array, got object"),
        ("sensors", [], "sensors is empty"),
        ("artifact", None, "key 'artifact' must be a JSON object, got null"),
        ("spindle", [1], "key 'spindle' must be a JSON object, got array"),
        ("acquisition", {"simulated": "yes"}, "key 'acquisition.simulated' must be a JSON boolean"),
    ],
)
def test_bad_json_values(scan_dir, key, value, match):
    rewrite_json(scan_dir, lambda m: m.__setitem__(key, value))
    expect(scan_dir, "scan.json", match)


def test_infinite_rate_and_bad_enums_and_sensors(scan_dir):
    (scan_dir / "scan.json").write_text(
        (scan_dir / "scan.json").read_text().replace('"sample_rate_hz": 625.0', '"sample_rate_hz": 1e999')
    )
    expect(scan_dir, "scan.json", "sample_rate_hz' must be a finite number")
    rewrite_json(scan_dir, lambda m: m.update(sample_rate_hz=625.0, device={"id": "T", "type": "laser"}))
    expect(scan_dir, "scan.json", "device.type 'laser' not one of tri_lds, rod")
    rewrite_json(
        scan_dir, lambda m: m.update(device={"id": "T", "type": "rod"}, artifact={"id": "A", "type": "cup"})
    )
    expect(scan_dir, "scan.json", "artifact.type 'cup' not one of ring_gauge, part")
    rewrite_json(scan_dir, lambda m: m.update(artifact={"id": "A", "type": "part"}))
    expect(scan_dir, "lds.parquet", r"pose is null in 120 rows \(first at row 0\); rod scans need it")
    rewrite_json(
        scan_dir,
        lambda m: m.update(device={"id": "T", "type": "tri_lds"}, sensors=[{"channel": 1}, {"channel": 1}]),
    )
    expect(scan_dir, "scan.json", "channel 1 listed twice in sensors")
    rewrite_json(scan_dir, lambda m: m.update(sensors=[{"channel": 0}]))
    expect(scan_dir, "scan.json", r"sensors\[0\].channel must be in 1..32767, got 0")
    rewrite_json(scan_dir, lambda m: m.update(sensors=[{"channel": 1.0}]))
    expect(scan_dir, "scan.json", r"key 'sensors\[0\].channel' must be a JSON integer, got number")
    rewrite_json(scan_dir, lambda m: m.update(sensors=[{"channel": 1, "range_mm": -3}]))
    expect(scan_dir, "scan.json", r"sensors\[0\].range_mm must be > 0")


def test_extra_keys_and_columns_are_ignored(scan_dir):
    rewrite_json(
        scan_dir, lambda m: m.update(vendor_blob={"x": [1, None]}, device={**m["device"], "firmware": 3})
    )
    rewrite_parquet(scan_dir / "lds.parquet", lambda df: df.with_columns(intensity=pl.lit(0.5)))
    rewrite_parquet(scan_dir / "spindle.parquet", lambda df: df.with_columns(torque=pl.lit(1)))
    scan = read_scan(scan_dir)
    assert scan.lds.columns == ["sample", "t_ns", "sensor", "value_mm", "pose"]
    assert scan.spindle.columns == ["t_ns", "angle_rad", "x_mm", "y_mm", "rpm"]
    assert scan.meta["vendor_blob"] == {"x": [1, None]}


# --------------------------------------------------------------------------------------------
# every reader error: lds.parquet


def test_truncated_and_corrupt_parquet(scan_dir):
    data = (scan_dir / "lds.parquet").read_bytes()
    (scan_dir / "lds.parquet").write_bytes(data[: len(data) // 2])
    expect(scan_dir, "lds.parquet", r"not a readable Parquet file \(truncated or corrupt\)")
    (scan_dir / "lds.parquet").write_bytes(b"")
    expect(scan_dir, "lds.parquet", "truncated or corrupt")
    (scan_dir / "lds.parquet").write_bytes(b"PAR1" + os.urandom(200) + b"PAR1")
    expect(scan_dir, "lds.parquet", "truncated or corrupt")


@pytest.mark.parametrize("col", ["sample", "t_ns", "sensor", "value_mm", "pose"])
def test_missing_column(scan_dir, col):
    rewrite_parquet(scan_dir / "lds.parquet", lambda df: df.drop(col))
    expect(scan_dir, "lds.parquet", f"missing column '{col}'")


@pytest.mark.parametrize(
    "col, dtype, match",
    [
        ("sample", pl.Int32, "column 'sample' has dtype int32, expected int64"),
        ("t_ns", pl.Float64, "column 't_ns' has dtype double, expected int64"),
        ("sensor", pl.Int64, "column 'sensor' has dtype int64, expected int16"),
        ("value_mm", pl.Float32, "column 'value_mm' has dtype float, expected double"),
        ("pose", pl.Int64, "column 'pose' has dtype int64, expected int32"),
        ("value_mm", pl.String, "column 'value_mm' has dtype large_string, expected double"),
    ],
)
def test_wrong_dtype(scan_dir, col, dtype, match):
    rewrite_parquet(scan_dir / "lds.parquet", lambda df: df.with_columns(pl.col(col).cast(dtype)))
    expect(scan_dir, "lds.parquet", match)


def _set(df, row, col, value):
    s = df[col].to_list()
    s[row] = value
    return df.with_columns(pl.Series(col, s, dtype=df[col].dtype))


@pytest.mark.parametrize(
    "mutate, match",
    [
        (lambda df: df.head(0), "no rows"),
        (lambda df: _set(df, 4, "sample", None), "column 'sample' has 1 null values"),
        (lambda df: _set(df, 4, "sensor", None), "column 'sensor' has 1 null values"),
        (lambda df: df.with_columns(pl.col("sample") - 1), "negative sample at row 0"),
        (
            lambda df: pl.concat([df.slice(6, 3), df.slice(0, 6), df.slice(9)]),
            r"sample is non-monotonic: decreases at row 3 \(2 -> 0\)",
        ),
        (
            lambda df: pl.concat([df.slice(0, 3), df.slice(3, 3).reverse(), df.slice(6)]),
            r"rows not sorted by \(sample, sensor\): row 4 has sensor 2 after 3",
        ),
        (lambda df: _set(df, 4, "sensor", 1), r"duplicate \(sample, sensor\) = \(1, 1\) at row 4"),
        (lambda df: _set(df, 5, "sensor", 2), r"duplicate \(sample, sensor\) = \(1, 2\) at row 5"),
        (lambda df: _set(df, 4, "t_ns", 1_600_001), r"t_ns differs within sample 1 \(1600000 vs 1600001\)"),
        (
            lambda df: df.with_columns(t_ns=pl.when(pl.col("sample") == 5).then(0).otherwise(pl.col("t_ns"))),
            r"t_ns is non-monotonic: sample 4 -> 5 has t_ns 6400000 -> 0",
        ),
        (lambda df: df.with_columns(t_ns=pl.col("t_ns") - 5), "negative t_ns at row 0"),
        (
            lambda df: df.with_columns(
                sensor=pl.when(pl.col("sensor") == 3).then(4).otherwise(pl.col("sensor"))
            ),
            "channel 4 is not listed in scan.json sensors",
        ),
        (lambda df: df.filter(pl.col("sensor") != 2), "channel 2 has no valid readings"),
        (
            lambda df: df.with_columns(
                value_mm=pl.when(pl.col("sensor") == 3).then(None).otherwise(pl.col("value_mm"))
            ),
            "channel 3 has no valid readings",
        ),
        (
            lambda df: _set(df, 8, "value_mm", float("nan")),
            r"value_mm has 1 NaN/inf values \(first at row 8\)",
        ),
        (lambda df: _set(df, 9, "value_mm", float("-inf")), "value_mm has 1 NaN/inf values"),
        (
            lambda df: _set(df, 9, "pose", 0),
            r"pose must be null on tri_lds spindle scans \(non-null at row 9\)",
        ),
    ],
)
def test_bad_lds_rows(scan_dir, mutate, match):
    rewrite_parquet(scan_dir / "lds.parquet", mutate)
    expect(scan_dir, "lds.parquet", match)


def test_rod_pose_rules_and_static_tri_pose_allowed(root):
    rod = write_scan(root, make_meta("S1", device_type="rod"), make_lds(rod=True))
    rewrite_parquet(rod / "lds.parquet", lambda df: _set(df, 7, "pose", None))
    expect(rod, "lds.parquet", r"pose is null in 1 rows \(first at row 7\)")
    rewrite_parquet(rod / "lds.parquet", lambda df: _set(df, 7, "pose", 1))
    expect(rod, "lds.parquet", "pose differs within sample 2")
    rewrite_parquet(rod / "lds.parquet", lambda df: df.with_columns(pose=pl.lit(-1, dtype=pl.Int32)))
    expect(rod, "lds.parquet", "negative pose at row 0")
    # a static tri_lds scan (no spindle.parquet) may index its stops with pose
    static = write_scan(root, make_meta("T1"), make_lds(rod=True))
    assert read_scan(static).lds["pose"].null_count() == 0


# --------------------------------------------------------------------------------------------
# spindle.parquet


@pytest.mark.parametrize(
    "mutate, match",
    [
        (lambda df: df.drop("rpm"), "missing column 'rpm'"),
        (
            lambda df: df.with_columns(pl.col("x_mm").cast(pl.Float32)),
            "column 'x_mm' has dtype float, expected double",
        ),
        (lambda df: df.with_columns(pl.col("t_ns").cast(pl.Int32)), "column 't_ns' has dtype int32"),
        (lambda df: df.head(0), "no rows"),
        (lambda df: _set(df, 10, "t_ns", 0), r"t_ns is non-monotonic at row 10 \(14400000 -> 0\)"),
        (lambda df: _set(df, 2, "rpm", None), "column 'rpm' has 1 null values"),
        (lambda df: _set(df, 2, "y_mm", float("nan")), r"y_mm has 1 NaN/inf values \(first at row 2\)"),
        (lambda df: _set(df, 5, "angle_rad", float("inf")), "angle_rad has 1 NaN/inf values"),
    ],
)
def test_bad_spindle(scan_dir, mutate, match):
    rewrite_parquet(scan_dir / "spindle.parquet", mutate)
    expect(scan_dir, "spindle.parquet", match)


def test_truncated_spindle(scan_dir):
    data = (scan_dir / "spindle.parquet").read_bytes()
    (scan_dir / "spindle.parquet").write_bytes(data[:-10])
    expect(scan_dir, "spindle.parquet", "truncated or corrupt")


# --------------------------------------------------------------------------------------------
# folders and paths


def test_symlinks_leaving_the_raw_root_are_rejected(tmp_path, root):
    outside = write_scan(tmp_path / "elsewhere", make_meta(), make_lds(), make_spindle())
    link = root / f"night={NIGHT}" / "scan=S1"
    link.parent.mkdir()
    link.symlink_to(outside, target_is_directory=True)
    with pytest.raises(ScanError, match="outside the raw root") as ei:
        read_scan(link)
    assert ei.value.scan_id == "S1" and ei.value.file == f"night={NIGHT}/scan=S1"
    # a real folder whose lds.parquet is a symlink to a file outside
    inside = write_scan(root, make_meta("S2"), make_lds(), make_spindle())
    (inside / "lds.parquet").unlink()
    (inside / "lds.parquet").symlink_to(outside / "lds.parquet")
    with pytest.raises(ScanError, match="lds.parquet: resolves to .*, outside the raw root"):
        read_scan(inside)
    problems = validate_root(root)
    assert {(e.scan_id, e.file) for e in problems} == {
        ("S1", f"night={NIGHT}/scan=S1"),
        ("S2", "lds.parquet"),
    }


def test_bad_folder_names(root, scan_dir):
    dotdot = scan_dir.parent / "scan=.."
    dotdot.mkdir()
    with pytest.raises(ScanError, match=r"folder scan_id '\.\.' does not match"):
        read_scan(dotdot)
    flat = root / "flat"
    shutil.copytree(scan_dir, flat)
    with pytest.raises(ScanError, match=r"folder is not <raw_root>/night=<YYYY-MM-DD>/scan=<scan_id>"):
        read_scan(flat)


def test_read_scan_meta_reads_only_json(scan_dir):
    (scan_dir / "lds.parquet").write_bytes(b"garbage")
    meta = read_scan_meta(scan_dir)
    assert meta["scan_id"] == "S1" and meta["device"]["type"] == "tri_lds"
    rewrite_json(scan_dir, lambda m: m.pop("kind"))
    with pytest.raises(ScanError, match="S1: scan.json: missing required key 'kind'"):
        read_scan_meta(scan_dir)


# --------------------------------------------------------------------------------------------
# validate_root and the CLI


def _tree(root):
    # measurements: a calibration scan this short (and a rod calibration without design layers) would be
    # valid raw data that validate reports as to be set aside by the calibrate stage
    write_scan(root, {**make_meta("A1"), "kind": "measurement"}, make_lds(), make_spindle())
    write_scan(
        root,
        {**make_meta("B1", night="2026-11-22", device_type="rod"), "kind": "measurement"},
        make_lds(rod=True),
    )
    return root


def test_discover_scans_sorted(root):
    write_scan(root, make_meta("Z9", night="2026-11-20"), make_lds())
    _tree(root)
    assert [(p.parent.name, p.name) for p in rawio.discover_scans(root)] == [
        ("night=2026-11-20", "scan=Z9"),
        (f"night={NIGHT}", "scan=A1"),
        ("night=2026-11-22", "scan=B1"),
    ]


def test_validate_cli_all_valid(root, capsys):
    _tree(root)
    assert main(["validate", str(root)]) == 0
    out = capsys.readouterr().out.splitlines()
    # valid; the notes say what a later stage will do without the optional device.nominal
    assert out[-1] == "2 scans, all valid (see the notes)"
    assert [line.split(":")[0] for line in out[:-1]] == ["A1", "B1"]
    assert all("note: discrepancy: no device.nominal" in line for line in out[:-1])


def test_validate_collects_every_problem_and_cli_prints_them(root, capsys):
    _tree(root)
    a1 = root / f"night={NIGHT}" / "scan=A1"
    rewrite_json(a1, lambda m: m.update(kind="bogus", sample_rate_hz=-1))
    rewrite_parquet(a1 / "spindle.parquet", lambda df: df.drop("x_mm"))
    # same scan id again under another night
    shutil.copytree(root / "night=2026-11-22" / "scan=B1", root / "night=2026-11-23" / "scan=B1")
    rewrite_json(
        root / "night=2026-11-23" / "scan=B1",
        lambda m: m.update(night="2026-11-23", started_at="2026-11-23T22:14:03Z"),
    )
    (root / "notes").mkdir()
    (root / f"night={NIGHT}" / "tmp-export").mkdir()
    (root / "night=yesterday").mkdir()
    (root / ".hidden").mkdir()
    errors = validate_root(root)
    lines = [str(e) for e in errors]
    assert lines == [
        "-: night=2026-11-21/tmp-export: not a scan=<scan_id> folder",
        "-: night=yesterday: folder night is not a date YYYY-MM-DD; its scans are not processed",
        "-: notes: not a night=<YYYY-MM-DD> folder",
        "A1: scan.json: kind 'bogus' not one of calibration, centering, verification, measurement",
        "A1: scan.json: sample_rate_hz must be > 0, got -1",
        "A1: spindle.parquet: missing column 'x_mm' (double)",
        "B1: night=2026-11-23/scan=B1: scan_id also used in night=2026-11-22 (scan ids are unique "
        "across nights)",
    ]
    # the command runs the ingest checks (borescan.validation): the duplicate is named as ingest names it
    assert main(["validate", str(root)]) == 1
    out = capsys.readouterr()
    assert out.out.splitlines() == lines[:-1] + [
        "B1: scan.json: scan_id already used by a scan of night=2026-11-22 (scan ids are unique across "
        "nights)"
    ]
    assert "7 problems; of 3 scans 2 invalid (set aside at ingest)" in out.err


def test_validate_missing_root_is_a_usage_error(tmp_path, capsys):
    assert validate_root(tmp_path / "nope")[0].problem == "raw root does not exist or is not a folder"
    assert main(["validate", str(tmp_path / "nope")]) == 2
    out = capsys.readouterr()
    assert out.out == ""
    assert out.err == f"borescan validate: raw root {tmp_path / 'nope'} does not exist\n"


def test_validate_cli_out_of_range_readings_are_problems(root, capsys):
    """validate_root (the format alone) only warns; the command, like ingest, rejects the scan."""
    lds = make_lds(null_every=1000).with_columns(
        value_mm=pl.when(pl.col("sample") < 2).then(12.0).otherwise(pl.col("value_mm"))
    )
    write_scan(root, make_meta(), lds)
    assert validate_root(root) == []
    assert main(["validate", str(root), "--warnings"]) == 1  # the old flag is still accepted
    out = capsys.readouterr()
    assert out.out.splitlines() == [
        f"S1: lds.parquet: channel {c}: 2 readings outside [0, 10] mm (a sensor reports null when out "
        "of range)"
        for c in (1, 2, 3)
    ]
    assert out.err.startswith("3 problems; of 1 scans 1 invalid (set aside at ingest)")


def test_lds_fast_check_on_columns_chunked_differently():
    """Columns whose Arrow chunks do not line up are checked as one chunk each: same warnings as the
    full check (a reading above the range), and a decreasing sample is still declined.
    """
    lds = make_lds(n=40)
    vals = lds["value_mm"].to_list()
    vals[5] = 12.5  # above the 10 mm range: a warning, not a problem
    lds = lds.with_columns(pl.Series("value_mm", vals, dtype=pl.Float64))
    tab = lds.to_arrow().select(rawio.LDS_SCHEMA.names).cast(rawio.LDS_SCHEMA)

    def rechunk(t: pa.Table, name: str, at: int) -> pa.Table:
        col = t.column(name).combine_chunks()
        return t.set_column(t.column_names.index(name), name, pa.chunked_array([col[:at], col[at:]]))

    tab = rechunk(rechunk(tab, "sample", 50), "value_mm", 17)
    assert [len(c) for c in tab.column("sample").chunks] != [len(c) for c in tab.column("value_mm").chunks]
    meta = make_meta()
    p = rawio.meta._Problems("S1")
    full = rawio.lds._check_lds_full(tab, meta, True, p, "lds.parquet")
    assert not p.errors and full == ["lds.parquet: channel 3: 1 readings outside [0, 10] mm"]
    warnings, mat = rawio.lds._lds_fast_check(
        tab, meta, True, "lds.parquet"
    )  # the usual layout: on the matrix
    assert warnings == full and mat is not None and mat.values_mm[5 // 3, 5 % 3] == 12.5
    listed = rawio.lds._listed_sensors(meta)
    assert rawio.lds._lds_chunk_warnings(tab, listed, "lds.parquet") == full  # and chunk by chunk
    sample = tab.column("sample").combine_chunks().to_numpy().copy()
    sample[60] = 0
    bad = tab.set_column(0, "sample", pa.chunked_array([sample[:50], sample[50:]]))
    assert rawio.lds._lds_fast_check(bad, meta, True, "lds.parquet") is None
    assert rawio.lds._lds_chunk_warnings(bad, listed, "lds.parquet") is None


def test_read_scan_keeps_the_matrix_its_check_built(root):
    """read_scan's check builds the wide matrix of a usual-layout table; lds_matrix(scan) returns
    that one (read-only, the same object every call), equal to the general long -> wide scatter;
    a scan whose lds frame was replaced gets a matrix of its own frame, not the stored one.
    """
    import dataclasses
    from types import SimpleNamespace

    scan = read_scan(write_scan(root, make_meta(), make_lds(), make_spindle()))
    m = lds_matrix(scan)
    assert lds_matrix(scan) is m
    for a in (m.sample, m.t_s, m.values_mm, m.pose):
        assert not a.flags.writeable
    with pytest.raises(ValueError, match="read-only"):
        m.values_mm[0, 0] = 1.0
    # a channel listed without rows forces the general scatter (its column all NaN)
    general = lds_matrix(SimpleNamespace(lds=scan.lds, channels=(1, 2, 3, 99)))
    np.testing.assert_array_equal(m.values_mm, general.values_mm[:, :3])
    np.testing.assert_array_equal(m.t_s, general.t_s)
    np.testing.assert_array_equal(m.sample, general.sample)
    assert np.isnan(m.values_mm).sum() == scan.lds["value_mm"].null_count() > 0
    other = dataclasses.replace(scan, lds=scan.lds.with_columns(pl.col("value_mm") + 1.0))
    m2 = lds_matrix(other)
    assert m2 is not m
    np.testing.assert_allclose(m2.values_mm, m.values_mm + 1.0)
