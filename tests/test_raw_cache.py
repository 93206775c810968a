"""Raw files parsed once per scan per night (issue 34 item 4): the reader's cache and the readings store.

Bound of the design: within one process (one stage job or one of its workers) each raw file of a
night is parsed at most once while it is unchanged on disk; ingest is the only stage that reads raw
files (it stores what it validated, :mod:`borescan.rawio.store`), so a night of the workflow parses
each raw file once.
"""

from __future__ import annotations

import json
import os
import shutil
from collections import Counter
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.compute  # noqa: F401 (pa.compute)
import pyarrow.parquet as pq
import pytest
from polars.testing import assert_frame_equal
from raw_reads import STAGES, count_night_reads

from borescan import rawio
from borescan.rawio import reader
from borescan.synthetic import demo, simulate

NIGHT = "2026-11-20"


@pytest.fixture(scope="module")
def one_night(tmp_path_factory) -> Path:
    """Write the demo's first three-sensor calibration scan (with spindle file) and rod calibration scan."""
    base = tmp_path_factory.mktemp("rawcache")
    scans = demo.demo_scans()
    tri = next(s for s in scans if s.scan_id.endswith("TRI01-CAL-P1-A"))
    rod = next(s for s in scans if s.scan_id.endswith("ROD01-CAL-RGS150"))
    for s in (tri, rod):
        simulate.write_simulated(s, base / "raw", base / "truth")
    return base / "raw"


@pytest.fixture
def parses(monkeypatch) -> Counter:
    """Every parse of a raw file from now on: (scan folder name, file name) -> count."""
    count: Counter = Counter()
    read_parquet, read_meta = reader._read_parquet, reader._read_meta_file

    def counted_parquet(path, fname, schema, p):
        count[(Path(path).parent.name, fname)] += 1
        return read_parquet(path, fname, schema, p)

    def counted_meta(path, p):
        count[(Path(path).parent.name, rawio.SCAN_JSON)] += 1
        return read_meta(path, p)

    monkeypatch.setattr(reader, "_read_parquet", counted_parquet)
    monkeypatch.setattr(reader, "_read_meta_file", counted_meta)
    reader._SCAN_CACHE.clear()
    yield count
    reader._SCAN_CACHE.clear()


def _assert_same_scan(a: rawio.RawScan, b: rawio.RawScan) -> None:
    assert (a.scan_id, a.night, a.path, a.files, a.warnings) == (
        b.scan_id,
        b.night,
        b.path,
        b.files,
        b.warnings,
    )
    assert a.meta == b.meta and a.sha256 == b.sha256
    assert_frame_equal(a.lds, b.lds)
    assert (a.spindle is None) == (b.spindle is None)
    if a.spindle is not None:
        assert_frame_equal(a.spindle, b.spindle)
    ma, mb = rawio.lds_matrix(a), rawio.lds_matrix(b)
    assert ma.channels == mb.channels
    for x, y in ((ma.sample, mb.sample), (ma.t_s, mb.t_s), (ma.values_mm, mb.values_mm), (ma.pose, mb.pose)):
        np.testing.assert_array_equal(x, y)  # the same parsed numbers: no arithmetic in between


def test_every_reader_of_a_night_parses_each_file_once_and_gets_what_an_uncached_read_gets(
    one_night, parses, monkeypatch
):
    dirs = rawio.discover_scans(one_night)
    assert len(dirs) == 2
    for _ in range(3):
        for d in dirs:
            rawio.read_scan_meta(d)
            rawio.read_scan(d, raw_root=one_night)
            assert rawio.inspect_scan(d, one_night)[1] == []
    assert rawio.validate_root(one_night) == []
    files = {(d.name, f.name) for d in dirs for f in d.iterdir()}
    assert dict(parses) == {f: 1 for f in files}  # scan.json, lds.parquet and spindle.parquet (tri) once
    cached = [rawio.read_scan(d) for d in dirs]
    monkeypatch.setattr(reader._SCAN_CACHE, "enabled", False)
    for d, c in zip(dirs, cached):
        _assert_same_scan(c, rawio.read_scan(d))
        assert rawio.read_scan_meta(d) == c.meta
    assert all(parses[f] == 2 for f in files if f[1] != rawio.SCAN_JSON)  # no cache: parsed again


def test_a_caller_cannot_change_what_the_next_caller_gets(one_night, parses):
    d = rawio.discover_scans(one_night)[0]
    first = rawio.read_scan(d)
    lds0, meta0 = first.lds.clone(), json.loads(json.dumps(first.meta))
    matrix = rawio.lds_matrix(first)  # built by the validation, shared by every copy
    with pytest.raises(ValueError):
        matrix.values_mm[0, 0] = 0.0  # read-only arrays
    first.meta["nominal_diameter_mm"] = -1.0
    first.meta.setdefault("sensors", []).clear()
    first.lds.insert_column(0, first.lds["sample"].alias("extra"))
    first.warnings.append("changed")
    second = rawio.read_scan(d)
    assert second.meta == meta0 and "changed" not in second.warnings
    assert_frame_equal(second.lds, lds0)
    assert rawio.read_scan_meta(d) == meta0
    assert rawio.lds_matrix(second) is matrix
    assert parses[(d.name, rawio.LDS_FILE)] == 1


