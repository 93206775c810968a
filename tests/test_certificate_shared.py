"""Parts shared by three-sensor and rod certificates: administrative data, one-result budget tables,
and the rod layers the discrepancy examination compares a scan with.
"""

import json
import math

import numpy as np
import polars as pl
import pytest

from borescan import certificate as C
from borescan.certificate.admin import _traceability_text
from borescan.certificate.budget_pages import _rod_layer_budget, _verification_budget
from borescan.artifacts import ArtifactCte, ScanTemperature
from borescan.calibrate.yang import yang_calibration
from borescan.calibrations import rod_layers
from borescan.discrepancy.reference import discrepancy_reference
from borescan.geometry import RodLayer
from borescan.rod_calibration import RodCalibration
from borescan.geometry import layer_dict
from borescan.synthetic.scenes import RodScene
from borescan.uncertainty import Budget, Input, Term

LAB = {
    "name": "Lab GmbH",
    "address": "Street 1",
    "country_code": "DE",
    "performance_location": "on site",
    "accreditation": "D-K-1",
    "customer": "Works",
    "signatory": "A. Example",
    "signatory_function": "Head",
    "decision_rule": "simple",
}
DATES = {
    "begin": "2026-11-20",
    "end": "2026-11-20",
    "issue": "2026-11-21",
    "issue_rule": "last scan",
    "recalibration_due": "2026-12-20",
    "recalibration_rule": "night + 30 days",
}
GAUGE = {
    "id": "RGS-150",
    "certificate": "C-150",
    "certificate_issuer": "DKD",
    "certificate_valid_until": "2027-01-01",
    "certified_diameter_mm": 150.002,
    "u_diameter_mm": 0.0006,
    "k": 2,
}


def _rod_cal() -> RodCalibration:
    """Two layers calibrated in one ring gauge: l0 with u from two inputs (gauge 0.3 um, resolution 0.1
    um).
    """
    budget = Budget(("l0_mm[1]", "l0_mm[2]"), ("mm", "mm"), [71.0012, 70.9991])
    budget.add(
        Term(Input("gauge:RGS-150", "gauge diameter", "D", "mm", 150.002, 0.0003, "normal"), [-0.5, -0.5])
    )
    budget.add(
        Term(Input("resolution:ch1", "resolution ch 1", "r", "mm", 0.0, 1e-4, "rectangular"), [1.0, 0.0])
    )
    gauges = tuple(dict(GAUGE, channel=ch, feature=f"H{ch}", radius_at_t_mm=75.001) for ch in (1, 2))
    return RodCalibration(
        calibration_id="ROD-01-20261120-rod_gauge-x",
        device_id="ROD-01",
        scan_ids=("S1",),
        layers=(RodLayer(1, 100.0, 71.0012), RodLayer(2, 300.0, 70.9991, gamma_rad=0.001)),
        l0_nominal_mm=np.array([71.0, 71.0]),
        u_l0_mm=budget.u(),
        budget=budget,
        gauges=gauges,
        solution=None,
        iterations=3,
        residual_rms_mm=0.0004,
    )


def _rod_kw(**kw) -> dict:
    return dict(
        device={"id": "ROD-01", "type": "rod", "sensors": []},
        artifact=dict(GAUGE),
        temperature=ScanTemperature(20.5, 0.1, 0.1 / math.sqrt(3), False, "scan.json"),
        cte=ArtifactCte(11.5e-6, 1e-6, 1e-6 / math.sqrt(3), False, "scan.json"),
        raw_files={"S1/lds": "a" * 64},
        software_version="0.1.0",
        config_hash="c0ffee",
        laboratory=LAB,
        dates=DATES,
        **kw,
    )


def _tri_cert(verifications=None) -> dict:
    cal = yang_calibration(
        [7.0549, 6.9256, 5.7177],
        [2.4067, 2.2804, 1.073],
        ["backward", "backward", "advanced"],
        [312.0, 88.0, 199.0],
        660.0,
        275.029 / 2,
        2.3222,
        device_id="TRI-01",
        scan_ids=["N20170205-P1"],
        u_d_max_mm=1e-4,
        u_d_min_mm=1e-4,
    )
    return C.certificate_dict(
        cal,
        device={"id": "TRI-01"},
        artifact=dict(GAUGE),
        conditions={},
        residuals={"t_s": np.arange(3) * 0.1, "residual_mm": np.zeros((3, 3))},
        raw_files={},
        software_version="0.1.0",
        config_hash="c0ffee",
        laboratory=LAB,
        dates=DATES,
        verifications=verifications,
    )


