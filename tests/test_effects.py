"""Each named effect changes the readings exactly as its formula in geometry-and-effects.md says."""

import math
import re

import numpy as np
import pytest

from borescan.effects import EFFECTS, Effect, apply_effects, get_effect, nonlinearity_bow, parse_effect
from borescan.geometry import (
    Bore,
    Hole,
    RodAxis,
    RodLayer,
    bore_wall_radius,
    rod_readings,
    tri_spindle_readings,
)
from borescan.geometry import wall_points_device
from borescan.synthetic.scenes import (
    RodScene,
    default_tri_scene,
    rod_readings_with_effects,
    tri_phi,
    tri_readings,
)

SCENE = default_tri_scene(phase_rad=0.4)
T_S = np.arange(0, 2.0, 1 / 660)  # two revolutions at 60 rpm
BASE = tri_readings(SCENE, T_S)
ROD = RodScene(
    layers=(RodLayer(1, 100.0, 71.0), RodLayer(2, 400.0, 71.0, phi_rad=0.3)),
    holes=(Hole((0.0, 0.0), 75.0), Hole((0.01, -0.02), 75.01)),
    axis=RodAxis(dx_mm=0.8, dy_mm=-0.5),
)
ALPHA = np.linspace(0, 2 * np.pi, 24, endpoint=False)

# The spec's "Named effects" table, transcribed: name -> parameter names (c written as channel).
SPEC_TABLE = {
    "sensor_offset": {"channel", "b_mm"},
    "sensor_gain": {"channel", "g"},
    "sensor_nonlinearity": {"channel", "a_mm"},
    "sensor_drift": {"channel", "k_mm_per_s"},
    "channel_delay": {"channel", "tau_s"},
    "quantization": {"channel", "lsb_mm"},
    "outliers": {"channel", "rate", "size_mm"},
    "vibration": {"f_hz", "a_mm", "phase"},
    "speed_error": {"eps"},
    "speed_ripple": {"a_rad", "phase"},
    "spindle_error_motion": {"k", "rho_mm", "phase"},
    "axis_tilt": {"beta_rad", "azimuth"},
    "bore_lobing": {"k", "a_mm", "phase"},
    "thermal_expansion": {"temperature_c"},
    "beam_tilt": {"channel", "gamma_rad"},
    "beam_offset": {"channel", "d_mm"},
}


def _with(*effects):
    return tri_readings(SCENE, T_S, list(effects))


def test_registry_mirrors_the_spec_table():
    assert list(EFFECTS) == list(SPEC_TABLE)
    for name, params in SPEC_TABLE.items():
        spec = EFFECTS[name]
        assert set(spec.params) == params
        assert spec.stage in (
            "time_base",
            "kinematics",
            "spindle_position",
            "bore",
            "beam",
            "reading",
            "output",
        )
        assert set(spec.forward) == set(spec.device_types)


def test_unknown_names_and_parameters_raise():
    with pytest.raises(
        ValueError, match=r"unknown effect 'lens_fog'; valid effects: sensor_offset, .*beam_offset"
    ):
        get_effect("lens_fog")
    with pytest.raises(ValueError, match=r"takes parameters \['b_mm', 'channel'\]"):
        Effect("sensor_offset", {"channel": 1, "offset": 0.1})
    with pytest.raises(ValueError, match="does not apply to a tri_lds"):
        tri_readings(SCENE, T_S, [Effect("beam_offset", {"channel": 1, "d_mm": 0.1})])
    with pytest.raises(ValueError, match="names channel 4"):
        tri_readings(SCENE, T_S, [Effect("sensor_offset", {"channel": 4, "b_mm": 0.1})])


def test_parse_effect_round_trip():
    e = parse_effect("channel_delay:channel=2,tau_s=0.0012")
    assert e == Effect("channel_delay", {"channel": 2, "tau_s": 0.0012})
    assert isinstance(e.params["channel"], int)
    assert Effect.from_dict(e.to_dict()) == e
    assert parse_effect(str(e)) == e


