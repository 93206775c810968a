"""The outlier test of pose scans (rods, static sets): few readings per pose, one jump named."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import polars as pl
import pytest
from test_discrepancy import _rod_case  # the rod on certified rings of the recovery tests

from borescan.discrepancy import examine_scan
from borescan.discrepancy.evidence import outlier_threshold_sigma
from borescan.discrepancy.poses import _median_of_others, _PoseModel, pose_data_from_arrays


def _pose_model(values_mm: np.ndarray, per_pose: int) -> _PoseModel:
    n = values_mm.shape[0]
    pose = np.repeat(np.arange(n // per_pose), per_pose)
    chans = tuple(range(1, values_mm.shape[1] + 1))
    return _PoseModel(pose_data_from_arrays("T", {}, np.arange(n) * 0.01, values_mm, chans, pose))


def test_median_of_the_others_is_the_median_without_each_reading():
    """Against numpy's median of the readings with one deleted, odd and even counts, ties included."""
    rng = np.random.default_rng(3)
    for n in range(2, 14):
        x = np.round(rng.standard_normal(n), 1)  # ties
        want = [np.median(np.delete(x, i)) for i in range(n)]
        np.testing.assert_allclose(_median_of_others(x), want, rtol=0, atol=0)


@pytest.mark.parametrize("per_pose", [5, 9, 30])
def test_gaussian_pose_scan_passes_the_outlier_threshold_at_most_at_its_false_rate(per_pose):
    """Gaussian noise, 11 poses of 5-30 readings, the noise level estimated from the scan itself (as the
    examination does): a channel shows a jump with chance <= the false rate.

    The threshold is the Bonferroni quantile at false rate 0.05 (large, so 600 channels measure it); the
    share of channels with a jump must not exceed 0.05 by more than 4 binomial standard deviations.
    """
    rng = np.random.default_rng(per_pose)
    n_pose, channels = 11, 600
    v = rng.standard_normal((n_pose * per_pose, channels))
    model = _pose_model(v, per_pose)
    k = outlier_threshold_sigma(v.shape[0], 0.05)
    hits = np.mean(model.spike_mask(v, model.noise_floor(v), k).any(axis=0))
    assert hits <= 0.05 + 4 * np.sqrt(0.05 * 0.95 / channels)


def test_one_jump_in_a_pose_of_five_is_found_and_nothing_else():
    """A 6 sigma jump among 5 readings of one pose (a plain pose median would move towards it)."""
    rng = np.random.default_rng(7)
    v = rng.standard_normal((60, 3))
    v[17, 1] += 6.0 * np.sign(v[17, 1] - np.median(v[15:20, 1]) or 1.0)
    model = _pose_model(v, 5)
    spikes = model.spike_mask(v, np.ones(3), outlier_threshold_sigma(60, 1e-3))
    assert spikes[17, 1] and spikes.sum() == 1


def test_one_jump_of_a_rod_scan_is_named_and_an_effect_free_rod_is_quiet():
    """A rod on certified rings (noise 5 um): one reading jumped by 60 um is named ``outliers`` at rate
    1 / readings of its channel and the statement says so; the same scan without the jump names nothing.
    """
    sim = _rod_case([])
    assert examine_scan(sim)["verdict"] == "no_missing_effect"
    sensor = sim.lds["sensor"].to_numpy()
    values = sim.lds["value_mm"].to_numpy().copy()
    values[np.flatnonzero(sensor == 2)[40]] += 0.060
    f = examine_scan(replace(sim, lds=sim.lds.with_columns(pl.Series("value_mm", values))))
    (out,) = [n for n in f["named"] if n["effect"] == "outliers"]
    assert out["channel"] == 2 and out["parameters"]["rate"] == pytest.approx(1.0 / np.sum(sensor == 2))
    assert f["verdict"] == "missing_effect" and [n["effect"] for n in f["named"]] == ["outliers"]
    assert f["statement"] == "explained by outliers on channel 2: the gap after is at the noise floor"


