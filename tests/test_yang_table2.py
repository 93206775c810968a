"""Yang 2017 Table 2: transcription and everything computed from it (papers/yang_table2.py)."""

import csv
import math

import numpy as np
import pytest

from borescan.papers.yang_table2 import TABLE2_CSV, load_table2, reproduce, write_reproduction


@pytest.fixture(scope="module")
def rep():
    return reproduce()


def test_transcription_is_complete_and_marks_the_gaps():
    t = load_table2()
    for ch in (1, 2, 3):
        assert t[ch]["min"].size == 18 and t[ch]["max"].size == 18
    # first and last printed Numbers of each column (thousands separators removed)
    first = [t[ch][k][0] for ch in (1, 2, 3) for k in ("min", "max")]
    last = [t[ch][k][-1] for ch in (1, 2, 3) for k in ("min", "max")]
    assert first == [312, 639, 88, 418, 531, 199]
    assert last == [11528, 11855, 11305, 11635, 11746, 11416]
    blanks = [(ch, k) for ch in (1, 2, 3) for k, v in t[ch]["diff"].items() if v is None]
    assert blanks == [(1, ("max", 18)), (2, ("max", 18)), (3, ("max", 18))]
    assert {ch: (t[ch]["mean"]["min"], t[ch]["mean"]["max"]) for ch in (1, 2, 3)} == {
        1: (328, 332),
        2: (329, 331),
        3: (331, 329),
    }
    with open(TABLE2_CSV) as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == 3 * 2 * 18 + 6
    assert all("Mean" in r["note"] for r in rows if r["row"] == "")


def test_every_printed_difference_is_the_interval_between_printed_numbers(rep):
    """All 105 printed Difference cells are successive intervals of the time-ordered Numbers."""
    assert rep["difference_mismatches"] == []
    # ... but one printed "Mean" is not the rounded mean of its 17 cells: sensor 2, max -> min
    assert len(rep["mean_mismatches"]) == 1
    mm = rep["mean_mismatches"][0]
    assert (mm["channel"], mm["column_next_to"], mm["printed"], mm["cells"]) == (2, "max", 331, 17)
    assert mm["computed"] == pytest.approx(5617 / 17)  # 330.41


def test_mean_counts_reproduce_the_printed_means_and_statuses(rep):
    c = rep["channels"]
    # n = min -> max, m = max -> min; printed means are these rounded to whole samples
    assert (round(c[1]["n_mean"]), round(c[1]["m_mean"])) == (328, 332)
    assert (round(c[2]["n_mean"]), round(c[2]["m_mean"])) == (329, 330)  # printed 331: 330.41 rounds to 330
    assert c[2]["m_mean"] == pytest.approx(5617 / 17)
    assert (round(c[3]["n_mean"]), round(c[3]["m_mean"])) == (329, 331)
    assert c[1]["n_mean"] == pytest.approx(5902 / 18) and c[1]["m_mean"] == pytest.approx(5641 / 17)
    # sensor 3 starts with a maximum: its d_min-side column is m, not n
    assert c[3]["first_extremum"] == "max"
    assert [c[ch]["status_computed"] for ch in (1, 2, 3)] == ["backward", "backward", "backward"]
    assert [c[ch]["status_printed"] for ch in (1, 2, 3)] == ["backward", "backward", "advanced"]
    assert c[3]["status_if_columns_read_by_position"] == "advanced"  # how the paper got "advanced"


def test_period_is_about_660_not_625(rep):
    t = load_table2()
    sp = rep["samples_per_rev"]
    assert sp["printed"] == 625.0
    # closed form: least-squares slope of the minima of sensor 1 against their index
    slope = np.polyfit(np.arange(18), t[1]["min"], 1)[0]
    assert rep["channels"][1]["samples_per_rev_from_minima"] == pytest.approx(slope, abs=1e-9)
    assert sp["measured"] == pytest.approx(659.72, abs=0.01)
    assert sp["u_measured"] == pytest.approx(0.026, abs=0.002)
    assert (sp["measured"] - 625.0) / sp["u_measured"] > 1000
    for ch in (1, 2, 3):
        c = rep["channels"][ch]
        assert abs(c["samples_per_rev_from_minima"] - sp["measured"]) < 3 * c["u_samples_per_rev_from_minima"]


def test_feature_spacings_and_theta_t(rep):
    sp = {(s["from_channel"], s["to_channel"]): s for s in rep["spacings"]}
    for pair, printed in {(2, 1): 222, (1, 3): 220, (3, 2): 219}.items():
        s = sp[pair]
        assert round(s["computed"]) == printed and abs(s["computed"] - printed) < 0.5
        assert s["theta_t_deg_at_625"] == pytest.approx(s["computed"] * 360 / 625)
        p_measured = rep["samples_per_rev"]["measured"]
        assert s["theta_t_deg_at_measured"] == pytest.approx(s["computed"] * 360 / p_measured)
        assert s["theta_t_error_deg"] == pytest.approx(6.67, abs=0.06)
    assert sp[(2, 1)]["computed"] == pytest.approx(3989 / 18)
    # once round the three sensors is one revolution
    assert rep["spacings_sum"]["computed"] == pytest.approx(rep["samples_per_rev"]["measured"], abs=0.2)
    assert rep["spacings_sum"]["printed"] == 661


def test_printed_asymmetry_exceeds_what_beam_offsets_allow(rep):
    """Table 1 r = 5.5484 mm etc.: |n - m| = 2 delta P / 2 pi <= 0.29 samples; Table 2 has -3.9 +- 0.8."""
    g = rep["geometry_n_minus_m"]
    d = math.atan(5.5484 / (132.6718 + 2.4067)) - math.atan(5.5484 / (132.6718 + 7.0549))
    expect = 2 * d * rep["samples_per_rev"]["measured"] / (2 * np.pi)
    assert g[1]["n_minus_m_abs_at_measured_P"] == pytest.approx(expect)
    c1 = rep["channels"][1]
    assert c1["n_minus_m"] == pytest.approx(-3.88, abs=0.01)
    assert (abs(c1["n_minus_m"]) - g[1]["n_minus_m_abs_at_measured_P"]) / c1["u_n_minus_m"] > 4


def test_write_reproduction(tmp_path, rep):
    paths = write_reproduction(tmp_path)
    assert [p.name for p in paths] == ["yang2017_table2.csv", "yang2017_table2.png"]
    with open(paths[0]) as fh:
        rows = list(csv.DictReader(fh))
    by = {(r["quantity"], r["channel"]): r for r in rows}
    computed = float(by[("samples_per_rev", "")]["computed"])
    assert computed == pytest.approx(rep["samples_per_rev"]["measured"], abs=1e-4)
    assert by[("status", "3")]["difference"] == "DISAGREES"
    assert float(by[("spacing_samples", "2->1")]["printed"]) == 222
    assert paths[1].read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
