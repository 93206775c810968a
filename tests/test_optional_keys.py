"""Issue 37 item 1: any scan the raw spec allows is processed or quarantined with its own reason at
the stage that found it; `borescan validate` predicts what the stages will do; one Snakemake run
over a night of scans with each optional key of ``scan.json`` removed never fails a job.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import duckdb
import pytest
from conftest import run_snakemake
from optional_keys import OPTIONAL_KEYS, has_key, key_name, write_night

from borescan import preconditions
from borescan.cli import main
from borescan.stages._common import Quarantined, write_quarantine_record


def _validate(raw: Path, capsys) -> tuple[int, dict[str, tuple[str, str]], str]:
    """Exit code, scan_id -> (file, text after the file) of each line, and stderr."""
    code = main(["validate", str(raw)])
    cap = capsys.readouterr()
    lines = {}
    for line in cap.out.splitlines():
        if ": " in line:
            sid, file, rest = line.split(": ", 2)
            lines.setdefault(sid, (file, rest))
    return code, lines, cap.err


@pytest.fixture(scope="module")
def night(tmp_path_factory):
    """Return the night of tests/optional_keys.py processed by one Snakemake run up to the catalog."""
    base = tmp_path_factory.mktemp("optional_keys")
    raw, results = base / "raw", base / "results"
    written = write_night(raw, base / "truth")
    proc = run_snakemake(raw, results, "--until", "build_catalog")
    con = duckdb.connect(str(results / "catalog.duckdb"), read_only=True) if proc.returncode == 0 else None
    yield {"raw": raw, "results": results, "proc": proc, "written": written, "con": con}
    if con is not None:
        con.close()


def test_every_optional_key_is_removed_from_some_scan(tmp_path):
    """Each optional key of the spec's scan.json has a variant without it (its complete scan has it)."""
    written = write_night(tmp_path / "raw", tmp_path / "truth")
    removed = {path for _, path in written.values() if path is not None}
    assert [key_name(p) for p in OPTIONAL_KEYS if p not in removed] == []
    for sid, (_, path) in written.items():
        meta = json.loads((tmp_path / "raw" / "night=2026-11-20" / f"scan={sid}" / "scan.json").read_text())
        if path is not None:
            assert not has_key(meta, path), (sid, key_name(path))


def test_a_later_stage_keeps_an_earlier_stages_quarantine_record(tmp_path):
    """The first stage's reason stays in quarantine/<scan>.json (as in the catalog); a rerun of
    the same stage, or an earlier stage, replaces it.
    """
    first = Quarantined("S1", "2026-11-20", "calibrate", "lds.parquet", "too few revolutions to calibrate")
    path = write_quarantine_record(tmp_path, first)
    write_quarantine_record(tmp_path, Quarantined("S1", "2026-11-20", "discrepancy", "scan.json", "later"))
    assert json.loads(path.read_text())["reason"] == first.reason
    write_quarantine_record(tmp_path, Quarantined("S1", "2026-11-20", "calibrate", "lds.parquet", "rerun"))
    assert json.loads(path.read_text())["reason"] == "rerun"
    write_quarantine_record(tmp_path, Quarantined("S1", "2026-11-20", "ingest", "scan.json", "bad json"))
    assert json.loads(path.read_text())["stage"] == "ingest"
    # another night's record of the same id (a duplicate id) is not an earlier stage of this one
    write_quarantine_record(tmp_path, Quarantined("S1", "2026-11-21", "measure", "scan.json", "other night"))
    assert json.loads(path.read_text())["night"] == "2026-11-21"


def test_design_geometry_missing_names_the_key_and_the_file():
    meta = {"scan_id": "X", "kind": "calibration", "device": {"id": "T", "type": "tri_lds"}}
    with pytest.raises(preconditions.MissingDesignGeometry, match=r"device\.nominal\.beams missing") as err:
        preconditions.design_beams(meta, preconditions.CALIBRATION_NEEDS_BEAMS)
    assert err.value.file == "scan.json"
    assert not preconditions.has_design_geometry(meta)
    # a 3-revolution scan without device.nominal: the revolutions come first, as in the stage
    (o,) = preconditions.expected_outcomes(meta, has_spindle=True, revolutions=(3, 3), min_rev=5)
    assert (o.stage, o.file, o.quarantined) == ("calibrate", "lds.parquet", True)
    assert o.reason.startswith("too few revolutions to calibrate: 3 whole revolutions recorded")
    (o,) = preconditions.expected_outcomes(meta, has_spindle=True, revolutions=(6, 6), min_rev=5)
    assert (o.file, o.reason) == (
        "scan.json",
        preconditions.missing_geometry_reason("beams", preconditions.CALIBRATION_NEEDS_BEAMS),
    )


