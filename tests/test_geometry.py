"""Closed-form checks of the exact forward geometry (spec: geometry-and-effects.md)."""

import numpy as np
import pytest
from scipy.optimize import minimize_scalar

from borescan.geometry import (
    Beams,
    Bore,
    Hole,
    RodAxis,
    RodLayer,
    bore_wall_radius,
    centred_beam_length_mm,
    circumcircle,
    ray_bore_distance,
    rod_readings,
    tri_spindle_readings,
    wall_points_device,
)

# Beams near Yang 2017 Table 1 (r, d_b) with beams about 120 deg apart.
BEAMS = Beams(
    channels=(1, 2, 3),
    beta_rad=np.array([0.3, 0.3 + 2.1, 0.3 + 4.2]),
    rho_mm=np.array([5.5484, -2.5295, 1.5262]),
    d_b_mm=np.array([132.6718, 132.8883, 134.1108]),
)
R_GAUGE = 275.029 / 2
CENTER = np.array([262.833, -273.182])
SPINDLE = np.array([262.955, -275.502])  # P1 of Yang 2017: oe = 2.3222 mm


def _reading(phi, ch):
    return tri_spindle_readings(np.array([phi]), SPINDLE, BEAMS, Bore(tuple(CENTER), R_GAUGE))[0, ch]


def test_a_centred_device_reads_its_centred_beam_length_less_d_b():
    """Spindle on the bore centre: every reading at every angle is sqrt(R^2 - rho^2) - d_b (to 1e-9 mm)."""
    phis = np.linspace(0.0, 2.0 * np.pi, 37)
    v = tri_spindle_readings(phis, CENTER, BEAMS, Bore(tuple(CENTER), R_GAUGE))
    expect = np.sqrt(R_GAUGE**2 - BEAMS.rho_mm**2) - BEAMS.d_b_mm
    assert np.allclose(
        centred_beam_length_mm(BEAMS.rho_mm, R_GAUGE) - BEAMS.d_b_mm, expect, rtol=0, atol=1e-12
    )
    assert np.abs(v - expect[None, :]).max() < 1e-9
    assert centred_beam_length_mm(R_GAUGE + 1.0, R_GAUGE) == 0.0  # a beam outside a centred bore: clipped


@pytest.mark.parametrize("ch", [0, 1, 2])
def test_extreme_readings_satisfy_yang_eq8(ch):
    """(d_b + d_min)^2 + r^2 = (R - oe)^2 and (d_b + d_max)^2 + r^2 = (R + oe)^2 to 1e-9 mm."""
    oe = np.hypot(*(SPINDLE - CENTER))
    # Eq. 9 on the printed P1/P0 gives 2.3232 mm; the paper prints 2.3222 mm (a 1.0 um slip).
    assert oe == pytest.approx(2.32321, abs=1e-5)
    phis = np.linspace(0, 2 * np.pi, 4001)
    v = tri_spindle_readings(phis, SPINDLE, BEAMS, Bore(tuple(CENTER), R_GAUGE))[:, ch]
    rho, d_b = BEAMS.rho_mm[ch], BEAMS.d_b_mm[ch]
    for sign, idx in ((+1, np.argmin(v)), (-1, np.argmax(v))):
        res = minimize_scalar(
            lambda p, sign=sign: sign * _reading(p, ch),
            bounds=(phis[idx] - 0.01, phis[idx] + 0.01),
            method="bounded",
            options={"xatol": 1e-12},
        )
        v_ext = sign * res.fun
        target = R_GAUGE - oe if sign > 0 else R_GAUGE + oe
        assert np.hypot(d_b + v_ext, rho) == pytest.approx(target, abs=1e-9)


def test_wall_points_are_on_the_bore_and_on_the_beam():
    phis = np.linspace(0, 2 * np.pi, 50)
    bore = Bore(tuple(CENTER), R_GAUGE)
    v = tri_spindle_readings(phis, SPINDLE, BEAMS, bore)
    W_dev = wall_points_device(v, BEAMS)  # (n, c, 2)
    c, s = np.cos(phis)[:, None], np.sin(phis)[:, None]
    W = SPINDLE + np.stack([c * W_dev[..., 0] - s * W_dev[..., 1], s * W_dev[..., 0] + c * W_dev[..., 1]], -1)
    assert np.max(np.abs(np.hypot(*(W - CENTER).transpose(2, 0, 1)) - R_GAUGE)) < 1e-10
    # |O'W|^2 = (d_b + v)^2 + rho^2 (Yang Eq. 8 form) for every sample
    assert np.allclose(np.sum(W_dev**2, -1), (BEAMS.d_b_mm + v) ** 2 + BEAMS.rho_mm**2, rtol=0, atol=1e-9)


