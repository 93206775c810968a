"""Issue 37 item 4: two calibrations valid from the same night. `borescan status`, the measure stage
(:func:`borescan.calibrations.choose_calibration`) and the report's calibration table name the same
current one: a calibration on certified gauges before a rod's design geometry (method ``nominal``),
then the later made (its scan's start), never the id string.
"""

from __future__ import annotations

import json

import polars as pl
from test_catalog import make_history

from borescan import catalog
from borescan.calibrations import choose_calibration, order_calibrations
from borescan.cli import main


def _tied_history(res):
    """Return the history of tests/test_catalog.py plus, on the 21st, ROD-01's design geometry under an id
    that sorts after its gauge calibration, and on the 22nd a second TRI-01 calibration CAL-0
    (its id sorts first) made after CAL-B.
    """
    t = make_history(res)
    scans = t["scans"]
    extra = scans.filter(pl.col("scan_id") == "CAL-B").with_columns(
        pl.lit("CAL-0-SCAN").alias("scan_id"), pl.lit("2026-11-22T22:40:00Z").alias("started_at")
    )
    t["scans"] = pl.concat([scans, extra], how="diagonal_relaxed")
    cal = t["calibrations"]
    nominal = cal.filter(pl.col("calibration_id") == "ROD-CAL-1").with_columns(
        pl.lit("ROD-ZZ-nominal-0000").alias("calibration_id"),
        pl.lit("nominal").alias("method"),
        pl.lit(None, dtype=pl.Utf8).alias("certificate_path"),
        pl.lit(71.0).alias("l0_mm"),
    )
    cal0 = cal.filter(pl.col("calibration_id") == "CAL-B").with_columns(
        pl.lit("CAL-0").alias("calibration_id"), pl.lit("CAL-0-SCAN").alias("scan_id")
    )
    t["calibrations"] = pl.concat([cal, nominal, cal0], how="diagonal_relaxed")
    t["calibration_scans"] = pl.concat(
        [t["calibration_scans"], pl.DataFrame({"calibration_id": ["CAL-0"], "scan_id": ["CAL-0-SCAN"]})]
    )
    catalog.build_catalog(res, t)
    return t


def test_order_breaks_ties_by_method_then_time_then_id():
    c = pl.DataFrame(
        {
            "calibration_id": ["Z-nominal", "A-gauge", "B-late", "C-early"],
            "valid_from": ["2026-11-21"] * 2 + ["2026-11-22"] * 2,
            "method": ["nominal", "rod_gauge", "full_lsq", "full_lsq"],
            "started_at": [
                "2026-11-21T20:00:00Z",
                "2026-11-21T19:00:00Z",
                "2026-11-22T23:00:00Z",
                "2026-11-22T22:00:00Z",
            ],
        }
    )
    assert order_calibrations(c)["calibration_id"].to_list() == ["Z-nominal", "A-gauge", "C-early", "B-late"]
    assert choose_calibration(
        c.filter(pl.col("valid_from") == "2026-11-21"), set(), None, "2026-11-21", 30, False
    ) == (None, "no calibration of device None on or before night 2026-11-21")
    c = c.with_columns(pl.lit("D").alias("device_id"))
    assert choose_calibration(c, set(), "D", "2026-11-21", 30, False) == ("A-gauge", None)
    assert choose_calibration(c, set(), "D", "2026-11-23", 30, False) == ("B-late", None)


def test_status_names_the_gauge_calibration_and_the_later_one(tmp_path, capsys):
    res = tmp_path / "results"
    _tied_history(res)
    code = main(
        [
            "status",
            "--results",
            str(res),
            "--as-of",
            "2026-11-23",
            "--validity-days",
            "30",
            "--format",
            "json",
        ]
    )
    assert code == 0
    devices = {d["device_id"]: d for d in json.loads(capsys.readouterr().out)["devices"]}
    assert devices["ROD-01"]["calibration"]["calibration_id"] == "ROD-CAL-1"
    assert devices["ROD-01"]["state"] == "valid"
    # CAL-0 and CAL-B both from the 22nd; CAL-0's scan started 40 min after CAL-B's
    assert devices["TRI-01"]["calibration"]["calibration_id"] == "CAL-0"


def test_report_calibration_table_agrees_with_status(tmp_path):
    import re

    from borescan.report.pages import write_report

    res = tmp_path / "results"
    _tied_history(res)
    html = write_report(res).read_text()
    for page in sorted((res / "report").glob("2026-11/index.html")):
        html += page.read_text()
    role = {}
    for cal_id, text in re.findall(
        r"<tr><td>([A-Z][A-Za-z0-9-]+)</td><td>2026-11-2\d</td>.*?<td>"
        r"(latest|failed verification|superseded by [A-Z0-9-]+|design geometry[^<]*)</td>",
        html,
    ):
        role.setdefault(cal_id, text)
    assert role == {
        "CAL-A": "failed verification",
        "CAL-B": "superseded by CAL-0",
        "CAL-0": "latest",
        "ROD-ZZ-nominal-0000": "design geometry, replaced by ROD-CAL-1",
        "ROD-CAL-1": "latest",
    }
