"""One model per device: the digital twin and the discrepancy fits agree, for every scan kind.

For every effect of the registry (:data:`borescan.effects.EFFECTS`) that applies to a scan kind,
the twin and the fitting model at the scene's true geometry (with the effect's parameters
converted to the fit's by the registry) give the same readings:

- spindle scans: :func:`borescan.synthetic.scenes.tri_readings` and
  :meth:`borescan.discrepancy.tri.TriModel.predict` (beams, centre, radius, spindle position,
  phase), and the pooled examination's model of the scan
  (:meth:`borescan.discrepancy.pooled.PooledModel.predict_scan`) to 1e-12 mm;
- static three-sensor sets: :func:`borescan.synthetic.scenes.tri_static_readings_with_effects` and
  :meth:`borescan.discrepancy.poses.StaticModel.predict` (device position per pose) to 1e-9 mm;
- rod scans: :func:`borescan.synthetic.scenes.rod_readings_with_effects` and
  :meth:`borescan.discrepancy.poses.RodModel.predict` (pose angles, hole centres relative to the
  axis, radii, deflection) to 1e-9 mm.

A new effect is its registry entry: one registered in a test reaches the twin and every fitting
model (:func:`test_a_new_registry_effect_reaches_the_twin_and_every_fitting_model`).

Output-stage effects (``quantization``, ``outliers``) act after the noise and are noise-like:
neither model has them in its deterministic readings (the workflow names them from the
residuals' lattice and spikes), so they are exempt here and only checked to be exempt.

The cases come from the registry (each effect with its ``example`` values): a new effect is
checked here without touching this file.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from borescan.discrepancy.terms import Term, term_effects, term_parameters, term_values
from borescan.discrepancy.tri import TriData, TriModel, candidate_terms
from borescan.discrepancy.poses import PoseData, RodModel, StaticModel
from borescan.effects import EFFECTS, Effect, EffectSpec, FitParam
from borescan.geometry import RodAxis
from borescan.synthetic.scenes import (
    default_rod_scene,
    default_tri_scene,
    rod_readings_with_effects,
    tri_readings,
    tri_static_readings_with_effects,
)
from borescan.synthetic.simulate import simulate_rod, simulate_tri_static

TOL_MM = 1e-12
#: static sets and rods: the twin and the fit reach the same geometry through different arithmetic
#: (the fit's unknowns are relative to the bore centre / the rod axis at the spot's height)
POSE_TOL_MM = 1e-9
TRI = "tri_lds"
ROD = "rod"
OUTPUT_STAGE = {name for name, spec in EFFECTS.items() if spec.stage == "output"}

#: Sensible parameter values per effect: the registry's ``example`` (channel effects on channel 2).
VALUES: dict[str, dict] = {name: dict(spec.example) for name, spec in EFFECTS.items()}
TRI_EFFECTS = [
    name for name, spec in EFFECTS.items() if TRI in spec.device_types and name not in OUTPUT_STAGE
]
#: a static set has no spindle turning: kinematic and spindle-position effects do not apply to it
STATIC_EFFECTS = [n for n in TRI_EFFECTS if EFFECTS[n].stage not in ("kinematics", "spindle_position")]
ROD_EFFECTS = [
    name for name, spec in EFFECTS.items() if ROD in spec.device_types and name not in OUTPUT_STAGE
]

SCENES = {
    "ccw": default_tri_scene(sample_rate_hz=120.0, phase_rad=0.7),
    "cw": default_tri_scene(sample_rate_hz=120.0, phase_rad=-0.3, direction="cw", rpm_nominal=45.0),
}


def _data(scene) -> TriData:
    """Return the discrepancy model's data at the scene's true geometry (readings are not used)."""
    t = np.arange(int(3 * scene.sample_rate_hz)) / scene.sample_rate_hz
    c = len(scene.beams.channels)
    return TriData(
        scan_id="parity",
        t_s=t,
        values_mm=np.zeros((t.size, c)),
        channels=scene.beams.channels,
        beams=scene.beams,
        radius_mm=scene.bore_radius_20_mm,
        cte_per_k=scene.cte_per_k,
        omega_rad_s=scene.omega_rad_per_s,
        direction=1.0 if scene.direction == "ccw" else -1.0,
        spindle_xy_mm=np.asarray(scene.spindle_xy_mm, dtype=float),
        center_xy_mm=None,
        range_mm=np.asarray(scene.range_mm, dtype=float),
        phase_rad=scene.phase_rad,
    )


def _term(e: Effect) -> Term:
    return Term(e.name, e.channel, int(e.params["k"]) if e.spec.harmonic else None)


def _base_params(scene) -> dict[str, float]:
    return {"cx": float(scene.bore_center_xy_mm[0]), "cy": float(scene.bore_center_xy_mm[1])}


def test_every_registry_effect_has_example_values():
    for name in EFFECTS:
        Effect(name, VALUES[name])  # raises for missing or unknown parameters


@pytest.mark.parametrize("scene", list(SCENES), ids=list(SCENES))
@pytest.mark.parametrize("name", TRI_EFFECTS)
def test_twin_and_fitting_model_give_the_same_readings(name, scene):
    sc = SCENES[scene]
    effect = Effect(name, VALUES[name])
    model = TriModel(_data(sc))
    term = _term(effect)
    p = {**_base_params(sc), **term_values(term, effect)}
    twin = tri_readings(sc, model.data.t_s, [effect])
    fit = model.predict(p, [term])
    base = tri_readings(sc, model.data.t_s, [])
    assert np.max(np.abs(twin - base)) > 1e-5, "the effect must show in the readings"
    assert np.max(np.abs(fit - twin)) < TOL_MM


def test_twin_and_fitting_model_agree_on_composed_effects():
    """Several effects at once, one per stage and two on one channel, compose alike."""
    sc = SCENES["ccw"]
    effects = [
        Effect(n, VALUES[n])
        for n in (
            "channel_delay",
            "speed_ripple",
            "spindle_error_motion",
            "bore_lobing",
            "axis_tilt",
            "thermal_expansion",
            "beam_tilt",
            "sensor_gain",
            "sensor_drift",
            "vibration",
        )
    ]
    effects.append(Effect("sensor_offset", {"channel": 1, "b_mm": -0.02}))
    model = TriModel(_data(sc))
    terms = [_term(e) for e in effects]
    p = _base_params(sc)
    for t, e in zip(terms, effects):
        p.update(term_values(t, e))
    assert np.max(np.abs(model.predict(p, terms) - tri_readings(sc, model.data.t_s, effects))) < TOL_MM


@pytest.mark.parametrize("name", sorted(OUTPUT_STAGE))
def test_output_stage_effects_are_exempt(name):
    """Noise-like: the twin's deterministic readings do not contain them, and they are no fit term."""
    spec = EFFECTS[name]
    assert not spec.fit and spec.candidate.get("tri_spindle") == "evidence"
    sc = SCENES["ccw"]
    t = np.arange(30) / sc.sample_rate_hz
    e = Effect(name, VALUES[name])
    assert np.array_equal(tri_readings(sc, t, [e]), tri_readings(sc, t, []))