def test_ellipse_and_lobed_bores_are_hit_exactly():
    rng = np.random.default_rng(1)
    o = rng.uniform(-3, 3, (200, 2))
    ang = rng.uniform(0, 2 * np.pi, 200)
    d = np.stack([np.cos(ang), np.sin(ang)], -1)
    bore = Bore(
        (0.0, 0.0), 100.0, tilt_rad=0.01, tilt_azimuth_rad=0.7, lobes=((3, 0.004, 0.2), (2, 0.002, 1.0))
    )
    s = ray_bore_distance(o, d, bore)
    p = o + s[:, None] * d
    theta = np.arctan2(p[:, 1], p[:, 0])
    r_wall, _ = bore_wall_radius(theta, bore)
    assert np.max(np.abs(np.hypot(p[:, 0], p[:, 1]) - r_wall)) < 1e-11
    # ellipse alone: x'^2/A^2 + y'^2/B^2 = 1
    ell = Bore((0.0, 0.0), 100.0, tilt_rad=0.02, tilt_azimuth_rad=0.7)
    p = o + ray_bore_distance(o, d, ell)[:, None] * d
    ca, sa = np.cos(0.7), np.sin(0.7)
    x, y = p[:, 0] * ca + p[:, 1] * sa, -p[:, 0] * sa + p[:, 1] * ca
    A = 100.0 / np.cos(0.02)
    assert np.max(np.abs((x / A) ** 2 + (y / 100.0) ** 2 - 1)) < 1e-14


def test_circumcircle_matches_yang_eq1_to_3():
    rng = np.random.default_rng(2)
    th = rng.uniform(0, 2 * np.pi, (20, 3))
    pts = np.stack([5 + 137.5 * np.cos(th), -2 + 137.5 * np.sin(th)], -1)
    center, radius = circumcircle(pts)
    assert np.allclose(center, [5, -2], atol=1e-9) and np.allclose(radius, 137.5, atol=1e-9)
    # Eq. 1-3: R = AB BC CA / (4 S) with Heron's area
    a = np.linalg.norm(pts[:, 0] - pts[:, 1], axis=1)
    b = np.linalg.norm(pts[:, 1] - pts[:, 2], axis=1)
    c = np.linalg.norm(pts[:, 0] - pts[:, 2], axis=1)
    S = 0.25 * np.sqrt((a + b + c) * (-a + b + c) * (a - b + c) * (a + b - c))
    assert np.allclose(a * b * c / (4 * S), radius, rtol=1e-9)


def test_effect_free_rod_satisfies_wang_eq16_exactly():
    layers = [RodLayer(channel=1, h_mm=100.0, l0_mm=70.0), RodLayer(channel=2, h_mm=400.0, l0_mm=70.0)]
    holes = [Hole((0.3, -0.2), 75.0), Hole((0.1, 0.25), 75.01)]
    axis = RodAxis(dx_mm=1.2, dy_mm=-0.7)
    alpha = np.linspace(0, 2 * np.pi, 17, endpoint=False)
    v = rod_readings(alpha, layers, holes, axis)
    for j, (lay, hole) in enumerate(zip(layers, holes)):
        l = lay.l0_mm + v[:, j]
        xm, ym = axis.dx_mm - hole.center_xy_mm[0], axis.dy_mm - hole.center_xy_mm[1]
        lhs = (xm + l * np.cos(alpha)) ** 2 + (ym + l * np.sin(alpha)) ** 2
        assert np.max(np.abs(lhs - hole.radius_mm**2)) < 1e-9


def test_rod_tilt_and_offset_spot_is_on_cylinder():
    lay = RodLayer(channel=1, h_mm=450.0, l0_mm=70.0, phi_rad=0.4, d_mm=0.5, gamma_rad=np.deg2rad(0.5))
    hole = Hole((0.0, 0.0), 75.0)
    axis = RodAxis(dx_mm=2.0, dy_mm=1.0, omega_rad=np.deg2rad(1.5), omega_az_rad=0.3)
    alpha = np.linspace(0, 2 * np.pi, 9)
    v = rod_readings(alpha, [lay], [hole], axis)[:, 0]
    from borescan.geometry import rod_axis_rotation

    Rm = rod_axis_rotation(axis)
    a = alpha + lay.phi_rad
    l = lay.l0_mm + v
    spot = (
        lay.d_mm * np.stack([-np.sin(a), np.cos(a), 0 * a], -1)
        + (l * np.cos(lay.gamma_rad))[:, None] * np.stack([np.cos(a), np.sin(a), 0 * a], -1)
        + (lay.h_mm + l * np.sin(lay.gamma_rad))[:, None] * np.array([0, 0, 1.0])
    )
    P = spot @ Rm.T + np.array([axis.dx_mm, axis.dy_mm, 0])
    assert np.max(np.abs(np.hypot(P[:, 0], P[:, 1]) - 75.0)) < 1e-10
    # the axis tilts towards its azimuth
    zt = Rm @ np.array([0, 0, 1.0])
    assert np.arctan2(zt[1], zt[0]) == pytest.approx(0.3) and np.arccos(zt[2]) == pytest.approx(
        np.deg2rad(1.5)
    )
