"""The device models' analytic Jacobians against central differences of their own predictions.

:meth:`borescan.physics.tri.TriDevice.jacobian` (static sets) and
:meth:`borescan.physics.rod.RodDevice.jacobian` differentiate the exact ray-to-wall intersection
implicitly; here every column is checked against a central difference of ``predict`` (step h: the
difference is exact to O(h^2 f''') plus rounding 1e-16 |v| / h), with and without effects that change
the bore's shape, the beam and the reading.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from borescan.effects import Effect
from borescan.geometry import RodAxis
from borescan.physics.rod import RodDevice, RodState
from borescan.physics.tri import TriDevice, TriStaticState
from borescan.synthetic.scenes import default_rod_scene, default_tri_scene

#: central differences with step 1e-6 of readings of ~5 mm: rounding ~1e-10 relative to slopes of ~1
TOL = 1e-6
H = 1e-6

TRI_EFFECTS = {
    "none": [],
    "shaped": [
        Effect("axis_tilt", {"beta_rad": 0.02, "azimuth": 0.6}),
        Effect("bore_lobing", {"k": 3, "a_mm": 0.005, "phase": 0.4}),
        Effect("thermal_expansion", {"temperature_c": 24.0}),
        Effect("beam_tilt", {"channel": 2, "gamma_rad": 0.06}),
        Effect("sensor_gain", {"channel": 1, "g": 0.003}),
        Effect("sensor_nonlinearity", {"channel": 3, "a_mm": 0.004}),
    ],
}
ROD_EFFECTS = {
    "none": [],
    "beam_and_reading": [
        Effect("beam_offset", {"channel": 1, "d_mm": 0.3}),
        Effect("beam_tilt", {"channel": 2, "gamma_rad": 0.06}),
        Effect("thermal_expansion", {"temperature_c": 24.0}),
        Effect("sensor_gain", {"channel": 1, "g": 0.003}),
        Effect("sensor_nonlinearity", {"channel": 2, "a_mm": 0.004}),
    ],
}


def _close(analytic: np.ndarray, numeric: np.ndarray) -> None:
    assert np.all(np.isfinite(analytic))
    assert np.max(np.abs(analytic - numeric)) <= TOL * max(1.0, float(np.max(np.abs(numeric))))


def _tri_case():
    sc = default_tri_scene()
    device = TriDevice(sc.beams, sc.cte_per_k, sc.range_mm)
    xy = np.array(sc.bore_center_xy_mm) + np.array([[0.3, -0.2], [-1.1, 0.4], [0.8, 0.9], [-0.2, -1.3]])
    state = TriStaticState(xy, np.array([0.0, 1.3, 2.9, 4.4]), sc.bore())
    pose = np.repeat(np.arange(4), 3)
    return device, state, pose, np.arange(pose.size) * 0.02


@pytest.mark.parametrize("case", list(TRI_EFFECTS))
def test_tri_static_jacobian_is_the_derivative_of_predict(case):
    device, state, pose, t = _tri_case()
    effects = TRI_EFFECTS[case]
    J = device.jacobian(state, pose, t, effects)

    def diff(make):
        return (device.predict(make(H), pose, t, effects) - device.predict(make(-H), pose, t, effects)) / (
            2 * H
        )

    for i in range(2):
        e = np.zeros(2)
        e[i] = 1.0
        _close(
            J.d_device_xy[..., i],
            diff(lambda h, e=e: replace(state, device_xy_mm=state.device_xy_mm + h * e)),
        )
        c0 = np.asarray(state.bore.center_xy_mm)
        _close(
            J.d_center[..., i],
            diff(
                lambda h, e=e, c0=c0: replace(state, bore=replace(state.bore, center_xy_mm=tuple(c0 + h * e)))
            ),
        )
    _close(J.d_device_angle, diff(lambda h: replace(state, device_angle_rad=state.device_angle_rad + h)))
    _close(
        J.d_radius,
        diff(lambda h: replace(state, bore=replace(state.bore, radius_mm=state.bore.radius_mm + h))),
    )


def test_tri_static_device_refuses_effects_of_a_turning_spindle():
    device, state, pose, t = _tri_case()
    with pytest.raises(ValueError, match="do not apply to a static"):
        device.predict(state, pose, t, [Effect("speed_error", {"eps": 0.002})])


def _rod_case():
    sc = default_rod_scene()
    device = RodDevice(sc.layers, sc.cte_per_k, sc.range_mm)
    state = RodState(
        alpha_rad=np.array([0.0, 1.1, 2.3, 3.0, 4.2, 5.5]),
        center_xy_mm=np.array([[-1.2, 0.8], [-1.18, 0.79]]),
        radius_mm=np.array([75.004, 74.997]),
        deflection_xy_rad=math.radians(0.1) * np.array([math.cos(0.7), math.sin(0.7)]),
    )
    pose = np.repeat(np.arange(6), 2)
    return device, state, pose, np.arange(pose.size) * 0.5


@pytest.mark.parametrize("case", list(ROD_EFFECTS))
def test_rod_jacobian_is_the_derivative_of_predict(case):
    device, state, pose, t = _rod_case()
    effects = ROD_EFFECTS[case]
    J = device.jacobian(state, pose, t, effects)

    def diff(make):
        return (device.predict(make(H), pose, t, effects) - device.predict(make(-H), pose, t, effects)) / (
            2 * H
        )

    _close(J.d_alpha, diff(lambda h: replace(state, alpha_rad=state.alpha_rad + h)))
    for j in range(2):  # a layer's centre and radius move its column only
        for i in range(2):
            e = np.zeros((2, 2))
            e[j, i] = 1.0
            num = diff(lambda h, e=e: replace(state, center_xy_mm=state.center_xy_mm + h * e))
            _close(J.d_center[:, j, i], num[:, j])
            assert np.all(num[:, 1 - j] == 0.0)
        e = np.zeros(2)
        e[j] = 1.0
        _close(J.d_radius[:, j], diff(lambda h, e=e: replace(state, radius_mm=state.radius_mm + h * e))[:, j])
    # the deflection's columns are central differences of predict by construction (not checked here)
    assert J.d_deflection.shape == J.d_alpha.shape + (2,)


def test_rod_device_keeps_its_holes_circles():
    device, state, pose, t = _rod_case()
    with pytest.raises(ValueError, match="does not apply to a rod"):
        device.predict(state, pose, t, [Effect("axis_tilt", {"beta_rad": 0.02, "azimuth": 0.6})])


def test_rod_device_base_is_the_geometry_of_its_unknowns():
    """Without deflection the holes are the centres themselves and the axis is the part's z axis."""
    device, state, _, _ = _rod_case()
    base = device.base(replace(state, deflection_xy_rad=np.zeros(2)))
    assert [h.center_xy_mm for h in base.holes] == [tuple(c) for c in state.center_xy_mm]
    assert base.axis == RodAxis(0.0, 0.0, 0.0, 0.0)


