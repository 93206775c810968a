"""A static set's offset-like class says what the data fix when no member is an offset."""

import numpy as np
import pytest

from borescan.discrepancy.classes import static_classes


def _entry(effect, ch, dbic, name, x, ux):
    return {"effect": effect, "channel": ch, "parameters": {name: x}, "uncertainties": {f"u_{name}": ux},
            "evidence": {"delta_bic": dbic}}  # fmt: skip


def test_a_class_of_gains_and_tilts_gives_the_combination_its_best_member_implies():
    """No offset member: q is the best member's mean shift of its channel's readings times the channel's
    weight, in closed form w_c g mean(v) for a gain (u: w_c u_g mean(v)) and w_c mean(v) (1 / cos gamma - 1)
    for a beam tilt (u: w_c mean(v) tan(gamma) / cos(gamma) u_gamma); the sentence states the value.
    """
    rng = np.random.default_rng(3)
    w = {1: 0.25, 2: 0.35, 3: 0.40}
    readings = {c: (rng.uniform(3.0, 7.0, 200), 10.0) for c in w}
    named = [
        _entry("sensor_gain", 1, 80.0, "g", -0.0024, 0.0003),
        _entry("beam_tilt", 3, 79.0, "gamma_rad", 0.084, 0.0045),
        _entry("sensor_gain", 2, 78.5, "g", 0.0035, 0.0004),
    ]
    tied = [("sensor_gain@1",), ("beam_tilt@3",), ("sensor_gain@2",)]
    _, (k,) = static_classes(named, w, tied, readings)
    v1 = readings[1][0].mean()
    assert k.q_from == "sensor_gain@1"
    assert k.q_um == pytest.approx(1e3 * 0.25 * -0.0024 * v1, rel=1e-9)
    assert k.u_q_um == pytest.approx(1e3 * 0.25 * 0.0003 * v1, rel=1e-6)
    assert f"= {k.q_um:.3g} +- {k.u_q_um:.2g} um (the shift sensor_gain@1 gives" in k.sentence
    # the tilt alone (the gain dropped): the second-order shift of 1 / cos
    _, (k,) = static_classes(named[1:], w, tied[1:], readings)
    v3, g = readings[3][0].mean(), 0.084
    assert k.q_um == pytest.approx(1e3 * 0.40 * v3 * (1 / np.cos(g) - 1), rel=1e-9)
    assert k.u_q_um == pytest.approx(1e3 * 0.40 * v3 * np.tan(g) / np.cos(g) * 0.0045, rel=1e-6)
    # without the readings a gain gives no value (the sentence then says only the combination)
    _, (k,) = static_classes(named, w, tied)
    assert k.q_um is None and k.q_from is None and "=" not in k.sentence


def test_a_gauge_expanded_as_at_its_recorded_temperature_is_said_to_be_so():
    """A static set on a ring gauge at 30 degC: named thermal expansion at the temperature scan.json records
    (within 3 u) leads the verdict as the artifact's expansion, nothing to recalibrate; the same scan with 20
    degC recorded names the same expansion, but not as recorded (the statement does not say so).
    """
    from borescan.discrepancy import examine_scan
    from borescan.effects import Effect
    from borescan.synthetic.simulate import simulate_tri_static

    hot = [Effect("thermal_expansion", {"temperature_c": 30.0})]
    f = examine_scan(simulate_tri_static(effects=hot, seed=4))
    rec = f["thermal_as_recorded"]
    assert rec["recorded_temperature_c"] == 30.0
    assert abs(rec["temperature_c"] - 30.0) <= 3 * rec["u_temperature_c"]
    assert f["statement"].startswith("the artifact expanded as at its recorded temperature 30 degC (fitted")
    assert "nothing to recalibrate; what fits as well: " in f["statement"]
    cold = simulate_tri_static(effects=hot, seed=4, extra_meta={"environment": {"temperature_c": 20.0}})
    f = examine_scan(cold)
    assert "thermal_expansion" in [n["effect"] for n in f["named"]]
    assert f["thermal_as_recorded"] is None and "recorded temperature" not in f["statement"]


