"""The report's numbers and plots for people (issue 37, item 10): a parameter's name never carries
a unit other than the one shown, no exponent notation, tick labels that do not overlap, no panel of
a parameter that was not fitted.
"""

from __future__ import annotations

import json
import math
import re

import numpy as np
import polars as pl
import pytest
from matplotlib.backends.backend_agg import FigureCanvasAgg

from borescan.report.plots import plot_calibration_trends, plot_diameters
from borescan.report.text import _parameters_text, format_quantity


@pytest.mark.parametrize("exponent", range(-5, 8))
def test_values_without_uncertainty_keep_four_significant_digits_and_no_exponent(exponent):
    v = 1.6734567 * 10.0**exponent
    text = format_quantity(v, None, "urad")
    number, unit = text.split(" ")
    assert unit == "urad" and "e" not in number.lower()
    # 4 significant digits: within half a unit of the 4th digit
    assert abs(float(number) - v) <= 0.5 * 10.0 ** (math.floor(math.log10(v)) - 3) * (1 + 1e-12)
    assert len(number.replace(".", "").replace("-", "").lstrip("0")) >= 4


def test_a_parameter_is_named_without_a_unit_it_is_not_shown_in():
    text = _parameters_text(
        "sensor_offset",
        json.dumps({"b_mm": 0.000907, "tau_s": 0.0012, "rho_mm": 5.51, "k": 2}),
        {"b_mm": 0.00003, "tau_s": 0.00003},
    )
    # b_mm = 0.907 ± 0.030 um was the bug: the name said mm, the value was in µm; an order k is an integer
    assert text == "b = 0.907 ± 0.030 µm; k = 2; rho = 5.510 mm; tau = 1.200 ± 0.030 ms"


def test_part_plot_labels_do_not_overlap():
    """Four verifications of a ring gauge with the demo's scan ids: the x labels are apart."""
    ids = [f"N202611{d}-TRI01-VER-RG275" for d in (20, 21, 23, 24)]
    dia = pl.DataFrame(
        {
            "night": ["2026-11-20", "2026-11-21", "2026-11-23", "2026-11-24"],
            "scan_id": ids,
            "artifact_id": ["RG-275"] * 4,
            "feature": [None] * 4,
            "diameter_mm": [275.0295, 275.0289, 275.0298, 275.0292],
            "u_diameter_mm": [0.0095] * 4,
        }
    )
    fig = plot_diameters(dia, "RG-275")
    FigureCanvasAgg(fig).draw()
    renderer = fig.canvas.get_renderer()
    (ax,) = [a for a in fig.axes if a.get_visible()]
    labels = [t for t in ax.get_xticklabels() if t.get_text()]
    assert len(labels) == 4
    angle = math.radians(labels[0].get_rotation())
    boxes = [t.get_window_extent(renderer) for t in labels]
    if angle == 0.0:
        assert all(a.x1 <= b.x0 for a, b in zip(boxes, boxes[1:]))
    else:  # slanted lines of text are apart when the spacing across them exceeds a label's height
        labels[0].set_rotation(0)
        height = labels[0].get_window_extent(renderer).height
        anchors = [ax.transData.transform((x, 0))[0] for x in ax.get_xticks()]
        assert min(np.diff(anchors)) * math.sin(angle) >= height
    assert "?" not in ax.get_title()  # a part without named features is no "feature ?"


def test_calibration_plot_leaves_out_parameters_held_at_their_design_values():
    """A rod's gauge calibration fits l0 only: h, phi, d and gamma keep their design values."""
    rows = []
    for cid, method, l0 in (("R-NOM", "nominal", (71.0, 71.0)), ("R-CAL", "rod_gauge", (71.016, 70.995))):
        for ch, (h, l) in enumerate(zip((100.0, 400.0), l0), start=1):
            rows.append(
                {
                    "calibration_id": cid,
                    "device_id": "ROD-01",
                    "valid_from": "2026-11-20",
                    "scan_id": "N20261120-ROD01-CAL-RGS150",
                    "method": method,
                    "channel": ch,
                    "l0_mm": l,
                    "u_l0_mm": 0.017 if method != "nominal" else None,
                    "h_mm": h,
                    "phi_rad": 0.0,
                    "d_mm": 0.0,
                    "gamma_rad": 0.0,
                }
            )
    fig = plot_calibration_trends(pl.DataFrame(rows), "ROD-01")
    FigureCanvasAgg(fig).draw()
    shown = [a for a in fig.axes if a.get_visible()]
    assert len(shown) == 2  # l0_mm on each channel
    assert all(np.ptp(a.get_lines()[0].get_ydata()) > 0 for a in shown if a.get_lines())
    title = fig._suptitle.get_text()
    held = title.split("no uncertainty; channel ")[1]  # named with their values, one per channel
    assert all(f"{p} " in held for p in ("h_mm", "phi_rad", "d_mm", "gamma_rad"))
    labels = [t.get_text() for t in shown[0].get_xticklabels() if t.get_text()]
    assert sorted(labels) == sorted(["2026-11-20\ndesign geometry", "2026-11-20\nN20261120-ROD01-CAL-RGS150"])


