"""The report's first screen (issue 37, build 2): each device's status, and a night's decisions
first: pooled verdicts with the devices.yaml entry to paste, drifts in u (an unexplained one makes
the night red), refused calibrations with their discrepancy verdict, the refused calibration on the
device-model plot.
"""

from __future__ import annotations

import datetime as dt
import html
import json
import re

import polars as pl
import pytest
import yaml
from matplotlib.backends.backend_agg import FigureCanvasAgg
from test_catalog import make_history

from borescan import catalog
from borescan.effects import device_model_effects
from borescan.report.device_model import device_model_history, plot_device_model_gap, refused_calibrations
from borescan.report.pages import write_report

#: The demo's pooled verdict of 2026-11-23 and its drifts, as the pooled stage writes them.
TAU_S, U_TAU_S = 0.0011514118326008765, 3.079531980826405e-05
DRIFT = [  # night, change [rad], u combined [rad], explained by
    ("2026-11-21", -0.00569, 0.00155, "channel_delay@2"),
    ("2026-11-22", 0.005651, 0.001685, None),
]


def _section(text: str, sid: str) -> str:
    return text.split(f'<section id="{sid}">')[1].split("</section>")[0]


def _night(summary: str, night: str) -> tuple[str, str]:
    """(class, inner HTML) of a night's box in the summary."""
    m = re.search(rf'<div class="([a-z ]+)" id="night-{night}">(.*?)</div>', summary, re.S)
    assert m, night
    return m.group(1), m.group(2)


def _history(res, explained_22: str | None = None, due: dict[str, str] | None = None):
    t = make_history(res)
    t["pooled_findings"] = pl.DataFrame(
        {
            "night": ["2026-11-21"],
            "device_id": ["TRI-01"],
            "verdict": ["missing_effect"],
            "effect": ["channel_delay"],
            "channel": [2],
            "term": ["channel_delay@2"],
            "parameters": [json.dumps({"tau_s": TAU_S})],
            "uncertainties": [json.dumps({"u_tau_s": U_TAU_S})],
            "evidence_scans": ["CAL-A-P1,CAL-A-P2"],
            "in_device_model": [False],
            "gap_before_mm": [0.0042],
            "gap_after_mm": [0.00398],
            "noise_floor_mm": [0.00398],
        }
    )
    t["calibration_drift"] = pl.DataFrame(
        {
            "night": [d[0] for d in DRIFT],
            "device_id": ["TRI-01"] * 2,
            "channel": [2, 2],
            "parameter": ["beta_rad"] * 2,
            "calibration_id_after": ["CAL-B"] * 2,
            "change": [d[1] for d in DRIFT],
            "u_combined": [d[2] for d in DRIFT],
            "change_over_u": [d[1] / d[2] for d in DRIFT],
            "multiple": [3.0, 3.0],
            "flagged": [True, True],
            "explained_by": [DRIFT[0][3], explained_22],
        }
    )
    if due:
        t["calibrations"] = t["calibrations"].with_columns(
            pl.col("calibration_id").replace_strict(due, default=None).alias("recalibration_due")
        )
    catalog.build_catalog(res, t)
    return t


def test_pooled_verdict_comes_with_the_devices_yaml_entry_that_adds_the_effect(tmp_path):
    res = tmp_path / "results"
    _history(res)
    summary = _section(write_report(res).read_text(), "summary")
    cls, box = _night(summary, "2026-11-21")
    assert cls == "night"
    item = box.split("<b>pooled verdict missing_effect</b>")[1].split("</li>")[0]
    assert "<b>channel_delay</b> on channel 2: tau = 1.151 ± 0.031 ms" in item  # GUM 7.2.6 rounding
    assert "evidence: CAL-A-P1,CAL-A-P2" in item
    (entry,) = re.findall(r"<pre>(.*?)</pre>", item, re.S)
    pasted = yaml.safe_load(html.unescape(entry))
    # what the workflow reads: the effect from the night after the verdict, not before
    assert device_model_effects(pasted["devices"], "TRI-01", "2026-11-22") == ("channel_delay@2",)
    assert device_model_effects(pasted["devices"], "TRI-01", "2026-11-21") == ()
    assert "tau = 1.151 ± 0.031 ms, named on 2026-11-21" in html.unescape(entry)  # the value, as a comment
    # the drift it explains is on the same screen, in mrad and in u
    change, u = DRIFT[0][1], DRIFT[0][2]
    assert f"{change * 1e3:+.2f} mrad = {change / u:+.2f} u" == "-5.69 mrad = -3.67 u"
    assert "<b>drift</b> TRI-01 channel 2 beta_rad: -5.69 mrad = -3.67 u" in box
    assert "explained by the pooled verdict channel_delay@2" in box
    # decisions before the routine lines of the night
    assert box.index("pooled verdict") < box.index("<b>drift</b>") < box.index("calibration made")


