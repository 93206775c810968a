"""Calibration records: which calibration a result may use, and the rows a calibration is stored as."""

import json
import math

import numpy as np
import polars as pl
import pytest

from borescan.calibrate.result import TriCalibration
from borescan.calibrations import (
    calibration_drift,
    calibration_rows,
    choose_calibration,
    days_between,
    failed_calibration_ids,
    rod_layers,
    rod_nominal_calibration_rows,
    tri_calibration,
)
from borescan.geometry import Beams


def _cals(*rows):
    return pl.DataFrame([{"calibration_id": c, "device_id": d, "valid_from": v} for c, d, v in rows])


CALS = _cals(
    ("TRI-A", "TRI-01", "2026-11-01"),
    ("TRI-B", "TRI-01", "2026-11-20"),
    ("TRI-C", "TRI-01", "2026-11-25"),
    ("OTHER", "TRI-02", "2026-11-19"),
)


def test_days_between_counts_calendar_days():
    assert days_between("2026-11-20", "2026-11-21") == 1
    assert days_between("2026-02-28", "2026-03-01") == 1
    assert days_between("2026-11-20", "2026-11-20") == 0


def test_latest_calibration_on_or_before_the_night_is_chosen():
    assert choose_calibration(CALS, set(), "TRI-01", "2026-11-21", 30, False) == ("TRI-B", None)
    assert choose_calibration(CALS, set(), "TRI-01", "2026-11-20", 30, False) == (
        "TRI-B",
        None,
    )  # same night counts
    assert choose_calibration(CALS, set(), "TRI-01", "2026-11-19", 30, False) == (
        "TRI-A",
        None,
    )  # later ones unseen


def test_same_night_ties_are_broken_by_calibration_id():
    cals = _cals(("TRI-Y", "TRI-01", "2026-11-20"), ("TRI-X", "TRI-01", "2026-11-20"))
    assert choose_calibration(cals, set(), "TRI-01", "2026-11-20", 30, False)[0] == "TRI-Y"


def test_no_calibration_names_device_and_night():
    cal, why = choose_calibration(CALS, set(), "TRI-01", "2026-10-31", 30, False)
    assert cal is None and why == "no calibration of device TRI-01 on or before night 2026-10-31"
    assert choose_calibration(pl.DataFrame(), set(), "TRI-01", "2026-11-21", 30, False)[0] is None
    assert choose_calibration(CALS, set(), "TRI-09", "2026-11-21", 30, False)[0] is None


def test_expiry_is_strictly_after_the_validity():
    # TRI-B valid from 2026-11-20: 30 days later is still valid, 31 days later it has expired
    assert choose_calibration(
        CALS.filter(pl.col("calibration_id") != "TRI-C"), set(), "TRI-01", "2026-12-20", 30, False
    ) == ("TRI-B", None)
    cal, why = choose_calibration(
        CALS.filter(pl.col("calibration_id") != "TRI-C"), set(), "TRI-01", "2026-12-21", 30, False
    )
    assert cal is None
    assert why == "latest calibration TRI-B of device TRI-01 expired (31 days old, validity 30 days)"


def test_failed_latest_is_refused_not_replaced_by_an_older_one():
    cal, why = choose_calibration(CALS, {"TRI-B"}, "TRI-01", "2026-11-21", 30, False)
    assert cal is None and "TRI-B" in why and "failed its verification; recalibrate" in why


def test_allow_unverified_takes_the_latest_even_if_failed_or_expired():
    assert choose_calibration(CALS, {"TRI-B"}, "TRI-01", "2026-11-21", 30, True) == ("TRI-B", None)
    assert choose_calibration(CALS, set(), "TRI-01", "2027-06-01", 30, True) == ("TRI-C", None)


def test_failed_calibration_ids_from_verifications():
    ver = pl.DataFrame({"calibration_id": ["A", "B", None, "C"], "passed": [True, False, False, False]})
    assert failed_calibration_ids(ver) == {"B", "C"}
    assert failed_calibration_ids(pl.DataFrame()) == set()


def _tri_cal():
    beams = Beams(
        channels=(1, 2, 3),
        beta_rad=np.array([0.0, 2.1, 4.2]),
        rho_mm=np.array([1.0, -2.0, 0.5]),
        d_b_mm=np.array([120.0, 121.0, 122.0]),
    )
    cov = np.diag(np.arange(1, 10, dtype=float) * 1e-8)
    return TriCalibration(
        "TRI-01-20261120-abc", "TRI-01", beams, cov, "full_lsq", ("S1", "S2"), residual_rms_mm=0.002
    )


