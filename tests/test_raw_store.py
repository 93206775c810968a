"""The readings store (issue 34 item 4): ingest reads raw once a night, later stages read what it stored.

A stored scan must be the raw scan as the reader gave it (the same parsed numbers: compared exactly,
there is no arithmetic in between), name its raw files and their SHA-256, and carry a typed, frozen
``ScanMeta``; a stage after ingest must work with the raw root gone.
"""

from __future__ import annotations

import dataclasses
import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from polars.testing import assert_frame_equal

from borescan import rawio
from borescan.config import load_config
from borescan.stages._common import write_table
from borescan.stages.ingest import stage_ingest
from borescan.stages.signal import stage_signal
from borescan.synthetic import demo, simulate

NIGHT = "2026-11-20"


@pytest.fixture(scope="module")
def raw(tmp_path_factory) -> Path:
    """Write the demo's first three-sensor calibration scan (spindle file) and its rod calibration scan."""
    base = tmp_path_factory.mktemp("rawstore")
    scans = demo.demo_scans()
    for suffix in ("TRI01-CAL-P1-A", "ROD01-CAL-RGS150"):
        s = next(s for s in scans if s.scan_id.endswith(suffix))
        simulate.write_simulated(s, base / "raw", base / "truth")
    return base / "raw"


def _tree(root: Path) -> dict[str, bytes]:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


def test_scan_meta_is_typed_frozen_and_round_trips(raw):
    d = rawio.night_scan_dirs(raw, NIGHT)
    for folder in d:
        meta = json.loads((folder / rawio.SCAN_JSON).read_text())
        sm = rawio.ScanMeta.from_scan_json(meta)
        assert (sm.scan_id, sm.night, sm.kind) == (meta["scan_id"], meta["night"], meta["kind"])
        assert (sm.device_id, sm.device_type) == (meta["device"]["id"], meta["device"]["type"])
        assert sm.channels == tuple(sorted(s["channel"] for s in meta["sensors"]))
        assert sm.temperature_c == meta["environment"]["temperature_c"]
        art = meta["artifact"]
        assert sm.certified_diameter_mm == art.get("certified_diameter_mm")
        assert sm.nominal_diameter_mm == art.get("nominal_diameter_mm")
        assert sm.has_device_nominal == ("nominal" in meta["device"])
        if sm.device_type == "tri_lds":
            assert sm.rpm_nominal == meta["spindle"]["rpm_nominal"]
            assert sm.spindle_x_mm == meta["spindle"]["position"]["x_mm"]
        assert rawio.ScanMeta.from_dict(json.loads(json.dumps(sm.to_dict()))) == sm
        with pytest.raises(dataclasses.FrozenInstanceError):
            sm.kind = "measurement"
    with pytest.raises(ValueError, match="unknown ScanMeta fields"):
        rawio.ScanMeta.from_dict({**sm.to_dict(), "colour": "red"})


def test_ingest_stores_each_valid_scan_as_read_and_leaves_raw_alone(tmp_path, raw):
    before = _tree(raw)
    res = tmp_path / "res"
    scans, files, bad = stage_ingest(raw, NIGHT, res)
    assert bad == [] and scans.height == 2
    for folder in rawio.night_scan_dirs(raw, NIGHT):
        scan = rawio.read_scan(folder, raw_root=raw)
        stored = rawio.load_stored_scan(rawio.stored_scan_dir(res, NIGHT, scan.scan_id))
        assert (stored.scan_id, stored.night, stored.path, stored.files, stored.warnings) == (
            scan.scan_id,
            scan.night,
            scan.path,
            scan.files,
            scan.warnings,
        )
        assert stored.meta == scan.meta
        # provenance: the raw files' digests as ingest hashed them, equal to hashing them now
        assert stored.sha256 == {f: rawio.sha256_file(folder / f) for f in scan.files}
        assert_frame_equal(stored.lds, scan.lds, check_exact=True)
        assert (stored.spindle is None) == (scan.spindle is None)
        if scan.spindle is not None:
            assert_frame_equal(stored.spindle, scan.spindle, check_exact=True)
        ma, mb = rawio.lds_matrix(stored), rawio.lds_matrix(scan)
        assert ma.channels == mb.channels
        for x, y in (
            (ma.sample, mb.sample),
            (ma.t_s, mb.t_s),
            (ma.values_mm, mb.values_mm),
            (ma.pose, mb.pose),
        ):
            np.testing.assert_array_equal(x, y)
        folder_store = rawio.stored_scan_dir(res, NIGHT, scan.scan_id)
        assert rawio.load_scan_meta(folder_store) == rawio.ScanMeta.from_scan_json(scan.meta)
        assert rawio.load_scan_json(folder_store) == scan.meta
    assert _tree(raw) == before  # raw files never modified
    first = _tree(rawio.readings_dir(res, NIGHT))
    stage_ingest(raw, NIGHT, res)
    assert _tree(rawio.readings_dir(res, NIGHT)) == first  # a rerun writes the same bytes


def test_a_bad_scan_is_not_stored_and_a_missing_store_is_named(tmp_path, raw):
    bad_raw = tmp_path / "raw"
    shutil.copytree(raw, bad_raw)
    tri = next(d for d in rawio.night_scan_dirs(bad_raw, NIGHT) if (d / rawio.SPINDLE_FILE).exists())
    (tri / rawio.LDS_FILE).write_bytes(b"not parquet")
    res = tmp_path / "res"
    stale = rawio.stored_scan_dir(res, NIGHT, "left-by-an-earlier-run")
    stale.mkdir(parents=True)
    scans, _, bad = stage_ingest(bad_raw, NIGHT, res)
    assert [q.scan_id for q in bad] == [tri.name[5:]]
    stored = sorted(p.name for p in rawio.readings_dir(res, NIGHT).iterdir())
    assert stored == [d.name for d in rawio.night_scan_dirs(bad_raw, NIGHT) if d != tri]
    with pytest.raises(
        FileNotFoundError, match=rf"{tri.name[5:]}: .*scan_meta.json: not in the readings store"
    ):
        rawio.load_stored_scan(rawio.stored_scan_dir(res, NIGHT, tri.name[5:]))


def test_a_stage_after_ingest_needs_no_raw_file(tmp_path, raw):
    cfg = load_config()
    quiet = lambda _: None  # noqa: E731
    results = {}
    for name, gone in (("with_raw", False), ("raw_gone", True)):
        here = tmp_path / name
        shutil.copytree(raw, here / "raw")
        scans, _, _ = stage_ingest(here / "raw", NIGHT, here / "res")
        write_table(scans, here / "scans.parquet")
        if gone:
            shutil.rmtree(here / "raw")
        results[name] = stage_signal(
            here / "raw", NIGHT, here / "res", here / "scans.parquet", cfg["signal"], quiet
        )
    (e1, s1, q1), (e2, s2, q2) = results["with_raw"], results["raw_gone"]
    assert q1 == q2 == [] and s1.height > 0
    assert_frame_equal(e1, e2, check_exact=True)
    assert_frame_equal(s1, s2, check_exact=True)
