"""report.html: sections, relative links that resolve, control-chart limits and run rules, pure plot
functions, the summary of what needs attention, self-contained pages, the papers' own page.
"""

from __future__ import annotations

import base64
import json
import re
import shutil
from html.parser import HTMLParser
from pathlib import Path

import numpy as np
import polars as pl
import pytest
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from test_catalog import make_history

from borescan import catalog
from borescan.report.actions import quarantine_action
from borescan.report.data import load_tables
from borescan.report.device_model import device_model_history, plot_device_model_gap
from borescan.report.pages import update_report, write_report
from borescan.report.plots import MAX_TICK_LABELS, plot_calibration_trends, plot_control_chart, plot_diameters
from borescan.report.spc import control_limits, run_rules
from borescan.report.text import format_quantity


class _Links(HTMLParser):
    def __init__(self):
        super().__init__()
        self.links: list[str] = []
        self.ids: set[str] = set()

    def handle_starttag(self, tag, attrs):
        a = dict(attrs)
        if "id" in a:
            self.ids.add(a["id"])
        for key in ("href", "src"):
            if a.get(key):
                self.links.append(a[key])


def _links(page: Path) -> _Links:
    p = _Links()
    p.feed(page.read_text())
    return p


def _check_links_resolve(root: Path, page: str = "report.html") -> list[str]:
    """Every link of ``root/page`` is relative and resolves (from the page's folder); the links."""
    parsed = _links(root / page)
    here = (root / page).parent
    files = []
    for link in parsed.links:
        if link.startswith("data:image/png;base64,"):  # an embedded plot: a real PNG
            assert base64.b64decode(link.split(",", 1)[1])[:8] == b"\x89PNG\r\n\x1a\n"
            continue
        if link.startswith("#"):
            assert link[1:] in parsed.ids, link
            continue
        assert "://" not in link and not link.startswith("/"), f"non-relative link {link}"
        assert (here / link).exists(), f"dangling link {link} in {page}"
        files.append(link)
    return files


@pytest.fixture()
def results(tmp_path):
    res = tmp_path / "results"
    tables = make_history(res)
    (res / "papers").mkdir()
    (res / "papers" / "yang_table1.csv").write_text("quantity,published,reproduced\nrho_1_mm,5.51,5.512\n")
    fig = Figure(figsize=(2, 2))
    fig.subplots().plot([0, 1], [0, 1])
    fig.savefig(res / "papers" / "wang_fig7.png")
    (res / "quarantine").mkdir()
    (res / "quarantine" / "BAD-1.json").write_text('{"scan_id": "BAD-1"}\n')
    catalog.build_catalog(res, tables)
    return res


# --------------------------------------------------------------------------- control chart


def test_control_limits_against_hand_computation():
    # x = 1, 3, 2, 6 -> MR = 2, 1, 4 ; MR-bar = 7/3 ; mean = 3
    lim = control_limits([1.0, 3.0, 2.0, 6.0])
    assert lim["mean"] == pytest.approx(3.0)
    np.testing.assert_allclose(lim["mr"], [2.0, 1.0, 4.0])
    assert lim["mr_bar"] == pytest.approx(7 / 3)
    assert lim["ucl"] == pytest.approx(3.0 + 2.66 * 7 / 3)  # 9.206667
    assert lim["lcl"] == pytest.approx(3.0 - 2.66 * 7 / 3)  # -3.206667
    assert lim["mr_ucl"] == pytest.approx(3.267 * 7 / 3)  # 7.623
    assert lim["ucl"] == pytest.approx(9.206666667) and lim["mr_ucl"] == pytest.approx(7.623)
    assert lim["mr_lcl"] == 0.0


def test_control_limits_nan_and_single_value():
    lim = control_limits([0.004, float("nan"), 0.006])
    assert lim["mean"] == pytest.approx(0.005) and lim["mr_bar"] == pytest.approx(0.002)
    one = control_limits([0.004])
    assert one["mean"] == pytest.approx(0.004) and np.isnan(one["ucl"]) and one["mr"].size == 0


# --------------------------------------------------------------------------- plots


def _frames(results):
    return load_tables(results)


def test_plot_functions_are_pure_and_labelled(results):
    t = _frames(results)
    before = t["verifications"].clone()
    fig = plot_control_chart(t["verifications"], "TRI-01")
    assert isinstance(fig, Figure)
    ax_i, ax_mr = fig.axes
    assert t["verifications"].equals(before)
    labels = [tick.get_text() for tick in ax_mr.get_xticklabels()]
    assert labels == ["2026-11-20\nVER-20", "2026-11-21\nVER-21", "2026-11-22\nVER-22"]
    # individuals chart lines: mean, UCL, LCL (in µm) from the hand formula
    err = np.array([0.004, 0.020, -0.001])
    mr_bar = np.mean(np.abs(np.diff(err)))
    hlines = sorted(
        round(line.get_ydata()[0], 6)
        for line in ax_i.get_lines()
        if len(set(line.get_ydata())) == 1 and len(line.get_ydata()) == 2
    )
    for expect in (err.mean(), err.mean() + 2.66 * mr_bar, err.mean() - 2.66 * mr_bar):
        assert round(expect * 1e3, 6) in hlines
    mr_lines = [
        round(line.get_ydata()[0], 6)
        for line in ax_mr.get_lines()
        if len(line.get_ydata()) == 2 and len(set(line.get_ydata())) == 1
    ]
    assert round(3.267 * mr_bar * 1e3, 6) in mr_lines

    cal_fig = plot_calibration_trends(t["calibrations"], "TRI-01")
    assert len([a for a in cal_fig.axes if a.get_visible()]) == 9  # 3 parameters x 3 channels
    bottom = [tick.get_text() for tick in cal_fig.axes[-1].get_xticklabels()]
    assert bottom == ["2026-11-20\nCAL-A-P1", "2026-11-22\nCAL-B"]
    rod_fig = plot_calibration_trends(t["calibrations"], "ROD-01")
    assert len([a for a in rod_fig.axes if a.get_visible()]) == 5  # l0, h, phi, d, gamma

    dia_fig = plot_diameters(t["diameters"], "P-7")
    (ax,) = [a for a in dia_fig.axes if a.get_visible()]
    assert [tick.get_text() for tick in ax.get_xticklabels()] == ["2026-11-20\nPART-7"]


# --------------------------------------------------------------------------- page


