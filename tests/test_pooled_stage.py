"""The night's pooled examination (borescan.stages.pooled, rule pooled_night): rows, JSON, drift, catalog.

A small simulated night: device TRI-S with three ring-gauge spindle scans (60 rpm ccw, 110 rpm
ccw, 60 rpm cw) and a 1.0 ms delay on channel 2 (hidden truth), plus one static verification
scan that the pooled examination must leave out; ingested by the ingest stage as a night is.
"""

import json
import math

import numpy as np
import polars as pl
import pytest

from borescan.catalog import STAGE_TABLES, open_catalog, update_catalog
from borescan.discrepancy.pooled import parse_device_effect
from borescan.effects import device_model_effects
from borescan.effects import Effect
from borescan.synthetic.scenes import default_tri_scene
from borescan.synthetic.simulate import simulate_tri_spindle, simulate_tri_static, write_simulated
from borescan.stages._common import write_table
from borescan.stages.ingest import stage_ingest
from borescan.stages.pooled import drift_rows, pooled_dir, pooled_rows, stage_pooled
from borescan.tables import TABLES, frame

NIGHT = "2027-06-01"
TAU_S = 0.0010
CFG = {"exact_refits": 4, "pair_seeds": 0}  # as the pooled recovery tests (pooled_max_samples: its default)


@pytest.fixture(scope="module")
def night(tmp_path_factory):
    """raw root, results root and the night's scans table of the simulated night."""
    root = tmp_path_factory.mktemp("pooled_night")
    raw, res = root / "raw", root / "results"
    eff = [Effect("channel_delay", {"channel": 2, "tau_s": TAU_S})]
    c = (10.0, -20.0)
    for i, (rpm, direction, ecc) in enumerate(
        [(60.0, "ccw", (1.5, 0.0)), (110.0, "ccw", (0.0, 2.0)), (60.0, "cw", (-1.2, -1.0))]
    ):
        scene = default_tri_scene(
            bore_center_xy_mm=c,
            spindle_xy_mm=(c[0] + ecc[0], c[1] + ecc[1]),
            rpm_nominal=rpm,
            direction=direction,
            sample_rate_hz=500.0,
            phase_rad=0.3 + i,
        )
        write_simulated(
            simulate_tri_spindle(
                scene,
                scan_id=f"S{i}",
                night=NIGHT,
                n_rev=6.0 * rpm / 60.0,
                effects=eff,
                noise_mm=0.002,
                seed=i,
                device_id="TRI-S",
                kind="calibration",
                started_at=f"{NIGHT}T22:0{i}:00Z",
            ),
            raw,
            root / "truth",
        )
    scene = default_tri_scene(bore_center_xy_mm=(0.0, 0.0))
    rng = np.random.default_rng(7)
    xy = rng.uniform(-1.0, 1.0, (6, 2))
    write_simulated(
        simulate_tri_static(
            scene,
            xy,
            rng.uniform(0, 2 * math.pi, 6),
            scan_id="V0",
            night=NIGHT,
            kind="verification",
            device_id="TRI-S",
            seed=9,
            started_at=f"{NIGHT}T23:00:00Z",
        ),
        raw,
        root / "truth",
    )
    scans, _, bad = stage_ingest(raw, NIGHT, res)
    assert not bad and scans.height == 4
    write_table(scans, res / "stage" / "scans" / f"night={NIGHT}.parquet")
    return raw, res, res / "stage" / "scans" / f"night={NIGHT}.parquet"