def test_a_rod_bow_at_mid_range_is_listed_in_its_layer_class():
    """A 6 um bow of sensor 2 whose readings sit near mid-range (u ~ 0.5, where 4u(1 - u) is flat): no
    second harmonic to resolve, so the verdict names layer 2's offset-like class, lists the bow in it and
    says what the data fix: the layer reads long by a 4u(1 - u) averaged over its readings (within 3 u).
    """
    from borescan.effects import Effect

    a_mm = 0.006
    sim = _rod_case([Effect("sensor_nonlinearity", {"channel": 2, "a_mm": a_mm})])
    f = examine_scan(sim)
    (k,) = [k for k in f["classes"] if k["channel"] == 2]
    assert f["verdict"] == "ambiguous" and k["nonlinearity_also_fits"]
    assert {"sensor_offset", "sensor_gain", "beam_tilt"} <= set(k["members"])
    assert "beam_offset" not in k["members"]  # a beam offset cannot lengthen a reading
    u = sim.lds.filter(pl.col("sensor") == 2)["value_mm"].to_numpy() / 8.0  # the rod's 8 mm range
    assert abs(k["reads_long_um"] - 1e3 * a_mm * np.mean(4 * u * (1 - u))) < 3 * k["u_reads_long_um"]
    assert "recalibrate l0 of layer 2" in f["statement"] and "sensor_nonlinearity" in f["statement"]


def test_zero_weights_span_what_the_device_positions_cannot_absorb():
    """``w`` is orthogonal to both beam directions (a pose's position absorbs those) and sums to 1: beams
    120 degrees apart give the mean zero (1/3 each); beams at 0, 90 and 180 degrees give (1/2, 0, 1/2).
    """
    from borescan.discrepancy.classes import zero_weights

    for beta in ([0.3, 0.3 + 2 * np.pi / 3, 0.3 + 4 * np.pi / 3], [0.1, 1.9, 4.0]):
        w = np.array(list(zero_weights([1, 2, 3], beta).values()))
        U = np.stack([np.cos(beta), np.sin(beta)], axis=1)
        assert np.abs(U.T @ w).max() < 1e-12 and w.sum() == pytest.approx(1.0, abs=1e-12)
    w = zero_weights([1, 2, 3], np.deg2rad([0.0, 120.0, 240.0]))
    assert list(w.values()) == pytest.approx([1 / 3] * 3, abs=1e-12)
    w = zero_weights([1, 2, 3], np.deg2rad([0.0, 90.0, 180.0]))
    assert list(w.values()) == pytest.approx([0.5, 0.0, 0.5], abs=1e-12)
    assert zero_weights([1, 2], [0.0, 1.0]) == {}