def test_papers_page_leads_with_printed_ours_why_read_from_the_reproductions(tmp_path):
    """The "ours" column is computed from the reproductions' CSVs (here constructed), not copied."""
    from borescan.report.pages import write_report
    from test_catalog import make_history

    from borescan import catalog

    res = tmp_path / "results"
    catalog.build_catalog(res, make_history(res))
    papers = res / "papers"
    papers.mkdir()
    pl.DataFrame(
        {
            "quantity": ["samples_per_rev", "samples_per_rev_from_minima"],
            "channel": [None, "1"],
            "printed": ["625.0000", "625.0000"],
            "computed": ["659.7176", "659.7626"],
            "u_computed": [0.0258, 0.0740],
        }
    ).write_csv(papers / "yang2017_table2.csv")
    diffs = [0.18, -0.22, 0.24, 0.17]
    pl.DataFrame({"no": [1, 2, 3, 4], "literal_eq14_diff_um": [-177.6, -239.5, -111.9, 300.0]}).write_csv(
        papers / "yang_table3.csv"
    )
    pl.DataFrame(
        {"theta_c": ["none", "eq14"], "N": [661.0, 659.7], "rms_um": [_rms_of(diffs), 229.0]}
    ).write_csv(papers / "yang_table3_alternatives.csv")
    pl.DataFrame(
        {"item": ["Eq. 15 total"], "paper": ["24.8 um"], "reproduced": ["24.805 um"], "note": ["sqrt(sum)"]}
    ).write_csv(papers / "wang_statements.csv")
    write_report(res)
    page = (res / "report" / "papers.html").read_text()
    table = page.split('<h3 class="headline">')[1].split("</table>")[0]
    rows = [re.findall(r"<td>(.*?)</td>", r) for r in table.split("<tr>")[2:]]
    assert [r[1] for r in rows] == [
        "§3.2: 625 samples per revolution",
        "Table 3 diameters",
        "Eq. 15 total: 24.8 um",
    ]
    assert rows[0][2] == "659.72 ± 0.03 from Table 2&#x27;s own sample numbers"
    literal = _rms_of([-177.6, -239.5, -111.9, 300.0])
    assert rows[1][2].startswith(
        f"reproduced to {_rms_of(diffs):.2f} µm RMS only with θ = θ_t, no θ_c and N = 661"
    )
    assert f"misses by {literal:.0f} µm RMS" in rows[1][2]
    assert rows[2][2:4] == ["24.805 um", "sqrt(sum)"]
    assert 'href="../papers/wang_statements.csv"' in table


def _rms_of(values: list[float]) -> float:
    return math.sqrt(sum(v * v for v in values) / len(values))


def test_control_chart_shows_the_error_bars_whole():
    """The demo's verifications: errors under 1 µm with U (k=2) near 19 µm; no bar is cut at the axes."""
    from borescan.report.plots import plot_control_chart

    err_mm = [0.00047, -0.00013, 0.00075, 0.00015]
    u_mm = [0.0094, 0.0094, 0.00944, 0.0094]
    ver = pl.DataFrame(
        {
            "night": ["2026-11-20", "2026-11-21", "2026-11-23", "2026-11-24"],
            "scan_id": [f"V{i}" for i in range(4)],
            "device_id": ["TRI-01"] * 4,
            "error_mm": err_mm,
            "u_error_mm": u_mm,
            "passed": [True] * 4,
            "tolerance_mm": [0.015] * 4,
        }
    )
    fig = plot_control_chart(ver, "TRI-01")
    lo, hi = fig.axes[0].get_ylim()
    tops = [(e + 2 * u) * 1e3 for e, u in zip(err_mm, u_mm)]
    bottoms = [(e - 2 * u) * 1e3 for e, u in zip(err_mm, u_mm)]
    assert lo < min(bottoms) and max(tops) < hi


def test_control_chart_marks_each_verification_by_its_verdict():
    """A verification that cannot decide (U not below T) was drawn as "passed": each point now
    carries its verdict under the decision rule, so the chart says what the summary says.
    """
    from borescan.report.plots import plot_control_chart

    ver = pl.DataFrame(
        {
            "night": ["2026-11-20", "2026-11-21", "2026-11-23", "2026-11-24"],
            "scan_id": [f"V{i}" for i in range(4)],
            "device_id": ["TRI-01"] * 4,
            "error_mm": [0.0005, 0.002, 0.0007, 0.02],
            "u_error_mm": [0.0094, 0.002, 0.0094, 0.002],
            "passed": [True, True, True, False],
            "conformity": ["cannot decide", "conforms", "cannot decide", "does not conform"],
            "tolerance_mm": [0.015] * 4,
        }
    )
    ax = plot_control_chart(ver, "TRI-01").axes[0]
    points = {
        line.get_label(): list(line.get_xdata())
        for line in ax.get_lines()
        if not line.get_label().startswith("_")
    }
    assert points["conforms"] == [1]
    assert points["cannot decide (U too large)"] == [0, 2]
    assert points["does not conform"] == [3]
    assert "passed" not in points
