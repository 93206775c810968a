"""Calibration lifecycle kept as history: the saved queries calibration_status_history and
calibration_lifecycle on a hand-made catalog whose every transition is known.
"""

from __future__ import annotations

import datetime as dt

import duckdb
import pytest

from borescan import catalog
from borescan.tables import TABLES


def _insert(con, table, rows):
    cols = list(rows[0])
    con.executemany(
        f"INSERT INTO {table} ({', '.join(cols)}) VALUES ({', '.join('?' * len(cols))})",
        [[r[c] for c in cols] for r in rows],
    )


@pytest.fixture()
def con():
    con = duckdb.connect()
    for t in TABLES.values():
        con.execute(t.ddl())
    d = dt.date.fromisoformat
    cal = lambda cid, dev, frm, due: {
        "calibration_id": cid,
        "device_id": dev,
        "channel": 1,
        "method": "full_lsq",
        "valid_from": d(frm),
        "night": d(frm),
        "recalibration_due": due and d(due),
    }
    _insert(
        con,
        "calibrations",
        [
            cal("A1", "TRI-A", "2026-01-01", "2026-01-31"),  # superseded by A2 on 01-10
            cal("A2", "TRI-A", "2026-01-10", "2026-02-09"),  # fails a verification on 01-12
            cal(
                "B1", "TRI-B", "2026-01-01", "2026-01-05"
            ),  # last usable 01-05: expired from 01-06 (newest night 01-20)
            cal("C1", "TRI-C", "2026-01-15", "2026-02-14"),  # still valid
            cal("R1", "ROD-1", "2026-01-01", None),  # nominal rod geometry: never expires
        ],
    )
    _insert(
        con,
        "scans",
        [
            {"scan_id": s, "night": d(n), "device_id": dev, "kind": k, "status": st}
            for s, n, dev, k, st in [
                ("VA2", "2026-01-12", "TRI-A", "verification", "ok"),
                ("VA2b", "2026-01-13", "TRI-A", "verification", "ok"),
                ("CB2", "2026-01-20", "TRI-B", "calibration", "quarantined"),
            ]
        ],
    )
    _insert(
        con,
        "verifications",
        [
            {
                "scan_id": "VA2",
                "night": d("2026-01-12"),
                "device_id": "TRI-A",
                "calibration_id": "A2",
                "error_mm": 0.021,
                "tolerance_mm": 0.015,
                "passed": False,
            },
            {
                "scan_id": "VA2b",
                "night": d("2026-01-13"),
                "device_id": "TRI-A",
                "calibration_id": "A2",
                "error_mm": 0.025,
                "tolerance_mm": 0.015,
                "passed": False,
            },
        ],
    )
    _insert(
        con,
        "quarantine",
        [
            {
                "scan_id": "CB2",
                "night": d("2026-01-20"),
                "stage": "calibrate",
                "file": "lds.parquet",
                "reason": "calibration refused: residual too large",
            }
        ],
    )
    catalog.build._create_views(con, None)
    return con


def test_status_history_has_every_transition(con):
    rows = con.execute(
        "SELECT calibration_id, device_id, status, CAST(night AS VARCHAR), reason "
        "FROM calibration_status_history"
    ).fetchall()
    got = [(c, dev, s, n) for c, dev, s, n, _r in rows]
    assert got == [
        ("R1", "ROD-1", "valid", "2026-01-01"),
        ("A1", "TRI-A", "valid", "2026-01-01"),
        ("A1", "TRI-A", "superseded", "2026-01-10"),
        ("A2", "TRI-A", "valid", "2026-01-10"),
        (
            "A2",
            "TRI-A",
            "failed_verification",
            "2026-01-12",
        ),  # the first failure only; due 02-09 not yet passed
        ("B1", "TRI-B", "valid", "2026-01-01"),
        ("B1", "TRI-B", "expired", "2026-01-06"),
        (None, "TRI-B", "refused", "2026-01-20"),
        ("C1", "TRI-C", "valid", "2026-01-15"),
    ]
    reasons = {(c, s): r for c, _d, s, _n, r in rows}
    assert reasons[("A1", "superseded")] == "superseded by A2"
    assert (
        "VA2" in reasons[("A2", "failed_verification")]
        and "21.0 um" in reasons[("A2", "failed_verification")]
    )
    assert reasons[(None, "refused")] == "calibration refused: residual too large"