@pytest.mark.parametrize("name", [n for n in TRI_EFFECTS])
def test_fit_parameters_convert_back_to_the_spec(name):
    """to_internal then from_internal is the identity (phases modulo their period)."""
    e = Effect(name, VALUES[name])
    term = _term(e)
    par, _ = term_parameters(term, term_values(term, e), {})
    want = {k: v for k, v in e.params.items() if k != "channel"}
    assert par.keys() == want.keys()
    for k, v in want.items():
        assert par[k] == pytest.approx(v, abs=1e-12), k
    (back,) = term_effects(term, term_values(term, e), (1, 2, 3))
    assert back.name == e.name and back.channel == e.channel


def test_candidates_come_from_the_registry():
    """Every screened candidate of a spindle scan is a registry effect marked for it, and
    every such effect is tried (given the scan's conditions).
    """
    data = _data(SCENES["ccw"])
    terms = candidate_terms(data, k_max=4, vibration_f_hz=7.3)
    names = {t.effect for t in terms}
    marked = {n for n, s in EFFECTS.items() if s.candidate.get("tri_spindle") == "screen"}
    assert names == marked
    assert {t.k for t in terms if t.effect == "bore_lobing"} == {2, 3, 4}
    assert any(t.effect == "sensor_offset" and t.channel == 0 for t in terms)
    assert not {t.effect for t in candidate_terms(data, vibration_f_hz=None)} & {"vibration"}


# --------------------------------------------------------------------------- recovery