def test_a_changed_file_is_read_again_and_its_new_content_served(tmp_path, one_night, parses):
    raw = tmp_path / "raw"
    src = next(d for d in rawio.discover_scans(one_night) if (d / rawio.SPINDLE_FILE).exists())
    dst = raw / src.parent.name / src.name
    dst.parent.mkdir(parents=True)
    shutil.copytree(src, dst)
    before = rawio.read_scan(dst)
    # scan.json rewritten (an extra key the format keeps as read)
    meta = json.loads((dst / rawio.SCAN_JSON).read_text())
    meta["operator_note"] = "rewritten"
    (dst / rawio.SCAN_JSON).write_text(json.dumps(meta))
    assert rawio.read_scan(dst).meta["operator_note"] == "rewritten"
    assert rawio.read_scan_meta(dst)["operator_note"] == "rewritten"
    assert parses[(dst.name, rawio.SCAN_JSON)] == 2
    # lds.parquet rewritten with one reading changed by 1 um
    t = pq.read_table(dst / rawio.LDS_FILE)
    v = t.column("value_mm").to_numpy(zero_copy_only=False).copy()
    i = int(np.flatnonzero(np.isfinite(v))[0])
    v[i] += 0.001
    t = t.set_column(t.schema.get_field_index("value_mm"), t.schema.field("value_mm"), pa.array(v))
    pq.write_table(t, dst / rawio.LDS_FILE)
    after = rawio.read_scan(dst)
    assert after.lds["value_mm"][i] == pytest.approx(before.lds["value_mm"][i] + 0.001, abs=1e-12)
    assert parses[(dst.name, rawio.LDS_FILE)] == 3  # any file of the folder changed: the whole scan again
    # a file made invalid is an error, never the earlier valid read
    (dst / rawio.SPINDLE_FILE).write_bytes(b"not parquet")
    with pytest.raises(rawio.ScanError, match="spindle.parquet"):
        rawio.read_scan(dst)
    # and a missing file too
    (dst / rawio.SPINDLE_FILE).unlink()
    (dst / rawio.LDS_FILE).unlink()
    with pytest.raises(rawio.ScanError, match="lds.parquet: missing"):
        rawio.read_scan(dst)


def test_memory_holds_one_night_and_stays_within_its_bound(tmp_path, one_night, parses, monkeypatch):
    dirs = rawio.discover_scans(one_night)
    other = tmp_path / "raw"
    moved = []
    for d in dirs:
        dst = other / "night=2026-11-21" / d.name
        shutil.copytree(d, dst)
        meta = json.loads((dst / rawio.SCAN_JSON).read_text())
        meta["night"] = "2026-11-21"
        (dst / rawio.SCAN_JSON).write_text(json.dumps(meta))
        moved.append(dst)
    cache = reader._SCAN_CACHE
    for d in dirs:
        rawio.read_scan(d)
    assert len(cache._items) == 2
    rawio.read_scan(moved[0])  # another night: the first one's scans are forgotten
    assert [k[0] for k in cache._items] == [os.path.abspath(moved[0])]
    one = cache._bytes
    assert one > 0
    monkeypatch.setattr(cache, "max_bytes", one + 1)  # room for one scan only
    rawio.read_scan(moved[1])
    assert [k[0] for k in cache._items] == [os.path.abspath(moved[1])]  # the least recent one went
    (kept,) = cache._items.values()
    assert cache._bytes == reader._nbytes(kept[1]) > 0  # the last scan read is kept even when larger


@pytest.mark.slow  # a demo night's six stages twice (about 25 s each)
def test_a_demo_night_parses_each_raw_file_once_in_ingest_and_never_after_with_the_same_results(
    tmp_path, monkeypatch
):
    demo.make_demo(tmp_path / "demo")
    raw = tmp_path / "demo" / "raw"
    reads = count_night_reads(raw, NIGHT, tmp_path / "cached", monkeypatch)
    files = {(d.name, f.name) for d in rawio.night_scan_dirs(raw, NIGHT) for f in d.iterdir()}
    # ingest validates every file of the night once; every later stage reads ingest's store
    ingest = {(scan, name): n for (st, name, scan), n in reads.parses.items() if st == "ingest"}
    assert ingest == {f: 1 for f in files}
    per_stage = {st: sum(n for (s, _, _), n in reads.parses.items() if s == st) for st in STAGES}
    assert per_stage == {"ingest": len(files), **{st: 0 for st in STAGES if st != "ingest"}}
    assert sum(reads.parses.values()) == len(files)
    assert all(reads.tables[t].height for t in ("scans", "summary", "calibrations", "diameters"))
    # without the reader's cache the night parses the same files the same number of times
    monkeypatch.setattr(reader._SCAN_CACHE, "enabled", False)
    plain = count_night_reads(raw, NIGHT, tmp_path / "plain", monkeypatch)
    assert plain.parses == reads.parses
    for name, table in reads.tables.items():
        assert_frame_equal(table, plain.tables[name], check_exact=True)