def test_static_class_drops_a_beam_member_whose_sign_does_not_fit():
    """With q = w_1 b_1 = +10 um (20 sigma), a beam offset (only shortens a reading) on a channel of
    positive weight cannot give it and is dropped; a beam tilt (only lengthens) stays; a member 12 above the
    best (beyond delta chi2 9) is not in the class.
    """
    from borescan.discrepancy.battery import named_label
    from borescan.discrepancy.classes import static_classes

    def entry(effect, ch, dbic, b=None):
        par, unc = ({"b_mm": b}, {"u_b_mm": 0.0015}) if b is not None else ({}, {})
        return {"effect": effect, "channel": ch, "parameters": par, "uncertainties": unc,
                "evidence": {"delta_bic": dbic}}  # fmt: skip

    named = [
        entry("sensor_offset", 1, 500.0, 0.030),
        entry("sensor_offset", 2, 498.0, 0.030),
        entry("beam_offset", 3, 497.0),
        entry("beam_tilt", 3, 496.0),
        entry("sensor_gain", 2, 488.0),
    ]
    tied = [(named_label(n),) for n in named]
    left, (k,) = static_classes(named, {1: 1 / 3, 2: 1 / 3, 3: 1 / 3}, tied)
    assert k.q_um == pytest.approx(10.0) and k.u_q_um == pytest.approx(0.5)
    assert k.members == ["sensor_offset@1", "sensor_offset@2", "beam_tilt@3"]
    assert k.dropped == ["beam_offset@3"] and [n["effect"] for n in left].count("beam_offset") == 0
    assert "sensor_gain" in [n["effect"] for n in left] and not k.holds(named[-1])
    w = {1: 1 / 3, 2: 1 / 3, 3: 1 / 3}
    one_channel = [entry("sensor_offset", 1, 500.0, 0.030), entry("sensor_gain", 1, 499.0)]
    assert static_classes(one_channel, w, [(named_label(n),) for n in one_channel]) == (one_channel, [])
    # the two terms of one pair explain the gap together, not alike; a term both pairs need is no member
    pair = [entry("sensor_gain", 1, 500.0), entry("sensor_gain", 2, 500.0)]
    assert static_classes(pair, w, [("sensor_gain@1", "sensor_gain@2")]) == (pair, [])
    two = [*pair, entry("sensor_gain", 3, 499.0)]
    _, (k,) = static_classes(two, w, [("sensor_gain@1", "sensor_gain@2"), ("sensor_gain@1", "sensor_gain@3")])
    assert k.members == ["sensor_gain@2", "sensor_gain@3"] and k.q_um is None


def test_a_one_channel_offset_of_a_static_set_is_named_as_its_class():
    """A 20 um offset of sensor 2 on a simulated static set (certified ring): the offsets of every
    channel tie, so the verdict names the offset-like class with what the data fix, w_2 x 20 um (within
    3 u), lists the three offsets and advises recalibrating the zeroes; the effect-free set has no class.
    """
    from borescan.effects import Effect
    from borescan.synthetic.simulate import simulate_tri_static

    sim = simulate_tri_static(effects=[Effect("sensor_offset", {"channel": 2, "b_mm": 0.020})], seed=4)
    f = examine_scan(sim)
    (k,) = f["classes"]
    assert f["verdict"] == "ambiguous" and k["channel"] is None
    assert {"sensor_offset@1", "sensor_offset@2", "sensor_offset@3"} <= set(k["members"])
    w = {int(c): v for c, v in k["zero_weights"].items()}
    assert abs(k["combination_um"] - w[2] * 20.0) < 3 * k["u_combination_um"]
    assert sum(w.values()) == pytest.approx(1.0)
    assert f["statement"].startswith("offset-like: one combination of the channels' zeroes b_c is fixed")
    assert "recalibrate the sensors' zeroes" in f["statement"]
    f0 = examine_scan(simulate_tri_static(effects=[], seed=5))
    assert f0["verdict"] == "no_missing_effect" and f0["classes"] == []


def test_a_pair_of_a_static_set_is_named_together_and_is_no_class():
    """The demo's first RG280 verification (a static set): one candidate, a pair of gains, explains the gap;
    the verdict names the two together, not as look-alikes, and builds no offset-like class from the two
    terms of one candidate.
    """
    from borescan.synthetic.demo import demo_scans

    (scan,) = [s for s in demo_scans() if s.scan_id == "N20261120-TRI01-VER-RG280"]
    f = examine_scan(scan)
    assert f["verdict"] == "missing_effect" and len(f["named"]) == 2 and f["classes"] == []
    assert " together with " in f["statement"] and "look alike" not in f["statement"]


def _rod_scan_and_model(
    seed: int, scan_id: str, *effects, noise_free: bool = False, calibration: bool = False
):
    """Return a rod scan drawn over the contract (night 2027-01-01, ``effects`` added, noise-free when asked)
    and the examination's model of it.
    """
    from borescan.discrepancy.examine import discrepancy_settings, model_of
    from borescan.synthetic import contract as sct
    from borescan.synthetic import rod_scenarios as rs

    contract = dict(sct.ROD_CONTRACT, noise_mm=(0.0, 0.0)) if noise_free else dict(sct.ROD_CONTRACT)
    sim = rs.draw_rod_scan(
        np.random.default_rng(seed),
        scan_id=scan_id,
        night="2027-01-01",
        contract=contract,
        extra_effects=tuple(effects),
        calibration=calibration,
    )
    return sim, model_of(sim, **discrepancy_settings())