@pytest.mark.parametrize("name", [n for n in TRI_EFFECTS if EFFECTS[n].fit])
def test_registry_effect_is_recovered_by_the_fitting_model(name):
    """Simulate with the effect (noise 2 um), fit base + its term from a start off the truth,
    recover the spec's parameters within 4 standard uncertainties.
    """
    from borescan.discrepancy.fitting import fit_least_squares

    sc = SCENES["ccw"]
    e = Effect(name, VALUES[name])
    data = _data(sc)
    rng = np.random.default_rng(5)
    data.values_mm = tri_readings(sc, data.t_s, [e]) + rng.normal(0.0, 0.002, data.values_mm.shape)
    model = TriModel(data)
    term = _term(e)
    truth = {**_base_params(sc), **term_values(term, e)}
    names = ["cx", "cy"] + term.names()
    scales = [1e-2, 1e-2] + term.scales()
    x0 = [truth[n] + (0.3 * s if not n.endswith("f_hz") else 0.0) for n, s in zip(names, scales)]
    fr = fit_least_squares(lambda p: model.residual(p, [term]), names, x0, scales)
    par, unc = term_parameters(term, fr.values(), fr.uncertainties())
    for k, v in e.params.items():
        if k in ("channel", "k"):
            continue
        if name == "axis_tilt" and k == "azimuth" or k == "phase":
            d = math.remainder(
                par[k] - v, 2 * math.pi / (e.params.get("k", 1) if name == "bore_lobing" else 1)
            )
        else:
            d = par[k] - v
        assert abs(d) <= 4 * unc[k], (k, par[k], v, unc[k])


@pytest.mark.parametrize("name", TRI_EFFECTS)
def test_twin_and_pooled_model_give_the_same_readings(name):
    """The pooled examination's model of one scan (shared beams at their start, the scan's nuisance at the
    scene's centre) gives the twin's readings; a speed error is the scan's own speed scale there.
    """
    from borescan.discrepancy.pooled import PooledModel, PooledScan, PooledTerm

    sc = SCENES["ccw"]
    data = _data(sc)
    model = PooledModel([PooledScan(data, "2026-11-20", "RG-275")])
    sid = data.scan_id
    p = {n: 0.0 for n in model._shared_names()} | {f"{sid}:{n}": 0.0 for n in model._nuisance(0)}
    p[f"{sid}:cx"], p[f"{sid}:cy"] = (float(x) for x in sc.bore_center_xy_mm)
    effect = Effect(name, VALUES[name])
    terms = []
    if name == "speed_error":
        p[f"{sid}:eps"] = effect.params["eps"]
    else:
        t = _term(effect)
        terms = [PooledTerm(t.effect, t.channel, t.k)]
        p.update(term_values(terms[0], effect))
    twin = tri_readings(sc, data.t_s, [effect])
    assert np.max(np.abs(model.predict_scan(0, p, terms) - twin)) < TOL_MM


# --------------------------------------------------------------------------- static sets and rods

#: a static set: the bore centred at the origin, five poses within 1.5 mm of it at device angle 0
#: (the static fit's frame), 20 samples a pose
STATIC_SCENE = default_tri_scene(bore_center_xy_mm=(0.0, 0.0), sample_rate_hz=50.0)
STATIC_XY_MM = np.array([[0.3, -0.2], [-1.1, 0.4], [0.8, 0.9], [-0.2, -1.3], [1.2, -0.5]])
#: a rod whose axis passes through the part origin at z = 0 (the rod fit's gauge), deflected by 0.1 deg
ROD_SCENE = default_rod_scene(axis=RodAxis(0.0, 0.0, math.radians(0.1), 0.7))
ROD_ALPHA_RAD = np.array([0.0, 0.9, 1.7, 2.6, 3.3, 4.4, 5.2, 5.9])


def _poses(n_pose: int, per_pose: int, rate_hz: float) -> tuple[np.ndarray, np.ndarray]:
    pose = np.repeat(np.arange(n_pose), per_pose)
    return np.arange(pose.size) / rate_hz, pose


