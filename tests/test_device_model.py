"""A device model's effects carried into calibration and measurement (issue 22).

Beam and reading effects are undone reading by reading (:func:`borescan.physics.tri.tri_correct_readings`,
the inverse of the one forward model's steps 6-7): for every such effect of the registry (its
``example`` values; a new one is checked here without touching this file) the twin's readings with
the effect, corrected, are the twin's readings without it. A channel delay is carried by the time
each channel's angle is taken at (:func:`borescan.device_model.channel_time_offsets`).
"""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

from borescan.effects import EFFECTS, Effect
from borescan.physics.tri import CORRECTABLE_STAGES, tri_correct_readings
from borescan.synthetic.scenes import default_tri_scene, tri_readings

TRI = "tri_lds"
CORRECTABLE = [n for n, s in EFFECTS.items() if TRI in s.device_types and s.stage in CORRECTABLE_STAGES]


@pytest.mark.parametrize("name", CORRECTABLE)
def test_corrected_readings_are_the_readings_without_the_effect(name):
    sc = default_tri_scene(phase_rad=0.7)
    t = np.arange(2000) / sc.sample_rate_hz
    e = Effect(name, dict(EFFECTS[name].example))
    with_effect = tri_readings(sc, t, [e])
    without = tri_readings(sc, t, [])
    assert np.nanmax(np.abs(with_effect - without)) > 1e-5, "the effect must show in the readings"
    corrected = tri_correct_readings(t, with_effect, sc.beams.channels, [e], sc.range_mm)
    assert np.max(np.abs(corrected - without)) < 1e-9


def test_several_reading_effects_on_one_channel_are_undone_together_and_nulls_stay_null():
    sc = default_tri_scene()
    t = np.arange(1500) / sc.sample_rate_hz
    effects = [
        Effect("sensor_gain", {"channel": 2, "g": -0.004}),
        Effect("sensor_offset", {"channel": 2, "b_mm": 0.012}),
        Effect("beam_tilt", {"channel": 1, "gamma_rad": 0.06}),
        Effect("sensor_nonlinearity", {"channel": 3, "a_mm": 0.01}),
        Effect("sensor_drift", {"channel": 2, "k_mm_per_s": 0.0015}),
    ]
    v = tri_readings(sc, t, effects)
    v[7, 1] = np.nan
    corrected = tri_correct_readings(t, v, sc.beams.channels, effects, sc.range_mm)
    without = tri_readings(sc, t, [])
    assert np.isnan(corrected[7, 1]) and np.isfinite(np.delete(corrected.ravel(), 7 * 3 + 1)).all()
    ok = np.isfinite(corrected)
    assert np.max(np.abs(corrected[ok] - without[ok])) < 1e-9


def test_scene_and_time_base_effects_are_not_corrected_in_the_readings():
    sc = default_tri_scene()
    t = np.arange(100) / sc.sample_rate_hz
    v = tri_readings(sc, t, [])
    for e in (
        Effect("thermal_expansion", {"temperature_c": 24.0}),
        Effect("channel_delay", {"channel": 2, "tau_s": 1e-3}),
    ):
        with pytest.raises(ValueError, match="not corrected in the readings"):
            tri_correct_readings(t, v, sc.beams.channels, [e])


def test_channel_time_offsets_of_a_device_model():
    from borescan.device_model import DeviceEffect, channel_time_offsets

    m = [
        DeviceEffect(
            "channel_delay@2", (Effect("channel_delay", {"channel": 2, "tau_s": 1.2e-3}),), {"tau_s": 2e-5}
        ),
        DeviceEffect(
            "sensor_offset@3", (Effect("sensor_offset", {"channel": 3, "b_mm": 0.01}),), {"b_mm": 1e-3}
        ),
        DeviceEffect("channel_delay@1"),
    ]
    assert np.array_equal(channel_time_offsets(m, (1, 2, 3)), [0.0, 1.2e-3, 0.0])
    assert channel_time_offsets(m[1:], (1, 2, 3)) is None


def _pooled_row(device_id: str, night: str, tau_s: float, u_tau_s: float) -> dict:
    return {
        "device_id": device_id,
        "night": night,
        "effect": "channel_delay",
        "channel": 2,
        "parameters": json.dumps({"tau_s": tau_s}),
        "uncertainties": json.dumps({"u_tau_s": u_tau_s}),
        "evidence_scans": "A,B",
        "in_device_model": False,
    }