def _true_rod_base(model, sim) -> dict:
    """Return the rod model's base parameters of a simulated scan's truth.

    The model's gauge: pose 0 at alpha = 0 (the part frame turned by -alpha_0), the axis through the
    origin at z = 0 (translated by -(dx, dy)), each centre relative to the axis at its spot's height
    z = h + r tan(gamma) (:func:`borescan.physics.rod.rod_section_geometry`).
    """
    import math

    from borescan.synthetic.scenes import RodScene

    sc = sim.truth["scene"]
    sc = RodScene.from_dict(sc) if isinstance(sc, dict) else sc
    a = np.asarray(sim.truth["alpha_rad"], dtype=float)
    ax = sc.axis
    turn = np.array([[math.cos(a[0]), math.sin(a[0])], [-math.sin(a[0]), math.cos(a[0])]])
    az = ax.omega_az_rad - a[0]
    toward = np.array([math.cos(az), math.sin(az)])
    p = {f"alpha[{k}]": float(a[k] - a[0]) for k in range(1, a.size)}
    p["wx"], p["wy"] = ax.omega_rad * toward
    for j, (lay, hole) in enumerate(zip(sc.layers, sc.holes, strict=True)):
        r = hole.radius_mm if model.radius_free[j] else model.radius[j]
        if model.radius_free[j]:
            p[f"dr[{j}]"] = hole.radius_mm - model.radius[j]
        c = turn @ (np.asarray(hole.center_xy_mm) - [ax.dx_mm, ax.dy_mm])
        c = c - (lay.h_mm + r * math.tan(lay.gamma_rad)) * math.sin(ax.omega_rad) * toward
        p[f"cx[{j}]"], p[f"cy[{j}]"] = float(c[0]), float(c[1])
    return p


@pytest.mark.parametrize("seed, calibration", [(0, False), (4, False), (0, True)])
def test_rod_model_at_the_true_geometry_and_temperature_is_the_simulated_thermal_scan(seed, calibration):
    """Parity of the examination's rod model (the path ``RodModel`` fits) with the simulator.

    A noise-free rod scan of the contract (seed 0: a part, radii free; seed 4: a ring-gauge set, radii
    certified; a rod calibration) with only ``thermal_expansion`` (T = 30 degC): at the true base
    parameters and the true dT the model's readings are the scan's to below 1e-3 of the contract's
    smallest noise (2 um); without the term they are not (the cte dT R of each hole is left).
    """
    from borescan.discrepancy.terms import Term, term_values
    from borescan.effects import Effect
    from borescan.synthetic import contract as sct

    effect = Effect("thermal_expansion", {"temperature_c": 30.0})
    sim, model = _rod_scan_and_model(seed, "THERMAL", effect, noise_free=True, calibration=calibration)
    assert model.radius_free.all() == (sim.truth["contract"]["artifact"] == "part")
    p = _true_rod_base(model, sim)
    term = Term("thermal_expansion", None)
    sigma_mm = sct.ROD_CONTRACT["noise_mm"][0]
    r_true = model.residual_matrix({**p, **term_values(term, effect)}, [term])  # [mm]
    assert np.nanmax(np.abs(r_true)) < 1e-3 * sigma_mm
    # the radius left by the base alone: cte dT R = 11.5e-6 x 10 K x (50-100 mm) = 6-12 um on some layer
    r_base = model.residual_matrix(p, [])
    assert np.nanmax(np.abs(r_base)) > 5e-3


