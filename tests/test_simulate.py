"""Digital twin: closed forms of the forward models, scan generators, demo nights."""

import json
import math

import numpy as np
import polars as pl
import pytest
from scipy.optimize import minimize_scalar

from borescan import rawio
from borescan.synthetic.demo import DEMO_NIGHTS, LOOP_NIGHTS, NOMINAL_BEAMS, demo_scans, make_demo
from borescan.effects import Effect, effects_from_dicts
from borescan.geometry import (
    Beams,
    Hole,
    RodAxis,
    RodLayer,
    circumcircle,
    tri_spindle_readings,
    wall_points_device,
)
from borescan.synthetic.scenes import (
    YANG_BEAMS,
    YANG_P0_XY_MM,
    YANG_P1_XY_MM,
    RodScene,
    TriScene,
    default_rod_scene,
    default_tri_scene,
    rod_readings_with_effects,
    tri_readings,
)
from borescan.synthetic.simulate import (
    load_truth,
    simulate_rod,
    simulate_tri_spindle,
    simulate_tri_static,
    write_simulated,
)

SCENE = default_tri_scene(phase_rad=1.0)
LDS_SCHEMA = {
    "sample": pl.Int64,
    "t_ns": pl.Int64,
    "sensor": pl.Int16,
    "value_mm": pl.Float64,
    "pose": pl.Int32,
}


def _values(lds: pl.DataFrame, c: int) -> np.ndarray:
    return lds["value_mm"].to_numpy().reshape(-1, c)


@pytest.mark.parametrize("ch", [0, 1, 2])
def test_ideal_spindle_scan_extremes_satisfy_yang_eq8(ch):
    """(d_b + d_min)^2 + r^2 = (R - oe)^2 and (d_b + d_max)^2 + r^2 = (R + oe)^2 to 1e-9 mm."""
    R = 275.029 / 2
    oe = math.dist(YANG_P1_XY_MM, YANG_P0_XY_MM)
    assert oe == pytest.approx(2.3232, abs=1e-4)  # the paper prints 2.3222
    t = np.arange(660) / 660.0
    v = tri_readings(SCENE, t)[:, ch]
    rho, d_b = YANG_BEAMS.rho_mm[ch], YANG_BEAMS.d_b_mm[ch]
    for sign, idx, target in ((1, np.argmin(v), R - oe), (-1, np.argmax(v), R + oe)):
        res = minimize_scalar(
            lambda s, sign=sign: sign * tri_readings(SCENE, np.array([s]))[0, ch],
            bounds=(t[idx] - 2 / 660, t[idx] + 2 / 660),
            method="bounded",
            options={"xatol": 1e-12},
        )
        assert math.hypot(d_b + sign * res.fun, rho) == pytest.approx(target, abs=1e-9)
    # the Yang set-up keeps every reading inside the 10 mm range (Table 1: d_min, d_max)
    assert 0.5 < v.min() and v.max() < 9.5


def test_default_readings_match_yang_table1():
    v = tri_readings(SCENE, np.arange(660 * 4) / (660 * 4))
    assert np.allclose(v.min(0), [2.4067, 2.2804, 1.073], atol=0.002)
    assert np.allclose(v.max(0), [7.0549, 6.9256, 5.7177], atol=0.002)


def test_effect_free_rod_satisfies_wang_eq16():
    scene = RodScene(
        layers=(RodLayer(1, 100.0, 71.0), RodLayer(2, 400.0, 71.0)),
        holes=(Hole((0.2, -0.1), 75.004), Hole((0.02, 0.03), 74.997)),
        axis=RodAxis(1.4, -0.9),
    )
    alpha = np.linspace(0, 2 * np.pi, 24, endpoint=False)
    v = rod_readings_with_effects(scene, alpha)
    for j, (lay, hole) in enumerate(zip(scene.layers, scene.holes)):
        l = lay.l0_mm + v[:, j]
        xm, ym = 1.4 - hole.center_xy_mm[0], -0.9 - hole.center_xy_mm[1]
        assert (
            np.max(np.abs((xm + l * np.cos(alpha)) ** 2 + (ym + l * np.sin(alpha)) ** 2 - hole.radius_mm**2))
            < 1e-9
        )