def test_sensor_offset_adds_b_on_its_channel_only():
    d = _with(Effect("sensor_offset", {"channel": 2, "b_mm": 0.0123})) - BASE
    assert np.max(np.abs(d[:, 1] - 0.0123)) < 1e-12
    assert np.max(np.abs(d[:, [0, 2]])) == 0.0


def test_same_effect_on_several_channels_composes():
    v = _with(
        Effect("sensor_offset", {"channel": 1, "b_mm": 0.01}),
        Effect("sensor_offset", {"channel": 3, "b_mm": -0.02}),
        Effect("sensor_gain", {"channel": 1, "g": 0.001}),
    )
    # spec table order inside the reading stage: offset, then gain
    assert np.allclose(v[:, 0], (BASE[:, 0] + 0.01) * 1.001, rtol=0, atol=1e-12)
    assert np.allclose(v[:, 2], BASE[:, 2] - 0.02, rtol=0, atol=1e-12)
    assert np.array_equal(v[:, 1], BASE[:, 1])


def test_sensor_gain_scales():
    v = _with(Effect("sensor_gain", {"channel": 3, "g": -0.002}))
    assert np.allclose(v[:, 2], BASE[:, 2] * 0.998, rtol=0, atol=1e-12)


def test_sensor_nonlinearity_is_a_bow():
    v = _with(Effect("sensor_nonlinearity", {"channel": 1, "a_mm": 0.01}))
    u = BASE[:, 0] / 10.0
    assert np.allclose(v[:, 0], BASE[:, 0] + 0.01 * 4 * u * (1 - u), rtol=0, atol=1e-12)
    assert nonlinearity_bow(np.array([0.0, 5.0, 10.0]), 10.0).tolist() == [0.0, 1.0, 0.0]


def test_sensor_drift_is_linear_in_time():
    v = _with(Effect("sensor_drift", {"channel": 2, "k_mm_per_s": 0.003}))
    assert np.allclose(v[:, 1], BASE[:, 1] + 0.003 * T_S, rtol=0, atol=1e-12)


def test_channel_delay_shows_the_reading_of_t_minus_tau():
    tau = 0.0012
    v = _with(Effect("channel_delay", {"channel": 2, "tau_s": tau}))
    shifted = tri_readings(SCENE, T_S - tau)
    assert np.max(np.abs(v[:, 1] - shifted[:, 1])) < 1e-10
    assert np.array_equal(v[:, [0, 2]], BASE[:, [0, 2]])
    # it is a real change: about dv/dt * tau
    assert np.max(np.abs(v[:, 1] - BASE[:, 1])) > 0.01


def test_channel_delay_also_delays_drift():
    v = _with(
        Effect("channel_delay", {"channel": 1, "tau_s": 0.01}),
        Effect("sensor_drift", {"channel": 1, "k_mm_per_s": 0.5}),
    )
    expect = tri_readings(SCENE, T_S - 0.01)[:, 0] + 0.5 * (T_S - 0.01)
    assert np.max(np.abs(v[:, 0] - expect)) < 1e-10


def test_speed_error_scales_phi():
    eps = 2e-3
    v = _with(Effect("speed_error", {"eps": eps}))
    # phi(t) = phase + omega (1 + eps) t: the nominal model at time t (1 + eps)
    assert np.max(np.abs(v - tri_readings(SCENE, T_S * (1 + eps)))) < 1e-10
    phi = tri_phi(SCENE, T_S, [Effect("speed_error", {"eps": eps})])
    assert np.allclose(phi, 0.4 + 2 * np.pi * (1 + eps) * T_S, rtol=0, atol=1e-12)


def test_speed_ripple():
    a, ph = 0.01, 0.7
    v = _with(Effect("speed_ripple", {"a_rad": a, "phase": ph}))
    w = 2 * np.pi
    t_equiv = (w * T_S + a * np.sin(w * T_S + ph)) / w
    assert np.max(np.abs(v - tri_readings(SCENE, t_equiv))) < 1e-10


def test_clockwise_turns_the_other_way():
    cw = default_tri_scene(phase_rad=0.4, direction="cw")
    assert np.allclose(tri_phi(cw, T_S), 0.4 - 2 * np.pi * T_S)