def test_device_model_at_takes_the_latest_earlier_estimate_and_says_when_there_is_none():
    from borescan.device_model import device_model_at

    rows = [
        _pooled_row("TRI-01", "2026-11-18", 1.0e-3, 5e-5),
        _pooled_row("TRI-01", "2026-11-19", 1.1e-3, 4e-5),
        _pooled_row("TRI-01", "2026-11-20", 9.9e-3, 4e-5),
        _pooled_row("TRI-02", "2026-11-19", 7e-3, 4e-5),
    ]
    (m,) = device_model_at("TRI-01", ["channel_delay@2"], rows, "2026-11-20", (1, 2, 3))
    assert (
        m.estimated and m.night == "2026-11-19" and m.values() == {"tau_s": 1.1e-3} and m.u == {"tau_s": 4e-5}
    )
    assert m.effects[0].channel == 2 and m.evidence_scans == ("A", "B")
    (none,) = device_model_at("TRI-01", ["sensor_offset@3"], rows, "2026-11-20", (1, 2, 3))
    assert not none.estimated and none.effects == ()


@pytest.mark.slow
def test_a_carried_channel_delay_corrects_the_calibration_and_its_u_enters_the_budgets(tmp_path):
    """Channel 2 of a device shows its readings 1.2 ms late. At one speed the calibration absorbs the
    delay into beta_2 (omega tau = 7.5 mrad at 60 rpm, ten times its U). Carried from a pooled
    estimate (1.19 ms, u 20 us), the calibration's beta_2 is the truth's within U, and the budget's
    device-model term of beta_2 is omega u(tau) (closed form); a static bore measured with it is
    within its U of the truth, the same input in its budget.
    """
    from borescan import rawio
    from borescan.synthetic import simulate
    from borescan.config import schema_defaults
    from borescan.device_model import device_model_at
    from borescan.measure import tri_diameter_with_budget
    from borescan.stages.calibration_fit import calibrate_raw_scans

    tau, tau_est, u_tau = 1.2e-3, 1.19e-3, 2e-5
    scene = default_tri_scene()
    delay = Effect("channel_delay", {"channel": 2, "tau_s": tau})
    sim = simulate.simulate_tri_spindle(
        scene,
        scan_id="N20261121-TRI01-CAL",
        night="2026-11-21",
        n_rev=20,
        effects=[delay],
        noise_mm=0.001,
        seed=3,
    )
    path = simulate.write_simulated(sim, tmp_path / "raw", tmp_path / "truth")
    scan = rawio.read_scan(path)
    cfg = schema_defaults()
    unc = cfg["uncertainty"]
    rows = [_pooled_row("TRI-01", "2026-11-20", tau_est, u_tau)]
    model = device_model_at("TRI-01", ["channel_delay@2"], rows, "2026-11-21", scene.beams.channels)
    plain = calibrate_raw_scans([scan], cfg["calibration"], uncertainty=unc)
    cal = calibrate_raw_scans([scan], cfg["calibration"], uncertainty=unc, model=model)
    omega = 2 * np.pi * scene.rpm_nominal / 60.0
    p = float(unc["coverage_probability"])

    def beta21(c):
        return float(c.beams.beta_rad[1] - c.beams.beta_rad[0])

    true21 = float(scene.beams.beta_rad[1] - scene.beams.beta_rad[0])
    e = np.zeros(9)
    e[3], e[0] = 1.0, -1.0
    b = __import__("borescan.uncertainty", fromlist=["Budget"]).Budget.from_dict(cal.diagnostics["budget"])
    U = b.combined(e, p).U
    assert abs(beta21(plain) - true21) > 5 * U  # absorbed: about omega tau
    assert abs(beta21(plain) - true21) == pytest.approx(omega * tau, rel=0.05)
    assert abs(beta21(cal) - true21) < U
    key = [t for t in b.terms if t.input.key.startswith("device_model:TRI-01:channel_delay@2:tau_s")]
    assert len(key) == 1
    assert abs(key[0].along(e)[1]) == pytest.approx(omega * u_tau, rel=0.05)
    assert cal.diagnostics["device_model"][0]["night"] == "2026-11-20"

    # a static bore of 150 mm measured with the corrected calibration (a delay shows nothing of a still scene)
    xy = np.asarray(scene.bore_center_xy_mm) + np.array([[0.3, -0.2], [-0.4, 0.5], [0.1, 0.1]])
    ang = np.array([0.2, 2.2, 4.1])
    meas = simulate.simulate_tri_static(
        scene,
        xy,
        ang,
        scan_id="N20261121-TRI01-MEAS",
        night="2026-11-21",
        kind="measurement",
        noise_mm=0.001,
        seed=4,
        artifact={"id": "PART-1", "type": "part", "nominal_diameter_mm": 275.0},
    )
    mscan = rawio.read_scan(simulate.write_simulated(meas, tmp_path / "raw", tmp_path / "truth"))
    truth_d = 2 * scene.bore_radius_20_mm * (1 + scene.cte_per_k * (scene.temperature_c - 20.0))
    _, du_plain = tri_diameter_with_budget(mscan, plain, unc)
    _, du = tri_diameter_with_budget(mscan, cal, unc)
    assert abs(du.diameter_mm - truth_d) < du.combined_t.U
    assert abs(du_plain.diameter_mm - truth_d) > abs(du.diameter_mm - truth_d)
    assert any(t.input.key == key[0].input.key for t in du.budget.terms)

    # a rotating measurement of the gauge's bore at half the speed: the channel's angle is taken tau earlier
    slow = replace(scene, rpm_nominal=30.0)
    rot = simulate.simulate_tri_spindle(
        slow,
        scan_id="N20261121-TRI01-ROT",
        night="2026-11-21",
        kind="measurement",
        n_rev=5,
        effects=[delay],
        noise_mm=0.001,
        seed=5,
        artifact={"id": "PART-2", "type": "part", "nominal_diameter_mm": 275.0},
    )
    rscan = rawio.read_scan(simulate.write_simulated(rot, tmp_path / "raw", tmp_path / "truth"))
    res_r, du_r = tri_diameter_with_budget(rscan, cal, unc)
    assert res_r["method"] == "rotating LS circle"
    assert abs(du_r.diameter_mm - truth_d) < du_r.combined_t.U
    assert any(t.input.key == key[0].input.key for t in du_r.budget.terms)

    # the certificate names the effect the calibration carried, with its value, u and evidence
    from borescan.certificate import device_model_text
    from borescan.certificate.tri import _fit_part

    (entry,) = _fit_part(cal)["device_model"]
    assert (
        entry["key"] == "channel_delay@2"
        and entry["values"] == {"tau_s": tau_est}
        and entry["night"] == "2026-11-20"
    )
    assert (
        "carried (the readings corrected for it, a channel delay taken in the channel's angle; each value's "
        "uncertainty is an input of the budget): channel_delay@2: tau_s = 0.00119 (u 2e-05), from the pooled "
        "examination of 2026-11-20 (A, B)." in device_model_text([entry])
    )
    assert "device_model" not in _fit_part(plain)

    # the scan's own examination against that calibration: with the device model in its base the delay is
    # fitted (near its carried value), not named; against the same beams without it, it is what is missing
    from borescan.device_model import carried_effects, from_dicts
    from borescan.discrepancy import analyse_scan

    carried = carried_effects(from_dicts(cal.diagnostics["device_model"]))
    with_model = analyse_scan(scan, beams=cal.beams, device_effects=carried).findings
    without = analyse_scan(scan, beams=cal.beams).findings
    assert with_model["verdict"] == "no_missing_effect", with_model["named"]
    # the findings name the device model they were examined with, and are written as JSON (the night's
    # discrepancy job failed on an Effect in them before)
    assert with_model["device_effects"] == [e.to_dict() for e in carried]
    from borescan.discrepancy import write_findings

    assert json.loads(write_findings(with_model, tmp_path / "findings").read_text())["device_effects"][0][
        "name"
    ] == ("channel_delay")
    assert without["verdict"] != "no_missing_effect"
    assert any(n["effect"] == "channel_delay" and n.get("channel") == 2 for n in without["named"])


