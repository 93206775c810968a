"""Plausibility of the numbers of scan.json that feed a result (issue 40 item 4): each absurd value is
named by its key at ingest and by `borescan validate`; no NaN or inf ever reaches a verdict.
"""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

import duckdb
import pytest

sys.path.insert(0, str(Path(__file__).parent))

from fault_roots import PLAUSIBILITY_CASES as CASES, ROD, ROD_MEAS, copy_scan  # noqa: E402

from borescan import measure, validation
from borescan.synthetic import demo  # noqa: E402
from borescan.stages.ingest import stage_ingest  # noqa: E402


@pytest.fixture(scope="module")
def demo_raw(tmp_path_factory):
    base = tmp_path_factory.mktemp("demo")
    demo.make_demo(base)
    return base / "raw"


@pytest.fixture(scope="module")
def bad_root(demo_raw, tmp_path_factory):
    """One scan per case (night 2026-11-20), plus the untouched scans they were made from."""
    raw = tmp_path_factory.mktemp("plaus") / "raw"
    for src in (ROD, ROD_MEAS):
        copy_scan(demo_raw / "night=2026-11-20" / src, raw, "2026-11-20", src[5:])
    for i, (_, src, edit, _) in enumerate(CASES):
        d = copy_scan(demo_raw / "night=2026-11-20" / src, raw, "2026-11-20", f"PLAUS-{i:02d}")
        meta = json.loads((d / "scan.json").read_text())
        edit(meta)
        (d / "scan.json").write_text(json.dumps(meta, indent=1))
    return raw


def test_validate_names_every_absurd_value_by_its_key(bad_root):
    report = validation.validate_tree(bad_root)
    by_scan: dict[str, list[str]] = {}
    for e in report.problems:
        assert e.file == "scan.json", str(e)
        by_scan.setdefault(e.scan_id, []).append(e.problem)
    assert sorted(by_scan) == [f"PLAUS-{i:02d}" for i in range(len(CASES))]  # the originals pass
    for i, (case, _, _, text) in enumerate(CASES):
        assert [p for p in by_scan[f"PLAUS-{i:02d}"] if p.startswith(text)], (case, by_scan[f"PLAUS-{i:02d}"])


def test_ingest_quarantines_them_with_the_same_reason(bad_root, tmp_path):
    scans, _, bad = stage_ingest(bad_root, "2026-11-20", tmp_path)
    reasons = {q.scan_id: q.reason for q in bad}
    for i, (case, _, _, text) in enumerate(CASES):
        assert reasons[f"PLAUS-{i:02d}"].startswith(text), case
    assert set(scans.filter(scans["status"] == "ok")["scan_id"]) == {ROD[5:], ROD_MEAS[5:]}


def test_workshop_range_comes_from_the_config(bad_root):
    warm = validation.Plausibility.from_config({"temperature_max_c": 70.0})
    meta = json.loads((bad_root / "night=2026-11-20" / "scan=PLAUS-03" / "scan.json").read_text())
    assert validation.plausibility_problems(meta, "PLAUS-03", warm) == []
    assert validation.plausibility_problems(meta, "PLAUS-03")[0].problem.startswith(CASES[3][3])


@pytest.mark.parametrize(
    "error, U, tol",
    [
        (0.001, math.inf, 0.015),
        (0.001, math.nan, 0.015),
        (math.nan, 0.002, 0.015),
        (0.001, 0.002, 0.0),
        (0.001, 0.002, math.inf),
    ],
)
def test_no_verdict_from_a_number_that_is_not_finite(error, U, tol):
    with pytest.raises(ValueError, match="no verdict"):
        measure.decide(error, U, tol)


def test_every_verdict_of_the_pipeline_has_a_finite_uncertainty(pipeline_run):
    """Every PASS/FAIL of the demo nights and the bad-input battery stands on a finite U and tolerance."""
    con = duckdb.connect(str(pipeline_run["results"] / "catalog.duckdb"), read_only=True)
    ver = con.execute(
        "SELECT expanded_u_error_mm, tolerance_mm, error_mm FROM verifications WHERE conformity IS NOT NULL"
    ).fetchall()
    parts = con.execute(
        "SELECT expanded_u_diameter_20_mm, tolerance_mm, deviation_mm FROM diameters "
        "WHERE conformity IS NOT NULL"
    ).fetchall()
    assert len(ver) >= 4 and len(parts) >= 4
    for row in ver + parts:
        assert all(x is not None and math.isfinite(x) for x in row), row
        assert row[0] > 0 and row[1] > 0