def test_rod_and_three_sensor_certificates_share_their_administrative_data():
    ver = [{"scan_id": "V1", "passed": True}, {"scan_id": "V2", "passed": False}]
    tri = _tri_cert(ver)["administrativeData"]
    rod = C.rod_certificate_dict(_rod_cal(), **_rod_kw(verifications=ver))["administrativeData"]
    assert tri["items"][0]["name"] == "three-sensor bore measuring device (tri_lds)"
    assert rod["items"][0]["name"] == "measuring rod (rod)"
    assert rod["items"][0]["identifications"] == [{"issuer": "customer", "value": "ROD-01"}]
    assert [s.get("refType", s.get("norm")) for s in rod["statements"]] == [
        "ISO/IEC 17025:2017",
        "basic_traceability",
        "basic_decisionRule",
        "basic_conformity",
        "basic_recalibration",
        "borescan_issueDate",
    ]
    # the gauge both layers were calibrated in is named once
    trace = rod["statements"][1]["declaration"]
    assert trace == _traceability_text(GAUGE) and "C-150 (issued by DKD; valid until 2027-01-01)" in trace
    assert rod["statements"][3] == {
        "refType": "basic_conformity",
        "conformity": "fail",
        "declaration": "The device does NOT conform to the verification tolerance under the stated "
        "decision rule: of 2 verifications on certified ring gauges 1 conforms, 1 does "
        "not conform (1 accepted by the rule).",
    }
    assert rod["statements"][4]["date"] == "2026-12-20"
    assert rod["coreData"]["issueDate"] == "2026-11-21" and rod["coreData"]["uniqueIdentifier"].startswith(
        "ROD-01"
    )
    assert rod["placeholders"] == [] and rod["respPersons"][0]["person"]["name"] == "A. Example"
    for part in ("dccSoftware", "calibrationLaboratory", "respPersons", "customer", "placeholders"):
        assert tri[part] == rod[part]
    assert tri["statements"][2:] == rod["statements"][2:]


def test_rod_certificate_numbers_and_byte_identical_regeneration(tmp_path):
    cal = _rod_cal()
    cert = C.rod_certificate_dict(cal, **_rod_kw())
    res = {r["name"]: r["real"] for r in cert["measurementResults"][0]["results"]}
    u1 = math.hypot(0.5 * 0.0003, 1e-4)  # gauge (c = -1/2) and resolution of layer 1 [mm]
    assert res["l0_mm[1]"]["value"] == 71.0012
    assert res["l0_mm[1]"]["expandedUnc"]["standardUncertainty"] == pytest.approx(u1, rel=1e-9)
    assert res["l0_mm[2]"]["expandedUnc"]["standardUncertainty"] == pytest.approx(0.00015, rel=1e-9)
    rows = cert["measurementResults"][0]["uncertaintyBudget"]["l0_mm[1]"]["rows"]
    assert [r["contribution"] for r in rows] == pytest.approx([0.00015, 1e-4])
    assert cert["conditions"]["gauge_radius_at_temperature_mm"] is None
    assert cert["conditions"]["temperature"]["value_c"] == 20.5
    assert cert["parameters"][1]["gamma_rad"] == 0.001 and cert["fit"]["solve_method"] is None
    a = C.write_rod_certificate(cal, tmp_path / "a", **_rod_kw())
    b = C.write_rod_certificate(cal, tmp_path / "b", **_rod_kw())
    assert json.loads(a["json"].read_text()) == cert
    for key in ("json", "pdf"):
        assert a[key].read_bytes() == b[key].read_bytes()


class _Recorder:
    """Stands in for the PDF layout: records what a table helper draws."""

    def __init__(self):
        self.calls = []

    def room(self, h):
        self.calls.append(("room", round(h, 6)))

    def para(self, text, size=7.5, **_kw):
        self.calls.append(("para", text, size))

    def table(self, cols, cells, widths=None, size=6.5, row_h=0.0145, bold_last=False):
        self.calls.append(("table", cols, cells, widths, size, row_h, bold_last))


def _row(key, u, contribution, unit="mm", c=1.0):
    return {
        "key": key,
        "quantity": key,
        "estimate": 0.0,
        "unit": unit,
        "standard_uncertainty": u,
        "distribution": "normal",
        "degrees_of_freedom": float("inf"),
        "sensitivity_coefficient": c,
        "contribution": contribution,
    }