@pytest.mark.parametrize("case", [*ROD_EFFECTS, "beam_and_reading_no_bore"])
def test_rod_stacked_prediction_is_the_prediction_state_by_state(case):
    """A fit's forward differences in one call (:meth:`RodDevice.predict_stack`): every state of the stack
    (pose angles, centres, radii, deflection moved one at a time, as its Jacobian's groups) predicts what
    :meth:`RodDevice.predict` gives for it alone, to the rounding of numpy's vectorised loops (1e-12 mm);
    a bore-stage effect (thermal expansion) takes the state-by-state path.
    """
    device, state, pose, t = _rod_case()
    if case == "beam_and_reading_no_bore":
        effects = [e for e in ROD_EFFECTS["beam_and_reading"] if e.name != "thermal_expansion"]
    else:
        effects = ROD_EFFECTS[case]
    states = [
        state,
        replace(state, alpha_rad=state.alpha_rad + 1e-4),
        replace(state, center_xy_mm=state.center_xy_mm + np.array([[1e-3, 0.0], [0.0, -2e-3]])),
        replace(state, radius_mm=state.radius_mm + np.array([0.0, 5e-3])),
        replace(state, deflection_xy_rad=state.deflection_xy_rad * 1.5 + 1e-4),
    ]
    stacked = device.predict_stack(states, pose, t, effects)
    assert stacked.shape == (len(states), pose.size, 2)
    for s, v in zip(states, stacked, strict=True):
        one = device.predict(s, pose, t, effects)
        assert np.all(np.isfinite(one))
        np.testing.assert_allclose(v, one, rtol=0, atol=1e-12)
