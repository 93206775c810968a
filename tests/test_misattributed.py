"""Messages that name the scan, the file and the cause (issue 40 item 11, issue 37's leftovers).

Built from the demo's first night: the two calibration scans of TRI-01 (P1-A, P1-B) that calibrate the
device together, one of them spoiled as a gauge PC can spoil it: a spindle clock in microseconds, an
encoder angle in degrees or standing still, ``spindle.direction: "sideways"``, an encoder stream that
does not fit the readings. Each fault must be named where it is (the file and the column or key), the
other scan of the pair still calibrate the device or say it lost its partner, and a calibration failure
never blame a file that is fine.
"""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.compute  # noqa: F401 (pa.compute)
import pyarrow.parquet as pq
import pytest
from fault_roots import copy_scan

from borescan import night_config, rawio, validation
from borescan.synthetic import demo
from borescan.config import load_config
from borescan.preconditions import CALIBRATE_STAGE
from borescan.signal.period import period_from_encoder
from borescan.stages._common import write_table
from borescan.stages.calibrate import stage_calibrate
from borescan.stages.ingest import stage_ingest
from borescan.stages.signal import stage_signal

NIGHT = "2026-11-20"
A, B = "N20261120-TRI01-CAL-P1-A", "N20261120-TRI01-CAL-P1-B"


@pytest.fixture(scope="module")
def night20(tmp_path_factory) -> Path:
    base = tmp_path_factory.mktemp("demo")
    demo.make_demo(base)
    return base / "raw" / f"night={NIGHT}"


def _pair(tmp: Path, night20: Path, keep_s: float | None = None) -> tuple[Path, Path]:
    """Copy the pair; with ``keep_s``, only their first seconds (fewer revolutions: faster fits)."""
    raw = tmp / "raw"
    for sid in (A, B):
        d = copy_scan(night20 / f"scan={sid}", raw, NIGHT, sid)
        for name in ("lds.parquet", "spindle.parquet") if keep_s else ():
            t = pq.read_table(d / name)
            pq.write_table(t.filter(pa.compute.less(t.column("t_ns"), int(keep_s * 1e9))), d / name)
    return raw, raw / f"night={NIGHT}" / f"scan={A}"


def _set_spindle(scan_dir: Path, col: str, fn) -> None:
    t = pq.read_table(scan_dir / "spindle.parquet")
    i = t.schema.get_field_index(col)
    values = pa.array(fn(t.column(col).to_numpy()), type=t.schema.field(col).type)
    pq.write_table(t.set_column(i, t.schema.field(col), values), scan_dir / "spindle.parquet")


def _first_problem(raw: Path, sid: str) -> tuple[str, str]:
    """Return the first problem validate finds for ``sid`` (ingest must quarantine the scan with it)."""
    problems = [e for e in validation.validate_tree(raw).problems if e.scan_id == sid]
    assert problems, f"validate finds nothing wrong with {sid}"
    _, _, bad = stage_ingest(raw, NIGHT, raw.parent / "res")
    assert [(q.scan_id, q.file, q.reason) for q in bad] == [(sid, problems[0].file, problems[0].problem)]
    return problems[0].file, problems[0].problem


def _spans_s(scan_dir: Path) -> tuple[float, float]:
    t_sp = pq.read_table(scan_dir / "spindle.parquet").column("t_ns").to_numpy()
    t_lds = pq.read_table(scan_dir / "lds.parquet").column("t_ns").to_numpy()
    return (t_sp[-1] - t_sp[0]) * 1e-9, (t_lds[-1] - t_lds[0]) * 1e-9


@pytest.mark.parametrize("factor", [1e-3, 1e3], ids=["microseconds", "picoseconds"])
def test_a_spindle_clock_in_other_units_is_named_with_its_column(tmp_path, night20, factor):
    """A clock in microseconds gave "readings barely vary with rotation" at calibrate; ingest names it now."""
    raw, bad = _pair(tmp_path, night20)
    _set_spindle(bad, "t_ns", lambda t: (t * factor).astype(np.int64))
    file, problem = _first_problem(raw, A)
    span_s, lds_span_s = _spans_s(bad)
    assert file == "spindle.parquet"
    assert problem.startswith(
        f"t_ns spans {span_s:.6g} s where the readings of lds.parquet span {lds_span_s:.6g} s"
    )
    assert f"({span_s / lds_span_s:.3g} times)" in problem and "not in nanoseconds" in problem
    assert span_s / lds_span_s == pytest.approx(factor, rel=1e-3)  # the demo's streams cover the readings
    assert "barely vary" not in problem


def test_an_encoder_in_degrees_or_standing_still_is_named_with_its_column(tmp_path, night20):
    raw, bad = _pair(tmp_path, night20)
    _set_spindle(bad, "angle_rad", np.degrees)
    file, problem = _first_problem(raw, A)
    rpm = json.loads((bad / "scan.json").read_text())["spindle"]["rpm_nominal"]
    # the demo spindle turns at its nominal speed; in degrees the encoder turns 180/pi times as fast
    assert file == "spindle.parquet"
    assert problem.startswith(
        f"angle_rad turns at {rpm * 180 / math.pi:.4g} rpm over t_ns where its rpm column"
    )
    _set_spindle(bad, "angle_rad", lambda a: np.full_like(a, a[0]))
    assert _first_problem(raw, A)[1].startswith("angle_rad turns at 0 rpm")