def test_spindle_error_motion_moves_the_spindle():
    k, rho, ph = 3, 0.002, 0.5
    v = _with(Effect("spindle_error_motion", {"k": k, "rho_mm": rho, "phase": ph}))
    phi = 0.4 + 2 * np.pi * T_S
    S = np.asarray(SCENE.spindle_xy_mm) + rho * np.stack([np.cos(k * phi + ph), np.sin(k * phi + ph)], -1)
    expect = tri_spindle_readings(phi, S, SCENE.beams, SCENE.bore())
    assert np.max(np.abs(v - expect)) < 1e-10
    assert 0.5 * rho < np.max(np.abs(v - BASE)) < 2.01 * rho


def _wall_points_machine(v, phi, S):
    W = wall_points_device(v, SCENE.beams)
    c, s = np.cos(phi)[:, None], np.sin(phi)[:, None]
    return np.asarray(S) + np.stack([c * W[..., 0] - s * W[..., 1], s * W[..., 0] + c * W[..., 1]], -1)


def test_axis_tilt_gives_the_ellipse():
    beta, az = 0.01, 0.8
    v = _with(Effect("axis_tilt", {"beta_rad": beta, "azimuth": az}))
    P = _wall_points_machine(v, 0.4 + 2 * np.pi * T_S, SCENE.spindle_xy_mm) - np.asarray(
        SCENE.bore_center_xy_mm
    )
    x = P[..., 0] * np.cos(az) + P[..., 1] * np.sin(az)
    y = -P[..., 0] * np.sin(az) + P[..., 1] * np.cos(az)
    R = SCENE.bore_radius_20_mm
    assert np.max(np.abs((x * np.cos(beta) / R) ** 2 + (y / R) ** 2 - 1)) < 1e-13
    assert np.max(v - BASE) == pytest.approx(R * (1 / np.cos(beta) - 1), rel=0.05)


def test_bore_lobing_wall_radius():
    k, a, ph = 3, 0.004, 0.2
    v = _with(Effect("bore_lobing", {"k": k, "a_mm": a, "phase": ph}))
    P = _wall_points_machine(v, 0.4 + 2 * np.pi * T_S, SCENE.spindle_xy_mm) - np.asarray(
        SCENE.bore_center_xy_mm
    )
    theta = np.arctan2(P[..., 1], P[..., 0])
    assert (
        np.max(
            np.abs(np.hypot(P[..., 0], P[..., 1]) - (SCENE.bore_radius_20_mm + a * np.cos(k * (theta - ph))))
        )
        < 1e-10
    )
    with pytest.raises(ValueError, match="k >= 2"):
        _with(Effect("bore_lobing", {"k": 1, "a_mm": a, "phase": ph}))


def test_thermal_expansion_scales_the_radius():
    T = 23.5
    v = _with(Effect("thermal_expansion", {"temperature_c": T}))
    R_T = SCENE.bore_radius_20_mm * (1 + SCENE.cte_per_k * (T - 20))
    expect = tri_spindle_readings(
        0.4 + 2 * np.pi * T_S, SCENE.spindle_xy_mm, SCENE.beams, Bore(SCENE.bore_center_xy_mm, R_T)
    )
    assert np.max(np.abs(v - expect)) < 1e-12
    # about R20 cte dT everywhere (the wall moves outwards along each beam)
    assert np.allclose(v - BASE, SCENE.bore_radius_20_mm * SCENE.cte_per_k * 3.5, rtol=2e-3)


def test_beam_tilt_divides_by_cos_gamma():
    g = math.radians(0.8)
    v = _with(Effect("beam_tilt", {"channel": 1, "gamma_rad": g}))
    assert np.allclose(v[:, 0], BASE[:, 0] / math.cos(g), rtol=0, atol=1e-12)
    assert np.array_equal(v[:, 1:], BASE[:, 1:])


