"""Contract scenarios (borescan.synthetic): valid scans over the whole contract, deterministic, and the
angle and readings written agree with the truth.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from borescan import cli, kinematics, rawio
from borescan.synthetic import battery, rod_scenarios, scenes, simulate, tri_scenarios
from borescan.synthetic.battery import battery_rng
from borescan.synthetic.contract import TRI_CONTRACT
from borescan.synthetic.tri_scenarios import draw_tri_calibration

N_DRAWS = 50
SEED = 20270101


@pytest.fixture(scope="module")
def draws():
    """50 scans of one battery seed, in memory."""
    return [
        draw_tri_calibration(battery_rng(SEED, i), scan_id=f"T{i:03d}", night="2027-01-01")
        for i in range(N_DRAWS)
    ]


def _scene(sim) -> scenes.TriScene:
    return scenes.TriScene.from_dict(sim.truth["scene"])


def _matrix(sim) -> tuple[np.ndarray, np.ndarray]:
    """(t_s (n,), readings (n, 3)) of an in-memory scan (NaN = null)."""
    t_ns = sim.lds["t_ns"].to_numpy()
    v = sim.lds["value_mm"].to_numpy().astype(float)
    return t_ns[::3] * 1e-9, v.reshape(-1, 3)


def _angle_model(sim) -> kinematics.AngleModel:
    sp = sim.spindle
    return kinematics.angle_model_from_arrays(
        rpm_nominal=sim.meta["spindle"]["rpm_nominal"],
        direction=sim.meta["spindle"]["direction"],
        spindle_t_s=sp["t_ns"].to_numpy() * 1e-9,
        spindle_angle_rad=sp["angle_rad"].to_numpy(),
        spindle_rpm=sp["rpm"].to_numpy(),
    )


def _pick(draws, **want):
    for sim in draws:
        c = sim.truth["contract"]
        if all(c[k] == v for k, v in want.items()):
            return sim
    raise AssertionError(f"no draw with {want} among {len(draws)}")


# --------------------------------------------------------------------------- validity


def test_written_scans_pass_read_scan_validation(draws, tmp_path):
    raw, truth = tmp_path / "raw", tmp_path / "truth"
    for sim in draws[:6]:
        path = simulate.write_simulated(sim, raw, truth)
        scan = rawio.read_scan(path)
        assert scan.scan_id == sim.scan_id
        assert scan.meta["kind"] == "calibration" and scan.meta["device"]["type"] == "tri_lds"
        assert scan.spindle is not None and scan.channels == (1, 2, 3)
        mat = rawio.lds_matrix(scan)
        assert mat.values_mm.shape == (sim.truth["contract"]["n_samples"], 3)
        # null where the sensor gives nothing: out of range or sporadic
        assert np.isnan(mat.values_mm).sum() >= sim.truth["contract"]["n_sporadic_nulls"] * 0.9
        t = simulate.load_truth(truth, sim.scan_id)
        assert t["contract"]["beams"] == sim.truth["contract"]["beams"]


def test_scan_json_reports_positions_with_machine_accuracy_and_a_design_geometry(draws):
    e = TRI_CONTRACT["position_error_mm"]
    for sim in draws:
        c, meta = sim.truth["contract"], sim.meta
        sp = np.array([sim.spindle["x_mm"][0], sim.spindle["y_mm"][0]])
        np.testing.assert_allclose(sp, c["spindle_reported_xy_mm"], rtol=0, atol=0)
        assert np.all(np.abs(sp - np.array(c["spindle_xy_mm"])) <= e)
        if c["position_known"]:
            C = np.array([meta["center"]["x_mm"], meta["center"]["y_mm"]])
            S = np.array([meta["spindle"]["position"]["x_mm"], meta["spindle"]["position"]["y_mm"]])
            assert np.all(np.abs(C - np.array(c["center_xy_mm"])) <= e)
            assert np.all(np.abs(S - np.array(c["spindle_xy_mm"])) <= e)
            assert np.abs(C - np.array(c["center_xy_mm"])).max() > 0  # an error, not the truth
        else:
            assert "center" not in meta and "position" not in meta["spindle"]
        nom = meta["device"]["nominal"]["beams"]
        for b_nom, b_true in zip(nom, c["beams"]):
            assert abs(b_nom["beta"] - b_true["beta"]) <= TRI_CONTRACT["nominal_beta_rad"]
            assert abs(b_nom["rho"] - b_true["rho"]) <= TRI_CONTRACT["nominal_rho_mm"]
            assert abs(b_nom["d_b"] - b_true["d_b"]) <= TRI_CONTRACT["nominal_d_b_mm"]
        assert nom != c["beams"]
        art = meta["artifact"]
        assert art["type"] == "ring_gauge" and art["certified_diameter_mm"] == 2 * c["bore_radius_mm"]
        assert (
            art["u_diameter_mm"] == 0.0015 and art["k"] == 2 and meta["environment"]["temperature_c"] == 20.0
        )


# --------------------------------------------------------------------------- ranges


def test_ranges_hold_over_50_draws(draws):
    C = [sim.truth["contract"] for sim in draws]
    R = np.array([c["bore_radius_mm"] for c in C])
    off = np.array([c["spindle_offset_mm"] for c in C])
    noise = np.array([c["noise_mm"] for c in C])
    spr = np.array([c["samples_per_rev"] for c in C])
    nrev = np.array([c["n_rev"] for c in C])
    rpm = np.array([c["rpm_nominal"] for c in C])
    rate = np.array([c["spindle_rate_hz"] for c in C])
    assert 75.0 <= R.min() and R.max() <= 200.0 and np.ptp(R) > 80.0
    assert 0.5 <= off.min() and off.max() <= 3.0 and np.ptp(off) > 1.5
    assert 0.001 <= noise.min() and noise.max() <= 0.005 and np.ptp(noise) > 0.0025
    assert 400 <= spr.min() and spr.max() <= 1000 and np.ptp(spr) > 350
    assert 20 <= nrev.min() and nrev.max() <= 120 and np.ptp(nrev) > 60
    assert 20.0 <= rpm.min() and rpm.max() <= 120.0
    assert 50.0 <= rate.min() and rate.max() <= 500.0
    for sim, c in zip(draws, C):
        off_xy = np.subtract(c["spindle_xy_mm"], c["center_xy_mm"])
        assert math.isclose(np.hypot(*off_xy), c["spindle_offset_mm"], rel_tol=1e-9)
        beta = np.array([b["beta"] for b in c["beams"]])
        d = np.abs(beta[:, None] - beta[None, :]) % (2 * np.pi)
        d = np.minimum(d, 2 * np.pi - d)[np.triu_indices(3, 1)]
        assert d.min() >= math.radians(20.0) - 1e-12
        assert max(abs(b["rho"]) for b in c["beams"]) <= 15.0
        assert all(4.0 <= r <= 10.0 for r in c["range_mm"])
        assert [s["range_mm"] for s in sim.meta["sensors"]] == c["range_mm"]
        # samples per revolution at the written sample rate, for every speed of the profile
        speeds = [c["rpm_nominal"]] + [k[1] for k in c["rpm_profile"]]
        for s in speeds:
            assert 400 - 1e-6 <= sim.meta["sample_rate_hz"] * 60.0 / s <= 1000 + 1e-6
            assert 20.0 - 1e-9 <= s <= 120.0 + 1e-9
        if c["speed_change"]:
            f = c["speed_factor"]
            assert 0.4 <= f <= 0.9 or 1.1 <= f <= 1.6
            assert (
                0.5 - 1.0 / c["spindle_rate_hz"]
                <= c["ramp_end_s"] - c["ramp_start_s"]
                <= 2.0 + 1.0 / c["spindle_rate_hz"]
            )
        # duration of n_rev revolutions of the commanded profile
        t_end = sim.truth["n_samples"] / sim.meta["sample_rate_hz"]
        assert abs(_scene(sim).commanded_angle_rad(t_end) / (2 * np.pi) - c["n_rev"]) < 0.01
    share = lambda key: np.mean([bool(c[key]) for c in C])  # noqa: E731
    assert 0.25 <= share("speed_change") <= 0.55
    assert 0.35 <= share("encoder") <= 0.65
    assert 0.5 <= share("position_known") <= 0.85
    assert 0.15 <= share("out_of_range") <= 0.45
    assert 0.3 <= np.mean([c["direction"] == "ccw" for c in C]) <= 0.7


def test_out_of_range_channel_and_sporadic_nulls(draws):
    for sim in draws[:25]:
        c = sim.truth["contract"]
        _, v = _matrix(sim)
        null = np.isnan(v).mean(axis=0)
        p = c["null_fraction"]
        assert 0.001 <= p <= 0.01
        for j, ch in enumerate((1, 2, 3)):
            oor = c["out_of_range"]
            if oor is not None and oor["channel"] == ch:
                # out of range for the drawn fraction of each revolution (+ sporadic nulls)
                assert abs(null[j] - oor["fraction_per_rev"] - p) < 0.03
            else:
                # only the sporadic nulls (binomial spread)
                n = v.shape[0]
                assert abs(null[j] - p) < 5 * math.sqrt(p / n) + 1e-4


# --------------------------------------------------------------------------- determinism


def test_same_seed_gives_byte_identical_lds_parquet(tmp_path):
    a = battery.write_battery(tmp_path / "a", 2, 7)
    b = battery.write_battery(tmp_path / "b", 3, 7)
    for pa_, pb in zip(a, b):
        assert (pa_ / "lds.parquet").read_bytes() == (pb / "lds.parquet").read_bytes()
        assert (pa_ / "scan.json").read_bytes() == (pb / "scan.json").read_bytes()
    # a subset of the battery is the same scans
    sub = battery.write_battery(tmp_path / "d", 3, 7, only=[2])
    assert (
        sub[0].name == b[2].name
        and (sub[0] / "lds.parquet").read_bytes() == (b[2] / "lds.parquet").read_bytes()
    )
    other = battery.write_battery(tmp_path / "c", 1, 8)
    assert (other[0] / "lds.parquet").read_bytes() != (a[0] / "lds.parquet").read_bytes()
    idx = json.loads((tmp_path / "b" / "battery.json").read_text())
    assert idx["seed"] == 7 and idx["n"] == 3 and len(idx["scan_ids"]) == 3
    # the child seed of scan i does not depend on the battery's length
    assert battery_rng(7, 1).random() == np.random.default_rng(np.random.SeedSequence(7).spawn(5)[1]).random()


def test_cli_simulate_contract(tmp_path, capsys):
    assert cli.main(["simulate", "contract", "--n", "2", "--seed", "3", "--out", str(tmp_path / "bat")]) == 0
    out = capsys.readouterr().out
    assert "2/2" in out and "2 scans written" in out
    scans = sorted((tmp_path / "bat" / "raw").glob("night=*/scan=*"))
    assert len(scans) == 2 and all(rawio.read_scan(p).meta["acquisition"]["simulated"] for p in scans)
    assert len(list((tmp_path / "bat" / "truth").glob("*.truth.json"))) == 2
    with pytest.raises(SystemExit) as e:
        cli.main(["simulate", "contract", "--n", "0", "--out", str(tmp_path / "x")])
    assert e.value.code == 2
    with pytest.raises(ValueError):
        battery.write_battery(tmp_path / "y", 0, 1)
    assert (
        cli.main(
            [
                "simulate",
                "contract",
                "--n",
                "1",
                "--seed",
                "3",
                "--out",
                str(tmp_path / "mix"),
                "--kinds",
                "calibration,static,rod",
            ]
        )
        == 0
    )
    names = sorted(p.name for p in (tmp_path / "mix" / "raw").glob("night=*/scan=*"))
    assert names == ["scan=CR3-00000", "scan=CS3-00000", "scan=CT3-00000"]
    assert {
        rawio.read_scan(p).meta["device"]["type"] for p in (tmp_path / "mix" / "raw").glob("night=*/scan=*")
    } == {"tri_lds", "rod"}
    assert cli.main(["simulate", "contract", "--n", "1", "--out", str(tmp_path / "z"), "--kinds", "foo"]) == 2
    assert "each kind must be one of" in capsys.readouterr().err


# --------------------------------------------------------------------------- the angle written


def test_encoder_angle_equals_tri_phi(draws):
    """Constant speed: the encoder spline is phi itself to 1e-6 rad. A ramp bends the angle
    (an acceleration step at each knot) and a cubic spline through a 50-500 Hz encoder misses
    it by up to ~ (rate^-2) * jump / 8 there; bound 1e-4 rad (< 0.3 um of reading at 3 mm offset).
    """
    n_const = n_ramp = 0
    for sim in draws:
        c = sim.truth["contract"]
        if not c["encoder"]:
            continue
        am = _angle_model(sim)
        assert am.source == "encoder"
        t, _ = _matrix(sim)
        err = np.abs(am.phi_rad(t) - scenes.tri_phi(_scene(sim), t)).max()
        if c["speed_change"]:
            n_ramp += 1
            assert err < 1e-4, (sim.scan_id, err)
        else:
            n_const += 1
            assert err < 1e-6, (sim.scan_id, err)
    assert n_const >= 5 and n_ramp >= 3


def test_profile_angle_equals_commanded_angle(draws):
    n = {True: 0, False: 0}
    for sim in draws:
        c = sim.truth["contract"]
        if c["encoder"]:
            continue
        am = _angle_model(sim)
        assert am.source == "profile" and am.fits_speed_and_phase
        scene = _scene(sim)
        t, _ = _matrix(sim)
        sgn = 1.0 if c["direction"] == "ccw" else -1.0
        np.testing.assert_allclose(am.commanded_rad(t), sgn * scene.commanded_angle_rad(t), rtol=0, atol=1e-9)
        # phi = phase + sgn Phi: the truth's phi is the model's with phase and speed scale 1
        np.testing.assert_allclose(
            am.phi_rad(t, phase_rad=scene.phase_rad), scenes.tri_phi(scene, t), rtol=0, atol=1e-9
        )
        n[c["speed_change"]] += 1
    assert n[True] >= 3 and n[False] >= 5


def test_speed_scale_recovered_from_readings(draws):
    for sim in draws[:20]:
        if sim.truth["contract"]["encoder"]:
            continue
        am = _angle_model(sim)
        t, v = _matrix(sim)
        scale = kinematics.speed_scale_from_readings(am.commanded_rad(t), v)
        assert abs(scale - 1.0) < 0.01, (sim.scan_id, scale)


def test_effect_free_readings_are_the_model_plus_noise(draws):
    for sim in draws[:20]:
        c = sim.truth["contract"]
        assert c["effect_free"] and sim.truth["effects"] == []
        t, v = _matrix(sim)
        model = scenes.tri_readings(_scene(sim), t)
        ok = np.isfinite(v)
        res = (v - model)[ok]
        assert abs(res.std() / c["noise_mm"] - 1.0) < 0.2
        assert abs(res.mean()) < 5 * c["noise_mm"] / math.sqrt(res.size)
        # null exactly where out of range or sporadic: every reading written lies in [0, range]
        assert np.all((v[ok] >= 0) & (v[ok] <= np.broadcast_to(c["range_mm"], v.shape)[ok]))


def test_effects_can_be_drawn_on_request():
    sim = draw_tri_calibration(battery_rng(3, 0), scan_id="E0", night="2027-01-01", effect_free=False)
    assert len(sim.truth["effects"]) == 1 and not sim.truth["contract"]["effect_free"]


def test_static_sets_over_the_contract_measure_to_their_truth(tmp_path):
    """Static three-sensor sets (ring gauges and parts, 3-12 poses, noise 1-5 um) written and read
    back like any scan, measured with the true beams: every diameter within 4 u of the truth, the
    z-scores' SD near 1 (the scan's repeatability is the drawn noise).
    """
    from borescan.geometry import Beams
    from borescan.measure import measure_scan

    z, kinds = [], set()
    for i in range(24):
        sim = tri_scenarios.draw_tri_static(battery_rng(5, i), scan_id=f"CS5-{i:05d}", night="2027-01-01")
        c = sim.truth["contract"]
        kinds.add(c["artifact"])
        d = simulate.write_simulated(sim, tmp_path / "raw", tmp_path / "truth")
        res = measure_scan(
            rawio.read_scan(d, raw_root=tmp_path / "raw"), Beams.from_nominal(c["beams"]), np.zeros((9, 9))
        )
        z.append((res["diameter_mm"] - c["diameter_mm"]) / res["u_diameter_mm"])
        assert 75.0 <= c["bore_radius_mm"] <= 200.0 and 3 <= c["n_poses"] <= 12
    z = np.array(z)
    assert kinds == {"ring_gauge", "part"}
    assert np.max(np.abs(z)) < 4.0 and 0.6 < np.std(z) < 1.5


def test_rod_scans_over_the_contract_and_a_mixed_battery(tmp_path):
    """Rod scans in ring-gauge sets (certified) and parts (nominal), ranges of the contract; the
    rod solve recovers every hole within 4 u; write_battery writes every kind from its own
    stream (calibration scans unchanged by adding the others).
    """
    from borescan.geometry import RodLayer
    from borescan.rod import solve_rod

    kinds = set()
    for i in range(6):
        sim = rod_scenarios.draw_rod_scan(battery_rng(6, i), scan_id=f"CR6-{i:05d}", night="2027-01-01")
        c = sim.truth["contract"]
        kinds.add(c["artifact"])
        assert 2 <= len(c["diameters_mm"]) <= 3 and all(100.0 <= d <= 200.0 for d in c["diameters_mm"])
        assert (
            8 <= c["n_poses"] <= 40
            and c["eccentricity_mm"] <= 2.5
            and c["deflection_rad"] <= math.radians(1.0)
        )
        art = sim.meta["artifact"]
        assert ("certified_diameter_mm" in art["features"][0]) == (c["artifact"] == "ring_gauge")
        lds = sim.lds.sort("sample", "sensor")
        m = len(c["diameters_mm"])
        vals = lds["value_mm"].to_numpy().reshape(-1, m)
        p = lds["pose"].to_numpy().reshape(-1, m)[:, 0]
        means = np.array([vals[p == k].mean(axis=0) for k in range(c["n_poses"])])
        layers = [
            RodLayer(int(lay["channel"]), lay["h"], lay["l0"], lay["phi"], lay["d"], lay["gamma"])
            for lay in sim.meta["device"]["nominal"]["layers"]
        ]
        sol = solve_rod(means, layers=layers, u_reading_mm=c["noise_mm"] / np.sqrt(c["samples_per_pose"]))
        assert np.all(np.abs(sol.diameter_mm - np.array(c["diameters_mm"])) < 4 * sol.u_diameter_mm)
    assert kinds == {"ring_gauge", "part"}
    paths = battery.write_battery(tmp_path / "b", 2, 9, kinds=("calibration", "static", "rod"))
    names = [p.name for p in paths]
    assert names == [
        "scan=CT9-00000",
        "scan=CT9-00001",
        "scan=CS9-00000",
        "scan=CS9-00001",
        "scan=CR9-00000",
        "scan=CR9-00001",
    ]
    only_cal = battery.write_battery(tmp_path / "c", 2, 9)
    assert (only_cal[0] / "lds.parquet").read_bytes() == (paths[0] / "lds.parquet").read_bytes()
    assert json.loads((tmp_path / "b" / "battery.json").read_text())["kinds"] == [
        "calibration",
        "static",
        "rod",
    ]
    with pytest.raises(ValueError, match="kinds must be among"):
        battery.write_battery(tmp_path / "d", 1, 1, kinds=("spindle",))


def test_scale_effect_scales_sizes_only():
    """Amplitudes, gains, delays scale by the factor, a temperature by its departure from 20 degC;
    channel, harmonic, phase and frequency stay.
    """
    from borescan.discrepancy.battery import scale_effect
    from borescan.effects import Effect

    e = scale_effect(Effect("spindle_error_motion", {"k": 3, "rho_mm": 0.004, "phase": 0.5}), 2.5)
    assert e.params == {"k": 3, "rho_mm": 0.01, "phase": 0.5}
    e = scale_effect(Effect("channel_delay", {"channel": 2, "tau_s": 0.001}), 0.3)
    assert e.params["channel"] == 2 and math.isclose(e.params["tau_s"], 3e-4, rel_tol=1e-15)
    e = scale_effect(Effect("thermal_expansion", {"temperature_c": 24.0}), 0.5)
    assert e.params["temperature_c"] == 22.0
    e = scale_effect(Effect("vibration", {"f_hz": 7.3, "a_mm": 0.004, "phase": 0.4}), 2.0)
    assert e.params == {"f_hz": 7.3, "a_mm": 0.008, "phase": 0.4}


def test_night_battery_measurements_on_calibrated_devices_and_rod_calibrations(tmp_path):
    """A contract night: rotating measurements on the device of calibration scan i (same id,
    beams, kinematics; a part of the gauge's size), rod calibration scans in ring-gauge sets, every
    scan on one night, effects on a share of the scans decided from a stream of their own (the
    scans' other draws unchanged), every scan valid for ingest.
    """
    kinds = ("calibration", "measurement", "rod_calibration")
    paths = battery.write_battery(
        tmp_path / "n", 2, 5, kinds=kinds, effect_share=1.0, effect_scale_range=(0.3, 3.0), per_night=100
    )
    assert [p.name for p in paths] == [
        "scan=CT5-00000",
        "scan=CT5-00001",
        "scan=CM5-00000",
        "scan=CM5-00001",
        "scan=CK5-00000",
        "scan=CK5-00001",
    ]
    assert {p.parent.name for p in paths} == {"night=2027-01-01"}
    scans = {p.name[5:]: rawio.read_scan(p) for p in paths}
    truth = {sid: json.loads((tmp_path / "n" / "truth" / f"{sid}.truth.json").read_text()) for sid in scans}
    assert all(len(t["effects"]) == 1 for t in truth.values())
    for i in (0, 1):
        cal, mea = scans[f"CT5-{i:05d}"].meta, scans[f"CM5-{i:05d}"].meta
        assert mea["kind"] == "measurement" and mea["device"] == cal["device"]
        assert mea["artifact"]["type"] == "part" and "certified_diameter_mm" not in mea["artifact"]
        assert abs(mea["artifact"]["nominal_diameter_mm"] - cal["artifact"]["certified_diameter_mm"]) < 0.2
        assert mea["started_at"] > cal["started_at"]
        rc = scans[f"CK5-{i:05d}"].meta
        assert rc["kind"] == "calibration" and rc["device"]["type"] == "rod"
        assert all("certified_diameter_mm" in f for f in rc["artifact"]["features"])
    free = battery.write_battery(
        tmp_path / "f", 2, 5, kinds=("calibration",), effect_share=0.0, per_night=100
    )
    assert all(not json.loads(p.read_text())["effects"] for p in (tmp_path / "f" / "truth").glob("*.json"))
    # the effect-free scan of the same index is the one the plain battery writes (its draws are untouched)
    plain = battery.write_battery(tmp_path / "p", 2, 5, per_night=100)
    assert (plain[0] / "lds.parquet").read_bytes() == (free[0] / "lds.parquet").read_bytes()
    with pytest.raises(ValueError, match="effect share"):
        battery.write_battery(tmp_path / "x", 1, 5, effect_share=1.5)