def _static_model() -> tuple[StaticModel, np.ndarray]:
    """Return the static fit model of the scene (nominal beams = true beams, certified R20) and the poses."""
    sim = simulate_tri_static(STATIC_SCENE, STATIC_XY_MM, np.zeros(len(STATIC_XY_MM)), noise_mm=0.0)
    t, pose = _poses(len(STATIC_XY_MM), 20, STATIC_SCENE.sample_rate_hz)
    c = STATIC_SCENE.beams.channels
    return StaticModel(PoseData("parity-static", sim.meta, t, np.zeros((t.size, len(c))), c, pose)), pose


def _static_params() -> dict[str, float]:
    out = {}
    for k, (x, y) in enumerate(STATIC_XY_MM):
        out[f"sx[{k}]"], out[f"sy[{k}]"] = float(x), float(y)
    return out


def _rod_model() -> tuple[RodModel, np.ndarray]:
    """Return the rod fit model of the scene (nominal layers = true layers, certified hole diameters)."""
    feats = [
        {"id": f"H{lay.channel}", "z_mm": lay.h_mm, "certified_diameter_mm": 2 * h.radius_mm}
        for lay, h in zip(ROD_SCENE.layers, ROD_SCENE.holes)
    ]
    artifact = {"id": "GAUGE-2H", "type": "ring_gauge", "cte_per_k": ROD_SCENE.cte_per_k, "features": feats}
    sim = simulate_rod(
        ROD_SCENE,
        ROD_ALPHA_RAD,
        nominal_layers=ROD_SCENE.layers,
        artifact=artifact,
        noise_mm=0.0,
        samples_per_pose=5,
    )
    t, pose = _poses(len(ROD_ALPHA_RAD), 5, ROD_SCENE.sample_rate_hz)
    c = ROD_SCENE.channels
    return RodModel(PoseData("parity-rod", sim.meta, t, np.zeros((t.size, len(c))), c, pose)), pose


def _rod_params() -> dict[str, float]:
    """Return the rod fit's base unknowns of the scene: the inverse of ``rod_section_geometry``."""
    ax = ROD_SCENE.axis
    w = ax.omega_rad * np.array([math.cos(ax.omega_az_rad), math.sin(ax.omega_az_rad)])
    out = {f"alpha[{k}]": float(a) for k, a in enumerate(ROD_ALPHA_RAD) if k > 0}
    out["wx"], out["wy"] = float(w[0]), float(w[1])
    for j, (lay, h) in enumerate(zip(ROD_SCENE.layers, ROD_SCENE.holes)):
        z = lay.h_mm + h.radius_mm * math.tan(lay.gamma_rad)
        c = np.asarray(h.center_xy_mm) - z * np.sinc(ax.omega_rad / np.pi) * w
        out[f"cx[{j}]"], out[f"cy[{j}]"] = float(c[0]), float(c[1])
    return out


def _static_twin(effects) -> np.ndarray:
    t, pose = _poses(len(STATIC_XY_MM), 20, STATIC_SCENE.sample_rate_hz)
    return tri_static_readings_with_effects(STATIC_SCENE, STATIC_XY_MM[pose], np.zeros(pose.size), t, effects)


def _rod_twin(effects) -> np.ndarray:
    t, pose = _poses(len(ROD_ALPHA_RAD), 5, ROD_SCENE.sample_rate_hz)
    return rod_readings_with_effects(ROD_SCENE, ROD_ALPHA_RAD[pose], effects, t)


@pytest.mark.parametrize("name", STATIC_EFFECTS)
def test_static_twin_and_fitting_model_give_the_same_readings(name):
    """A time-base effect shows in a static set only through what changes in time: with a vibration."""
    effect = Effect(name, VALUES[name])
    with_it = [Effect("vibration", VALUES["vibration"])] if effect.spec.stage == "time_base" else []
    model, _ = _static_model()
    terms, p = [], _static_params()
    for e in [effect] + with_it:
        terms.append(_term(e))
        p.update(term_values(terms[-1], e))
    twin = _static_twin([effect] + with_it)
    assert np.max(np.abs(twin - _static_twin(with_it))) > 1e-5, "the effect must show in the readings"
    assert np.max(np.abs(model.predict(p, terms) - twin)) < POSE_TOL_MM


@pytest.mark.parametrize("name", ROD_EFFECTS)
def test_rod_twin_and_fitting_model_give_the_same_readings(name):
    effect = Effect(name, VALUES[name])
    model, _ = _rod_model()
    term = _term(effect)
    fit = model.predict({**_rod_params(), **term_values(term, effect)}, [term])
    twin = _rod_twin([effect])
    assert np.max(np.abs(twin - _rod_twin([]))) > 1e-5, "the effect must show in the readings"
    assert np.max(np.abs(fit - twin)) < POSE_TOL_MM