def test_thermal_start_of_a_ring_gauge_rod_lands_on_the_true_temperature():
    """A rod in certified rings 13.25 K below 20 degC (noise-free): the thermal start from the radii solved
    free is the true dT to 0.1 K, and the exact fit from it leaves the readings at below 0.05 of the
    contract's smallest noise (2 um) with dT within 0.01 K (the truth is a zero of the model: the parity
    test above).
    """
    from borescan.discrepancy.search import Fitter
    from borescan.effects import Effect
    from borescan.synthetic import contract as sct

    _, model = _rod_scan_and_model(
        4, "COLD", Effect("thermal_expansion", {"temperature_c": 6.75}), noise_free=True
    )
    assert not model.radius_free.any()
    ((_, term, start),) = model._thermal_start()
    assert abs(start["thermal_expansion.dT"] + 13.25) < 0.1
    fit = Fitter(model)([term], start)
    rms_mm = float(np.sqrt(np.nanmean(model.residual_matrix(fit.values(), [term])[model.mask] ** 2)))
    assert rms_mm < 0.05 * sct.ROD_CONTRACT["noise_mm"][0]
    assert abs(fit.values()["thermal_expansion.dT"] + 13.25) < 0.01


@pytest.mark.parametrize("seed", [0, 4])
@pytest.mark.parametrize("gamma_rad", [0.09, -0.09])
def test_rod_model_with_the_true_signed_beam_tilt_is_the_simulated_scan(seed, gamma_rad):
    """Parity of a rod's ``beam_tilt`` of either sign (the registry's rod parameterisation: the signed gamma).

    A noise-free contract rod scan (seed 0: a part; seed 4: a ring-gauge set) whose layer 1 is tilted by
    +-0.09 rad on top of its own gamma0: at the true base parameters the rod model with the rod's term at the
    true gamma reproduces the readings to below 1e-3 of the contract's smallest noise (2 um). The three-sensor
    parameterisation (h = 1 / cos(gamma) - 1, even in gamma) cannot: for -0.09 it adds +0.09 to gamma0, and
    leaves more than 10 um rms (0.05-0.07 mm measured).
    """
    from borescan.discrepancy.terms import Term, term_values
    from borescan.effects import Effect
    from borescan.synthetic import contract as sct

    effect = Effect("beam_tilt", {"channel": 1, "gamma_rad": gamma_rad})
    sim, model = _rod_scan_and_model(seed, "TILT", effect, noise_free=True)
    (term,) = [t for t in model.candidate_terms() if t.key == "beam_tilt@1"]
    values = term_values(term, effect)
    assert values == {"beam_tilt@1.gamma_rad": pytest.approx(gamma_rad, abs=1e-15)}
    p = _true_rod_base(model, sim)
    sigma_mm = sct.ROD_CONTRACT["noise_mm"][0]
    r_true = model.residual_matrix({**p, **values}, [term])  # [mm]
    assert np.nanmax(np.abs(r_true)) < 1e-3 * sigma_mm
    even = Term("beam_tilt", 1)  # the effect's default (three-sensor) parameterisation
    r_even = model.residual_matrix({**p, **term_values(even, effect)}, [even])
    rms_even_mm = float(np.sqrt(np.nanmean(r_even**2)))
    assert (rms_even_mm > 1e-2) == (gamma_rad < 0)


def test_tilt_starts_are_both_roots_of_the_offsets_lengthening():
    """A rod layer's beam-tilt starts lengthen its mean beam l by the offset b: l (sec(g0 + g) - sec g0) = b.

    Both roots (the beam tilted up or down past its own gamma0), checked on the closed form; a shortening
    that no tilt can give (below gamma = -gamma0) gives no start.
    """
    import math

    _, model = _rod_scan_and_model(4, "T")
    j, b_mm = 0, 0.05
    starts = model._tilt_starts(j, b_mm, {"alpha[1]": 0.25})
    assert len(starts) == 2
    ok = model.valid[:, j]
    length = float(np.mean(model.data.values_mm[ok, j])) + model.l0[j]
    g0 = float(model.gamma[j])
    for _, term, st in starts:
        assert term.key == "beam_tilt@1" and term.device == "rod" and st["alpha[1]"] == 0.25
        g = st["beam_tilt@1.gamma_rad"]
        assert length * (1.0 / math.cos(g0 + g) - 1.0 / math.cos(g0)) == pytest.approx(b_mm, rel=1e-9)
    assert {math.copysign(1.0, st["beam_tilt@1.gamma_rad"] + g0) for _, _, st in starts} == {1.0, -1.0}
    assert model._tilt_starts(j, -length, {}) == []