@pytest.mark.slow
def test_pooled_night_names_the_delay_with_its_value_and_writes_json(night):
    """Three speeds of one device: channel_delay@2 named, tau within max(4 u, 5 %) of 1.0 ms; the
    static verification scan left out; the JSON beside the rows; nothing to drift (no calibrations).
    """
    raw, res, scans = night
    findings, drift = stage_pooled(raw, NIGHT, res, [scans], [], CFG, {}, log=lambda m: None)
    assert drift.height == 0
    row = findings.row(0, named=True)
    assert findings.height == 1 and row["verdict"] == "missing_effect"
    assert (row["effect"], row["channel"], row["term"], row["in_device_model"]) == (
        "channel_delay",
        2,
        "channel_delay@2",
        False,
    )
    assert row["scan_ids"] == "S0,S1,S2"  # V0 is static: not pooled
    tau, u = json.loads(row["parameters"])["tau_s"], json.loads(row["uncertainties"])["u_tau_s"]
    assert abs(tau - TAU_S) < max(4 * u, 0.05 * TAU_S), (tau, u)
    assert set(row["evidence_scans"].split(",")) <= {"S0", "S1", "S2"} and row["evidence_scans"]
    assert row["findings_path"] == f"discrepancy/pooled/night={NIGHT}/TRI-S.json"
    f = json.loads((res / row["findings_path"]).read_text())
    assert f["device_id"] == "TRI-S" and f["named"][0]["parameters"]["tau_s"] == pytest.approx(tau, rel=1e-12)
    assert f["reference"] == "device.nominal (beam geometry free)"
    assert f["gap_after"]["rms_mm"] < 1.2 * f["noise_floor_mm"]
    assert findings.schema == pl.Schema(TABLES["pooled_findings"].polars_schema())


@pytest.mark.slow
def test_an_effect_in_the_device_model_is_fitted_with_the_base_not_named(night):
    """The user has decided TRI-S has channel_delay@2: the pooled examination fits it with the base
    model (tau within max(4 u, 5 %) of the truth), names nothing and reports it as in the device model.
    """
    raw, res, scans = night
    devices = {"TRI-S": {"effects": ["channel_delay@2"]}}
    findings, _ = stage_pooled(raw, NIGHT, res, [scans], [], CFG, devices, log=lambda m: None)
    assert findings["verdict"].to_list() == ["no_missing_effect"]
    row = findings.row(0, named=True)
    assert (row["term"], row["in_device_model"], row["device_model"]) == (
        "channel_delay@2",
        True,
        "channel_delay@2",
    )
    tau, u = json.loads(row["parameters"])["tau_s"], json.loads(row["uncertainties"])["u_tau_s"]
    assert abs(tau - TAU_S) < max(4 * u, 0.05 * TAU_S), (tau, u)
    f = json.loads((pooled_dir(res, NIGHT) / "TRI-S.json").read_text())
    assert f["named"] == [] and "in the device model" in f["in_device_model"][0]["note"]
    assert all(c["term"] != "channel_delay@2" for c in f["candidates"])
    assert f["gap_after"]["rms_mm"] < 1.2 * f["noise_floor_mm"]


def test_a_device_that_cannot_be_examined_gets_a_failed_row_naming_why(night):
    """A device model naming channel 4 of a three-channel device: the night goes on, the device's
    row says failed, with the scans and the problem.
    """
    raw, res, scans = night
    logged = []
    findings, _ = stage_pooled(
        raw, NIGHT, res, [scans], [], CFG, {"TRI-S": {"effects": ["sensor_gain@4"]}}, log=logged.append
    )
    row = findings.row(0, named=True)
    assert (findings.height, row["verdict"], row["scan_ids"]) == (1, "failed", "S0,S1,S2")
    assert "pooled examination of S0, S1, S2 failed" in row["reason"] and "channel 4" in row["reason"]
    assert any("TRI-S: pooled examination" in m for m in logged)


