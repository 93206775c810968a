"""Bad input never stops a night and never loses data (issue 8), through the real pipeline."""

from __future__ import annotations

import json
import re

import duckdb
import pytest

from conftest import BAD_NIGHT


def test_battery_is_large_enough(pipeline_run):
    assert len(pipeline_run["cases"]) >= 30


def test_every_bad_scan_is_quarantined_with_scan_file_and_problem(pipeline_run):
    con = duckdb.connect(str(pipeline_run["results"] / "catalog.duckdb"), read_only=True)
    for case in pipeline_run["cases"]:
        rec_path = pipeline_run["results"] / "quarantine" / f"{case.scan_id}.json"
        assert rec_path.is_file(), f"{case.scan_id} was not quarantined"
        rec = json.loads(rec_path.read_text())
        assert rec["scan_id"] == case.scan_id
        assert rec["file"] == case.file, (case.scan_id, rec)
        assert re.search(case.problem, rec["reason"], re.I), (case.scan_id, rec["reason"])
        assert rec["message"] == f"{case.scan_id}: {case.file}: {rec['reason']}"
        status, reason = con.execute(
            "SELECT status, reason FROM scans WHERE scan_id = ? AND night = ?", [case.scan_id, BAD_NIGHT]
        ).fetchone()
        assert status == "quarantined" and case.file in reason


@pytest.mark.parametrize("table", ["scans"])
def test_good_scans_processed_beside_bad_ones(pipeline_run, table):
    con = duckdb.connect(str(pipeline_run["results"] / "catalog.duckdb"), read_only=True)
    n_ok = con.execute(f"SELECT count(*) FROM {table} WHERE status = 'ok'").fetchone()[0]
    # + the verification that fails (a result, not bad input); - night 2's two calibration scans, whose
    # joint calibration is refused (they disagree: a hidden channel_delay on one, tests/test_pipeline.py)
    assert n_ok == len(pipeline_run["good_ids"]) + 1 - 2


def test_very_large_scan_is_read_with_bounded_memory(tmp_path):
    """A 1.2 M-reading scan (600 revolutions) is validated in a fresh process within 400 MB peak RSS.

    The raw Parquet holds ~28 MB of values; the reader reads only the format's columns and checks
    them vectorised, so its peak stays a small multiple of that (measured ~+30 MB over imports).
    """
    import subprocess
    import sys

    from borescan.synthetic import scenes, simulate

    sim = simulate.simulate_tri_spindle(
        scenes.default_tri_scene(),
        n_rev=600,
        scan_id="HUGE",
        night="2026-11-22",
        kind="measurement",
        seed=1,
        started_at="2026-11-22T20:00:00Z",
    )
    d = simulate.write_simulated(sim, tmp_path / "raw", tmp_path / "truth")
    # the peak RSS of the child alone: Linux starts a forked child's high-water mark (ru_maxrss, VmHWM)
    # at the parent's RSS, so a large test process would be counted; writing 5 to clear_refs resets it
    code = (
        "open('/proc/self/clear_refs', 'w').write('5'); from borescan import rawio; "
        f"s = rawio.read_scan(__import__('pathlib').Path({str(d)!r})); m = rawio.lds_matrix(s); "
        "print(m.values_mm.shape[0], next(int(x.split()[1]) for x in open('/proc/self/status') if "
        "x.startswith('VmHWM')))"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True
    ).stdout.split()
    assert int(out[0]) == 600 * 660
    assert int(out[1]) < 400_000  # VmHWM in kB (measured 240 MB: 95 MB of imports, the read, polars)