def test_verification_budget_lists_inputs_of_5_percent_and_folds_the_rest():
    rows = [
        _row("gauge:RG-275@C1", 0.0003, 0.003),
        _row("readings", 0.0, 0.004),
        _row("resolution:ch1", 1e-4, 1e-4),
        _row("cte:RG", 0.0, 0.0),
    ]
    d = _Recorder()
    _verification_budget(d, {"scan_id": "V1", "budget": rows})
    uc = math.sqrt(0.003**2 + 0.004**2 + 1e-4**2)
    assert d.calls[0] == ("room", round(0.013 * 5 + 0.03, 6))
    assert d.calls[1] == ("para", "Budget of E, V1 (contributions in um):", 7.5)
    _, cols, cells, widths, size, row_h, bold = d.calls[2]
    assert cols == ["input x_i", "estimate", "u(x_i)", "dist.", "nu_i", "c_i", "u_i [um]"]
    assert cells == [
        ["gauge RG-275: certified D20", "0.00000 mm", "0.00030 mm", "normal", "inf", "1", "3"],
        ["readings (scatter)", "0 um", "0 um", "normal", "inf", "1", "4"],  # u 0 shown as 0 here
        ["2 further inputs (each < 5 % of u_c), combined", "", "", "", "", "", "0.1"],
        ["combined standard uncertainty u_c(E)", "", "", "", "", "", f"{1e3 * uc:.3g}"],
    ]
    assert (widths, size, row_h, bold) == ([0.42, 0.12, 0.1, 0.1, 0.06, 0.1, 0.1], 6, 0.013, True)
    d = _Recorder()
    _verification_budget(d, {"scan_id": "V1", "budget": []})
    assert d.calls == []


def test_rod_layer_budget_drops_negligible_inputs_and_shows_zero_u_as_a_dash():
    rows = [
        _row("gauge:RGS-150@C-150", 0.0003, 0.00015, c=-0.5),
        _row("readings", 0.0, 1e-4),
        _row("resolution:ch2", 1e-4, 1e-12),
    ]  # 1e-12 mm < 1e-5 u_c: left out
    comb = {
        "standard_uncertainty": 0.00018,
        "effective_degrees_of_freedom": 40.2,
        "coverage_factor": 2.05,
        "expanded_uncertainty": 0.000369,
    }
    d = _Recorder()
    _rod_layer_budget(d, 2, {"rows": rows, "combined": comb})
    assert d.calls[1] == ("para", "Layer 2 (contributions in um; inputs below 1e-5 u_c left out):", 7.5)
    _, _, cells, widths, size, _, bold = d.calls[2]
    assert cells == [
        ["gauge RGS-150: certified D20", "0.00000 mm", "0.00030 mm", "normal", "inf", "-0.5", "0.15"],
        ["readings (scatter)", "0 um", "-", "normal", "inf", "1", "0.1"],
        ["combined standard uncertainty u_c", "", "", "", "40", "", "0.18"],
        ["expanded uncertainty U (k = 2.05)", "", "", "", "", "", "0.369"],
    ]
    assert (widths, size, bold) == ([0.4, 0.13, 0.1, 0.1, 0.07, 0.09, 0.11], 6.2, True)
    assert d.calls[0] == ("room", round(0.013 * 5 + 0.03, 6))


def test_rod_reference_layers_are_the_measurements_rod_layers_in_nominal_format():
    cals = pl.DataFrame(
        [
            {
                "calibration_id": "ROD-G1",
                "device_id": "ROD-01",
                "valid_from": "2026-11-10",
                "method": "rod_gauge",
                "channel": ch,
                "l0_mm": 71.0 + ch * 1e-3,
                "h_mm": 100.0 * ch,
                "phi_rad": float("nan"),
                "d_mm": None,
                "gamma_rad": 0.002,
            }
            for ch in (3, 1, 2)
        ]
    )
    kw, ref = discrepancy_reference(cals, "ROD-01", "rod", "2026-11-21")
    assert ref == "calibration ROD-G1"
    assert kw["layers"] == [
        {"channel": ch, "h": 100.0 * ch, "phi": 0.0, "d": 0.0, "gamma": 0.002, "l0": 71.0 + ch * 1e-3}
        for ch in (1, 2, 3)
    ]
    lays = rod_layers(cals, (1, 2, 3))
    assert kw["layers"] == [layer_dict(lay) for lay in lays]
    # the device.nominal format the simulator writes and RodScene.from_dict reads back
    scene = {
        "layers": kw["layers"],
        "holes": [{"center_xy_mm": [0.0, 0.0], "radius_mm": 75.0}] * 3,
        "axis": {"dx_mm": 0.0, "dy_mm": 0.0, "omega_rad": 0.0, "omega_az_rad": 0.0},
        "range_mm": [8.0] * 3,
        "sample_rate_hz": 100.0,
        "cte_per_k": 11.5e-6,
        "temperature_c": 20.0,
    }
    assert list(RodScene.from_dict(scene).layers) == lays