def test_calibration_rows_one_per_channel_and_round_trip():
    cal = _tri_cal()
    rows = calibration_rows(cal, "tri_lds", "2026-11-20", "calibration/x/certificate.pdf", "f" * 64)
    assert [r["channel"] for r in rows] == [1, 2, 3]
    assert rows[1]["rho_mm"] == -2.0 and rows[1]["u_rho_mm"] == pytest.approx(math.sqrt(5e-8))
    assert {r["valid_from"] for r in rows} == {"2026-11-20"} and rows[0]["scan_id"] == "S1"
    back = tri_calibration(pl.DataFrame(rows), cal.calibration_id)
    np.testing.assert_array_equal(back.beams.rho_mm, cal.beams.rho_mm)
    np.testing.assert_array_equal(back.cov, cal.cov)


ROD_META = {
    "device": {
        "id": "ROD-01",
        "type": "rod",
        "nominal": {
            "layers": [
                {"channel": 2, "l0": 40.0, "h": 100.0},
                {"channel": 1, "l0": 39.5, "h": 50.0, "phi": 0.1, "d": 0.02, "gamma": 0.003},
            ]
        },
    }
}


def test_rod_nominal_rows_id_depends_only_on_the_geometry():
    rows = rod_nominal_calibration_rows(ROD_META, "2026-11-20", "R1")
    again = rod_nominal_calibration_rows(ROD_META, "2026-11-21", "R7")
    assert [r["channel"] for r in rows] == [1, 2]
    assert rows[0]["calibration_id"] == again[0]["calibration_id"]
    assert (
        rows[0]["calibration_id"].startswith("ROD-01-nominal-")
        and len(rows[0]["calibration_id"]) == len("ROD-01-nominal-") + 8
    )
    layers = json.loads(json.dumps(ROD_META))
    layers["device"]["nominal"]["layers"][0]["l0"] = 40.001
    assert (
        rod_nominal_calibration_rows(layers, "2026-11-20", "R1")[0]["calibration_id"]
        != rows[0]["calibration_id"]
    )
    assert rod_nominal_calibration_rows({"device": {"id": "ROD-01"}}, "2026-11-20", "R1") == []


def test_rod_layers_from_rows_default_missing_geometry_to_zero():
    rows = pl.DataFrame(rod_nominal_calibration_rows(ROD_META, "2026-11-20", "R1"))
    rows = rows.with_columns(
        pl.when(pl.col("channel") == 2).then(float("nan")).otherwise(pl.col("phi_rad")).alias("phi_rad")
    )
    lays = rod_layers(rows, (2, 1))
    assert [l.channel for l in lays] == [2, 1]
    assert lays[0].phi_rad == 0.0 and lays[0].l0_mm == 40.0
    assert lays[1].phi_rad == 0.1 and lays[1].d_mm == 0.02 and lays[1].gamma_rad == 0.003


def _drift_rows():
    """Hand-made calibrations: TRI-01 channel 2 three times (beta moves 4 mrad between A and B),
    TRI-02 channel 1 twice with beta across 2 pi, a rod's nominal record (no beta).
    """

    def row(cid, dev, ch, valid, beta, u_beta, rho, u_rho, d_b, u_d_b, method="full_lsq"):
        return {
            "calibration_id": cid,
            "device_id": dev,
            "channel": ch,
            "valid_from": valid,
            "method": method,
            "beta_rad": beta,
            "u_beta_rad": u_beta,
            "rho_mm": rho,
            "u_rho_mm": u_rho,
            "d_b_mm": d_b,
            "u_d_b_mm": u_d_b,
        }

    return pl.DataFrame(
        [
            row("C", "TRI-01", 2, "2026-11-25", 2.1041, 0.0006, -2.005, 0.01, 121.001, 0.002),
            row("A", "TRI-01", 2, "2026-11-20", 2.1000, 0.0005, -2.000, 0.01, 121.000, 0.002),
            row("B", "TRI-01", 2, "2026-11-21", 2.1040, 0.0006, -2.005, 0.01, 121.001, 0.002),
            row("Y", "TRI-02", 1, "2026-11-20", 0.002, 0.001, 1.0, 0.01, 120.0, 0.002),
            row("X", "TRI-02", 1, "2026-11-20", 6.28, 0.001, 1.0, 0.01, 120.0, 0.002),
            row(
                "ROD-01-nominal-1",
                "ROD-01",
                1,
                "2026-11-20",
                None,
                None,
                None,
                None,
                None,
                None,
                method="nominal",
            ),
        ]
    )