def test_an_unexplained_drift_makes_an_otherwise_quiet_night_red(tmp_path):
    quiet = tmp_path / "explained"
    _history(quiet, explained_22="channel_delay@2")
    summary = _section(write_report(quiet).read_text(), "summary")
    assert _night(summary, "2026-11-22")[0] == "night quiet"  # the same night with its drift explained

    res = tmp_path / "results"
    _history(res, explained_22=None)
    summary = _section(write_report(res).read_text(), "summary")
    cls, box = _night(summary, "2026-11-22")
    assert cls == "night"
    assert "<b>drift NOT EXPLAINED</b> TRI-01 channel 2 beta_rad: +5.65 mrad = +3.35 u" in box
    assert box.index("drift NOT EXPLAINED") < box.index("calibration made")  # the decision comes first
    row = summary.split('href="#night-2026-11-22">2026-11-22</a></td>')[1].split("</tr>")[0]
    assert re.findall(r"<td[^>]*>(.*?)</td>", row)[-1] == "1 (1 not explained)"
    head = summary.split("<th>night</th>")[1].split("</tr>")[0]  # the counts table
    assert "drifts flagged" in head and "pooled verdicts" in head


def test_devices_status_as_of_the_last_night(tmp_path):
    res = tmp_path / "results"
    due = {"CAL-A": "2026-12-20", "CAL-B": "2026-11-27", "ROD-CAL-1": "2026-12-21"}
    _history(res, due=due)
    text = write_report(res).read_text()
    summary = _section(text, "summary")
    assert summary.index("Devices as of 2026-11-22") < summary.index('id="night-2026-11-22"')
    table = summary.split("Devices as of 2026-11-22")[1].split("</table>")[0]
    rows = {
        re.sub(r"<[^>]+>", "", cells[0]): [re.sub(r"<[^>]+>", "", c) for c in cells]
        for cells in (re.findall(r"<td[^>]*>(.*?)</td>", r) for r in table.split("<tr")[1:])
        if cells
    }

    def left(until: str) -> str:
        return str((dt.date.fromisoformat(until) - dt.date(2026, 11, 22)).days)

    # TRI-01: CAL-B (CAL-A failed its verification and is superseded), 5 days left: due soon
    assert rows["TRI-01"][1:5] == ["due soon", "CAL-B", "2026-11-27", left("2026-11-27")]
    assert rows["ROD-01"][1:5] == ["valid", "ROD-CAL-1", "2026-12-21", left("2026-12-21")]
    # a month page shows the nights only: its rows do not hold the devices' whole history
    month = (res / "report" / "2026-11" / "index.html").read_text()
    assert "Devices as of" not in month


REFUSAL = (
    "calibration failed: C-A,C-B: calibration refused: C-A channel 2: residual rms is 1.45 times the "
    "readings' own noise floor (limit 1.25): the model misses an effect; C-B channel 2: residual rms is "
    "1.44 times the readings' own noise floor (limit 1.25): the model misses an effect"
)


def test_refused_calibration_is_on_the_device_model_plot():
    scans = pl.DataFrame(
        {
            "scan_id": ["C-A", "C-B", "X"],
            "device_id": ["TRI-01", "TRI-01", "TRI-01"],
            "night": ["2026-11-21"] * 3,
        }
    )
    quarantine = pl.DataFrame(
        {
            "scan_id": ["C-A", "C-B", "X"],
            "night": ["2026-11-21"] * 3,
            "reason": [REFUSAL, REFUSAL, "non-monotonic sample"],
        }
    )
    refused = refused_calibrations(scans, quarantine)
    assert refused.rows() == [("2026-11-21", "TRI-01", "C-A,C-B", 1.45)]  # one calibration, its worst channel
    pf = pl.DataFrame(
        {
            "night": ["2026-11-20", "2026-11-21", "2026-11-23"],
            "device_id": ["TRI-01"] * 3,
            "gap_before_mm": [0.0040, 0.0051, 0.0042],
            "noise_floor_mm": [0.0040, 0.0040, 0.0040],
        }
    )
    hist = device_model_history(pf, None, None, "TRI-01", refused)
    assert hist["refused_residual_to_noise"].to_list() == [None, pytest.approx(1.45), None]
    fig = plot_device_model_gap(hist, "TRI-01")
    FigureCanvasAgg(fig).draw()
    ax_g = fig.axes[0]
    (mark,) = [ln for ln in ax_g.get_lines() if ln.get_label().startswith("calibration refused")]
    assert list(mark.get_xdata()) == [1] and list(mark.get_ydata()) == pytest.approx([1.45])
    assert ax_g.get_ylim()[1] > 1.45  # on the axes


