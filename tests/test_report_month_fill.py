"""A month full of nights: the parts' and calibration plots stay readable (labelled by night, no
caps that merge, a bounded width) and a part's tables are rendered again only when its rows change.
"""

from __future__ import annotations

import datetime as dt
import shutil

import numpy as np
import polars as pl
import pytest
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.lines import TICKDOWN

from borescan.report.pages import update_report
from borescan.report.plots import MAX_TICK_LABELS, plot_calibration_trends, plot_diameters

NIGHTS = [str(dt.date(2027, 12, 1) + dt.timedelta(days=k)) for k in range(31)]


def _gauge_rows(per_night: int, features=(None,), nights=NIGHTS) -> pl.DataFrame:
    rng = np.random.default_rng(7)
    return pl.DataFrame(
        [
            {
                "artifact_id": "RG-275",
                "feature": f,
                "night": night,
                "scan_id": f"N{night.replace('-', '')}-TRI01-VER-RG275-S{s}",
                "diameter_mm": 275.029 + float(rng.normal(0.0, 3e-4)),
                "u_diameter_mm": 0.0095,
            }
            for night in nights
            for s in range(per_night)
            for f in features
        ]
    )


def _labels(ax) -> list[str]:
    return [t.get_text() for t in ax.get_xticklabels() if t.get_text()]


def _caps(ax) -> list:
    return [line for line in ax.get_lines() if line.get_marker() in ("_", "|")]


@pytest.mark.parametrize("features", [(None,), ("H1", "H2")])
def test_a_month_of_a_gauge_is_labelled_by_night_without_caps_and_a_page_wide(features):
    """31 nights of 4 verifications (124 points a panel): at most MAX_TICK_LABELS labels, each a
    night (no scan ids), every other night marked; error bars without caps; the figure no wider
    than 8.8 in (it was 12.8 in, wider with every point). Four points keep "night / scan" labels
    and their caps.
    """
    fig = plot_diameters(_gauge_rows(4, features), "RG-275")
    FigureCanvasAgg(fig).draw()
    assert fig.get_figwidth() <= 8.8 + 1e-9
    for ax in [a for a in fig.axes if a.get_visible()]:
        labels = _labels(ax)
        assert 2 <= len(labels) <= MAX_TICK_LABELS
        assert set(labels) <= set(NIGHTS)
        (marks,) = [line for line in ax.get_lines() if line.get_marker() == TICKDOWN]
        firsts = [4 * k for k in range(31)]  # each night's first point
        assert sorted([int(x) for x in ax.get_xticks()] + [int(x) for x in marks.get_xdata()]) == firsts
        assert _caps(ax) == []

    few = plot_diameters(_gauge_rows(1, nights=NIGHTS[:4]), "RG-275")
    FigureCanvasAgg(few).draw()
    (ax,) = few.axes
    assert _labels(ax) == [f"{n}\nN{n.replace('-', '')}-TRI01-VER-RG275-S0" for n in NIGHTS[:4]]
    assert len(_caps(ax)) == 2  # the upper and lower caps, one line of markers each


def _calibrations(nights: list[str], per_night: int) -> pl.DataFrame:
    return pl.DataFrame(
        [
            {
                "calibration_id": f"C{night}-{s}",
                "device_id": "TRI-01",
                "scan_id": f"N{night.replace('-', '')}-TRI01-CAL-S{s}",
                "valid_from": dt.date.fromisoformat(night),
                "method": "spindle",
                "channel": ch,
                "beta_rad": 2.0 * ch + 1e-4 * s,
                "u_beta_rad": 5e-4,
                "rho_mm": -2.0 + ch,
                "u_rho_mm": 0.05,
                "d_b_mm": 132.0 + ch,
                "u_d_b_mm": 0.006,
            }
            for night in nights
            for s in range(per_night)
            for ch in (1, 2, 3)
        ]
    )