def test_report_written_with_sections_and_existing_links(results):
    page = write_report(results)
    assert page == results / "report.html"
    text = page.read_text()
    for sid in ("summary", "calibration", "verification", "diameters", "discrepancy", "papers", "quarantine"):
        assert f'<section id="{sid}">' in text
    files = _check_links_resolve(results)
    # the plots, certificates, gap plots and the papers' page are all linked
    for expect in (
        "report/2026-11/control_TRI-01.png",
        "report/2026-11/calibration_TRI-01.png",
        "report/2026-11/index.html",
        "calibration/TRI-01/CAL-A/certificate.pdf",
        "calibration/TRI-01/CAL-A/certificate.json",
        "discrepancy/PART-7/gap.png",
        "report/papers.html",
        "quarantine/BAD-1.json",
    ):
        assert expect in files, expect
    # the papers are on their own page, not inline
    assert "papers/wang_fig7.png" not in files and "rho_1_mm" not in text
    papers = _check_links_resolve(results, "report/papers.html")
    assert {"../papers/wang_fig7.png", "../papers/yang_table1.csv", "../report.html"} <= set(papers)
    papers_text = (results / "report" / "papers.html").read_text()
    assert "rho_1_mm" in papers_text  # the paper CSV as a table
    assert "data:image/png;base64," in papers_text  # the paper's plot embedded
    # the month's own page: the same sections (papers aside), its links relative to report/2026-11/
    month = _check_links_resolve(results, "report/2026-11/index.html")
    for expect in (
        "control_TRI-01.png",
        "../../calibration/TRI-01/CAL-A/certificate.pdf",
        "../../discrepancy/PART-7/gap.png",
        "../../quarantine/BAD-1.json",
        "../../report.html",
    ):
        assert expect in month, expect
    month_text = (results / "report" / "2026-11" / "index.html").read_text()
    assert text.split('<section id="calibration">')[1].split("</section>")[0].replace(
        "report/2026-11/", ""
    ) == month_text.split('<section id="calibration">')[1].split("</section>")[0].replace("../../", "")
    assert '<section id="papers">' not in month_text
    # a certificate whose files are absent is named, not linked
    assert "calibration/ROD-01/ROD-CAL-1/certificate.pdf (missing)" in text
    assert "lds.parquet: non-monotonic sample" in text
    assert "missing_effect" in text and "channel_delay" in text
    assert "tau = 1.200 ms" in text  # the finding's parameter in words, with its unit (not tau_s in ms)
    assert "VER-21" in text and "FAILED" in text
    # the suspect measurement (PART-7 used CAL-A, which failed on the 21st) is listed
    suspect = text.split("Measurements put in doubt")[1].split("</table>")[0]
    assert "PART-7" in suspect and "PART-8" not in suspect
    # every PNG written is a real PNG
    pngs = list((results / "report").rglob("*.png"))
    assert sorted(p.name for p in pngs) == ["calibration_TRI-01.png", "control_TRI-01.png"]
    # ROD-01 has one calibration: no trend of one point a panel, its values instead (held: no ±)
    rod = text.split("<h3>Device ROD-01</h3>")[1].split("<h3>")[0]
    assert rod.startswith('<p class="note">One calibration so far') and "calibration_ROD-01" not in rod
    values = rod.split("<tbody>")[1].split("</tbody>")[0]
    assert (
        values
        == "<tr>"
        + "".join(
            f"<td{c}>{v}</td>"
            for c, v in zip(
                ["", *[' class="num"'] * 5],
                ["1", "120.0 mm", "100.0 mm", "10.00 mrad", "0.2000 mm", "3.000 mrad"],
            )
        )
        + "</tr>"
    )
    for png in pngs:
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    # parts measured once share one table (a single value has no distribution to plot)
    once = text.split("Parts measured once (3)")[1].split("</table>")[0]
    assert all(p in once for p in ("P-7", "P-8", "P-9")) and "diameters_P-7.png" not in files


def test_report_from_a_relative_results_folder_links_what_an_absolute_one_does(
    results, tmp_path, monkeypatch
):
    """The workflow passes ``results`` relative to the working folder: the page is the same, with the
    certificate's JSON linked (it was looked for under ``results/results/`` and left out).
    """
    absolute = write_report(results).read_text()
    assert "calibration/TRI-01/CAL-A/certificate.json" in _check_links_resolve(results)
    shutil.copytree(results, tmp_path / "elsewhere" / "results", ignore=shutil.ignore_patterns("report*"))
    monkeypatch.chdir(tmp_path / "elsewhere")
    relative = write_report(Path("results")).read_text()
    assert "calibration/TRI-01/CAL-A/certificate.json" in _check_links_resolve(
        tmp_path / "elsewhere" / "results"
    )
    assert relative == absolute