def test_beam_tilt_is_fitted_even_on_the_three_sensor_device_and_signed_on_a_rod():
    """The registry's per-device fit parameters of ``beam_tilt``.

    Three-sensor: h = 1 / cos(gamma) - 1 >= 0 (its reading v / cos gamma is even in gamma), so -gamma reads
    back as +gamma. Rod: the signed gamma added to the layer's own (both signs read back, unbounded).
    """
    spec = EFFECTS["beam_tilt"]
    assert [q.name for q in spec.fit_params()] == ["h"] and spec.fit_params()[0].lower == 0.0
    assert spec.fit_params("tri_lds") == spec.fit_params()
    (q,) = spec.fit_params("rod")
    assert (q.name, q.unit, q.lower, q.upper) == ("gamma_rad", "rad", -math.inf, math.inf)
    for g in (0.07, -0.07):
        h = spec.internal({"gamma_rad": g})["h"]
        assert h == pytest.approx(1.0 / math.cos(g) - 1.0, rel=1e-14)
        assert spec.spec_params({"h": h})[0]["gamma_rad"] == pytest.approx(abs(g), rel=1e-12)
        x = spec.internal({"gamma_rad": g}, "rod")
        assert x == {"gamma_rad": g}
        par, unc = spec.spec_params(x, {"gamma_rad": 0.003}, None, "rod")
        assert par == {"gamma_rad": g} and unc == {"gamma_rad": 0.003}
    # an effect without a device's own parameterisation fits the same way on both devices
    assert EFFECTS["sensor_gain"].fit_params("rod") == EFFECTS["sensor_gain"].fit


def test_vibration_adds_a_sine_on_every_channel():
    f, a, ph = 7.3, 0.002, 1.1
    v = _with(Effect("vibration", {"f_hz": f, "a_mm": a, "phase": ph}))
    assert np.allclose(v - BASE, (a * np.sin(2 * np.pi * f * T_S + ph))[:, None], rtol=0, atol=1e-12)


def test_quantization_gives_multiples_of_lsb():
    lsb = 0.001
    q = apply_effects(
        BASE, T_S, (1, 2, 3), [Effect("quantization", {"channel": 3, "lsb_mm": lsb})], stages=("output",)
    )
    k = q[:, 2] / lsb
    assert np.max(np.abs(k - np.round(k))) < 1e-9
    assert np.max(np.abs(q[:, 2] - BASE[:, 2])) <= lsb / 2 + 1e-12
    assert np.array_equal(q[:, :2], BASE[:, :2])


def test_outliers_rate_within_binomial_tolerance():
    n, rate, size = 40000, 0.01, 0.5
    v0 = np.full((n, 3), 5.0)
    rng = np.random.default_rng(7)
    v = apply_effects(
        v0,
        np.zeros(n),
        (1, 2, 3),
        [Effect("outliers", {"channel": 2, "rate": rate, "size_mm": size})],
        stages=("output",),
        rng=rng,
    )
    jumped = np.abs(v[:, 1] - 5.0) > 0
    sd = math.sqrt(n * rate * (1 - rate))
    assert abs(jumped.sum() - n * rate) < 4 * sd
    jumps = np.abs(v[jumped, 1] - 5.0)
    assert jumps.min() >= 0.75 * size and jumps.max() <= 1.25 * size
    assert abs(np.mean(v[jumped, 1] > 5.0) - 0.5) < 0.1
    assert np.array_equal(v[:, [0, 2]], v0[:, [0, 2]])
    with pytest.raises(ValueError, match="needs a numpy Generator"):
        apply_effects(
            v0,
            np.zeros(n),
            (1, 2, 3),
            [Effect("outliers", {"channel": 2, "rate": rate, "size_mm": size})],
            stages=("output",),
        )


def test_rod_beam_offset_is_wang_eq5():
    d = 0.4
    v = rod_readings_with_effects(ROD, ALPHA, [Effect("beam_offset", {"channel": 1, "d_mm": d})])
    layers = [RodLayer(1, 100.0, 71.0, d_mm=d), ROD.layers[1]]
    assert np.max(np.abs(v - rod_readings(ALPHA, layers, list(ROD.holes), ROD.axis))) < 1e-12
    # centred rod: a chord at distance d from the centre, l = sqrt(r^2 - d^2)
    centred = RodScene(
        layers=ROD.layers, holes=(Hole((0.0, 0.0), 75.0), Hole((0.0, 0.0), 75.0)), axis=RodAxis()
    )
    vc = rod_readings_with_effects(centred, ALPHA, [Effect("beam_offset", {"channel": 2, "d_mm": d})])
    assert np.allclose(vc[:, 1], math.sqrt(75.0**2 - d**2) - 71.0, rtol=0, atol=1e-12)
    assert np.allclose(vc[:, 0], 4.0, rtol=0, atol=1e-12)