def test_a_static_set_of_a_lobed_part_says_the_radius_changes_from_pose_to_pose():
    """HSG-1105 of the demo, simulated: a part (no certified diameter, radius free) with a 3-lobing of 4 um,
    measured static in 6 poses whose angles put 3 theta evenly over a cycle. With beams about 120 degrees
    apart each pose reads its own radius R + a cos(3 (theta_p - phase)), so the spread of the poses' radii
    is a / sqrt(2) = 2.83 um rms (closed form); the verdict ends with that alternative. The same set on a
    certified ring gauge (radius held) and the lobe-free part have no such line.
    """
    from borescan.discrepancy import examine_scan
    from borescan.effects import Effect
    from borescan.synthetic.simulate import default_tri_scene, simulate_tri_static

    part = {"id": "HSG-T", "type": "part", "nominal_diameter_mm": 275.029, "cte_per_k": 1.15e-05}
    angles = 2 * np.pi * np.arange(6) / 18.0
    off = np.array([[0.5, 0.2], [-0.4, 0.3], [0.1, -0.6], [0.6, 0.5], [-0.3, -0.2], [0.2, 0.7]])
    xy = np.asarray(default_tri_scene().bore_center_xy_mm) + off  # within 0.8 mm of the bore centre
    lobes = [Effect("bore_lobing", {"k": 3, "a_mm": 0.004, "phase": 0.4})]
    kw = dict(device_xy_mm=xy, device_angle_rad=angles, kind="measurement", artifact=part, seed=7)
    f = examine_scan(simulate_tri_static(effects=lobes, **kw))
    form = f["pose_radii"]
    u_pose_um = 1e3 * f["noise_floor_mm"] / np.sqrt(3 * 20)  # one pose's mean over 3 channels x 20 samples
    assert f["verdict"] != "no_missing_effect" and form["dof"] == 5
    assert abs(form["rms_um"] - 4.0 / np.sqrt(2)) < 0.15 * 4.0 / np.sqrt(2) + 3 * u_pose_um
    assert f["statement"].endswith(form["statement"]) and "or the part is out of round" in f["statement"]
    gauge = examine_scan(simulate_tri_static(effects=lobes, device_xy_mm=xy, device_angle_rad=angles, seed=7))
    assert gauge["pose_radii"] is None
    clean = examine_scan(simulate_tri_static(effects=[], **kw))
    assert clean["verdict"] == "no_missing_effect" and clean["pose_radii"] is None


def test_a_recorded_expansion_tied_with_a_channel_effect_does_not_say_nothing_to_recalibrate():
    """The demo's warm calibration scan N20261121-TRI01-CAL-P1-B: thermal expansion at 20.58 +- 0.02 degC
    (recorded 20.6) ties with a common zero and a channel delay on channel 2 (truth: both the expansion and
    a 1.2 ms delay). The common zero is the expansion's look-alike; the delay is not, so it is named to be
    checked; 20.0 recorded is 29 u away: not the recorded expansion.
    """
    from borescan.discrepancy.classes import recorded_thermal

    def entry(effect, ch, par, unc):
        return {"effect": effect, "channel": ch, "parameters": par, "uncertainties": unc}

    named = [
        entry("channel_delay", 2, {"tau_s": 0.0012}, {"u_tau_s": 1e-5}),
        entry("thermal_expansion", None, {"temperature_c": 20.576}, {"u_temperature_c": 0.019}),
        entry("sensor_offset", None, {"b_mm": 0.0009}, {"u_b_mm": 3e-5}),
    ]
    k = recorded_thermal(named, 20.6)
    assert k.others == ("channel_delay@2",) and "nothing to recalibrate" not in k.sentence
    assert k.sentence.endswith("but channel_delay@2 fit as well and are not its look-alikes: check them")
    assert recorded_thermal(named[1:], 20.6).sentence.endswith("; nothing to recalibrate")
    assert recorded_thermal(named, 20.0) is None