def test_report_plots_parts_measured_more_than_once(results):
    t = load_tables(results)
    dia = t["diameters"]
    again = dia.filter(pl.col("artifact_id") == "P-7").with_columns(
        pl.lit("PART-7B").alias("scan_id"), (pl.col("diameter_mm") + 0.002).alias("diameter_mm")
    )
    t["diameters"] = pl.concat([dia, again], how="diagonal_relaxed")
    text = write_report(results, t).read_text()
    assert "<h3>Part P-7</h3>" in text and "Parts measured once (2)" in text
    assert (results / "report" / "2026-11" / "diameters_P-7.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_report_links_survive_moving_the_folder(results, tmp_path):
    write_report(results)
    moved = tmp_path / "elsewhere" / "results-copy"
    shutil.move(str(results), str(moved))
    assert _check_links_resolve(moved)


def _files(folder):
    return {
        p.relative_to(folder).as_posix(): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()
    }


def test_report_rerun_is_byte_identical(results):
    write_report(results)
    first = _files(results / "report")
    html1 = (results / "report.html").read_bytes()
    write_report(results)
    assert _files(results / "report") == first
    assert (results / "report.html").read_bytes() == html1
    write_report(results, full=True)  # everything drawn again: the same bytes
    assert _files(results / "report") == first
    assert (results / "report.html").read_bytes() == html1


def test_report_of_empty_catalog(tmp_path):
    res = tmp_path / "results"
    catalog.build_catalog(res, {})
    text = write_report(res).read_text()
    assert "No calibrations in the catalog." in text
    assert "No verifications in the catalog." in text
    assert "No quarantined scans." in text
    assert "No paper reproductions" in text
    assert _check_links_resolve(res) == []


def test_report_from_given_frames_without_catalog(tmp_path):
    res = tmp_path / "results"
    ver = pl.DataFrame(
        {
            "scan_id": ["V1", "V2", "V3", "V4"],
            "night": ["2026-11-20", "2026-11-21", "2026-11-22", "2026-11-23"],
            "device_id": ["TRI-02"] * 4,
            "error_mm": [0.001, 0.003, 0.002, 0.006],
            "tolerance_mm": [0.015] * 4,
            "passed": [True] * 4,
            "calibration_id": ["C"] * 4,
            "measured_mm": [None] * 4,
            "certified_mm": [None] * 4,
        }
    )
    text = write_report(res, {"verifications": ver}).read_text()
    # limits table of the device in µm, as its chart: mean 3, MR-bar 7/3 µm, UCL 3 + 2.66 * 7/3
    assert f">{3.0 + 2.66 * 7.0 / 3:.2f}<" in text and ">9.21<" in text
    assert f">{3.267 * 7.0 / 3:.2f}<" in text
    assert (res / "report" / "2026-11" / "control_TRI-02.png").is_file()


def test_a_gauge_verified_once_gets_a_note_instead_of_an_empty_chart(tmp_path):
    """One verification of a device on a gauge has no moving range, hence no control limits: the
    report says so and draws no chart (a contract night verifies most rod gauges once); the
    device's other gauge, verified twice, keeps its chart.
    """
    res = tmp_path / "results"
    ver = pl.DataFrame(
        {
            "scan_id": ["V1", "V2", "V3"],
            "night": ["2026-11-20", "2026-11-21", "2026-11-21"],
            "device_id": ["ROD-01"] * 3,
            "artifact_id": ["RGS-1/H1", "RGS-1/H1", "RGS-1/H2"],
            "error_mm": [0.001, 0.003, 0.002],
            "tolerance_mm": [0.015] * 3,
            "passed": [True] * 3,
            "calibration_id": ["C"] * 3,
            "measured_mm": [None] * 3,
            "certified_mm": [None] * 3,
        }
    )
    text = write_report(res, {"verifications": ver}).read_text()
    assert 'Device ROD-01 · gauge RGS-1/H2</h3><p class="note">One verification: no control chart' in text
    assert 'Device ROD-01 · gauge RGS-1/H1</h3><p class="note">One verification' not in text
    charts = sorted(p.name for p in (res / "report" / "2026-11").glob("control_*.png"))
    assert charts == ["control_ROD-01_RGS-1_H1.png"], charts
    assert ">V3<" in text  # the single verification's row is still in its table


# --------------------------------------------------------------------------- what needs attention


def _rich_tables(res: Path) -> dict[str, pl.DataFrame]:
    """Return the constructed history plus: a scan quarantined by the measure stage (no calibration), the
    GUM columns of the diameters (PART-8 at 20 °C assumed, out of its ±8 µm tolerance of nominal
    150.000 mm), an ambiguous finding for PART-9 (its findings.json with uncertainties) and ROD-CAL-1
    due for recalibration on the 21st (its last usable night), so expired from the 22nd.
    """
    t = make_history(res)
    scans = t["scans"]
    extra = scans.filter(pl.col("scan_id") == "PART-8").with_columns(
        pl.lit("MEAS-X").alias("scan_id"),
        pl.lit("TRI-09").alias("device_id"),
        pl.lit("quarantined").alias("status"),
        pl.lit("scan.json: no calibration of device TRI-09 on or before night 2026-11-22").alias("reason"),
    )
    t["scans"] = pl.concat([scans, extra])
    t["quarantine"] = pl.concat(
        [
            t["quarantine"],
            pl.DataFrame(
                {
                    "scan_id": ["MEAS-X"],
                    "night": ["2026-11-22"],
                    "stage": ["measure"],
                    "file": ["scan.json"],
                    "reason": ["no calibration of device TRI-09 on or before night 2026-11-22"],
                }
            ),
        ]
    )
    t["diameters"] = t["diameters"].with_columns(
        pl.Series("temperature_c", [20.4, 20.0, 21.0]),
        pl.Series("temperature_assumed", [False, True, False]),
        pl.Series("diameter_20_mm", [150.0121123456789, 150.0101, 80.0030]),
        pl.Series("u_diameter_20_mm", [0.0022, 0.0021, 0.0041]),
        pl.Series("expanded_u_diameter_20_mm", [0.0045, 0.0043, 0.0083]),
        pl.Series("k", [2.05, 2.03, 2.02]),
        pl.Series("coverage_probability", [0.95, 0.95, 0.95]),
        pl.Series("tolerance_mm", [None, 0.008, None]),
    )
    t["artifacts"] = pl.concat(
        [
            t["artifacts"],
            pl.DataFrame({"artifact_id": ["P-8"], "type": ["part"], "nominal_diameter_mm": [150.0]}),
        ],
        how="diagonal_relaxed",
    )
    t["calibrations"] = t["calibrations"].with_columns(
        pl.when(pl.col("calibration_id") == "ROD-CAL-1")
        .then(pl.lit("2026-11-21"))
        .otherwise(pl.lit("2026-12-20"))
        .alias("recalibration_due")
    )
    named = [
        {
            "effect": "sensor_offset",
            "channel": 1,
            "parameters": {"b_mm": 0.0031234567},
            "uncertainties": {"u_b_mm": 0.00041},
        },
        {
            "effect": "sensor_nonlinearity",
            "channel": 1,
            "parameters": {"a_mm": 0.0052},
            "uncertainties": {"u_a_mm": 0.0007},
        },
    ]
    (res / "discrepancy" / "PART-9").mkdir(parents=True)
    (res / "discrepancy" / "PART-9" / "findings.json").write_text(
        json.dumps(
            {
                "scan_id": "PART-9",
                "verdict": "ambiguous",
                "named": named,
                "gap_before": {"rms_mm": 0.0050123456789},
                "gap_after": {"rms_mm": 0.0021},
                "noise_floor_mm": 0.0020,
            }
        )
    )
    t["findings"] = pl.concat(
        [
            t["findings"],
            pl.DataFrame(
                {
                    "scan_id": ["PART-9", "PART-9"],
                    "verdict": ["ambiguous", "ambiguous"],
                    "effect": ["sensor_offset", "sensor_nonlinearity"],
                    "channel": [1, 1],
                    "parameters": ['{"b_mm": 0.0031234567}', '{"a_mm": 0.0052}'],
                    "gap_before_mm": [0.0050123456789] * 2,
                    "gap_after_mm": [0.0021] * 2,
                }
            ),
        ],
        how="diagonal_relaxed",
    )
    return t


@pytest.fixture()
def rich(tmp_path):
    res = tmp_path / "results"
    tables = _rich_tables(res)
    catalog.build_catalog(res, tables)
    return res, tables


def _section(text: str, sid: str) -> str:
    return text.split(f'<section id="{sid}">')[1].split("</section>")[0]


def _without_images(text: str) -> str:
    return re.sub(r"data:image/png;base64,[A-Za-z0-9+/=]+", "data:", text)


def test_summary_per_night_lists_what_needs_attention(rich):
    res, _ = rich
    text = write_report(res).read_text()
    month_text = (res / "report" / "2026-11" / "index.html").read_text()
    for page in (text, month_text):
        summary = _section(page, "summary")
        # newest night first
        assert summary.index("2026-11-22") < summary.index("2026-11-21") < summary.index("2026-11-20")
        # every quarantined scan (scans.status or a quarantine row) is listed with its reason and action
        con = catalog.open_catalog(res, read_only=True)
        quarantined = {
            r[0]: r[1]
            for r in con.execute(
                "SELECT scan_id, any_value(reason) FROM (SELECT scan_id, reason FROM scans WHERE "
                "status = 'quarantined' "
                "UNION ALL SELECT scan_id, file || ': ' || reason FROM quarantine) GROUP BY scan_id"
            ).fetchall()
        }
        con.close()
        assert set(quarantined) == {"BAD-1", "MEAS-X"}
        for sid, reason in quarantined.items():
            assert sid in summary, sid
            assert html_escape(quarantine_action(reason)[1]) in summary, sid
        assert "Fix the export or rescan" in summary and "Calibrate the device" in summary
        # the overview row of the 22nd: 4 scans in, 1 quarantined, CAL-B made, ROD-CAL-1 expired,
        # CAL-A superseded, 1 verification passed, none failed, 1 part out of tolerance, none that cannot
        # decide (the history has no verdict statements), no verdict for a person, no pooled verdict, no drift
        row = summary.split('href="#night-2026-11-22">2026-11-22</a></td>')[1].split("</tr>")[0]
        cells = re.findall(r"<td[^>]*>(.*?)</td>", row)
        assert cells == [
            "4",
            "calibration 1, measurement 2, verification 1",
            "1",
            "1",
            "1",
            "1",
            "1",
            "0",
            "1",
            "0",
            "0",
            "0",
            "0",
        ]
        night22 = summary.split('id="night-2026-11-22"')[1].split("</div>")[0]
        assert "calibration expired</b> ROD-CAL-1" in night22
        assert "calibration superseded: CAL-A of TRI-01 by CAL-B" in night22
        assert "part out of tolerance</b> P-8" in night22 and "deviation 10.1 µm" in night22
        night21 = summary.split('id="night-2026-11-21"')[1].split("</div>")[0]
        assert "verification failed</b> VER-21" in night21 and "recalibrate" in night21
        assert "discrepancy ambiguous</b> PART-9" in night21
        night20 = summary.split('id="night-2026-11-20"')[1].split("</div>")[0]
        assert "discrepancy missing_effect</b> PART-7" in night20


def html_escape(s: str) -> str:
    import html

    return html.escape(s)


def _cell_texts(page: str) -> list[str]:
    return [
        re.sub(r"<[^>]+>", " ", c) for c in re.findall(r"<td[^>]*>(.*?)</td>", _without_images(page), re.S)
    ]


def test_pages_have_no_raw_json_and_no_long_floats(rich):
    res, _ = rich
    pages = [write_report(res).read_text(), (res / "report" / "2026-11" / "index.html").read_text()]
    for page in pages:
        plain = _without_images(page)
        assert '{"' not in plain and "{&quot;" not in plain
        numbers = [
            n for cell in _cell_texts(page) for n in re.findall(r"\d+(?:\.\d+)?(?:[eE][-+]?\d+)?", cell)
        ]
        assert numbers  # the check sees the tables
        for n in numbers:
            mantissa = re.split(r"[eE]", n)[0].replace(".", "").lstrip("0")
            assert len(mantissa) <= 9 or "." not in n, n
    # the values that had 11 to 13 digits are rounded
    assert "150.0121" in pages[0] and "150.01211" not in pages[0]  # diameters to 0.1 µm


def test_parts_show_both_temperatures_uncertainty_and_deviation(rich):
    res, _ = rich
    parts = _section(write_report(res).read_text(), "diameters")
    rows = {
        re.findall(r"<td[^>]*>(.*?)</td>", r)[1]: [
            re.sub(r"<[^>]+>", "", c) for c in re.findall(r"<td[^>]*>(.*?)</td>", r)
        ]
        for r in parts.split("<tr")[1:]
        if "<td" in r and "PART-" in r
    }
    # night, scan, part, feature, D at T, T, D at 20, U [µm], k, coverage, nominal, deviation [µm],
    # tolerance, verdict
    assert rows["PART-8"][4:14] == [
        "150.0101",
        "20 (assumed)",
        "150.0101",
        "4.30",
        "2.03",
        "0.9500",
        "150.0000",
        "10.1",
        "8.0",
        "OUT OF TOLERANCE",
    ]
    assert rows["PART-7"][4:12] == ["150.0123", "20.4", "150.0121", "4.50", "2.05", "0.9500", "", ""]
    assert "temperature" in parts and "(assumed)" in parts


def test_discrepancy_in_words_and_ambiguous_explained(rich):
    res, _ = rich
    disc = _section(write_report(res).read_text(), "discrepancy")
    part9 = disc.split("<td>PART-9</td>")[1].split("</tr>")[0]
    assert "<b>sensor_offset</b> on channel 1: b = 3.12 ± 0.41 µm" in part9
    assert "<b>sensor_nonlinearity</b> on channel 1: a = 5.20 ± 0.70 µm" in part9
    assert "Ambiguous between sensor_nonlinearity, sensor_offset" in part9 and "equally well" in part9
    assert "another eccentricity" in part9
    assert ">5.01<" in part9 and ">2.10<" in part9  # gaps in µm rms, rounded


def test_quarantine_actions_follow_the_readme_classes():
    assert quarantine_action("lds.parquet: non-monotonic sample")[0] == "broken file"
    assert quarantine_action("lds.parquet: t_ns clock jumps back")[0] == "broken file"
    assert (
        quarantine_action(
            "scan.json: scan_id already used by a scan of night=2026-11-20 (scan ids "
            "are unique across nights)"
        )[0]
        == "scan id reused"
    )
    assert (
        quarantine_action("lds.parquet: calibration failed: calibration refused: residual")[0]
        == "calibration refused"
    )
    assert (
        quarantine_action("latest calibration CAL-A of device TRI-01 failed its verification; recalibrate")[0]
        == "calibration failed verification"
    )
    assert (
        quarantine_action(
            "latest calibration CAL-A of device TRI-01 expired (40 days old, validity 30 days)"
        )[0]
        == "calibration expired"
    )
    assert (
        quarantine_action("too few revolutions to calibrate: 3 whole revolutions")[0]
        == "too few revolutions or poses"
    )
    assert quarantine_action("measurement failed: singular matrix")[0] == "processing error"
    assert (
        quarantine_action(
            "scan.json: device.nominal.beams missing (optional in the raw format, but a "
            "three-sensor calibration starts its fit from the design beam geometry)"
        )[0]
        == "design geometry missing"
    )
    assert "new scan id" in quarantine_action(None)[1]


def test_format_quantity_rounds_to_the_uncertainty():
    assert format_quantity(0.0012, 0.00003, "s") == "1.200 ± 0.030 ms"
    assert format_quantity(3e-6, 4e-7, "s") == "3.00 ± 0.40 µs"
    assert format_quantity(150.01234567, 0.0021, "mm") == "150.0123 ± 0.0021 mm"
    assert format_quantity(0.0031234567, None, "mm") == "3.123 µm"
    assert format_quantity(1.0002, 0.00004, "-") == "1.000200 ± 0.000040"
    assert format_quantity(float("nan"), 0.1, "mm") == ""


def test_pages_are_self_contained_with_a_print_stylesheet(rich):
    res, _ = rich
    for rel in ("report.html", "report/2026-11/index.html"):
        write_report(res)
        page = (res / rel).read_text()
        srcs = re.findall(r'<img src="([^"]*)"', page)
        assert srcs and all(s.startswith("data:image/png;base64,") for s in srcs), rel
        assert "@media print" in page and "<script" not in page and "http://" not in page.split("</style>")[1]
        # each embedded plot links to its PNG file, which is kept
        for href in re.findall(r'<a class="plot" href="([^"]*)"', page):
            assert ((res / rel).parent / href).is_file()


def test_a_later_month_supersedes_a_calibration_without_rewriting_the_earlier_page(rich):
    res, tables = rich
    first = update_report(res)
    assert first.rendered == ("2026-11",)
    assert update_report(res).rendered == ()  # the same rows: nothing rewritten
    dec = (
        tables["scans"]
        .filter(pl.col("scan_id") == "CAL-B")
        .with_columns(
            pl.lit("CAL-C").alias("scan_id"),
            pl.lit("2026-12-02").alias("night"),
            pl.lit("2026-12-02T22:00:00Z").alias("started_at"),
        )
    )
    tables["scans"] = pl.concat([tables["scans"], dec])
    tables["calibrations"] = pl.concat(
        [
            tables["calibrations"],
            tables["calibrations"]
            .filter(pl.col("calibration_id") == "CAL-B")
            .with_columns(
                pl.lit("CAL-C").alias("calibration_id"),
                pl.lit("CAL-C").alias("scan_id"),
                pl.lit(None, dtype=pl.Utf8).alias("certificate_path"),
            ),
        ]
    )
    tables["calibration_scans"] = pl.concat(
        [tables["calibration_scans"], pl.DataFrame({"calibration_id": ["CAL-C"], "scan_id": ["CAL-C"]})]
    )
    catalog.build_catalog(res, tables)
    second = update_report(res)
    assert second.rendered == ("2026-12",)
    december = _section((res / "report" / "2026-12" / "index.html").read_text(), "summary")
    assert "calibration superseded: CAL-B of TRI-01 by CAL-C" in december
    assert "CAL-B" in _section((res / "report.html").read_text(), "summary")


# --------------------------------------------------------------------------- run rules and the chart


def test_run_rules_on_constructed_series():
    # centre 0, sigma 1
    rule1 = run_rules([0.5, -3.2, 1.0, 3.0, 3.01], 0.0, 1.0)
    assert rule1[1].tolist() == [False, True, False, False, True]  # beyond, not at, 3 sigma
    # two of three beyond 2 sigma on the same side: indices 1 and 3 (window 1-3); 6 and 7 opposite sides: no
    rule2 = run_rules([0.0, 2.5, 0.1, 2.2, 0.0, 0.0, 2.5, -2.5, 0.0], 0.0, 1.0)[2]
    assert np.nonzero(rule2)[0].tolist() == [1, 3]
    # 2 of 3 below -2 sigma
    assert np.nonzero(run_rules([-2.1, -2.1, 0.0], 0.0, 1.0)[2])[0].tolist() == [0, 1]
    # eight in a row above the centre (values 10.1 around centre 10): 8 points flagged; seven are not enough
    above = [9.0] + [10.1] * 8 + [9.5] + [10.2] * 7
    r4 = run_rules(above, 10.0, 1.0)[4]
    assert np.nonzero(r4)[0].tolist() == list(range(1, 9))
    # a run of 9 below: all nine; a NaN breaks a run
    assert run_rules([-1.0] * 9, 0.0, 1.0)[4].sum() == 9
    assert run_rules([-1.0] * 4 + [np.nan] + [-1.0] * 4, 0.0, 1.0)[4].sum() == 0
    # no spread: no judgement
    assert not any(v.any() for v in run_rules([1.0, 5.0], 1.0, 0.0).values())


def _verifications(n: int, gauges=("RG-275",)) -> pl.DataFrame:
    import datetime as dt

    rows = []
    for i in range(n):
        for g in gauges:
            rows.append(
                {
                    "scan_id": f"V{i}-{g}",
                    "night": str(dt.date(2026, 1, 1) + dt.timedelta(days=i)),
                    "device_id": "TRI-01",
                    "artifact_id": g,
                    "error_mm": 0.001 * ((i * 7) % 5) + (0.01 if g != "RG-275" else 0.0),
                    "tolerance_mm": 0.015,
                    "passed": True,
                    "u_error_mm": 0.0012,
                }
            )
    return pl.DataFrame(rows)


def test_control_chart_is_per_gauge_with_marked_rule_breaks(tmp_path):
    ver = _verifications(12, ("RG-275", "RG-150"))
    fig = plot_control_chart(ver, "TRI-01", "RG-150")
    ax_i = fig.axes[0]
    assert "gauge RG-150" in ax_i.get_title()
    points = [line for line in ax_i.get_lines() if line.get_label() == "passed"][0]
    assert len(points.get_xdata()) == 12 and min(points.get_ydata()) >= 10.0  # only RG-150's errors [µm]
    labels = [t.get_text() for t in ax_i.get_legend().get_texts()]
    assert "U (k=2)" in labels
    # a point beyond 3 sigma is ringed and named in the legend
    jump = ver.with_columns(
        pl.when(pl.col("scan_id") == "V6-RG-275").then(0.05).otherwise(pl.col("error_mm")).alias("error_mm")
    )
    jump = (
        pl.concat([jump.filter(pl.col("artifact_id") == "RG-275")] * 3)
        .with_row_index()
        .with_columns(pl.format("S{}", pl.col("index")).alias("scan_id"))
        .drop("index")
    )
    ax = plot_control_chart(jump, "TRI-01", "RG-275").axes[0]
    assert any(t.get_text().startswith("breaks run rule 1") for t in ax.get_legend().get_texts())
    # the report draws one chart per gauge
    res = tmp_path / "results"
    text = write_report(res, {"verifications": ver}).read_text()
    assert "Device TRI-01 · gauge RG-150" in text and "Device TRI-01 · gauge RG-275" in text
    assert sorted(p.name for p in (res / "report" / "2026-01").glob("control_*.png")) == [
        "control_TRI-01_RG-150.png",
        "control_TRI-01_RG-275.png",
    ]


@pytest.mark.parametrize("n", [2, 8, 30, 365])
def test_control_chart_axis_readable_and_tolerance_label_inside(n):
    fig = plot_control_chart(_verifications(n), "TRI-01", "RG-275")
    FigureCanvasAgg(fig).draw()
    ax_i, ax_mr = fig.axes
    labels = [t for t in ax_mr.get_xticklabels() if t.get_text()]
    assert 2 <= len(labels) <= MAX_TICK_LABELS or len(labels) == n
    renderer = fig.canvas.get_renderer()
    boxes = [t.get_window_extent(renderer) for t in labels]
    assert all(a.x1 <= b.x0 + 1 for a, b in zip(boxes, boxes[1:])), "tick labels overlap"
    (tol,) = [t for t in ax_i.texts if t.get_text().startswith("tolerance")]
    assert tol.get_text() == "tolerance ±15 µm"
    inside = ax_i.get_window_extent(renderer)
    box = tol.get_window_extent(renderer)
    assert inside.x0 <= box.x0 and box.x1 <= inside.x1 and inside.y0 <= box.y0 and box.y1 <= inside.y1
    for text in ax_i.texts:  # the limit labels too
        b = text.get_window_extent(renderer)
        assert inside.y0 - 1 <= b.y0 and b.y1 <= inside.y1 + 1, text.get_text()


def test_control_chart_marks_every_night_as_matplotlibs_minor_ticks_would():
    """A month of 1-3 verifications a night: every night's first point gets a tick (labelled every
    k-th night, a short mark for the others) on both panels, and the marks, one artist a panel, give
    the very pixels matplotlib's own minor ticks at those nights give (both drawn here).
    """
    import datetime as dt

    from matplotlib.lines import TICKDOWN

    per_night = [1 + (k * 5) % 3 for k in range(31)]
    ver = pl.concat(
        _verifications(n).with_columns(
            pl.lit(str(dt.date(2026, 1, 1) + dt.timedelta(days=k))).alias("night"),
            pl.format("V{}-{}", pl.lit(k), pl.col("scan_id")).alias("scan_id"),
        )
        for k, n in enumerate(per_night)
    )
    firsts = np.cumsum([0, *per_night[:-1]]).tolist()  # each night's first point, counted independently
    fig = plot_control_chart(ver, "TRI-01", "RG-275")
    ax_i, ax_mr = fig.axes
    labelled = [int(x) for x in ax_mr.get_xticks()]
    assert len(ax_mr.get_xticklabels()) == len(labelled) <= MAX_TICK_LABELS
    for ax in (ax_i, ax_mr):
        (marks,) = [line for line in ax.get_lines() if line.get_marker() == TICKDOWN]
        assert sorted(labelled + [int(x) for x in marks.get_xdata()]) == firsts
    canvas = FigureCanvasAgg(fig)
    canvas.draw()
    ours = np.asarray(canvas.buffer_rgba()).copy()
    for ax in (ax_i, ax_mr):
        [line for line in ax.get_lines() if line.get_marker() == TICKDOWN][0].remove()
    ax_mr.set_xticks(firsts, minor=True)  # matplotlib drops the minor ticks on labelled nights
    canvas.draw()
    assert np.array_equal(ours, np.asarray(canvas.buffer_rgba()))


def test_device_model_section_shows_pooled_verdicts_device_effects_and_flagged_drift(tmp_path):
    """The pooled examination and calibration drift in words: value ± u, evidence scans, the device
    model's effects apart from named ones, the gap against the noise floor, flagged drifts only.
    """
    res = tmp_path / "results"
    t = _rich_tables(res)
    night = t["scans"]["night"].cast(pl.String).max()
    t["pooled_findings"] = pl.DataFrame(
        {
            "night": [night] * 2,
            "device_id": ["TRI-01"] * 2,
            "verdict": ["missing_effect"] * 2,
            "effect": ["channel_delay", "sensor_gain"],
            "channel": [2, 1],
            "term": ["channel_delay@2", "sensor_gain@1"],
            "parameters": ['{"tau_s": 0.0012}', '{"g": 0.0011}'],
            "uncertainties": ['{"u_tau_s": 0.00003}', '{"u_g": 0.0002}'],
            "evidence_scans": ["CAL-A,CAL-B", None],
            "in_device_model": [False, True],
            "absorbed": [None, None],
            "gap_before_mm": [0.0061] * 2,
            "gap_after_mm": [0.0021] * 2,
            "noise_floor_mm": [0.0020] * 2,
            "reason": [None, None],
        }
    )
    t["calibration_drift"] = pl.DataFrame(
        {
            "night": [night] * 2,
            "device_id": ["TRI-01"] * 2,
            "channel": [2, 3],
            "parameter": ["beta_rad", "rho_mm"],
            "calibration_id_after": ["CAL-2"] * 2,
            "change": [0.0040, 0.0001],
            "u_combined": [0.00085, 0.001],
            "change_over_u": [4.7, 0.1],
            "flagged": [True, False],
            "explained_by": ["channel_delay@2", None],
        }
    )
    # the night's calibration of TRI-01 carried channel_delay@2 (from the night before) and listed an offset
    base = t["calibrations"].filter(pl.col("device_id") == "TRI-01").head(1)
    carried = {
        "diagnostics": {
            "device_model": [
                {
                    "key": "channel_delay@2",
                    "estimated": True,
                    "values": {"tau_s": 0.00119},
                    "u": {"tau_s": 0.00002},
                    "night": "2026-11-19",
                    "source": "config",
                },
                {
                    "key": "sensor_offset@3",
                    "estimated": False,
                    "values": {},
                    "u": {},
                    "night": None,
                    "source": "automatic",
                },
            ]
        },
        "nuisance": {"CAL-A": {"residual_to_noise": [1.01, 1.03, 0.99]}},
    }
    t["calibrations"] = pl.concat(
        [
            t["calibrations"],
            base.with_columns(
                pl.lit("CAL-DM").alias("calibration_id"),
                pl.lit(night).alias("night"),
                pl.lit(night).alias("valid_from"),
                pl.lit(json.dumps(carried)).alias("calibration_json"),
            ),
        ],
        how="diagonal_relaxed",
    )
    catalog.build_catalog(res, t)
    sec = _section(write_report(res).read_text(), "pooled")
    row = sec.split("<td>TRI-01</td>")[1].split("</tr>")[0]
    assert "<b>channel_delay</b> on channel 2: tau = 1.200 ± 0.030 ms (evidence: CAL-A,CAL-B)" in row
    assert "<b>sensor_gain</b> on channel 1" in row.split("</td><td>")[2]  # the device-model column
    cell = row.split("</td><td>")[3]  # what the night's calibration carried, and its residual
    assert "<b>channel_delay@2</b>: tau = 1.190 ± 0.020 ms (from 2026-11-19)" in cell
    assert "<b>sensor_offset@3</b>: not estimated yet" in cell and "residual 1.03 × noise floor" in cell
    assert ">6.10<" in row and ">2.10<" in row and ">2.00<" in row
    drift = sec.split("Calibration drift (1 flagged of 2 changes)")[1]
    assert (
        "+4.00 mrad" in drift
        and "0.85 mrad" in drift
        and "+4.70" in drift
        and "channel_delay@2" in drift
        and "rho_mm" not in drift
    )


def test_findings_rows_carry_the_uncertainties_the_report_shows(tmp_path):
    """A finding's uncertainties travel in the findings table (no findings.json needed to show value ± u)."""
    from borescan.stages.discrepancy import findings_rows

    rows = findings_rows(
        {
            "scan_id": "S-1",
            "verdict": "missing_effect",
            "gap_before": {"rms_mm": 0.0061},
            "gap_after": {"rms_mm": 0.0021},
            "noise_floor_mm": 0.002,
            "named": [
                {
                    "effect": "channel_delay",
                    "channel": 2,
                    "parameters": {"tau_s": 0.0012},
                    "uncertainties": {"u_tau_s": 0.00003},
                }
            ],
        }
    )
    assert json.loads(rows[0]["uncertainties"]) == {"u_tau_s": 0.00003}
    assert findings_rows({"scan_id": "S-2", "verdict": "no_missing_effect"})[0]["uncertainties"] is None
    res = tmp_path / "results"
    t = _rich_tables(res)
    night = t["scans"]["night"].cast(pl.String).max()
    t["findings"] = pl.concat(
        [t["findings"], pl.DataFrame([dict(r, night=night) for r in rows])], how="diagonal_relaxed"
    )
    catalog.build_catalog(res, t)
    disc = _section(write_report(res).read_text(), "discrepancy")
    assert "<b>channel_delay</b> on channel 2: tau = 1.200 ± 0.030 ms" in disc


def test_rod_diameters_without_a_gauge_calibration_need_attention(tmp_path):
    """A rod hole measured with the design base lengths (no ring-gauge calibration yet) is flagged
    in the night's summary with what to do.
    """
    from borescan.stages.measure import ROD_METHOD_NOMINAL

    res = tmp_path / "results"
    tables = _rich_tables(res)
    rod_scan = tables["diameters"].filter(pl.col("calibration_id") == "ROD-CAL-1")["scan_id"][0]
    tables["diameters"] = tables["diameters"].with_columns(
        pl.when(pl.col("calibration_id") == "ROD-CAL-1")
        .then(pl.lit(ROD_METHOD_NOMINAL))
        .otherwise(pl.col("method"))
        .alias("method")
    )
    catalog.build_catalog(res, tables)
    summary = _section(write_report(res).read_text(), "summary")
    assert f"not traceable</b> {rod_scan} (ROD-01)" in summary
    assert "calibrate the rod in its certified ring gauges" in summary


def test_device_model_history_and_its_plot_mark_the_night_the_model_changed():
    """Three nights of one device: the gaps per night from the pooled findings, the calibrations'
    residuals and the verifications' |E| / U (independent arithmetic on the rows), and a dashed line
    with what was carried where the carried model changes.
    """
    nights = ["2026-11-21", "2026-11-23", "2026-11-24"]
    pf = pl.DataFrame(
        {
            "night": nights + ["2026-11-24"],
            "device_id": ["TRI-01"] * 3 + ["TRI-02"],
            "gap_before_mm": [0.0041, 0.0180, 0.0042, 0.009],
            "noise_floor_mm": [0.004, 0.004, 0.0040, 0.003],
        }
    )
    dm = [
        {
            "key": "channel_delay@2",
            "estimated": True,
            "values": {"tau_s": 0.00119},
            "u": {"tau_s": 0.00002},
            "night": "2026-11-23",
        }
    ]

    def cal(cid, night, model, ratios):
        return {
            "calibration_id": cid,
            "device_id": "TRI-01",
            "valid_from": night,
            "calibration_json": json.dumps(
                {"diagnostics": {"device_model": model}, "nuisance": {"A": {"residual_to_noise": ratios}}}
            ),
        }

    newer = [
        dict(dm[0], values={"tau_s": 0.00121}, night="2026-11-24")
    ]  # the next night's estimate: no new mark
    cals = pl.DataFrame(
        [
            cal("C1", nights[0], [], [1.0, 1.02, 0.99]),
            cal("C2", nights[1], [dict(dm[0], estimated=False)], [1.0, 4.5, 1.1]),
            cal("C3", nights[2], dm, [1.01, 1.03, 1.0]),
            cal("C4", "2026-11-25", newer, [1.0, 1.0, 1.0]),
        ]
    )
    ver = pl.DataFrame(
        {
            "night": [nights[1], nights[1], nights[2]],
            "device_id": ["TRI-01"] * 3,
            "error_mm": [-0.004, 0.001, 0.0005],
            "expanded_u_error_mm": [0.0025, 0.0025, 0.0026],
        }
    )
    hist = device_model_history(pf, cals, ver, "TRI-01")
    assert hist["night"].to_list() == nights + ["2026-11-25"]
    assert hist["pooled_gap_to_noise"].to_list()[:3] == pytest.approx([1.025, 4.5, 1.05])
    assert hist["calibration_residual_to_noise"].to_list() == pytest.approx([1.02, 4.5, 1.03, 1.0])
    assert hist["verification_e_over_u"].to_list()[0] is None
    assert hist["verification_e_over_u"].to_list()[1:3] == pytest.approx([1.6, 0.5 / 2.6])
    assert hist["verification_error_um"].to_list()[1:3] == pytest.approx(
        [-4.0, 0.5]
    )  # the worst of the night
    assert hist["carried"].to_list()[:3] == ["", "", "channel_delay@2 tau = 1.190 ± 0.020 ms (2026-11-23)"]
    assert hist["carried_keys"].to_list() == ["", "", "channel_delay@2", "channel_delay@2"]
    fig = plot_device_model_gap(hist, "TRI-01")
    FigureCanvasAgg(fig).draw()
    ax_g, ax_v = fig.axes
    marks = [ln.get_xdata()[0] for ln in ax_g.get_lines() if ln.get_linestyle() == "--"]
    assert marks == [1.5]  # between the night the delay was estimated and the first that carried it
    (note,) = [t.get_text() for t in ax_g.texts]
    assert note == "device model from here:\nchannel_delay@2\ntau = 1.190 ± 0.020 ms\n(estimated 2026-11-23)"
    assert sorted(t.get_text() for t in ax_v.texts) == ["+0.50 µm", "-4.00 µm"]
    renderer = fig.canvas.get_renderer()
    box, axes = ax_g.texts[0].get_window_extent(renderer), ax_g.get_window_extent(renderer)
    assert axes.x0 <= box.x0 and box.x1 <= axes.x1  # the label stays inside the axes
    assert [t.get_text() for t in ax_v.get_xticklabels() if t.get_text()] == nights + ["2026-11-25"]


def test_calibration_trends_give_a_panel_only_to_parameters_that_change():
    """A rod's design geometry (h, phi, d, gamma) is the same in every calibration: no flat panels,
    one line in the title with the values; l0, which the calibrations change, keeps its panels.
    """
    import polars as pl

    from borescan.report.plots import plot_calibration_trends

    rows = [
        {
            "device_id": "ROD-01",
            "calibration_id": f"C{k}",
            "valid_from": f"2026-11-2{k}",
            "scan_id": f"S{k}",
            "channel": ch,
            "l0_mm": 71.0 + 0.01 * k + 0.001 * ch,
            "u_l0_mm": 0.01,
            "h_mm": 100.0 * ch,
            "phi_rad": 0.0,
            "d_mm": 0.0,
            "gamma_rad": 0.0,
        }
        for k in (0, 1)
        for ch in (1, 2)
    ]
    fig = plot_calibration_trends(pl.DataFrame(rows), "ROD-01")
    shown = [ax for ax in fig.axes if ax.get_visible()]
    assert len(shown) == 2 and {ax.get_title() for ax in shown} == {"channel 1", "channel 2"}
    title = fig._suptitle.get_text()
    assert "h_mm 100, 200; phi_rad 0, 0; d_mm 0, 0; gamma_rad 0, 0" in " ".join(title.split())
    # wrapped to the figure's width (it ran off both sides of a two-channel figure)
    assert max(len(line) for line in title.splitlines()) <= 12 * fig.get_figwidth()


def test_part_plot_labels_that_would_overlap_are_slanted_and_a_gauge_is_the_bore():
    """RG-275: four night / scan-id labels side by side on one 3.8 in panel overlapped; a ring gauge
    (no feature in scan.json) was titled "feature ?".
    """
    import polars as pl
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    from borescan.report.plots import plot_diameters

    rows = [
        {
            "artifact_id": "RG-275",
            "feature": None,
            "night": f"2026-11-2{k}",
            "scan_id": f"N2026112{k}-TRI01-VER-RG275",
            "diameter_mm": 275.03,
            "u_diameter_mm": 0.009,
        }
        for k in range(4)
    ]
    fig = plot_diameters(pl.DataFrame(rows), "RG-275")
    (ax,) = fig.axes
    assert ax.get_title() == "the bore (n=4)"
    FigureCanvasAgg(fig).draw()
    labels = [t for t in ax.get_xticklabels() if t.get_text()]
    assert len(labels) == 4 and all(t.get_rotation() == 45 for t in labels)
    # upright they would overlap: together wider than the panel
    upright = sum(t.get_window_extent().width for t in labels) / np.sqrt(0.5)
    assert upright > ax.get_window_extent().width


def test_a_month_assembled_from_cached_pieces_equals_one_built_from_scratch(rich, tmp_path):
    """The month page grown night by night (each night's summary box and each scan's findings row
    reused from pieces.json while their rows and linked files are unchanged) equals the page built
    from scratch, byte for byte; a linked file that appears or a findings.json read for the
    uncertainties that changes re-renders the pieces showing it.
    """
    res, _ = rich
    tables = load_tables(res)
    nights = sorted({str(n) for n in tables["scans"]["night"].drop_nulls().to_list()})
    assert len(nights) == 3

    def upto(last: str) -> dict[str, pl.DataFrame]:
        return {
            name: df.filter(pl.col("night").is_null() | (pl.col("night").cast(pl.Utf8) <= last))
            if "night" in df.columns
            else df
            for name, df in tables.items()
        }

    # PART-7's findings are of the first night, PART-9's of the second, PART-8's of the third
    updates = [update_report(res, upto(nights[0]))]
    (res / "discrepancy" / "PART-7" / "gap.png").unlink()  # a linked file goes
    updates.append(update_report(res, upto(nights[1])))
    part9 = res / "discrepancy" / "PART-9" / "findings.json"  # PART-9's row reads its uncertainties
    part9.write_text(part9.read_text().replace('"u_a_mm": 0.0007', '"u_a_mm": 0.0009'))
    updates.append(update_report(res, upto(nights[2])))
    assert [u.rendered for u in updates] == [("2026-11",)] * 3
    pieces = json.loads((res / "report" / "2026-11" / "pieces.json").read_text())
    assert len(pieces) == len(nights) + tables["findings"]["scan_id"].n_unique() == 6
    # each night renders its own box and its scans' rows; the second also PART-7's row and the first
    # night's box (both linked the gap plot of PART-7 that went), the third PART-9's row (its findings.json
    # changed); every other piece is reused
    assert [u.pieces_rendered for u in updates] == [2, 4, 3]
    grown = {p.name: p.read_bytes() for p in (res / "report" / "2026-11").iterdir()}
    grown["report.html"] = (res / "report.html").read_bytes()

    scratch = tmp_path / "scratch"
    shutil.copytree(res, scratch, ignore=shutil.ignore_patterns("report*"))
    built = update_report(scratch, tables, full=True)
    assert built.pieces_rendered == len(pieces)
    fresh = {p.name: p.read_bytes() for p in (scratch / "report" / "2026-11").iterdir()}
    fresh["report.html"] = (scratch / "report.html").read_bytes()
    assert sorted(grown) == sorted(fresh)
    for name in grown:
        if name != "pieces.json":  # it records each linked file's time, which the copy changed
            assert grown[name] == fresh[name], name
    page = _without_images(grown["index.html"].decode())
    assert "PART-7" in _section(page, "summary") and "PART-7/gap.png" not in page
    assert "0.9" in _section(page, "discrepancy") and "0.7" not in _section(page, "discrepancy")


def test_one_calibration_is_a_table_of_its_values_with_U_at_k2():
    """A device's single calibration: a row per channel, each fitted value ± U (k = 2) = 2 u, as the trend's
    error bars would show it (GUM rounding: U to two digits, the value to the same place).
    """
    from borescan.report.section_calibration import _parameter_values

    cal = pl.DataFrame(
        {
            "calibration_id": ["C1"] * 2,
            "channel": [2, 1],
            "beta_rad": [4.1887902, 2.0943951],
            "u_beta_rad": [1e-4, 1e-4],
            "rho_mm": [0.0123, -0.004],
            "u_rho_mm": [0.0005, 0.0005],
            "d_b_mm": [151.27312, 157.70934],
            "u_d_b_mm": [0.012, 0.012],
            "l0_mm": [None, None],
        }
    )
    html = _parameter_values(cal)
    assert "<th>beta</th><th>rho</th><th>d_b</th></tr>" in html and "l0" not in html
    rows = html.split("<tbody>")[1].split("</tbody>")[0].split("</tr>")[:-1]
    assert [r.replace('<td class="num">', "<td>").replace("<tr>", "") for r in rows] == [
        "<td>1</td><td>2.09440 ± 0.00020 rad</td><td>-4.0 ± 1.0 µm</td><td>157.709 ± 0.024 mm</td>",
        "<td>2</td><td>4.18879 ± 0.00020 rad</td><td>12.3 ± 1.0 µm</td><td>151.273 ± 0.024 mm</td>",
    ]