def test_calibration_drift_against_hand_computed_changes():
    d = calibration_drift(_drift_rows(), 3.0)
    beta = d.filter((pl.col("device_id") == "TRI-01") & (pl.col("parameter") == "beta_rad"))
    assert beta["calibration_id_before"].to_list() == ["A", "B"] and beta[
        "calibration_id_after"
    ].to_list() == ["B", "C"]
    # A -> B: 0.004 rad over sqrt(0.0005^2 + 0.0006^2) = 7.8102e-4 rad: 5.1215 combined u, a finding
    assert beta["change"][0] == pytest.approx(0.004, abs=1e-12)
    assert beta["u_combined"][0] == pytest.approx(7.810250e-4, rel=1e-6)
    assert beta["change_over_u"][0] == pytest.approx(5.121475, rel=1e-6)
    # B -> C: 1e-4 rad over sqrt(2) 6e-4 = 8.4853e-4: 0.1179, not one
    assert beta["change_over_u"][1] == pytest.approx(0.117851, rel=1e-5)
    assert beta["flagged"].to_list() == [True, False]
    rho = d.filter((pl.col("device_id") == "TRI-01") & (pl.col("parameter") == "rho_mm"))
    assert rho["change"][0] == pytest.approx(-0.005, abs=1e-12) and rho["change_over_u"][0] == pytest.approx(
        -0.353553, rel=1e-5
    )
    assert not d.filter(pl.col("parameter") != "beta_rad")["flagged"].any()
    # same night: ordered by calibration id (X before Y); beta wrapped: 0.002 - 6.28 + 2 pi = 0.0051853 rad
    w = d.filter((pl.col("device_id") == "TRI-02") & (pl.col("parameter") == "beta_rad"))
    assert w["calibration_id_before"][0] == "X" and w["change"][0] == pytest.approx(
        0.002 - 6.28 + 2 * math.pi, abs=1e-12
    )
    assert w["change_over_u"][0] == pytest.approx(
        (0.002 - 6.28 + 2 * math.pi) / math.sqrt(2e-6), rel=1e-9
    )  # 3.6666
    assert (
        w["flagged"][0]
        and not calibration_drift(_drift_rows(), 4.0).filter(
            (pl.col("device_id") == "TRI-02") & (pl.col("parameter") == "beta_rad")
        )["flagged"][0]
    )
    assert "ROD-01" not in d["device_id"].to_list()
    assert d.height == 3 * 2 + 3 * 1  # three parameters: two pairs of TRI-01, one of TRI-02


def test_calibration_drift_without_pairs_or_uncertainty_and_bad_input():
    one = _drift_rows().filter(pl.col("calibration_id") == "A")
    empty = calibration_drift(one, 3.0)
    assert empty.height == 0 and "flagged" in empty.columns and "change_over_u" in empty.columns
    assert calibration_drift(pl.DataFrame(), 3.0).height == 0
    no_u = _drift_rows().with_columns(
        pl.when(pl.col("calibration_id") == "B")
        .then(None)
        .otherwise(pl.col("u_beta_rad"))
        .alias("u_beta_rad")
    )
    b = calibration_drift(no_u, 3.0).filter(
        (pl.col("device_id") == "TRI-01") & (pl.col("parameter") == "beta_rad")
    )
    assert math.isnan(b["change_over_u"][0]) and not b["flagged"].any()  # no uncertainty, no judgement
    with pytest.raises(ValueError, match="positive"):
        calibration_drift(_drift_rows(), 0.0)
    with pytest.raises(ValueError, match=r"lacks the columns \['u_d_b_mm'\]"):
        calibration_drift(_drift_rows().drop("u_d_b_mm"), 3.0)


def test_drift_multiple_default_comes_from_the_schema():
    from borescan.config import schema_defaults

    assert schema_defaults()["discrepancy"]["drift_multiple"] == 3.0
