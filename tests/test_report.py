"""report.html: sections, relative links that resolve, control-chart limits, pure plot functions."""

from __future__ import annotations

import shutil
from html.parser import HTMLParser
from pathlib import Path

import numpy as np
import polars as pl
import pytest
from matplotlib.figure import Figure
from test_catalog import make_history

from borescan import catalog, report


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
    lim = report.control_limits([1.0, 3.0, 2.0, 6.0])
    assert lim["mean"] == pytest.approx(3.0)
    np.testing.assert_allclose(lim["mr"], [2.0, 1.0, 4.0])
    assert lim["mr_bar"] == pytest.approx(7 / 3)
    assert lim["ucl"] == pytest.approx(3.0 + 2.66 * 7 / 3)  # 9.206667
    assert lim["lcl"] == pytest.approx(3.0 - 2.66 * 7 / 3)  # -3.206667
    assert lim["mr_ucl"] == pytest.approx(3.267 * 7 / 3)  # 7.623
    assert lim["ucl"] == pytest.approx(9.206666667) and lim["mr_ucl"] == pytest.approx(7.623)
    assert lim["mr_lcl"] == 0.0


def test_control_limits_nan_and_single_value():
    lim = report.control_limits([0.004, float("nan"), 0.006])
    assert lim["mean"] == pytest.approx(0.005) and lim["mr_bar"] == pytest.approx(0.002)
    one = report.control_limits([0.004])
    assert one["mean"] == pytest.approx(0.004) and np.isnan(one["ucl"]) and one["mr"].size == 0


# --------------------------------------------------------------------------- plots


def _frames(results):
    return report.load_tables(results)


def test_plot_functions_are_pure_and_labelled(results):
    t = _frames(results)
    before = t["verifications"].clone()
    fig = report.plot_control_chart(t["verifications"], "TRI-01")
    assert isinstance(fig, Figure)
    ax_i, ax_mr = fig.axes
    assert t["verifications"].equals(before)
    labels = [tick.get_text() for tick in ax_mr.get_xticklabels()]
    assert labels == ["2026-11-20\nVER-20", "2026-11-21\nVER-21", "2026-11-22\nVER-22"]
    # individuals chart lines: mean, UCL, LCL (in µm) from the hand formula
    err = np.array([0.004, 0.020, -0.001])
    mr_bar = np.mean(np.abs(np.diff(err)))
    hlines = sorted(round(line.get_ydata()[0], 6) for line in ax_i.get_lines()
                    if len(set(line.get_ydata())) == 1 and len(line.get_ydata()) == 2)
    for expect in (err.mean(), err.mean() + 2.66 * mr_bar, err.mean() - 2.66 * mr_bar):
        assert round(expect * 1e3, 6) in hlines
    mr_lines = [round(line.get_ydata()[0], 6) for line in ax_mr.get_lines() if len(line.get_ydata()) == 2
                and len(set(line.get_ydata())) == 1]
    assert round(3.267 * mr_bar * 1e3, 6) in mr_lines

    cal_fig = report.plot_calibration_trends(t["calibrations"], "TRI-01")
    assert len([a for a in cal_fig.axes if a.get_visible()]) == 9  # 3 parameters x 3 channels
    bottom = [tick.get_text() for tick in cal_fig.axes[-1].get_xticklabels()]
    assert bottom == ["2026-11-20\nCAL-A-P1", "2026-11-22\nCAL-B"]
    rod_fig = report.plot_calibration_trends(t["calibrations"], "ROD-01")
    assert len([a for a in rod_fig.axes if a.get_visible()]) == 5  # l0, h, phi, d, gamma

    dia_fig = report.plot_diameters(t["diameters"], "P-7")
    (ax,) = [a for a in dia_fig.axes if a.get_visible()]
    assert [tick.get_text() for tick in ax.get_xticklabels()] == ["2026-11-20\nPART-7"]


# --------------------------------------------------------------------------- page


