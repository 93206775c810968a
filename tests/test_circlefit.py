"""Circle fits against NIST reference circles, closed forms and brute force (ISO 12181)."""

from itertools import combinations
from pathlib import Path

import numpy as np
import pytest

from borescan.circlefit import (
    CircleFitError,
    fit_circle_ls,
    harmonic_spectrum,
    max_inscribed_circle,
    min_circumscribed_circle,
    min_zone_circle,
    reference_circles,
    roundness,
)

NIST = Path("/work/shared/reference/nist-circle2d")
if not NIST.exists():  # repository checkout next to shared/
    NIST = Path(__file__).resolve().parents[2] / "shared" / "reference" / "nist-circle2d"


def _nist(i):
    pts = np.loadtxt(NIST / f"cir2d{i}.ds", skiprows=1).reshape(-1, 3)
    fit = np.array([float(v) for v in (NIST / f"cir2d{i}.fit").read_text().split()])
    keep = [j for j in range(3) if np.ptp(pts[:, j]) > 0]  # plane parallel to a coordinate plane
    assert len(keep) == 2 and abs(fit[3 + 3 - sum(keep)]) == 1.0  # normal along the constant axis
    return pts[:, keep[0]], pts[:, keep[1]], fit[:3][keep], fit[6]


@pytest.mark.parametrize("i", range(1, 31))
def test_nist_circle2d_reference_fits(i):
    """Centre and diameter within 1e-9 mm of NIST's reference LS circle (all 30 sets)."""
    x, y, c_ref, d_ref = _nist(i)
    fit = fit_circle_ls(x, y)
    err_c = np.max(np.abs(fit.center_xy_mm - c_ref))
    err_d = abs(fit.diameter_mm - d_ref)
    digits = -np.log10(max(err_c, err_d, 1e-17) / d_ref)
    print(f"cir2d{i}: n={x.size} centre err {err_c:.1e} mm, diameter err {err_d:.1e} mm, {digits:.1f} digits")
    assert err_c < 1e-9 and err_d < 1e-9


def _lobed(n=720, R=50.0, a=0.004, k=3, c=(3.0, -2.0), phase=0.3, noise=0.0, seed=0):
    th = np.linspace(0, 2 * np.pi, n, endpoint=False)
    r = R + a * np.cos(k * (th - phase)) + noise * np.random.default_rng(seed).standard_normal(n)
    return c[0] + r * np.cos(th), c[1] + r * np.sin(th), th


def test_perfect_circle_all_reference_circles_coincide():
    rng = np.random.default_rng(3)
    th = rng.uniform(0, 2 * np.pi, 200)
    x, y = 700.0 + 137.5 * np.cos(th), -275.0 + 137.5 * np.sin(th)
    for name, circ in reference_circles(x, y).items():
        assert np.allclose(circ.center_xy_mm, [700.0, -275.0], atol=1e-9), name
        assert circ.radius_mm == pytest.approx(137.5, abs=1e-9), name
        assert circ.ront_mm < 1e-9, name


def test_three_lobe_profile_known_peak_to_valley():
    """r = R + a cos 3(theta - phase): every centre is the true one, RONt = 2a exactly
    (the odd-lobed profile has no eccentricity the reference circles could trade for)."""
    a = 0.004
    x, y, _ = _lobed(a=a, phase=np.deg2rad(10.0))  # peaks and valleys on samples
    circ = reference_circles(x, y)
    for name in ("MZCI", "MICI", "MCCI", "LSCI"):
        assert np.allclose(circ[name].center_xy_mm, [3.0, -2.0], atol=1e-9), name
        assert circ[name].ront_mm == pytest.approx(2 * a, abs=1e-9), name
    assert circ["MICI"].radius_mm == pytest.approx(50.0 - a, abs=1e-9)
    assert circ["MCCI"].radius_mm == pytest.approx(50.0 + a, abs=1e-9)
    assert circ["LSCI"].radius_mm == pytest.approx(50.0, abs=1e-9)


def _brute_mcc(P):
    best = None
    for i, j in combinations(range(len(P)), 2):
        c = 0.5 * (P[i] + P[j])
        r = np.hypot(*(P[i] - c))
        if np.all(np.hypot(*(P - c).T) <= r + 1e-9) and (best is None or r < best[1]):
            best = (c, r)
    for i, j, k in combinations(range(len(P)), 3):
        from borescan.geometry import circumcircle

        c, r = circumcircle(P[[i, j, k]])
        if np.all(np.hypot(*(P - c).T) <= r + 1e-9) and (best is None or r < best[1]):
            best = (c, r)
    return best


def _brute_mic(P):
    """Largest empty circle through 3 points with its centre inside the profile polygon."""
    from matplotlib.path import Path as MPath

    from borescan.geometry import circumcircle

    poly = MPath(P)
    best = None
    for tri in combinations(range(len(P)), 3):
        c, r = circumcircle(P[list(tri)])
        if not poly.contains_point(c):
            continue
        if np.all(np.hypot(*(P - c).T) >= r - 1e-9) and (best is None or r > best[1]):
            best = (c, r)
    return best


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_mcci_and_mici_equal_brute_force(seed):
    """Irregular 24-point profile: exact MCCI/MICI equal the brute-force enumeration to 1e-9 mm."""
    rng = np.random.default_rng(seed)
    th = np.sort(rng.uniform(0, 2 * np.pi, 24))
    r = 20.0 + 0.05 * rng.standard_normal(24) + 0.03 * np.cos(2 * th + 1.0)
    x, y = 1.0 + r * np.cos(th), 2.0 + r * np.sin(th)
    P = np.column_stack([x, y])
    mcc, mic = min_circumscribed_circle(x, y), max_inscribed_circle(x, y)
    c, rr = _brute_mcc(P)
    assert np.allclose(mcc.center_xy_mm, c, atol=1e-9) and mcc.radius_mm == pytest.approx(rr, abs=1e-9)
    c, rr = _brute_mic(P)
    assert np.allclose(mic.center_xy_mm, c, atol=1e-9) and mic.radius_mm == pytest.approx(rr, abs=1e-9)