def test_lifecycle_gives_the_current_status_and_validity_window(con):
    rows = {
        r[0]: r[1:]
        for r in con.execute(
            "SELECT calibration_id, status, CAST(valid_until AS VARCHAR), CAST(status_night AS VARCHAR) "
            "FROM calibration_lifecycle"
        ).fetchall()
    }
    assert rows == {
        "A1": ("superseded", "2026-01-10", "2026-01-10"),
        "A2": ("failed_verification", "2026-01-12", "2026-01-12"),
        "B1": ("expired", "2026-01-06", "2026-01-06"),
        "C1": ("valid", None, "2026-01-15"),
        "R1": ("valid", None, "2026-01-01"),
    }


def test_trace_shows_the_lifecycle_status(con, tmp_path):
    from borescan import trace

    node = trace._Tracer(con, tmp_path).calibration("A2")
    assert node["status"] == "failed_verification" and str(node["valid_until"]) == "2026-01-12"
    line = trace._cal_lines(node, "")[0]
    assert "until 2026-01-12, status failed_verification (verification VA2 error 21.0 um" in line
    assert trace._Tracer(con, tmp_path).calibration("C1")["status"] == "valid"


def test_superseded_before_due_never_expires_and_a_rod_design_is_superseded_by_its_gauge_calibration():
    con = duckdb.connect()
    for t in TABLES.values():
        con.execute(t.ddl())
    d = dt.date.fromisoformat
    rows = [
        ("T1", "TRI-A", "full_lsq", "2026-01-01", "2026-01-31"),  # superseded 01-10, due 01-31 passes later
        ("T2", "TRI-A", "full_lsq", "2026-01-10", "2026-02-09"),
        ("ROD-1-nominal-x", "ROD-1", "nominal", "2026-01-01", None),
        ("ROD-1-cal", "ROD-1", "rod_gauge", "2026-01-03", "2026-02-02"),
    ]
    _insert(
        con,
        "calibrations",
        [
            {
                "calibration_id": c,
                "device_id": dev,
                "channel": 1,
                "method": m,
                "valid_from": d(f),
                "night": d(f),
                "recalibration_due": due and d(due),
            }
            for c, dev, m, f, due in rows
        ],
    )
    _insert(
        con,
        "scans",
        [
            {
                "scan_id": "S",
                "night": d("2026-03-01"),
                "device_id": "TRI-A",
                "kind": "measurement",
                "status": "ok",
            }
        ],
    )
    catalog.build._create_views(con, None)
    got = con.execute(
        "SELECT calibration_id, status, CAST(night AS VARCHAR), other_id, method "
        "FROM calibration_status_history"
    ).fetchall()
    assert got == [
        ("ROD-1-nominal-x", "valid", "2026-01-01", None, "nominal"),
        ("ROD-1-cal", "valid", "2026-01-03", None, "rod_gauge"),
        ("ROD-1-nominal-x", "superseded", "2026-01-03", "ROD-1-cal", "nominal"),
        ("ROD-1-cal", "expired", "2026-02-03", None, "rod_gauge"),
        ("T1", "valid", "2026-01-01", None, "full_lsq"),
        ("T1", "superseded", "2026-01-10", "T2", "full_lsq"),  # and no 'expired' on 02-01
        ("T2", "valid", "2026-01-10", None, "full_lsq"),
        ("T2", "expired", "2026-02-10", None, "full_lsq"),
    ]
