"""Rotation angle of a spindle scan (spec "Spindle scan"): encoder, rpm profile, rpm_nominal."""

from __future__ import annotations

import math

import numpy as np
import pytest

from borescan.kinematics import (
    AngleModel,
    angle_model_from_arrays,
    estimate_speed_scale,
    profile_angle_rad,
    speed_scale_from_readings,
)


def test_profile_integral_is_exact_for_piecewise_linear_speed():
    # 60 rpm for 2 s, linear ramp to 30 rpm over 1 s, then 30 rpm: closed-form angles
    tk = np.array([0.0, 2.0, 3.0])
    wk = np.array([2 * np.pi, 2 * np.pi, np.pi])
    t = np.array([0.0, 1.0, 2.0, 2.5, 3.0, 5.0, -1.0])
    ramp_half = 2 * np.pi * 0.5 - 0.5 * np.pi * 0.25  # w0 tau - (w0 - w1) tau^2 / 2 at tau = 0.5
    expected = [
        0.0,
        2 * np.pi,
        4 * np.pi,
        4 * np.pi + ramp_half,
        4 * np.pi + 1.5 * np.pi,
        5.5 * np.pi + 2 * np.pi,
        -2 * np.pi,
    ]
    assert np.allclose(profile_angle_rad(t, tk, wk), expected, atol=1e-12)


def test_profile_starts_at_zero_when_the_clock_starts_late():
    tk = np.array([0.5, 1.0])
    wk = np.array([1.0, 3.0])
    assert profile_angle_rad(np.array([0.0]), tk, wk)[0] == pytest.approx(0.0, abs=1e-15)
    assert profile_angle_rad(np.array([1.0]), tk, wk)[0] == pytest.approx(0.5 + 1.0, abs=1e-12)


def test_order_of_preference_encoder_profile_nominal():
    t = np.arange(0.0, 2.0, 0.02)
    enc = angle_model_from_arrays(
        rpm_nominal=60,
        spindle_t_s=t,
        spindle_angle_rad=0.3 + 2 * np.pi * t,
        spindle_rpm=np.full(t.size, 60.0),
    )
    assert enc.source == "encoder" and not enc.fits_speed_and_phase
    assert enc.phi_rad(np.array([0.5]), phase_rad=9.0, speed_scale=3.0)[0] == pytest.approx(
        0.3 + np.pi, abs=1e-12
    )
    prof = angle_model_from_arrays(
        rpm_nominal=60,
        direction="cw",
        spindle_t_s=t,
        spindle_angle_rad=np.full(t.size, np.nan),
        spindle_rpm=np.full(t.size, 30.0),
    )
    assert prof.source == "profile" and prof.fits_speed_and_phase
    assert prof.phi_rad(np.array([1.0]), phase_rad=0.1, speed_scale=1.02)[0] == pytest.approx(
        0.1 - 1.02 * np.pi
    )
    nom = angle_model_from_arrays(rpm_nominal=120, direction="ccw")
    assert nom.source == "nominal" and nom.commanded_rad(np.array([0.25]))[0] == pytest.approx(np.pi)
    with pytest.raises(ValueError, match="rotation angle is unknown"):
        angle_model_from_arrays(rpm_nominal=None)
    with pytest.raises(ValueError, match="direction must be 'ccw' or 'cw'"):
        angle_model_from_arrays(rpm_nominal=60, direction="left")


def test_encoder_spline_follows_a_ramp_between_samples():
    # true angle of a ramp 60 -> 30 rpm, encoder sampled at 50 Hz, read at 600 Hz
    tk = np.array([0.0, 1.0, 2.0])
    wk = np.array([2 * np.pi, 2 * np.pi, np.pi])
    t_enc = np.arange(0.0, 4.0, 0.02)
    am = AngleModel("encoder", t_enc, profile_angle_rad(t_enc, tk, wk))
    t = np.arange(0.0, 3.98, 1 / 600)
    err = am.phi_rad(t) - profile_angle_rad(t, tk, wk)
    # a cubic spline cannot follow the speed's kinks exactly: ~ (dw/dt) dt^2 / 20 near them
    assert np.max(np.abs(err)) < 1e-4


@pytest.mark.parametrize("scale", [0.3, 0.93, 1.0, 1.036, 2.5])
def test_speed_scale_found_from_the_readings(scale):
    rng = np.random.default_rng(1)
    tk, wk = np.array([0.0, 6.0, 7.5]), np.array([2 * np.pi, 2 * np.pi, 0.55 * 2 * np.pi])
    t = np.arange(0.0, 30.0, 1 / 500)
    Phi = profile_angle_rad(t, tk, wk)
    phi = 0.7 + scale * Phi
    y = np.stack([2.1 * np.cos(phi + b) + 0.01 * np.cos(2 * (phi + b)) for b in (0.2, 2.3, 4.4)], axis=1)
    y += 0.003 * rng.standard_normal(y.shape)
    y[rng.random(y.shape) < 0.01] = np.nan
    coarse = speed_scale_from_readings(Phi, y)
    assert abs(coarse / scale - 1) < 0.02
    fine = estimate_speed_scale(Phi, y)
    # phase error at the end of the scan well under a tenth of a radian
    assert abs(fine - scale) * np.ptp(Phi) < 0.05


def test_speed_scale_without_rotation_is_an_error():
    t = np.arange(0.0, 10.0, 0.01)
    with pytest.raises(ValueError, match="does not advance"):
        speed_scale_from_readings(np.zeros(t.size), np.ones((t.size, 3)))
    assert math.isfinite(AngleModel("nominal", np.zeros(1), np.array([1.0])).mean_omega_rad_s())