def test_spindle_scan_frames_follow_the_raw_format():
    sim = simulate_tri_spindle(SCENE, n_rev=2, seed=3)
    assert dict(sim.lds.schema) == LDS_SCHEMA
    assert sim.lds.height == 2 * 660 * 3
    assert sim.lds["pose"].null_count() == sim.lds.height
    assert sim.lds.select(pl.col("sample").diff().fill_null(0).ge(0).all()).item()
    assert sim.lds["sensor"].to_list()[:6] == [1, 2, 3, 1, 2, 3]
    t = sim.lds.filter(pl.col("sensor") == 1)["t_ns"].to_numpy()
    assert np.array_equal(t, np.round(np.arange(1320) * 1e9 / 660).astype(np.int64))
    sp = sim.spindle
    assert dict(sp.schema) == {
        "t_ns": pl.Int64,
        "angle_rad": pl.Float64,
        "x_mm": pl.Float64,
        "y_mm": pl.Float64,
        "rpm": pl.Float64,
    }
    # the spec: the device frame is the machine frame at encoder angle 0, so the encoder shows phi itself
    assert np.allclose(
        sp["angle_rad"].to_numpy(), 1.0 + 2 * np.pi * sp["t_ns"].to_numpy() * 1e-9, rtol=0, atol=1e-12
    )
    assert sim.meta["format"] == "borescan-raw/1" and sim.meta["acquisition"]["simulated"] is True
    assert "truth" not in json.dumps(sim.meta)


def test_noise_free_scan_equals_the_forward_model_and_noise_has_sigma():
    effects = [
        Effect("channel_delay", {"channel": 2, "tau_s": 0.0012}),
        Effect("sensor_offset", {"channel": 1, "b_mm": 0.02}),
    ]
    clean = simulate_tri_spindle(SCENE, n_rev=2, noise_mm=0.0, effects=effects)
    t = np.round(np.arange(1320) * 1e9 / 660) * 1e-9
    expect = tri_readings(SCENE, t, effects)
    assert np.max(np.abs(_values(clean.lds, 3) - expect)) < 1e-12
    noisy = simulate_tri_spindle(SCENE, n_rev=10, noise_mm=0.004, effects=effects, seed=11)
    resid = _values(noisy.lds, 3) - tri_readings(SCENE, np.round(np.arange(6600) * 1e9 / 660) * 1e-9, effects)
    assert np.std(resid) == pytest.approx(0.004, rel=0.03)
    assert noisy.truth["noise_sigma_mm"] == 0.004
    assert noisy.truth["effects"] == [e.to_dict() for e in effects]


def test_same_seed_same_scan_other_seed_other_noise():
    a = simulate_tri_spindle(
        SCENE, n_rev=1, seed=5, effects=[Effect("outliers", {"channel": 1, "rate": 0.05, "size_mm": 0.3})]
    )
    b = simulate_tri_spindle(
        SCENE, n_rev=1, seed=5, effects=[Effect("outliers", {"channel": 1, "rate": 0.05, "size_mm": 0.3})]
    )
    c = simulate_tri_spindle(
        SCENE, n_rev=1, seed=6, effects=[Effect("outliers", {"channel": 1, "rate": 0.05, "size_mm": 0.3})]
    )
    assert a.lds.equals(b.lds) and a.spindle.equals(b.spindle) and a.meta == b.meta
    assert not a.lds.equals(c.lds)


def test_readings_outside_range_become_null():
    eff = [Effect("sensor_offset", {"channel": 3, "b_mm": -2.0})]  # channel 3 spans 1.07..5.72 mm
    sim = simulate_tri_spindle(SCENE, n_rev=1, noise_mm=0.0, effects=eff)
    v = _values(sim.lds, 3)
    expect = tri_readings(SCENE, np.round(np.arange(660) * 1e9 / 660) * 1e-9, eff)[:, 2]
    assert np.array_equal(np.isnan(v[:, 2]), expect < 0)
    assert 0 < np.isnan(v[:, 2]).sum() < 660 and not np.isnan(v[:, :2]).any()


def test_quantization_after_noise():
    sim = simulate_tri_spindle(
        SCENE, n_rev=1, seed=2, effects=[Effect("quantization", {"channel": 2, "lsb_mm": 0.002})]
    )
    k = _values(sim.lds, 3)[:, 1] / 0.002
    assert np.max(np.abs(k - np.round(k))) < 1e-9


def test_spindle_stream_reports_commanded_position_and_true_angle():
    eff = [
        Effect("spindle_error_motion", {"k": 2, "rho_mm": 0.003, "phase": 0.0}),
        Effect("speed_error", {"eps": 0.001}),
    ]
    sim = simulate_tri_spindle(SCENE, n_rev=1, effects=eff)
    assert np.all(sim.spindle["x_mm"].to_numpy() == YANG_P1_XY_MM[0])
    assert np.all(sim.spindle["y_mm"].to_numpy() == YANG_P1_XY_MM[1])
    ts = sim.spindle["t_ns"].to_numpy() * 1e-9
    assert np.allclose(sim.spindle["angle_rad"].to_numpy(), 1.0 + 2 * np.pi * 1.001 * ts, rtol=0, atol=1e-12)
    assert np.all(sim.spindle["rpm"].to_numpy() == 60.0)
    no_enc = simulate_tri_spindle(SCENE, n_rev=1, encoder=False)
    assert no_enc.spindle["angle_rad"].null_count() == no_enc.spindle.height