@pytest.mark.slow
def test_no_job_fails_and_every_scan_is_processed_or_quarantined(night):
    proc = night["proc"]
    assert proc.returncode == 0, (proc.stdout + proc.stderr)[-3000:]
    rows = night["con"].execute("SELECT scan_id, status, reason FROM scans").fetchall()
    assert {r[0] for r in rows} == set(night["written"])
    for sid, status, reason in rows:
        assert status in ("ok", "quarantined"), (sid, status)
        assert (status == "quarantined") == (reason is not None), (sid, status, reason)
    # nothing crashed into a reason: no KeyError text, no exception names
    assert not [r for r in rows if r[2] and ("KeyError" in r[2] or r[2].endswith("'nominal'"))]


@pytest.mark.slow
def test_each_quarantine_file_holds_the_catalogs_first_reason(night):
    rows = night["con"].execute("SELECT scan_id, reason FROM scans WHERE status = 'quarantined'").fetchall()
    assert rows
    for sid, reason in rows:
        rec = json.loads((night["results"] / "quarantine" / f"{sid}.json").read_text())
        assert f"{rec['file']}: {rec['reason']}" == reason, sid
    # the import-csv example: too short and without device.nominal; calibrate found it first
    rec = json.loads((night["results"] / "quarantine" / "OPT-SHORT-NO-NOMINAL.json").read_text())
    assert rec["stage"] == "calibrate" and re.match(
        r"too few revolutions to calibrate: 2 whole revolutions recorded,", rec["reason"]
    ), rec  # 3 turns from an arbitrary phase: 2 whole


@pytest.mark.slow
def test_a_scan_without_device_nominal_is_measured_and_examined_with_its_calibration(night):
    con = night["con"]
    for sid in (
        "OPT-TRI-MEAS-NO-DEVICE-NOMINAL",
        "OPT-ROD-MEAS-NO-DEVICE-NOMINAL",
        "OPT-TRI-VER-NO-DEVICE-NOMINAL",
    ):
        assert con.execute("SELECT status FROM scans WHERE scan_id = ?", [sid]).fetchone()[0] == "ok", sid
        assert con.execute("SELECT count(*) FROM findings WHERE scan_id = ?", [sid]).fetchone()[0] == 1, sid
    # the same diameter as the complete scan: device.nominal is not an input of a calibrated measurement
    d = dict(
        con.execute(
            "SELECT scan_id, diameter_mm FROM diameters WHERE scan_id IN "
            "('OPT-TRI-MEAS', 'OPT-TRI-MEAS-NO-DEVICE-NOMINAL')"
        ).fetchall()
    )
    assert d["OPT-TRI-MEAS"] == d["OPT-TRI-MEAS-NO-DEVICE-NOMINAL"]
    reason = con.execute(
        "SELECT reason FROM scans WHERE scan_id = 'OPT-TRI-CAL-NO-DEVICE-NOMINAL'"
    ).fetchone()[0]
    assert reason == "scan.json: " + preconditions.missing_geometry_reason(
        "beams", preconditions.CALIBRATION_NEEDS_BEAMS
    )


@pytest.mark.slow
def test_validate_predicts_what_the_stages_did(night, capsys):
    code, lines, err = _validate(night["raw"], capsys)
    assert code == 1
    rows = dict(
        night["con"].execute("SELECT scan_id, reason FROM scans WHERE status = 'quarantined'").fetchall()
    )
    q = {sid: json.loads((night["results"] / "quarantine" / f"{sid}.json").read_text()) for sid in rows}
    predicted = {sid: v for sid, v in lines.items() if not v[1].startswith("note: ")}
    for sid, (file, text) in predicted.items():
        assert sid in rows, (sid, text)
        if text.startswith("will be quarantined at "):  # a later stage: named with its reason
            stage, _, reason = text.removeprefix("will be quarantined at ").partition(": ")
            assert (q[sid]["stage"], q[sid]["file"], q[sid]["reason"]) == (stage, file, reason), sid
        else:
            assert q[sid]["stage"] == "ingest" and (file, text) == (q[sid]["file"], q[sid]["reason"]), sid
    # every scan set aside for a missing design geometry or too few revolutions was predicted
    for sid, reason in rows.items():
        if "device.nominal" in reason and q[sid]["stage"] == "calibrate" or "too few revolutions" in reason:
            assert sid in predicted, (sid, reason)
    assert "to be set aside by a later stage" in err


def test_a_nights_log_line_names_the_scans_set_aside_and_why():
    from borescan.stages._common import quarantined_text

    long = "x" * 300
    text = quarantined_text(
        [
            Quarantined("S1", "2026-11-20", "calibrate", "lds.parquet", "too few revolutions"),
            Quarantined("S2", "2026-11-20", "calibrate", "scan.json", long),
        ]
    )
    assert text == f"2 quarantined: S1 (lds.parquet: too few revolutions); S2 (scan.json: {'x' * 157}...)"
    assert quarantined_text([]) == "0 quarantined"