def test_a_gauges_expansion_is_a_member_of_the_static_class_and_the_advice_says_so():
    """A thermal expansion of a certified gauge moves the wall along every beam alike: the common zero's
    look-alike (spec), so the class holds it (labelled without a channel, as the findings name it) and the
    advice adds the recorded temperature; offsets give q = w . b in closed form.
    """
    w = {1: 0.3, 2: 0.3, 3: 0.4}
    named = [
        _entry("sensor_offset", 2, 100.0, "b_mm", -0.010, 0.0002),
        {**_entry("thermal_expansion", None, 99.0, "temperature_c", 15.0, 0.3)},
        {**_entry("sensor_offset", None, 98.5, "b_mm", -0.003, 0.0001), "channels": [1, 2, 3]},
    ]
    tied = [("sensor_offset@2",), ("thermal_expansion",), ("sensor_offset@all",)]
    left, (k,) = static_classes(named, w, tied)
    assert k.members == ["sensor_offset@2", "thermal_expansion", "sensor_offset@all"]
    assert left == named
    assert k.q_um == pytest.approx(1e3 * 0.3 * -0.010, rel=1e-12)
    assert "check the temperature scan.json records" in k.sentence
    _, (k,) = static_classes([named[0], named[2]], w, [tied[0], tied[2]])
    assert "temperature" not in k.sentence


def test_a_static_set_refits_every_zero_member_where_the_cut_kept_one():
    """The zero members (each channel's offset, the common one, the expansion) screen level: where the
    exact refits' cut keeps one, the others are refitted from their screen starts; beside a pair's first
    term too, never the first term itself; nothing where no zero member was chosen.
    """
    from borescan.discrepancy.poses import StaticModel
    from borescan.discrepancy.terms import Term

    screen = [
        (1.0, Term("sensor_nonlinearity", 1), {"a": 1}),
        (2.0, Term("sensor_offset", 1), {"b": 1}),
        (2.1, Term("sensor_offset", 0), {"b": 0}),
        (2.2, Term("thermal_expansion", None), {"t": 1}),
        (2.3, Term("sensor_offset", 2), {"b": 2}),
        (3.0, Term("sensor_gain", 2), {"g": 2}),
    ]
    extra = StaticModel.extra_starts
    keys = {"sensor_nonlinearity@1", "sensor_offset@1"}
    got = [z[1].key for z in extra(None, screen, keys, None)]
    assert got == ["sensor_offset@all", "thermal_expansion", "sensor_offset@2"]
    got = [z[1].key for z in extra(None, screen, {"sensor_offset@all", "*"}, Term("sensor_offset", 1))]
    assert got == ["thermal_expansion", "sensor_offset@2"]
    assert extra(None, screen, {"sensor_nonlinearity@1", "sensor_gain@2"}, None) == []


def test_a_term_every_tied_pair_holds_is_said_together_with_the_class():
    """Battery static 143 of seed 2: a bow on channel 1 in every tied pair beside the zero members. The bow
    is needed with the class, not an alternative to it: "together with the class", never "fitting as well";
    a term only some tied candidates hold is an alternative.
    """
    from borescan.discrepancy.classes import class_statement

    w = {1: 0.5, 2: 0.45, 3: 0.05}
    bow = _entry("sensor_nonlinearity", 1, 2011.4, "a_mm", 0.043, 0.001)
    named = [
        bow,
        _entry("sensor_offset", 1, 2011.4, "b_mm", 0.018, 0.001),
        _entry("sensor_offset", 2, 2011.2, "b_mm", 0.019, 0.001),
    ]
    tied = [("sensor_nonlinearity@1", "sensor_offset@1"), ("sensor_nonlinearity@1", "sensor_offset@2")]
    left, classes = static_classes(named, w, tied)
    assert classes[0].members == ["sensor_offset@1", "sensor_offset@2"]
    needed = frozenset.intersection(*(frozenset(k) for k in tied))
    s = class_statement(classes, left, "fully", None, needed)
    assert s.endswith("; together with the class: sensor_nonlinearity on channel 1")
    assert "fitting as well" not in s
    s = class_statement(classes, left, "fully", None, frozenset())
    assert s.endswith("; or, fitting as well: sensor_nonlinearity on channel 1")