@pytest.mark.parametrize("seed", [0, 1])
def test_min_zone_is_the_smallest_ront(seed):
    """MZCI width <= RONt about every other centre (dense grid and the other three circles)."""
    rng = np.random.default_rng(10 + seed)
    th = np.sort(rng.uniform(0, 2 * np.pi, 60))
    r = 30.0 + 0.01 * rng.standard_normal(60) + 0.02 * np.cos(2 * th) + 0.01 * np.cos(5 * th + 2)
    x, y = r * np.cos(th), r * np.sin(th)
    circ = reference_circles(x, y)
    mz = circ["MZCI"]
    assert mz.ront_mm == pytest.approx(mz.zone_mm[1] - mz.zone_mm[0], abs=1e-15)
    for name in ("LSCI", "MICI", "MCCI"):
        assert mz.ront_mm <= circ[name].ront_mm + 1e-12
    g = np.linspace(-0.03, 0.03, 61)
    c0 = mz.center_xy_mm
    grid = [roundness(x, y, c0 + [dx, dy]) for dx in g for dy in g]
    assert mz.ront_mm <= min(grid) + 1e-12
    # and the optimum is a vertex: perturbing the centre by 1e-7 mm in any direction increases RONt
    for ang in np.linspace(0, 2 * np.pi, 16, endpoint=False):
        assert roundness(x, y, c0 + 1e-7 * np.array([np.cos(ang), np.sin(ang)])) > mz.ront_mm


def test_eccentric_two_lobe_minimum_zone_known_width():
    """Ellipse-like r = R + a cos 2 theta about a known centre: MZ width = 2a, centre exact."""
    x, y, _ = _lobed(n=360, R=75.0, a=0.01, k=2, c=(-5.0, 8.0), phase=0.0)
    mz = min_zone_circle(x, y)
    assert np.allclose(mz.center_xy_mm, [-5.0, 8.0], atol=1e-9)
    assert mz.ront_mm == pytest.approx(0.02, abs=1e-9)


def test_harmonic_spectrum_recovers_lobes():
    th = np.random.default_rng(4).uniform(0, 2 * np.pi, 400)  # non-uniform angles
    r = 50 + 0.004 * np.cos(3 * (th - 0.3)) + 0.002 * np.cos(7 * th - 1.1)
    upr, amp, phase = harmonic_spectrum(th, r, max_upr=20)
    assert amp[0] == pytest.approx(50.0, abs=1e-12)
    assert amp[3] == pytest.approx(0.004, abs=1e-12) and amp[7] == pytest.approx(0.002, abs=1e-12)
    assert phase[3] == pytest.approx(0.9, abs=1e-9) and phase[7] == pytest.approx(1.1, abs=1e-9)
    others = np.delete(amp[1:], [2, 6])
    assert np.max(others) < 1e-12 and upr[-1] == 20


@pytest.mark.parametrize("arc_rad", [2 * np.pi, 0.5])
def test_harmonic_spectrum_equals_design_matrix_least_squares(arc_rad):
    """Power-sum normal equations give the same coefficients as lstsq on the full design matrix,
    for noisy non-uniform data over a full turn and (ill-conditioned: fallback path) a short arc."""
    rng = np.random.default_rng(11)
    th = rng.uniform(0, arc_rad, 3000)
    r = 138.0 + 0.003 * np.cos(2 * th) + 0.001 * rng.standard_normal(th.size)
    K = 12
    k = np.arange(1, K + 1)
    A = np.column_stack([np.ones_like(th), np.cos(np.outer(th, k)), np.sin(np.outer(th, k))])
    coef, *_ = np.linalg.lstsq(A, r, rcond=None)
    _, amp, phase = harmonic_spectrum(th, r, max_upr=K)
    ours = amp[0] + np.cos(np.outer(th, k) - phase[1:]) @ amp[1:]
    rss_ours, rss_ref = np.sum((r - ours) ** 2), np.sum((r - A @ coef) ** 2)
    assert rss_ours <= rss_ref * (1 + 1e-6)  # the least-squares optimum (short arc: cond(A) ~ 1e13)
    if arc_rad > 6:  # well conditioned: the coefficients themselves are unique and agree
        ref = np.concatenate([[coef[0]], np.hypot(coef[1 : K + 1], coef[K + 1 :])])
        assert np.max(np.abs(amp - ref)) < 1e-12


def test_ls_covariance_matches_monte_carlo():
    """u(R) from s^2 (J^T J)^-1 agrees with the Monte Carlo scatter within 10 %."""
    rng = np.random.default_rng(5)
    th = np.linspace(0, 2 * np.pi, 50, endpoint=False)
    rs, us = [], []
    for _ in range(400):
        r = 10 + 0.01 * rng.standard_normal(th.size)
        f = fit_circle_ls(r * np.cos(th), r * np.sin(th))
        rs.append(f.radius_mm)
        us.append(np.sqrt(f.cov[2, 2]))
    assert np.std(rs) / np.mean(us) == pytest.approx(1.0, abs=0.1)
    assert np.mean(us) == pytest.approx(0.01 / np.sqrt(50), rel=0.05)  # closed form sigma / sqrt(n)


def test_failure_paths():
    with pytest.raises(CircleFitError, match="at least 3"):
        fit_circle_ls([0, 1], [0, 1])
    with pytest.raises(CircleFitError, match="collinear"):
        fit_circle_ls([0, 1, 2, 3], [0, 1, 2, 3])