def test_rod_beam_tilt_and_thermal_and_reading_effects():
    centred = RodScene(
        layers=ROD.layers, holes=(Hole((0.0, 0.0), 75.0), Hole((0.0, 0.0), 75.0)), axis=RodAxis()
    )
    g = math.radians(0.5)
    v = rod_readings_with_effects(centred, ALPHA, [Effect("beam_tilt", {"channel": 1, "gamma_rad": g})])
    assert np.allclose(v[:, 0], 75.0 / math.cos(g) - 71.0, rtol=0, atol=1e-12)  # in-plane 75 mm / cos(gamma)
    v = rod_readings_with_effects(centred, ALPHA, [Effect("thermal_expansion", {"temperature_c": 25.0})])
    assert np.allclose(v, 75.0 * (1 + 11.5e-6 * 5) - 71.0, rtol=0, atol=1e-12)
    t = np.linspace(0, 60, ALPHA.size)
    v = rod_readings_with_effects(
        ROD, ALPHA, [Effect("sensor_drift", {"channel": 2, "k_mm_per_s": 1e-4})], t_s=t
    )
    base = rod_readings_with_effects(ROD, ALPHA)
    assert np.allclose(v[:, 1] - base[:, 1], 1e-4 * t, rtol=0, atol=1e-12)
    with pytest.raises(ValueError, match=re.escape("does not apply to a rod")):
        rod_readings_with_effects(ROD, ALPHA, [Effect("channel_delay", {"channel": 1, "tau_s": 0.001})])


def test_effects_are_pure():
    before = BASE.copy()
    _with(
        Effect("sensor_offset", {"channel": 1, "b_mm": 1.0}),
        Effect("beam_tilt", {"channel": 1, "gamma_rad": 0.1}),
    )
    assert np.array_equal(before, BASE)
    b = Bore((0.0, 0.0), 10.0)
    EFFECTS["thermal_expansion"].forward["tri_lds"](b, {"temperature_c": 30.0}, 1e-5)
    assert b.radius_mm == 10.0
    r, _ = bore_wall_radius(np.array([0.0]), b)
    assert r[0] == 10.0


def test_candidates_of_every_scan_kind_come_from_the_registry():
    """The discrepancy candidates are the registry's "screen" entries of the scan kind, less what a
    freed base parameter absorbs: a rod layer's free hole radius its own offset (and everything
    common), a free bore radius only what every channel shares.
    """
    from borescan.discrepancy.terms import registry_terms
    from borescan.effects import EFFECTS

    for kind in ("tri_spindle", "tri_static", "rod"):
        keys = {
            t.effect
            for t in registry_terms(
                kind, (1, 2, 3), have={"cte": True, "commanded_angle": True, "vibration_line": True}
            )
        }
        assert keys == {n for n, s in EFFECTS.items() if s.candidate.get(kind) == "screen"}
    rod = [t.key for t in registry_terms("rod", (1, 2), have={"cte": True}, freed={"R": {2}})]
    assert "sensor_offset@1" in rod and "sensor_offset@2" not in rod
    assert "sensor_offset@all" not in rod and "thermal_expansion" not in rod and "sensor_gain@2" in rod
    static = [
        t.key for t in registry_terms("tri_static", (1, 2, 3), have={"cte": True}, freed={"R": "shared"})
    ]
    assert {"sensor_offset@1", "sensor_offset@2", "sensor_offset@3"} <= set(static)
    assert "sensor_offset@all" not in static and "thermal_expansion" not in static
    free_db = registry_terms("tri_spindle", (1, 2, 3), have={}, freed={"d_b": {1, 2, 3}})
    assert not any(t.effect in ("sensor_offset", "thermal_expansion") for t in free_db)