def test_the_screen_starts_a_rod_tilt_at_its_offsets_root_of_the_linear_starts_sign():
    """A screened ``beam_tilt`` (its linearised start meaningless: its column at 0 is l tan gamma0) starts at
    the root of :meth:`RodModel._tilt_starts` for the same layer's screened offset whose sign is the linear
    start's, with the offset's base parameters; with no offset screened for its layer, at gamma = 0.
    """
    from borescan.discrepancy.search import Screened
    from borescan.discrepancy.terms import Term

    _, model = _rod_scan_and_model(4, "T")
    tilt1, tilt2 = (Term("beam_tilt", c, device="rod") for c in (1, 2))
    offset1 = Term("sensor_offset", 1, device="rod")
    screen = [
        Screened(1.0, tilt1, {"alpha[1]": 0.1, "beam_tilt@1.gamma_rad": 6006.0}),
        Screened(2.0, offset1, {"alpha[1]": 0.2, "sensor_offset@1.b_mm": 0.03}),
        Screened(3.0, tilt2, {"alpha[1]": 0.3, "beam_tilt@2.gamma_rad": -5.0}),
    ]
    settled = model.settle_screen(screen)
    assert [z.term.key for z in settled] == ["beam_tilt@1", "sensor_offset@1", "beam_tilt@2"]
    roots = [st["beam_tilt@1.gamma_rad"] for _, _, st in model._tilt_starts(0, 0.03, {})]
    (positive,) = [g for g in roots if g > 0]
    assert settled[0].start == {"alpha[1]": 0.2, "beam_tilt@1.gamma_rad": positive}
    assert settled[1] == screen[1]
    assert settled[2].start == {"alpha[1]": 0.3, "beam_tilt@2.gamma_rad": 0.0}


def test_a_rod_tilt_is_judged_plausible_on_the_beams_own_angle():
    """A rod's ``beam_tilt`` gamma adds to its layer's nominal gamma0; the plausible range (|angle| <= 0.1
    rad, no uncertainty slack here) judges gamma0 + gamma: a fitted gamma just past -0.1 whose beam sits
    inside is kept (seed 1 rod 10 of the battery: -0.1015 on a beam at -0.096), one whose beam is past it
    is refused and the sentence gives the beam's angle.
    """
    from borescan.discrepancy.judge import implausible, plausible_ranges
    from borescan.discrepancy.search import Candidate
    from borescan.discrepancy.terms import Term
    from borescan.fit import FitResult

    _, model = _rod_scan_and_model(4, "T")
    g0 = float(model.gamma[0])
    assert g0 > 1e-4  # the drawn layer has a nominal out-of-plane angle (0.00077 rad)
    ranges = plausible_ranges()
    high = ranges["beam_tilt"].high
    term = Term("beam_tilt", 1, device="rod")

    def candidate(gamma_rad: float) -> Candidate:
        z = np.zeros((1, 1))
        fit = FitResult(("beam_tilt@1.gamma_rad",), np.array([gamma_rad]), np.zeros(1), z, z[0], 0.0, 1, 1)
        return Candidate(fit, (term,))

    assert implausible(model, candidate(-high - 0.5 * g0), ranges) is None
    why = implausible(model, candidate(high - 0.5 * g0), ranges)  # inside as fitted, its beam past
    assert why is not None and f"the nominal {g0:.4g} + gamma_rad = {high + 0.5 * g0:.4g}" in why
    assert model.plausibility_origin(Term("sensor_offset", 1, device="rod"), "b_mm") == 0.0
