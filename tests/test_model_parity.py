"""One model of the three-sensor spindle scan: the digital twin and the discrepancy fit agree.

For every effect of the registry (:data:`borescan.effects.EFFECTS`) that applies to a
``tri_lds`` spindle scan, :func:`borescan.simulate.tri_readings` (the twin) and
:meth:`borescan.discrepancy.tri.TriModel.predict` (the fitting model, at the scene's true
geometry: beams, centre, radius, spindle position, phase, with the effect's parameters
converted to the fit's by the registry) give the same readings to 1e-12 mm.

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

from borescan.discrepancy.tri import (
    Term,
    TriData,
    TriModel,
    candidate_terms,
    term_effects,
    term_parameters,
    term_values,
)
from borescan.effects import EFFECTS, Effect
from borescan.simulate import default_tri_scene, tri_readings

TOL_MM = 1e-12
TRI = "tri_lds"
OUTPUT_STAGE = {name for name, spec in EFFECTS.items() if spec.stage == "output"}

#: Sensible parameter values per effect: the registry's ``example`` (channel effects on channel 2).
VALUES: dict[str, dict] = {name: dict(spec.example) for name, spec in EFFECTS.items()}
TRI_EFFECTS = [name for name, spec in EFFECTS.items() if TRI in spec.device_types and name not in OUTPUT_STAGE]

SCENES = {
    "ccw": default_tri_scene(sample_rate_hz=120.0, phase_rad=0.7),
    "cw": default_tri_scene(sample_rate_hz=120.0, phase_rad=-0.3, direction="cw", rpm_nominal=45.0),
}


def _data(scene) -> TriData:
    """Return the discrepancy model's data at the scene's true geometry (readings are not used)."""
    t = np.arange(int(3 * scene.sample_rate_hz)) / scene.sample_rate_hz
    c = len(scene.beams.channels)
    return TriData(
        scan_id="parity", t_s=t, values_mm=np.zeros((t.size, c)), channels=scene.beams.channels,
        beams=scene.beams, radius_mm=scene.bore_radius_20_mm, cte_per_k=scene.cte_per_k,
        omega_rad_s=scene.omega_rad_per_s, direction=1.0 if scene.direction == "ccw" else -1.0,
        spindle_xy_mm=np.asarray(scene.spindle_xy_mm, dtype=float), center_xy_mm=None,
        range_mm=np.asarray(scene.range_mm, dtype=float), phase_rad=scene.phase_rad,
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
    effects = [Effect(n, VALUES[n]) for n in ("channel_delay", "speed_ripple", "spindle_error_motion",
                                              "bore_lobing", "axis_tilt", "thermal_expansion", "beam_tilt",
                                              "sensor_gain", "sensor_drift", "vibration")]
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
            d = math.remainder(par[k] - v, 2 * math.pi / (e.params.get("k", 1) if name == "bore_lobing" else 1))
        else:
            d = par[k] - v
        assert abs(d) <= 4 * unc[k], (k, par[k], v, unc[k])