def test_angle_model_of_a_simulated_scan_matches_the_twin():
    """The raw scan's spindle stream gives back the twin's angle: encoder -> phi, profile -> Phi (cw
    signed).
    """
    from dataclasses import replace

    from borescan.synthetic import scenes, simulate
    from borescan.kinematics import angle_model_of_scan

    scene = replace(
        scenes.default_tri_scene(),
        rpm_profile=((0.0, 60.0), (2.0, 60.0), (3.0, 30.0)),
        direction="cw",
        phase_rad=0.4,
    )
    t = np.linspace(0.0, 5.0, 301)
    enc = simulate.simulate_tri_spindle(scene, n_rev=4, encoder=True, seed=1, spindle_rate_hz=50.0)
    am = angle_model_of_scan(enc.meta, enc.spindle)
    assert am.source == "encoder"
    assert np.max(np.abs(am.phi_rad(t) - scenes.tri_phi(scene, t))) < 1e-4  # spline through the ramp's kinks
    prof = simulate.simulate_tri_spindle(scene, n_rev=4, encoder=False, seed=1, spindle_rate_hz=50.0)
    am = angle_model_of_scan(prof.meta, prof.spindle)
    assert am.source == "profile"
    assert np.allclose(am.commanded_rad(t), -scene.commanded_angle_rad(t), atol=1e-9)
    assert angle_model_of_scan(prof.meta, None).source == "nominal"


def test_repeated_evaluation_on_fixed_times_is_cached_and_exact():
    """Fits evaluate Phi(t) on one read-only time array again and again: the second call returns
    the first result (the same values), views of it hit the cache too, writable arrays never do.
    """
    tk = np.linspace(0.0, 2.0, 400)
    model = AngleModel("encoder", tk, 2 * np.pi * tk + 0.1 * np.sin(3 * tk))
    t = np.array(np.linspace(0.01, 1.99, 5000))  # owns its memory (linspace returns a view)
    fresh = model.commanded_rad(t.copy())
    t.flags.writeable = False
    a = model.commanded_rad(t)
    assert model.commanded_rad(t) is a  # served from the cache
    b = model.commanded_rad(t[:, None])
    assert model.commanded_rad(t[:, None]) is b  # a new view of the same times: cached too
    assert np.array_equal(a, fresh) and np.array_equal(b[:, 0], fresh)
    w = t.copy()
    assert model.commanded_rad(w) is not model.commanded_rad(w)  # writable: evaluated every time
    w[0] = 0.5
    assert model.commanded_rad(w)[0] == pytest.approx(model.commanded_rad(np.array([0.5]))[0])


def _lstsq_misfits(scales, Phi, y, mask, channels) -> np.ndarray:
    """Return each scale's first-harmonic misfit summed over ``channels``, by numpy's lstsq (SVD) alone."""
    expected = np.zeros(scales.size)
    for i, g in enumerate(scales):
        for j in channels:
            m = mask[:, j]
            A = np.column_stack([np.ones(m.sum()), np.cos(g * Phi[m]), np.sin(g * Phi[m])])
            r = A @ np.linalg.lstsq(A, y[m, j], rcond=None)[0] - y[m, j]
            expected[i] += r @ r
    return expected


@pytest.mark.parametrize("revolutions", [0.7, 3.0, 25.0])
def test_first_harmonic_misfit_over_the_grid_is_each_scale_s_least_squares(revolutions):
    """first_harmonic_sse_grid (every scale at once, normal equations) against numpy's lstsq of each scale and
    channel on its own (the SVD), nulls and a channel with too few readings included: the same sums of
    squares to 1e-10 relative, so refine_speed_scale picks the same grid point and parabola.
    """
    from borescan.kinematics import first_harmonic_sse_grid

    rng = np.random.default_rng(7)
    n = 1500
    Phi = np.linspace(0.0, 2 * np.pi * revolutions, n)
    y = np.stack([4.0 + 0.08 * np.cos(1.03 * Phi + b) for b in (0.1, 2.0, 4.1)], axis=1)
    y += 0.002 * rng.standard_normal(y.shape)
    mask = rng.random(y.shape) > 0.05
    mask[3:, 2] = False  # three readings: left out
    scales = 1.03 + np.linspace(-0.05, 0.05, 21)
    expected = _lstsq_misfits(scales, Phi, y, mask, channels=(0, 1))
    got = first_harmonic_sse_grid(scales, Phi, y, mask)
    np.testing.assert_allclose(got, expected, rtol=1e-10)
    assert np.argmin(got) == np.argmin(expected)


def test_first_harmonic_misfit_of_readings_at_one_angle_is_lstsq_s():
    """A channel whose readings (four or more) all sit at one commanded angle (a stopped spindle) makes the
    normal equations singular: its misfit is then numpy's lstsq's (the least-norm solution), not an error.
    """
    from borescan.kinematics import first_harmonic_sse_grid

    Phi = np.linspace(0.0, 20.0, 400)
    y = np.stack([2.0 + 0.1 * np.cos(Phi), 1.5 + 0.1 * np.cos(Phi + 1.0)], axis=1)
    mask = np.ones(y.shape, dtype=bool)
    mask[:, 1] = False
    Phi[100:106] = Phi[100]
    mask[100:106, 1] = True
    y[100:106, 1] = [0.30, 0.31, 0.29, 0.30, 0.32, 0.28]
    scales = np.array([0.98, 1.0, 1.02])
    expected = _lstsq_misfits(scales, Phi, y, mask, channels=(0, 1))
    np.testing.assert_allclose(first_harmonic_sse_grid(scales, Phi, y, mask), expected, rtol=1e-9, atol=1e-15)