def test_report_written_with_sections_and_existing_links(results):
    page = report.write_report(results)
    assert page == results / "report.html"
    text = page.read_text()
    for sid in ("calibration", "verification", "diameters", "discrepancy", "papers", "quarantine"):
        assert f'<section id="{sid}">' in text
    files = _check_links_resolve(results)
    # the plots, certificates, gap plots and paper outputs are all linked
    for expect in ("report/2026-11/control_TRI-01.png", "report/2026-11/calibration_TRI-01.png",
                   "report/2026-11/calibration_ROD-01.png", "report/2026-11/index.html",
                   "calibration/TRI-01/CAL-A/certificate.pdf",
                   "calibration/TRI-01/CAL-A/certificate.json", "discrepancy/PART-7/gap.png",
                   "papers/wang_fig7.png", "papers/yang_table1.csv", "quarantine/BAD-1.json"):
        assert expect in files, expect
    # the month's own page: the same sections (papers aside), its links relative to report/2026-11/
    month = _check_links_resolve(results, "report/2026-11/index.html")
    for expect in ("control_TRI-01.png", "../../calibration/TRI-01/CAL-A/certificate.pdf",
                   "../../discrepancy/PART-7/gap.png", "../../quarantine/BAD-1.json", "../../report.html"):
        assert expect in month, expect
    month_text = (results / "report" / "2026-11" / "index.html").read_text()
    assert text.split('<section id="calibration">')[1].split("</section>")[0].replace("report/2026-11/", "") == \
        month_text.split('<section id="calibration">')[1].split("</section>")[0].replace("../../", "")
    assert '<section id="papers">' not in month_text
    # a certificate whose files are absent is named, not linked
    assert "calibration/ROD-01/ROD-CAL-1/certificate.pdf (missing)" in text
    assert "lds.parquet: non-monotonic sample" in text
    assert "missing_effect" in text and "channel_delay" in text
    assert "rho_1_mm" in text  # the paper CSV as a table
    assert "VER-21" in text and "FAILED" in text
    # the suspect measurement (PART-7 used CAL-A, which failed on the 21st) is listed
    suspect = text.split("Measurements put in doubt")[1].split("</table>")[0]
    assert "PART-7" in suspect and "PART-8" not in suspect
    # every PNG written is a real PNG
    pngs = list((results / "report").rglob("*.png"))
    assert sorted(p.name for p in pngs) == ["calibration_ROD-01.png", "calibration_TRI-01.png", "control_TRI-01.png"]
    for png in pngs:
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    # parts measured once share one table (a single value has no distribution to plot)
    once = text.split("Parts measured once (3)")[1].split("</table>")[0]
    assert all(p in once for p in ("P-7", "P-8", "P-9")) and "diameters_P-7.png" not in files


def test_report_plots_parts_measured_more_than_once(results):
    t = report.load_tables(results)
    dia = t["diameters"]
    again = dia.filter(pl.col("artifact_id") == "P-7").with_columns(
        pl.lit("PART-7B").alias("scan_id"), (pl.col("diameter_mm") + 0.002).alias("diameter_mm"))
    t["diameters"] = pl.concat([dia, again], how="diagonal_relaxed")
    text = report.write_report(results, t).read_text()
    assert "<h3>Part P-7</h3>" in text and "Parts measured once (2)" in text
    assert (results / "report" / "2026-11" / "diameters_P-7.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_report_links_survive_moving_the_folder(results, tmp_path):
    report.write_report(results)
    moved = tmp_path / "elsewhere" / "results-copy"
    shutil.move(str(results), str(moved))
    assert _check_links_resolve(moved)


def _files(folder):
    return {p.relative_to(folder).as_posix(): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def test_report_rerun_is_byte_identical(results):
    report.write_report(results)
    first = _files(results / "report")
    html1 = (results / "report.html").read_bytes()
    report.write_report(results)
    assert _files(results / "report") == first
    assert (results / "report.html").read_bytes() == html1
    report.write_report(results, full=True)  # everything drawn again: the same bytes
    assert _files(results / "report") == first
    assert (results / "report.html").read_bytes() == html1


def test_report_of_empty_catalog(tmp_path):
    res = tmp_path / "results"
    catalog.build_catalog(res, {})
    text = report.write_report(res).read_text()
    assert "No calibrations in the catalog." in text
    assert "No verifications in the catalog." in text
    assert "No quarantined scans." in text
    assert "No paper reproductions" in text
    assert _check_links_resolve(res) == []


def test_report_from_given_frames_without_catalog(tmp_path):
    res = tmp_path / "results"
    ver = pl.DataFrame({
        "scan_id": ["V1", "V2", "V3", "V4"], "night": ["2026-11-20", "2026-11-21", "2026-11-22", "2026-11-23"],
        "device_id": ["TRI-02"] * 4, "error_mm": [0.001, 0.003, 0.002, 0.006], "tolerance_mm": [0.015] * 4,
        "passed": [True] * 4, "calibration_id": ["C"] * 4, "measured_mm": [None] * 4, "certified_mm": [None] * 4,
    })
    text = report.write_report(res, {"verifications": ver}).read_text()
    # limits table of the device: mean 0.003, MR-bar 7/3 µm, UCL 0.003 + 2.66 * 0.0023333
    assert f"{0.003 + 2.66 * 0.007 / 3:.6g}" in text
    assert f"{3.267 * 0.007 / 3:.6g}" in text
    assert (res / "report" / "2026-11" / "control_TRI-02.png").is_file()