def test_device_model_entries_are_checked_against_the_registry():
    assert device_model_effects(
        {"TRI-S": {"effects": ["channel_delay@2", "sensor_offset@all"]}}, "TRI-S"
    ) == ("channel_delay@2", "sensor_offset@all")
    assert device_model_effects({}, "TRI-S") == ()
    with pytest.raises(
        ValueError, match=r"devices\.TRI-S\.effects: unknown effect 'channel_dealy'.*valid: .*channel_delay"
    ):
        device_model_effects({"TRI-S": {"effects": ["channel_dealy@2"]}}, "TRI-S")
    with pytest.raises(ValueError, match="'thermal_expansion' belongs to the night, not to the device"):
        parse_device_effect("thermal_expansion", (1, 2, 3), "TRI-S")
    with pytest.raises(ValueError, match="acts on one channel; write channel_delay@<channel>"):
        parse_device_effect("channel_delay", (1, 2, 3), "TRI-S")
    with pytest.raises(ValueError, match=r"channel 4 is not one of the scans' channels \(1, 2, 3\)"):
        parse_device_effect("sensor_gain@4", (1, 2, 3), "TRI-S")
    with pytest.raises(ValueError, match="listed twice"):
        device_model_effects({"TRI-S": {"effects": ["sensor_gain@1", "sensor_gain@1"]}}, "TRI-S")


def test_a_device_model_entry_applies_from_its_night_on():
    """A user's decision dated in the config: before that night the effect is not in the model."""
    devices = {"TRI-S": {"effects": ["sensor_gain@1", {"effect": "channel_delay@2", "from": "2026-11-24"}]}}
    assert device_model_effects(devices, "TRI-S", "2026-11-23") == ("sensor_gain@1",)
    assert device_model_effects(devices, "TRI-S", "2026-11-24") == ("sensor_gain@1", "channel_delay@2")
    assert device_model_effects(devices, "TRI-S") == ("sensor_gain@1", "channel_delay@2")
    with pytest.raises(ValueError, match=r"'channel_delay@2': from '24\.11\.2026' is not a night"):
        device_model_effects(
            {"TRI-S": {"effects": [{"effect": "channel_delay@2", "from": "24.11.2026"}]}}, "TRI-S"
        )
    with pytest.raises(ValueError, match="an entry is an effect key or"):
        device_model_effects({"TRI-S": {"effects": [{"key": "channel_delay@2"}]}}, "TRI-S")
    with pytest.raises(ValueError, match="unknown effect 'channel_dealy'"):
        device_model_effects(
            {"TRI-S": {"effects": [{"effect": "channel_dealy@2", "from": "2026-11-24"}]}}, "TRI-S"
        )


def _cal(cal_id, night, beta2, u_beta=1e-4, d_b1=130.0, u_d_b=1e-3):
    """Calibration rows of device TRI-S: channel 1 and 2 (beta, rho, d_b with their u)."""
    return [
        {
            "calibration_id": cal_id,
            "device_id": "TRI-S",
            "channel": ch,
            "valid_from": night,
            "method": "full",
            "beta_rad": b,
            "u_beta_rad": u_beta,
            "rho_mm": -2.0,
            "u_rho_mm": 0.01,
            "d_b_mm": d,
            "u_d_b_mm": u_d_b,
        }
        for ch, b, d in ((1, 0.35, d_b1), (2, beta2, 132.0))
    ]