def test_an_effect_named_night_after_night_enters_automatically_and_leaves_when_a_night_does_not_name_it():
    from borescan.device_model import auto_keys, device_model_at

    def row(night, effect=None, channel=None, model=False, tau=1e-3):
        return {
            "device_id": "TRI-01",
            "night": night,
            "effect": effect,
            "channel": channel,
            "in_device_model": model,
            "parameters": json.dumps({"tau_s": tau}) if effect else None,
            "uncertainties": json.dumps({"u_tau_s": 1e-5}) if effect else None,
            "evidence_scans": "A,B",
        }

    rows = [
        row("2026-11-01", "channel_delay", 2),
        row("2026-11-02", "channel_delay", 2, tau=1.1e-3),
        row("2026-11-02", "bore_lobing"),
        row("2026-11-03"),
        row("2026-11-04", "channel_delay", 2, tau=1.2e-3),
        row("2026-11-05", "channel_delay", 2, tau=1.3e-3),
        row("2026-11-05", "sensor_gain", 1, model=True),
    ]
    assert auto_keys("TRI-01", rows, "2026-11-03", 2) == [
        "channel_delay@2"
    ]  # 1st and 2nd (lobing: the gauge's)
    assert auto_keys("TRI-01", rows, "2026-11-04", 2) == []  # the 3rd named nothing: it leaves
    assert auto_keys("TRI-01", rows, "2026-11-06", 2) == ["channel_delay@2"]
    assert (
        auto_keys("TRI-01", rows, "2026-11-06", 0) == [] and auto_keys("TRI-01", rows, "2026-11-02", 2) == []
    )
    (m,) = device_model_at("TRI-01", [], rows, "2026-11-06", (1, 2, 3), auto=["channel_delay@2"])
    assert m.source == "automatic" and m.values() == {"tau_s": 1.3e-3} and m.night == "2026-11-05"
    (m,) = device_model_at(
        "TRI-01", ["channel_delay@2"], rows, "2026-11-06", (1, 2, 3), auto=["channel_delay@2"]
    )
    assert m.source == "config"