def test_pose_models_agree_with_the_twin_on_composed_effects():
    """Every effect of each pose kind at once (two on one channel) composes alike in twin and fit."""
    for kind, names, model_of, params, twin in (
        ("static", STATIC_EFFECTS, _static_model, _static_params, _static_twin),
        ("rod", ROD_EFFECTS, _rod_model, _rod_params, _rod_twin),
    ):
        effects = [Effect(n, VALUES[n]) for n in names]
        effects.append(Effect("sensor_offset", {"channel": 1, "b_mm": -0.02}))
        model, _ = model_of()
        terms = [_term(e) for e in effects]
        p = params()
        for t, e in zip(terms, effects):
            p.update(term_values(t, e))
        assert np.max(np.abs(model.predict(p, terms) - twin(effects))) < POSE_TOL_MM, kind


def test_rod_beam_tilt_was_the_documented_mismatch():
    """The old rod fit scaled the whole reading length by 1 / cos(gamma) on top of the layer's own tilt
    (0.3 deg on layer 1 of ``default_rod_scene``); the twin tilts the layer. At 0.5 deg the old form
    was 4.6 um off the twin there; the rod fit now calls the twin's model (parity above, 1e-9 mm).
    """
    sc = default_rod_scene()
    alpha = np.linspace(0.0, 2 * np.pi, 24, endpoint=False)
    g = math.radians(0.5)
    twin = rod_readings_with_effects(sc, alpha, [Effect("beam_tilt", {"channel": 1, "gamma_rad": g})])[:, 0]
    l0 = sc.layers[0].l0_mm
    old = (rod_readings_with_effects(sc, alpha)[:, 0] + l0) / math.cos(g) - l0
    assert 4.5e-3 < np.max(np.abs(old - twin)) < 4.7e-3


# ------------------------------------------------------------------ a new effect is its registry entry


def _scale_bore(bore, p, cte_per_k=0.0):
    """R' = R (1 + s): the test's new bore effect."""
    from dataclasses import replace

    return replace(bore, radius_mm=bore.radius_mm * (1.0 + p["s"]))


def test_a_new_registry_effect_reaches_the_twin_and_every_fitting_model(monkeypatch):
    """Registering a bore effect (its registry entry, nothing else) changes the twin's readings of
    every scan kind, and each fitting model gives the twin's readings with it.
    """
    spec = EffectSpec(
        "bore_scale",
        (TRI, ROD),
        {"s": "-"},
        "bore",
        {TRI: _scale_bore, ROD: _scale_bore},
        "R' = R (1 + s)",
        fit=(FitParam("s", "-", 1e-5),),
        candidate={"tri_spindle": "screen", "tri_static": "screen", "rod": "screen"},
        example={"s": 4e-5},
    )
    monkeypatch.setitem(EFFECTS, "bore_scale", spec)
    effect = Effect("bore_scale", {"s": 4e-5})
    term = _term(effect)
    # spindle
    sc = SCENES["ccw"]
    tri = TriModel(_data(sc))
    twin = tri_readings(sc, tri.data.t_s, [effect])
    assert np.max(np.abs(twin - tri_readings(sc, tri.data.t_s, []))) > 1e-3
    assert (
        np.max(np.abs(tri.predict({**_base_params(sc), **term_values(term, effect)}, [term]) - twin)) < TOL_MM
    )
    assert term in candidate_terms(tri.data, k_max=2)
    # static
    static, _ = _static_model()
    twin = _static_twin([effect])
    assert np.max(np.abs(twin - _static_twin([]))) > 1e-3
    assert (
        np.max(np.abs(static.predict({**_static_params(), **term_values(term, effect)}, [term]) - twin))
        < POSE_TOL_MM
    )
    assert term in static.candidate_terms(k_max=2)
    # rod
    rod, _ = _rod_model()
    twin = _rod_twin([effect])
    assert np.max(np.abs(twin - _rod_twin([]))) > 1e-3
    assert (
        np.max(np.abs(rod.predict({**_rod_params(), **term_values(term, effect)}, [term]) - twin))
        < POSE_TOL_MM
    )
    assert term in rod.candidate_terms(k_max=2)