def test_an_encoder_that_does_not_turn_gives_no_period_and_no_crash():
    t_s = np.linspace(0.0, 10.0, 50)
    with pytest.raises(ValueError, match="angle_rad does not turn"):
        period_from_encoder(t_s, np.full(50, 1.0), np.linspace(0.0, 10.0, 6000), sample_rate_hz=600.0)


def test_a_direction_outside_the_spec_is_refused_naming_the_key(tmp_path, night20):
    raw, bad = _pair(tmp_path, night20)
    meta = json.loads((bad / "scan.json").read_text())
    meta["spindle"]["direction"] = "sideways"
    (bad / "scan.json").write_text(json.dumps(meta))
    assert _first_problem(raw, A) == (
        "scan.json",
        "key 'spindle.direction' must be one of ccw, cw, got 'sideways'",
    )
    meta["spindle"]["direction"] = "cw"
    (bad / "scan.json").write_text(json.dumps(meta))
    assert rawio.inspect_scan(bad, raw)[1] == []


def _through_calibrate(raw: Path, tmp: Path, **cal) -> tuple[dict, list, list]:
    """Run ingest, signal and calibrate: (quarantines by scan, calibration ids, scans calibrated from)."""
    cfg, res = load_config(), tmp / "res"
    night_config.settle(res, [NIGHT], cfg)  # the night's record (date of issue), as the workflow first does
    scans, _, bad = stage_ingest(raw, NIGHT, res)
    write_table(scans, tmp / "scans.parquet")
    _, summary, q = stage_signal(raw, NIGHT, res, tmp / "scans.parquet", cfg["signal"], log=lambda _: None)
    bad += q
    cals, links, q = stage_calibrate(
        raw, NIGHT, res, tmp / "scans.parquet", summary, {**cfg["calibration"], **cal}, log=lambda _: None
    )
    bad += q
    used = sorted(links["scan_id"]) if links.height else []
    return {x.scan_id: x for x in bad}, sorted(set(cals["calibration_id"])) if cals.height else [], used


@pytest.mark.slow  # calibration fits of one demo scan
def test_the_partner_of_a_scan_set_aside_still_calibrates_or_says_it_lost_it(tmp_path, night20):
    """Issue 40 item 11: one bad spindle stream no longer sets aside both scans, blaming lds.parquet."""
    raw, bad = _pair(tmp_path, night20, keep_s=6.5)
    _set_spindle(bad, "t_ns", lambda t: t // 1000)
    q, cals, used = _through_calibrate(raw, tmp_path / "default")
    assert list(q) == [A] and (q[A].stage, q[A].file) == ("ingest", "spindle.parquet")
    assert len(cals) == 1 and used == [B]  # B calibrates the device alone
    # a rule B cannot meet alone (a head smaller than its beams' offsets): B says why and whom it lost
    q, cals, used = _through_calibrate(raw, tmp_path / "strict", head_radius_mm=1.0)
    assert cals == [] and used == []
    assert (q[B].stage, q[B].file) == ("calibrate", CALIBRATE_STAGE)
    assert q[B].reason.startswith("calibration failed: ") and "exceeds the head radius 1 mm" in q[B].reason
    assert q[B].reason.endswith(
        f"calibrated without its partner scan(s) set aside before the fit: {A} (set aside at ingest: "
        f"spindle.parquet: {q[A].reason})"
    )
    assert "lds.parquet" not in q[B].reason.split(f"{A} (set aside")[0]


@pytest.mark.slow  # a joint fit and each scan's own fit (about 70 s on a loaded machine)
def test_a_joint_fit_spoiled_by_one_encoder_stream_blames_that_scan_only(tmp_path, night20):
    """An encoder stream that passes every format check but does not fit the readings (1.5 x its angle)."""
    raw, bad = _pair(tmp_path, night20, keep_s=12.0)
    _set_spindle(bad, "angle_rad", lambda a: a[0] + 1.5 * (a - a[0]))
    q, cals, used = _through_calibrate(raw, tmp_path)
    assert list(q) == [A] and (q[A].stage, q[A].file) == ("calibrate", CALIBRATE_STAGE)
    assert q[A].reason.startswith(f"calibration failed on its own: {A}: calibration refused")
    assert q[A].reason.endswith(f"(the joint fit with {B} failed too)")
    assert len(cals) == 1 and used == [B]


@pytest.mark.parametrize("nights", [0, 1])
def test_validate_on_a_root_without_scans_says_so_and_fails(tmp_path, nights):
    for i in range(nights):
        (tmp_path / f"night=2026-11-2{i}").mkdir()
    proc = subprocess.run(
        [
            sys.executable,
            "-c",
            "import sys; from borescan.cli import main; sys.exit(main())",
            "validate",
            str(tmp_path),
        ],
        capture_output=True,
        text=True,
        check=False,
    )
    assert proc.returncode == 1, proc.stderr
    where = "1 night folder(s), none with a scan" if nights else "no night=YYYY-MM-DD folder"
    assert proc.stderr.strip().splitlines()[-1] == f"no scans under RAW_ROOT {tmp_path} ({where})"
    assert "all valid" not in proc.stdout + proc.stderr