def test_static_scan_blocks_per_pose_and_circumcircle_gives_the_diameter():
    scene = default_tri_scene(bore_center_xy_mm=(0.0, 0.0), bore_radius_20_mm=140.0059)
    xy = np.array([[0.3, -0.2], [-1.0, 0.4], [0.0, 1.2]])
    ang = np.array([0.1, 2.0, 4.0])
    sim = simulate_tri_static(
        scene,
        xy,
        ang,
        samples_per_pose=7,
        noise_mm=0.0,
        effects=[Effect("thermal_expansion", {"temperature_c": 22.0})],
    )
    assert sim.spindle is None and dict(sim.lds.schema) == LDS_SCHEMA
    assert sim.lds.filter(pl.col("sensor") == 1)["pose"].to_list() == [0] * 7 + [1] * 7 + [2] * 7
    v = _values(sim.lds, 3)
    _, r = circumcircle(wall_points_device(v, YANG_BEAMS))
    R_T = 140.0059 * (1 + 11.5e-6 * 2.0)
    assert np.max(np.abs(r - R_T)) < 1e-9
    assert sim.truth["diameter_mm"] == pytest.approx(2 * R_T, abs=1e-12)
    assert sim.meta["environment"]["temperature_c"] == 22.0
    with pytest.raises(ValueError, match="do not apply to a static"):
        simulate_tri_static(scene, xy, ang, effects=[Effect("speed_error", {"eps": 0.01})])


def test_rod_scan_poses_and_noise_free_readings():
    scene = default_rod_scene()
    sim = simulate_rod(scene, n_poses=20, samples_per_pose=4, noise_mm=0.0, seed=4)
    assert dict(sim.lds.schema) == LDS_SCHEMA and sim.spindle is None
    pose = sim.lds.filter(pl.col("sensor") == 1)["pose"].to_numpy()
    assert np.array_equal(pose, np.repeat(np.arange(20), 4))
    alpha = np.asarray(sim.truth["alpha_rad"])
    v = _values(sim.lds, 2)
    assert np.max(np.abs(v - rod_readings_with_effects(scene, alpha[pose]))) < 1e-12
    assert np.all((v > 0) & (v < 8))  # l0 = 71 mm puts 150 mm holes mid-span
    assert [lay["feature"] for lay in sim.meta["rod"]["layers"]] == ["H1", "H2"]
    assert sim.meta["device"]["nominal"]["layers"][0] == {
        "channel": 1,
        "h": 100.0,
        "phi": 0.0,
        "d": 0.0,
        "gamma": 0.0,
        "l0": 71.0,
    }
    assert sim.truth["diameters_mm"] == {"H1": 150.008, "H2": 149.994}


def test_fast_circle_path_equals_the_general_geometry():
    t = np.arange(0, 1.0, 1 / 660)
    for S in (YANG_P1_XY_MM, YANG_P0_XY_MM, (262.0, -272.0)):
        scene = default_tri_scene(spindle_xy_mm=S, phase_rad=0.3)
        v = tri_readings(scene, t)
        expect = tri_spindle_readings(0.3 + 2 * np.pi * t, np.asarray(S), scene.beams, scene.bore())
        assert np.max(np.abs(v - expect)) < 1e-11


def test_truth_rebuilds_the_scene(tmp_path):
    eff = [
        Effect("channel_delay", {"channel": 3, "tau_s": 0.002}),
        Effect("sensor_gain", {"channel": 1, "g": 1e-3}),
    ]
    sim = simulate_tri_spindle(SCENE, n_rev=1, effects=eff, noise_mm=0.0, scan_id="TT")
    write_simulated(sim, tmp_path / "raw", tmp_path / "truth")
    truth = load_truth(tmp_path / "truth", "TT")
    scene = TriScene.from_dict(truth["scene"])
    assert scene.to_dict() == SCENE.to_dict()
    v = tri_readings(scene, np.round(np.arange(660) * 1e9 / 660) * 1e-9, effects_from_dicts(truth["effects"]))
    assert np.max(np.abs(v - _values(sim.lds, 3))) < 1e-12
    rod = simulate_rod(scan_id="TR")
    assert RodScene.from_dict(json.loads(json.dumps(rod.truth["scene"]))) == default_rod_scene()