def test_refused_calibration_in_the_summary_names_its_discrepancy_verdict(tmp_path):
    res = tmp_path / "results"
    t = make_history(res)
    t["quarantine"] = pl.concat(
        [
            t["quarantine"],
            pl.DataFrame(
                {
                    "scan_id": ["VER-21"],
                    "night": ["2026-11-21"],
                    "stage": ["calibrate"],
                    "file": ["lds.parquet"],
                    "reason": [REFUSAL],
                }
            ),
        ]
    )
    t["scans"] = t["scans"].with_columns(
        pl.when(pl.col("scan_id") == "VER-21")
        .then(pl.lit("quarantined"))
        .otherwise(pl.col("status"))
        .alias("status"),
        pl.when(pl.col("scan_id") == "VER-21")
        .then(pl.lit(REFUSAL))
        .otherwise(pl.col("reason"))
        .alias("reason"),
    )
    t["findings"] = pl.concat(
        [
            t["findings"],
            pl.DataFrame(
                {
                    "scan_id": ["VER-21"] * 2,
                    "night": ["2026-11-21"] * 2,
                    "verdict": ["ambiguous"] * 2,
                    "effect": ["sensor_offset", "channel_delay"],
                    "channel": [None, 2],
                }
            ),
        ],
        how="diagonal_relaxed",
    )
    catalog.build_catalog(res, t)
    _cls, box = _night(_section(write_report(res).read_text(), "summary"), "2026-11-21")
    item = box.split("VER-21")[1].split("</li>")[0]
    assert "discrepancy verdict: <b>ambiguous</b>: channel_delay (channel 2), sensor_offset" in item
    assert "calibration refused — what to do" in item


def test_device_status_table_reads_only_the_current_calibrations():
    """The first screen's device table, read from the rows that can be current, equals the table over
    every calibration and verification of the history, on every night: a rod's design geometry made
    after its gauge calibration, a failed verification, a device calibrated only later.
    """
    from borescan.report.data import _memory_catalog
    from borescan.report.decisions import device_status, device_status_html
    from borescan.report.pages import _devices

    cals = [  # calibration_id, device, valid_from, method, recalibration_due, scan
        ("CAL-A", "TRI-01", "2026-11-20", "yang", "2026-12-20", "S1"),
        ("CAL-B", "TRI-01", "2026-11-22", "yang", "2026-11-26", "S2"),
        ("NOM-1", "ROD-01", "2026-11-19", "nominal", None, "S3"),
        ("GAU-R", "ROD-01", "2026-11-21", "rod_gauge", "2026-12-21", "S4"),
        ("NOM-2", "ROD-01", "2026-11-23", "nominal", None, "S5"),
        ("LATE", "DEV-3", "2026-11-30", "yang", "2026-12-30", "S6"),
    ]
    cal = pl.DataFrame(
        [(c, d, v, m, r, s, ch) for c, d, v, m, r, s in cals for ch in (1, 2)],
        schema=[
            "calibration_id",
            "device_id",
            "valid_from",
            "method",
            "recalibration_due",
            "scan_id",
            "channel",
        ],
        orient="row",
    )
    scans = pl.DataFrame(
        {
            "scan_id": [c[5] for c in cals],
            "night": [c[2] for c in cals],
            "device_id": [c[1] for c in cals],
            "started_at": [f"{c[2]}T22:00:00Z" for c in cals],
        }
    )
    ver = pl.DataFrame(
        {"calibration_id": ["CAL-A", "CAL-B"], "passed": [True, False], "night": ["2026-11-21", "2026-11-23"]}
    )
    con = _memory_catalog({"calibrations": cal, "scans": scans, "verifications": ver})
    try:
        states = {}
        for as_of in ("2026-11-18", "2026-11-20", "2026-11-21", "2026-11-22", "2026-11-23", "2026-11-30"):
            full = con.sql(
                "SELECT c.*, s.started_at FROM calibrations c LEFT JOIN (SELECT DISTINCT ON (scan_id) "
                "scan_id, started_at FROM scans ORDER BY scan_id, night) s ON s.scan_id = c.scan_id"
            ).pl()
            every = device_status(
                full, con.sql("SELECT calibration_id, passed FROM verifications").pl(), as_of
            )
            assert _devices(con, as_of) == device_status_html(every, as_of), as_of
            states[as_of] = {s.device_id: (s.calibration_id, s.state) for s in every}
    finally:
        con.close()
    # the cases the comparison covers
    assert states["2026-11-18"] == {
        "TRI-01": (None, "no calibration"),
        "ROD-01": (None, "no calibration"),
        "DEV-3": (None, "no calibration"),
    }
    assert states["2026-11-20"]["ROD-01"] == ("NOM-1", "design geometry")
    assert states["2026-11-23"] == {
        "TRI-01": ("CAL-B", "failed verification"),
        "ROD-01": ("GAU-R", "valid"),
        "DEV-3": (None, "no calibration"),
    }
    assert states["2026-11-30"]["TRI-01"] == ("CAL-B", "failed verification")
    assert states["2026-11-30"]["DEV-3"] == ("LATE", "valid")