def test_drift_rows_of_the_night_with_the_pooled_explanation():
    """beta_2 moves by -7.5e-4 rad between two calibrations of u 1e-4: |change| / sqrt(2) u = 5.3 > 3,
    flagged and explained by a named channel_delay@2; d_b_1 moves 2e-3 mm with u 1e-3: 1.41, not
    flagged. Only pairs whose later calibration is the night's are the night's rows.
    """
    cals = pl.DataFrame(
        _cal("C0", "2027-05-20", 2.44)
        + _cal("C1", "2027-05-30", 2.44, d_b1=130.002)
        + _cal("C2", NIGHT, 2.44 - 7.5e-4, d_b1=130.002)
    )
    findings = {
        "TRI-S": {
            "device_id": "TRI-S",
            "scan_ids": ["S0", "S1"],
            "named": [
                {
                    "effect": "channel_delay",
                    "channel": 2,
                    "term": "channel_delay@2",
                    "parameters": {"tau_s": 0.0012},
                    "calibration_equivalent": {"S0": {"beta_rad": -0.00075}},
                }
            ],
        }
    }
    rows = {(r["channel"], r["parameter"]): r for r in drift_rows(cals, NIGHT, 3.0, findings)}
    assert len(rows) == 6 and {r["calibration_id_after"] for r in rows.values()} == {"C2"}
    b = rows[(2, "beta_rad")]
    assert b["change"] == pytest.approx(-7.5e-4, abs=1e-12)
    assert b["u_combined"] == pytest.approx(math.sqrt(2) * 1e-4, rel=1e-12)
    assert b["change_over_u"] == pytest.approx(-7.5 / math.sqrt(2), rel=1e-9) and b["flagged"]
    assert (
        b["explained_by"] == "channel_delay@2" and "explained by the pooled examination" in b["explanation"]
    )
    assert not any(r["flagged"] for k, r in rows.items() if k != (2, "beta_rad"))
    assert all(r["explanation"] is None for k, r in rows.items() if k != (2, "beta_rad"))
    # without a pooled examination of the device the flag stays, and says so
    (lone,) = [r for r in drift_rows(cals, NIGHT, 3.0, {}) if r["flagged"]]
    assert lone["explained_by"] == "" and "has no pooled examination on night" in lone["explanation"]
    # the night before: C1 after C0, d_b_1 moved 2e-3 mm = 1.41 combined u: recorded, not flagged
    (d1,) = [
        r for r in drift_rows(cals, "2027-05-30", 3.0, {}) if (r["channel"], r["parameter"]) == (1, "d_b_mm")
    ]
    assert d1["change_over_u"] == pytest.approx(2e-3 / (math.sqrt(2) * 1e-3), rel=1e-6) and not d1["flagged"]


def test_the_catalog_holds_the_pooled_tables_night_by_night(tmp_path):
    """Two nights of pooled_findings and calibration_drift stage files: the catalog has both
    tables with every row and its night; adding the second night appends it.
    """
    assert {"pooled_findings", "calibration_drift"} <= set(STAGE_TABLES)
    cals = pl.DataFrame(_cal("C0", "2027-05-31", 2.44) + _cal("C1", NIGHT, 2.44 - 7.5e-4))
    for n in ("2027-05-31", NIGHT):
        f = {
            "device_id": "TRI-S",
            "nights": [n],
            "scan_ids": ["S0", "S1"],
            "verdict": "no_missing_effect",
            "named": [],
            "absorbed": [],
            "gap_before": {"rms_mm": 0.0021},
            "gap_after": {"rms_mm": 0.002},
            "noise_floor_mm": 0.002,
        }
        write_table(
            frame("pooled_findings", pooled_rows(f, n, f"discrepancy/pooled/night={n}/TRI-S.json")),
            tmp_path / "stage" / "pooled_findings" / f"night={n}.parquet",
        )
        write_table(
            frame("calibration_drift", drift_rows(cals, n, 3.0, {})),
            tmp_path / "stage" / "calibration_drift" / f"night={n}.parquet",
        )
        up = update_catalog(tmp_path)
    assert up.mode == "append" and up.added == (NIGHT,)
    con = open_catalog(tmp_path)
    try:
        pf = con.execute(
            "SELECT CAST(night AS VARCHAR), device_id, verdict FROM pooled_findings ORDER BY night"
        ).fetchall()
        dr = con.execute(
            "SELECT CAST(night AS VARCHAR), count(*), sum(flagged::INT) FROM calibration_drift GROUP BY night"
        ).fetchall()
        gap = con.execute(
            "SELECT CAST(night AS VARCHAR), gap_over_noise, named, drifts_flagged, drifts_explained "
            "FROM device_gap_history"
        ).fetchall()
    finally:
        con.close()
    assert pf == [("2027-05-31", "TRI-S", "no_missing_effect"), (NIGHT, "TRI-S", "no_missing_effect")]
    assert dr == [(NIGHT, 6, 1)]  # the first night has no earlier calibration: no pair, no rows
    # the saved query: gap over time per device (2.1 um over a 2 um floor), the night's flagged drift
    assert [(n, round(g, 12), named, fl, ex) for n, g, named, fl, ex in gap] == [
        ("2027-05-31", 1.05, None, 0, 0),
        (NIGHT, 1.05, None, 1, 0),
    ]