def test_a_month_of_calibrations_is_labelled_by_night_on_the_bottom_row_only():
    """93 calibrations: the bottom panels labelled by night (at most four), the others unlabelled,
    every other night marked, no caps; four calibrations keep "night / scan" labels, caps, and
    labels on the bottom row only.
    """
    fig = plot_calibration_trends(_calibrations(NIGHTS, 3), "TRI-01")
    FigureCanvasAgg(fig).draw()
    axes = np.asarray(fig.axes).reshape(3, 3)
    for i, row in enumerate(axes):
        for ax in row:
            labels = [t for t in ax.get_xticklabels() if t.get_visible() and t.get_text()]
            if i == 2:
                assert 2 <= len(labels) <= 4 and {t.get_text() for t in labels} <= set(NIGHTS)
            else:
                assert labels == []
            (marks,) = [line for line in ax.get_lines() if line.get_marker() == TICKDOWN]
            ticks = [int(x) for x in ax.get_xticks()] + [int(x) for x in marks.get_xdata()]
            assert sorted(ticks) == [3 * k for k in range(31)]
            assert _caps(ax) == []

    few = plot_calibration_trends(_calibrations(NIGHTS[:2], 2), "TRI-01")
    FigureCanvasAgg(few).draw()
    axes = np.asarray(few.axes).reshape(3, 3)
    for i, row in enumerate(axes):
        for ax in row:
            labels = [t.get_text() for t in ax.get_xticklabels() if t.get_visible() and t.get_text()]
            assert labels == (
                [f"{n}\nN{n.replace('-', '')}-TRI01-CAL-S{s}" for n in NIGHTS[:2] for s in (0, 1)]
                if i == 2
                else []
            )
            assert len(_caps(ax)) == 2


def test_a_parts_tables_are_rendered_again_only_when_its_rows_change(tmp_path):
    """Three nights: RG-275 measured every night, P-7 twice on the first night only. P-7's tables are
    rendered once and reused; RG-275's each night (its rows grow); the month page grown night by
    night equals the page built from scratch, byte for byte.
    """
    nights = NIGHTS[:3]
    dia = pl.concat(
        [
            _gauge_rows(2, nights=nights),
            _gauge_rows(2, nights=nights[:1]).with_columns(
                pl.lit("P-7").alias("artifact_id"), pl.format("P7-{}", pl.col("scan_id")).alias("scan_id")
            ),
        ]
    ).with_columns(pl.col("night").str.to_date())
    res = tmp_path / "results"
    updates = [
        update_report(res, {"diameters": dia.filter(pl.col("night") <= pl.lit(n).str.to_date())})
        for n in nights
    ]
    assert [u.pieces_rendered for u in updates] == [2, 1, 1]
    grown = (res / "report" / "2027-12" / "index.html").read_bytes()
    scratch = tmp_path / "scratch"
    shutil.copytree(res, scratch, ignore=shutil.ignore_patterns("report*"))
    built = update_report(scratch, {"diameters": dia}, full=True)
    assert built.pieces_rendered == 2
    assert (scratch / "report" / "2027-12" / "index.html").read_bytes() == grown


def test_a_months_plots_drawn_on_two_processes_are_the_plots_drawn_on_one(tmp_path):
    """Nine parts' diameter plots drawn together after the sections, on two processes: every PNG and
    every page byte for byte what one process draws (a worker has the same matplotlib settings), and
    a second update draws none (each PNG is read back where its input is unchanged).
    """
    dia = pl.concat(
        [
            _gauge_rows(2, nights=NIGHTS[:2]).with_columns(
                pl.lit(f"P-{k}").alias("artifact_id"), pl.format("P{}-{}", pl.lit(k), pl.col("scan_id"))
            )
            for k in range(9)
        ]
    ).with_columns(pl.col("night").str.to_date())
    pages = {}
    for workers in (1, 2):
        res = tmp_path / f"results{workers}"
        first = update_report(res, {"diameters": dia}, workers=workers)
        assert first.plots_drawn == 9
        assert update_report(res, {"diameters": dia}, workers=workers).plots_drawn == 0
        month = res / "report" / "2027-12"
        pages[workers] = {
            f.name: f.read_bytes() for f in sorted(month.iterdir()) if f.suffix in (".png", ".html")
        } | {"report.html": (res / "report.html").read_bytes()}
        assert b"@@PNG" not in pages[workers]["index.html"] + pages[workers]["report.html"]
    assert len([f for f in pages[1] if f.endswith(".png")]) == 9
    assert pages[2] == pages[1]