def test_rod_residuals_per_pose_are_the_solves_and_are_drawn(tmp_path):
    """residuals.png of a rod certificate: model - reading of the solve per pose and layer (outputs.md)."""
    from borescan.geometry import Hole, RodAxis, rod_readings
    from borescan.rod import solve_rod

    layers = [RodLayer(1, 100.0, 71.0), RodLayer(2, 400.0, 71.0)]
    holes = [Hole((0.0, 0.0), 75.0), Hole((0.01, -0.02), 75.012)]
    rng = np.random.default_rng(5)
    alpha = np.sort(rng.uniform(0, 2 * np.pi, 16))
    v = rod_readings(alpha, layers, holes, RodAxis(1.0, 0.5, np.deg2rad(0.3), 2.1))
    v = v + 0.002 * rng.standard_normal(v.shape)
    v[4, 1] = np.nan  # a reading missing: pose 4, seen by one layer only, is dropped by the solve
    sol = solve_rod(v, layers=layers, u_reading_mm=0.002)
    pr = C.rod_pose_residuals(sol, v)
    r = pr["residual_mm"]
    assert r.shape == v.shape and np.isnan(r[4]).all() and np.isnan(pr["pose_angle_rad"][4])
    assert np.isfinite(np.delete(r, 4, axis=0)).all()
    # the solve's own rms (mean over the readings it used) and cost
    assert np.sqrt(np.nanmean(r**2)) == pytest.approx(sol.residual_rms_mm, rel=1e-12)
    # model = reading + (model - reading): readings the solution explains exactly, so a solve of them
    # leaves nothing (with the sign reversed it would leave twice the noise)
    again = solve_rod(v + r, layers=layers, u_reading_mm=0.002)
    assert again.residual_rms_mm < 1e-3 * sol.residual_rms_mm
    cal = _rod_cal()
    pr2 = {"pose_angle_rad": alpha, "residual_mm": r}
    a = C.write_rod_certificate(cal, tmp_path / "a", residuals=pr2, **_rod_kw())
    b = C.write_rod_certificate(cal, tmp_path / "b", residuals=pr2, **_rod_kw())
    assert a["png"].name == "residuals.png" and a["png"].read_bytes() == b["png"].read_bytes()
    cert = json.loads(a["json"].read_text())
    assert np.allclose(
        np.array(cert["fit"]["pose_residuals"]["residual_mm"], dtype=float), r, rtol=1e-11, equal_nan=True
    )
    with pytest.raises(ValueError, match="no least-squares fit"):
        C.rod_pose_residuals(None, v)


def test_budget_numbers_one_style_units_per_quantity_and_no_exponent():
    """An input's estimate and u in one unit chosen for the quantity (not by its size), the estimate with
    u's decimals (u to 2 significant digits, rounded up); sensitivities and contributions never in
    exponent notation (the certificate printed 1.67e+03 urad, 122.00 um beside -2.3200 mm).
    """
    from borescan.certificate.layout import _est_u_text, _label, _sig

    assert (_sig(1670.4), _sig(-6.66e-5), _sig(-0.5), _sig(850.2), _sig(0.0)) == (
        "1670",
        "-0.0000666",
        "-0.5",
        "850",
        "0",
    )
    assert _est_u_text(0.122, 0.00163, "mm", "position:x") == ("0.1220 mm", "0.0017 mm")
    assert _est_u_text(-2.32, 0.00163, "mm", "position:y") == ("-2.3200 mm", "0.0017 mm")
    assert _est_u_text(275.029, 0.00075, "mm", "gauge:RG-275@C") == ("275.02900 mm", "0.00075 mm")
    assert _est_u_text(0.0, 0.00577, "mm", "linearity:ch1") == ("0.0 um", "5.8 um")
    assert _est_u_text(None, 0.004, "mm", "fit:readings") == ("-", "4.0 um")
    tau = "device_model:TRI-01:channel_delay@2:tau_s@2026-11-23"
    assert _est_u_text(0.00115141, 3.08e-5, "s", tau) == ("1.151 ms", "0.031 ms")
    assert _est_u_text(20.0, 0.0577, "degC", "temperature:S") == ("20.000 degC", "0.058 K")
    assert _est_u_text(11.5e-6, 0.58e-6, "1/K", "cte:RG-275@C") == ("11.50 ppm/K", "0.58 ppm/K")
    # a label keeps the whole scan id
    assert _label({"key": "temperature:N20261124-TRI01-CAL-P1-A", "quantity": "t"}) == (
        "temperature, N20261124-TRI01-CAL-P1-A"
    )