def test_write_simulated_keeps_truth_outside_raw(tmp_path):
    raw, truth = tmp_path / "raw", tmp_path / "truth"
    sims = [
        simulate_tri_spindle(SCENE, n_rev=1, scan_id="T1"),
        simulate_tri_static(scan_id="T2"),
        simulate_rod(scan_id="T3"),
    ]
    for s in sims:
        path = write_simulated(s, raw, truth)
        assert path == raw / "night=2026-11-20" / f"scan={s.scan_id}"
        assert json.loads((truth / f"{s.scan_id}.truth.json").read_text())["scan_id"] == s.scan_id
    assert not list(raw.rglob("*truth*"))
    assert rawio.validate_root(raw) == []
    scan = rawio.read_scan(raw / "night=2026-11-20" / "scan=T1")
    assert scan.lds.height == 660 * 3 and scan.spindle is not None


def test_demo_writes_the_listed_scans(tmp_path):
    paths = make_demo(tmp_path)
    raw = tmp_path / "raw"
    assert (tmp_path / ".complete").exists()
    assert rawio.validate_root(raw) == []
    ids = {p.name.removeprefix("scan=") for p in paths}
    assert DEMO_NIGHTS == ("2026-11-20", "2026-11-21") + LOOP_NIGHTS
    for night in DEMO_NIGHTS[:2]:
        tag = "N" + night.replace("-", "")
        for name in (
            "TRI01-CEN",
            "TRI01-CAL-P1-A",
            "TRI01-CAL-P1-B",
            "TRI01-VER-RG275",
            "TRI01-VER-RG280",
            "ROD01-MEAS-CYL2H",
            "ROD01-VER-RGS150",
        ):
            assert f"{tag}-{name}" in ids
        assert sum(i.startswith(f"{tag}-TRI01-MEAS-") for i in ids) == 3
    assert "N20261120-ROD01-CAL-RGS150" in ids  # the rod is calibrated on its ring gauges on the first night
    # the loop nights: TRI-01 calibrated at 60 and 30 rpm with the 1.2 ms delay on channel 2 in every scan
    assert {i for i in ids if i.startswith(("N20261123", "N20261124"))} == {
        "N20261123-TRI01-CAL-P1-A",
        "N20261123-TRI01-CAL-P1-B",
        "N20261123-TRI01-VER-RG275",
        "N20261124-TRI01-CAL-P1-A",
        "N20261124-TRI01-CAL-P1-B",
        "N20261124-TRI01-VER-RG275",
        "N20261124-TRI01-VER-RG280",
    }
    for night in LOOP_NIGHTS:
        tag = "N" + night.replace("-", "")
        speeds = [
            json.loads((raw / f"night={night}" / f"scan={tag}-TRI01-CAL-P1-{x}" / "scan.json").read_text())[
                "spindle"
            ]["rpm_nominal"]
            for x in "AB"
        ]
        assert speeds == [60.0, 30.0]
        truth = json.loads((tmp_path / "truth" / f"{tag}-TRI01-CAL-P1-B.truth.json").read_text())
        assert truth["effects"] == [{"name": "channel_delay", "params": {"channel": 2, "tau_s": 0.0012}}]
    kinds = {}
    for p in paths:
        meta = json.loads((p / "scan.json").read_text())
        kinds.setdefault(meta["kind"], 0)
        kinds[meta["kind"]] += 1
        assert (tmp_path / "truth" / f"{meta['scan_id']}.truth.json").exists()
    assert kinds == {"centering": 2, "calibration": 9, "verification": 9, "measurement": 8}
    cal = json.loads((raw / "night=2026-11-20" / "scan=N20261120-TRI01-CAL-P1-A" / "scan.json").read_text())
    assert cal["spindle"]["position"] == {"label": "P1", "x_mm": 262.955, "y_mm": -275.502}
    nominal = Beams.from_nominal(cal["device"]["nominal"]["beams"])
    assert np.array_equal(nominal.beta_rad, NOMINAL_BEAMS.beta_rad)
    assert 0 < np.max(np.abs(nominal.beta_rad - YANG_BEAMS.beta_rad)) < math.radians(1.01)
    assert 0 < np.max(np.abs(nominal.d_b_mm - YANG_BEAMS.d_b_mm)) < 0.05  # nominal differs from truth
    assert 0 < np.max(np.abs(nominal.rho_mm - YANG_BEAMS.rho_mm)) < 0.06
    lds = pl.read_parquet(raw / "night=2026-11-20" / "scan=N20261120-TRI01-CAL-P1-A" / "lds.parquet")
    assert lds.height == 60 * 660 * 3
    size = sum(f.stat().st_size for f in raw.rglob("*") if f.is_file())
    assert size < 20e6


def test_demo_is_deterministic():
    a, b = demo_scans(7)[:3], demo_scans(7)[:3]
    for x, y in zip(a, b):
        assert x.meta == y.meta and x.lds.equals(y.lds) and x.truth == y.truth
