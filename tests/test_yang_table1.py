"""Yang 2017 Table 1 recomputed from its printed inputs (Eqs. 8, 10, 11).

Tolerances: a recomputed value may differ from the printed one by the worst-case linear effect
of rounding every printed input by half its last digit (d_max, d_min 0.05 um, sensor 3's d_min
0.5 um, oe 0.05 um, R 0.25 um) plus half the printed output's last digit. That bound is 6-19 um
for d_b and 0.15-1.7 mm for r, because r = sqrt((R - oe)^2 - (d_b + d_min)^2) subtracts two
numbers near 135 mm.
"""

import csv

import numpy as np
import pytest

from borescan.papers.yang_table1 import TABLE1_CSV, load_table1, reproduce, write_reproduction


@pytest.fixture(scope="module")
def rep():
    return reproduce(n_mc=50_000)


def test_transcription():
    rows = load_table1()
    assert [r["sensor"] for r in rows] == [1, 2, 3]
    assert [r["d_max_mm"] for r in rows] == [7.0549, 6.9256, 5.7177]
    assert [r["d_min_mm"] for r in rows] == [2.4067, 2.2804, 1.073]
    assert [r["r_mm"] for r in rows] == [5.5484, 2.5295, 1.5262]
    assert [r["d_b_mm"] for r in rows] == [132.6718, 132.8883, 134.1108]
    assert rows[2]["half_lsb_d_min_mm"] == pytest.approx(5e-4) and rows[0][
        "half_lsb_d_min_mm"
    ] == pytest.approx(5e-5)


def test_table1_within_rounding_bounds_with_printed_oe(rep):
    for row in rep["rows"]:
        assert abs(row["diff_d_b_oe_printed_um"]) <= row["d_b_round_bound_um"] + 0.05
        assert abs(row["diff_r_oe_printed_um"]) <= row["r_round_bound_um"] + 0.05
    # measured: d_b -0.52, -0.48, -0.53 um; r +10.2, +22.2, +36.5 um
    assert [round(r["diff_d_b_oe_printed_um"], 2) for r in rep["rows"]] == [-0.52, -0.48, -0.53]
    assert [round(r["diff_r_oe_printed_um"], 1) for r in rep["rows"]] == [10.2, 22.2, 36.5]


def test_printed_d_b_imply_one_unrounded_oe(rep):
    """All three printed d_b come from oe = 2.322209 mm (not 2.3222): spread < 2 nm, which is the
    effect of d_b's own rounding (0.05 um / (dd_b/doe = 59)) = 0.85 nm per sensor.
    """
    oe = np.array(rep["oe_from_printed_d_b_mm"])
    assert np.ptp(oe) < 2e-6
    assert oe.mean() == pytest.approx(2.322209, abs=1e-6)


def test_computed_oe_breaks_r(rep):
    """With oe from Eq. 9 (2.3232 mm, 1.0 um more) d_b moves by 59 um and r has no real value for
    sensors 2 and 3; sensor 1's r drops from 5.55 to 3.81 mm.
    """
    assert rep["oe_computed_mm"] - rep["oe_printed_mm"] == pytest.approx(1.0055e-3, abs=1e-7)
    r1, r2, r3 = rep["rows"]
    assert r1["r_oe_computed_mm"] == pytest.approx(3.8143, abs=1e-4)
    assert np.isnan(r2["r_oe_computed_mm"]) and np.isnan(r3["r_oe_computed_mm"])
    for row in rep["rows"]:
        assert row["diff_d_b_oe_computed_um"] - row["diff_d_b_oe_printed_um"] == pytest.approx(
            row["dd_b_doe"] * 1.0055, rel=1e-3
        )
    # the printed coordinates themselves (1 um digits) allow oe anywhere in about [2.32215, 2.32426]
    lo, hi = rep["oe_computed_range_mm"]
    assert lo < rep["oe_printed_mm"] < hi


def test_r_sensitivity_and_rounding_spread(rep):
    r1, r2, r3 = rep["rows"]
    assert r1["dr_dd_min"] == pytest.approx(-730.5, abs=0.1) and r3["dr_dd_min"] == pytest.approx(
        -2604.3, abs=0.1
    )
    assert r1["dr_doe"] == pytest.approx(-1462.2, abs=0.1) and r3["dr_doe"] == pytest.approx(-5208.8, abs=0.1)
    assert abs(r1["dr_dR"]) < 0.05
    # sensor 3: rounding alone leaves r anywhere from ~0.4 to ~2.6 mm, 1 in 5 draws have no real r
    assert r3["mc_r_imaginary_fraction"] == pytest.approx(0.20, abs=0.02)
    assert r3["mc_r_p2.5_mm"] < 0.6 and r3["mc_r_p97.5_mm"] > 2.4
    # sensor 1's 95 % range is +-0.1 mm around 5.56 mm
    assert r1["mc_r_p97.5_mm"] - r1["mc_r_p2.5_mm"] == pytest.approx(0.194, abs=0.01)


def test_write_reproduction(tmp_path):
    paths = write_reproduction(tmp_path)
    assert paths["png"].read_bytes().startswith(b"\x89PNG")
    with open(paths["csv"]) as fh:
        rows = list(csv.DictReader(fh))
    assert [int(r["sensor"]) for r in rows] == [1, 2, 3]
    assert float(rows[0]["diff_d_b_oe_printed_um"]) == pytest.approx(-0.521, abs=1e-3)
    assert rows[2]["r_oe_computed_mm"] == ""  # no real r
    assert TABLE1_CSV.name == "yang2017_table1.csv"
