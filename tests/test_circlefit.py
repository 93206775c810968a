"""Circle fits against NIST reference circles, closed forms and brute force (ISO 12181)."""

from itertools import combinations
from pathlib import Path

import numpy as np
import pytest

from borescan.circlefit import (
    CLOSED_MAX_GAP_DEG,
    CircleFitError,
    fit_circle_ls,
    harmonic_spectrum,
    largest_gap_deg,
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


@pytest.mark.parametrize("n, regular", [(200, False), (20000, True)])
def test_perfect_circle_all_reference_circles_coincide(n, regular):
    """Points exactly on a circle (random angles, or a regular 20000-gon: every point cocircular,
    diametrically opposite pairs): all four circles are that circle.
    """
    rng = np.random.default_rng(3)
    th = np.linspace(0, 2 * np.pi, n, endpoint=False) if regular else rng.uniform(0, 2 * np.pi, n)
    x, y = 700.0 + 137.5 * np.cos(th), -275.0 + 137.5 * np.sin(th)
    for name, circ in reference_circles(x, y).items():
        assert np.allclose(circ.center_xy_mm, [700.0, -275.0], atol=1e-9), name
        assert circ.radius_mm == pytest.approx(137.5, abs=1e-9), name
        assert circ.ront_mm < 1e-9, name


def test_three_lobe_profile_known_peak_to_valley():
    """r = R + a cos 3(theta - phase): every centre is the true one, RONt = 2a exactly
    (the odd-lobed profile has no eccentricity the reference circles could trade for).
    """
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
    for noisy non-uniform data over a full turn and (ill-conditioned: fallback path) a short arc.
    """
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


# ------------------------------------------------------------------ global optima, open profiles


def _dist(C, P):
    """|p_i - c_j| for centres C (m, 2) and points P (n, 2): (m, n), plain numpy."""
    return np.hypot(C[:, :1] - P[:, 0], C[:, 1:] - P[:, 1])


def _chunked(fun, C, P):
    """fun(_dist(C, P)) row-wise, in chunks of at most ~2^22 distances."""
    step = max(1, (1 << 22) // len(P))
    return np.concatenate([fun(_dist(C[i : i + step], P)) for i in range(0, len(C), step)])


def _angular_polygon(P):
    """Return the profile polygon: the points in angular order about their least-squares centre."""
    from matplotlib.path import Path as MPath

    c = fit_circle_ls(P[:, 0], P[:, 1]).center_xy_mm
    return MPath(P[np.argsort(np.arctan2(P[:, 1] - c[1], P[:, 0] - c[0]))])


def _edge_distance(C, V):
    """Distance from each centre C (m, 2) to the closed polygon V (n, 2) (its edges)."""
    A, B = V, np.roll(V, -1, axis=0)
    AB = B - A
    out = np.empty(len(C))
    step = max(1, (1 << 20) // len(V))
    for i in range(0, len(C), step):
        Q = C[i : i + step, None, :] - A  # (m, n, 2)
        t = np.clip(np.einsum("mnk,nk->mn", Q, AB) / np.einsum("nk,nk->n", AB, AB), 0.0, 1.0)
        out[i : i + step] = np.min(np.hypot(*np.moveaxis(Q - t[..., None] * AB, -1, 0)), axis=1)
    return out


def _branch_and_bound(P, value, lipschitz, poly=None, tol_mm=1e-10):
    """Global maximum of ``value(C)`` over centres in the points' bounding square (and, with a
    polygon ``poly``, inside it), independent of circlefit: squares of half-diagonal a are
    dropped when value(centre) + lipschitz * a cannot reach the best value found at a centre
    (inside ``poly``) or when they lie wholly outside ``poly``; the rest are split in four,
    until lipschitz * a < tol_mm. Returns (best, its centre, bound on the maximum).
    """
    lo, size = P.min(axis=0), float(np.max(np.ptp(P, axis=0)))
    n0 = 32
    h = size / n0  # side
    ij = np.stack(np.meshgrid(np.arange(n0), np.arange(n0)), -1).reshape(-1, 2)
    C = lo + (ij + 0.5) * h
    best, best_c = -np.inf, None
    while True:
        v = value(C)
        ok = poly.contains_points(C) if poly is not None else np.ones(len(C), bool)
        if ok.any():
            j = int(np.argmax(np.where(ok, v, -np.inf)))
            if v[j] > best:
                best, best_c = float(v[j]), C[j].copy()
        a = h / np.sqrt(2)
        keep = v + lipschitz * a >= best
        if poly is not None:
            out = keep & ~ok
            keep[out] = _edge_distance(C[out], poly.vertices) <= a
        assert keep.sum() < 20_000, "branch and bound does not converge (a flat maximum?)"
        if lipschitz * a < tol_mm:
            return best, best_c, float(np.max(v[keep] + lipschitz * a))
        C = C[keep]
        q = h / 4
        C = np.concatenate([C + [dx, dy] for dx in (-q, q) for dy in (-q, q)])
        h /= 2


def _bb_mic(P, tol_mm=1e-10):
    """Largest f(c) = min_i |p_i - c| (1-Lipschitz) over centres inside the profile polygon."""

    def f(C):
        return _chunked(lambda d: d.min(axis=1), C, P)

    return _branch_and_bound(P, f, 1.0, _angular_polygon(P), tol_mm)


def _bb_mcc(P, tol_mm=1e-10):
    """Smallest max_i |p_i - c| (1-Lipschitz)."""

    def minus_g(C):
        return -_chunked(lambda d: d.max(axis=1), C, P)

    best, c, bound = _branch_and_bound(P, minus_g, 1.0, None, tol_mm)
    return -best, c, -bound


def _bb_mz(P, tol_mm=1e-10):
    """Smallest max_i |p_i - c| - min_i |p_i - c| (2-Lipschitz)."""

    def width(C):
        return _chunked(lambda d: d.min(axis=1) - d.max(axis=1), C, P)

    best, c, bound = _branch_and_bound(P, width, 2.0, None, tol_mm)
    return -best, c, -bound


def _peanut(R1=50.0, R2=49.99, s=3.0, n1=720, n2=2881):
    """Points on the outline of two overlapping disks, centres (-s, 0) (radius R1, n1 points)
    and (s, 0) (R2, n2 points): each outer arc spans more than 180 deg about its own centre
    when |R1^2 - R2^2| < 4 s^2, so f(c) = min_i |p_i - c| has a local maximum R_k at each
    centre (a two-lobed bore with a waist). Returns x, y (the two waist points included).
    """
    x0 = (R1**2 - R2**2) / (4 * s)  # abscissa of the waist (radical line)
    y0 = np.sqrt(R1**2 - (x0 + s) ** 2)
    a1, a2 = np.arctan2(y0, x0 + s), np.arctan2(y0, x0 - s)
    t1 = np.linspace(a1, 2 * np.pi - a1, n1)[1:-1]
    t2 = np.linspace(-a2, a2, n2)[1:-1]
    x = np.concatenate([-s + R1 * np.cos(t1), s + R2 * np.cos(t2), [x0, x0]])
    y = np.concatenate([R1 * np.sin(t1), R2 * np.sin(t2), [y0, -y0]])
    return x, y


@pytest.mark.parametrize("n1, n2", [(720, 2881), (400, 4001)])  # odd n2: a point at angle 0
def test_mici_is_the_largest_of_two_local_maxima(n1, n2):
    """Two-lobed bore (disks R1 = 50 mm at (-3, 0), R2 = 49.99 mm at (3, 0)): f has a local
    maximum in each lobe; the MIC is the larger one, centre (-3, 0), radius 50 mm exactly,
    although the denser sampling of the smaller lobe puts the least-squares centre there.
    """
    R1, R2, s = 50.0, 49.99, 3.0
    x, y = _peanut(R1, R2, s, n1, n2)
    P = np.column_stack([x, y])
    x0 = (R1**2 - R2**2) / (4 * s)
    assert fit_circle_ls(x, y).center_xy_mm[0] > x0  # the start a local search would take
    for c, R in (([-s, 0.0], R1), ([s, 0.0], R2)):  # both centres are strict local maxima
        ang = np.arange(16) * np.pi / 8
        ring = np.array(c) + 1e-3 * np.column_stack([np.cos(ang), np.sin(ang)])
        assert _dist(np.array([c]), P).min() == pytest.approx(R, abs=1e-12)
        assert np.all(_dist(ring, P).min(axis=1) < R - 1e-5)
    mic = max_inscribed_circle(x, y)
    assert np.allclose(mic.center_xy_mm, [-s, 0.0], atol=1e-9)
    assert mic.radius_mm == pytest.approx(R1, abs=1e-9)
    # RONt about the MIC centre: the farthest point is the right lobe's (s + R2, 0)
    assert mic.ront_mm == pytest.approx(2 * s + R2 - R1, abs=1e-9)
    best, _, bound = _bb_mic(P, tol_mm=1e-8)  # and no centre anywhere in the profile does better
    assert best <= mic.radius_mm + 1e-12 and bound <= mic.radius_mm + 1e-8
    assert mic.n_iter >= 2  # both lobes' maxima were candidates


def _lobed_bore(kind, noise_mm=0.0, dent_mm=0.0, dent_deg=0.0, seed=0):
    """Lobed bores about (40, -25) mm, radial noise and an off-centre inward dent (Gaussian,
    8 deg wide about the origin) added: "peanut" (:func:`_peanut`, the smaller lobe sampled 4x
    denser), "clover" (outline of three disks of radius 50, 49.97, 49.94 mm centred 30 mm out at
    90, 210, 330 deg, 1500 random angles), "trefoil" (r = 50 + 0.05 cos 3 theta, 3000 points).
    """
    rng = np.random.default_rng(seed)
    if kind == "peanut":
        x, y = _peanut(50.0, 49.99, 3.0, 720, 2881)
        th = np.arctan2(y, x)
        r = np.hypot(x, y)
    elif kind == "clover":
        th = np.sort(rng.uniform(0, 2 * np.pi, 1500))
        u = np.column_stack([np.cos(th), np.sin(th)])
        t = []
        for ang, R in zip(np.deg2rad([90.0, 210.0, 330.0]), (50.0, 49.97, 49.94)):
            uc = 30.0 * (u @ [np.cos(ang), np.sin(ang)])
            t.append(uc + np.sqrt(uc**2 - 30.0**2 + R**2))  # the ray from the origin leaves disk k
        r = np.max(t, axis=0)
    else:
        th = np.linspace(0, 2 * np.pi, 3000, endpoint=False)
        r = 50.0 + 0.05 * np.cos(3 * th)
    dent = np.exp(-0.5 * (np.angle(np.exp(1j * (th - np.deg2rad(dent_deg)))) / np.deg2rad(8.0)) ** 2)
    r = r + noise_mm * rng.standard_normal(th.size) - dent_mm * dent
    return 40.0 + r * np.cos(th), -25.0 + r * np.sin(th)


@pytest.mark.parametrize(
    "kind, noise_mm, dent_mm, dent_deg, seed",
    [
        ("peanut", 0.001, 0.0, 0.0, 0),
        ("peanut", 0.002, 0.02, 150.0, 2),
        ("peanut", 0.003, 0.02, -60.0, 3),
        ("clover", 0.005, 0.1, 100.0, 4),
        ("trefoil", 0.002, 0.5, 20.0, 0),
        ("trefoil", 0.002, 0.3, 60.0, 5),
    ],
)
def test_mici_equals_branch_and_bound_on_lobed_profiles(kind, noise_mm, dent_mm, dent_deg, seed):
    """Lobed bores with noise and a dent: MICI radius = the global maximum found by branch and
    bound over centres within 1e-9 mm (its bound), centre within 1e-6 mm, RONt about it within
    twice that distance. The peanut has a local maximum in each lobe (checked: f near each lobe centre
    exceeds f on a 1 mm circle around it) and its least-squares centre in the smaller one.
    """
    x, y = _lobed_bore(kind, noise_mm, dent_mm, dent_deg, seed)
    P = np.column_stack([x, y])
    if kind == "peanut":
        g = np.linspace(-0.3, 0.3, 13)
        disk = np.stack(np.meshgrid(g, g), -1).reshape(-1, 2)
        circle = np.column_stack([np.cos(np.arange(64) * np.pi / 32), np.sin(np.arange(64) * np.pi / 32)])
        for c in ([37.0, -25.0], [43.0, -25.0]):
            assert _dist(c + disk, P).min(axis=1).max() > _dist(c + circle, P).min(axis=1).max()
        assert fit_circle_ls(x, y).center_xy_mm[0] > 40.0 + (50.0**2 - 49.99**2) / 12.0  # right of the waist
    best, c_bb, bound = _bb_mic(P)
    mic = max_inscribed_circle(x, y)
    print(
        f"{kind}: MIC r {mic.radius_mm:.9f} at {mic.center_xy_mm}, branch and bound {best:.9f} "
        f"at {c_bb}, {mic.n_iter} candidates"
    )
    assert best - 1e-12 <= mic.radius_mm <= bound + 1e-12 and bound - best < 1e-9
    dc = np.hypot(*(mic.center_xy_mm - c_bb))
    assert dc < 1e-6
    assert abs(mic.ront_mm - roundness(x, y, c_bb)) <= 2 * dc + 1e-12  # RONt is 2-Lipschitz in the centre


NIST_CLOSED = [1, 4, 6, 8, 9, 10, 11, 12, 13, 16, 17, 18, 19, 22, 23, 25, 27, 29]
NIST_OPEN = [2, 3, 5, 7, 14, 15, 20, 21, 24, 26, 28, 30]


def test_nist_sets_closed_and_open():
    """The sets that sample the whole circle (3 to 360 points) have gaps <= 120 deg about the
    LS centre, the partial arcs >= 179.9 deg: the 150 deg default tells them apart.
    """
    gaps = {i: largest_gap_deg(*_nist(i)[:2]) for i in range(1, 31)}
    assert max(gaps[i] for i in NIST_CLOSED) < 120.01 < 179.9 < min(gaps[i] for i in NIST_OPEN)
    assert max(gaps[i] for i in NIST_CLOSED) < CLOSED_MAX_GAP_DEG < min(gaps[i] for i in NIST_OPEN)


@pytest.mark.parametrize("i", NIST_CLOSED)
def test_nist_reference_circles_equal_branch_and_bound(i):
    """Every closed NIST circle2d set: MICI, MCCI and MZCI equal the global optimum found by
    branch and bound over centres to 1e-9 mm, and RONt about the MIC centre matches (within
    twice the distance of the two centres).
    """
    x, y, _, _ = _nist(i)
    shift = np.array([x.mean(), y.mean()])
    P = np.column_stack([x, y]) - shift  # NIST parts sit up to 1000 mm out
    mic = max_inscribed_circle(x, y)
    best, c_bb, bound = _bb_mic(P)
    assert best - 1e-12 <= mic.radius_mm <= bound + 1e-12 and bound - best < 1e-9
    dc = np.hypot(*(mic.center_xy_mm - shift - c_bb))
    assert dc < 1e-6
    assert abs(mic.ront_mm - roundness(*P.T, c_bb)) <= 2 * dc + 1e-12  # RONt is 2-Lipschitz in the centre
    mcc = min_circumscribed_circle(x, y)
    best, c_bb, bound = _bb_mcc(P)
    assert bound - 1e-12 <= mcc.radius_mm <= best + 1e-12 and best - bound < 1e-9
    if x.size >= 4:
        mz = min_zone_circle(x, y)
        best, c_bb, bound = _bb_mz(P)
        assert bound - 1e-12 <= mz.ront_mm <= best + 1e-12 and best - bound < 1e-9


def test_nist_cir2d19_mici_is_the_global_maximum():
    """cir2d19 (20 points): the inscribed circle nearest the LS centre is 1 nm smaller and
    12.3 um away from the largest; RONt about the largest one's centre is 35.393 um. Exhaustive
    check: every circle through 3 of the 20 points that is empty and centred inside.
    """
    from borescan.geometry import circumcircle

    x, y, _, _ = _nist(19)
    shift = np.array([x.mean(), y.mean()])
    P = np.column_stack([x, y]) - shift  # the part sits 600 mm out
    mic = max_inscribed_circle(x, y)
    poly = _angular_polygon(P)
    found = []
    for tri in combinations(range(len(P)), 3):
        c, r = circumcircle(P[list(tri)])
        if np.isfinite(r) and poly.contains_point(c) and _dist(np.array([c]), P).min() >= r - 1e-9:
            found.append((r, c))
    r_max, c_max = max(found, key=lambda t: t[0])
    assert len(found) >= 2  # several empty circles to choose from
    assert mic.radius_mm == pytest.approx(r_max, abs=1e-9)
    assert np.allclose(mic.center_xy_mm - shift, c_max, atol=1e-9)
    assert mic.ront_mm == pytest.approx(roundness(*P.T, c_max), abs=1e-9)
    assert mic.ront_mm == pytest.approx(0.035393, abs=1e-6)


@pytest.mark.parametrize("i", NIST_OPEN)
def test_nist_open_arcs_refused(i):
    """The partial-arc NIST sets: a clear 'not closed' error from MICI, MZCI, MCCI and
    reference_circles, not an LP status.
    """
    x, y, _, _ = _nist(i)
    msg = r"profile is not closed \(largest gap (179\.9|18[01]\.\d|2[67]\d\.\d) deg\)"
    for f in (max_inscribed_circle, min_zone_circle, min_circumscribed_circle, reference_circles):
        with pytest.raises(CircleFitError, match=msg):
            f(x, y)


@pytest.mark.parametrize("arc_deg", [90.0, 180.0, 200.0])
def test_open_arc_reports_its_gap(arc_deg):
    """A noisy arc of arc_deg: the error names the gap, 360 - arc_deg (to the spacing)."""
    th = np.deg2rad(np.linspace(0.0, arc_deg, 500))
    r = 20.0 + 0.001 * np.random.default_rng(0).standard_normal(th.size)
    x, y = 5 + r * np.cos(th), 7 + r * np.sin(th)
    gap = 360.0 - arc_deg
    assert largest_gap_deg(x, y) == pytest.approx(gap, abs=0.5)
    for f in (max_inscribed_circle, min_zone_circle, min_circumscribed_circle):
        with pytest.raises(CircleFitError, match=rf"profile is not closed \(largest gap {gap:.0f}\.\d deg\)"):
            f(x, y)


def test_max_gap_deg_argument():
    """A full circle missing a 160 deg sector is refused by default and accepted at 170 deg,
    where the reference circles of points exactly on a circle are that circle.
    """
    th = np.deg2rad(np.linspace(0.0, 200.0, 201))
    x, y = 1 + 30 * np.cos(th), 2 + 30 * np.sin(th)
    with pytest.raises(CircleFitError, match=r"largest gap 160\.0 deg"):
        reference_circles(x, y)
    for name, circ in reference_circles(x, y, max_gap_deg=170.0).items():
        assert np.allclose(circ.center_xy_mm, [1, 2], atol=1e-9), name
        assert circ.radius_mm == pytest.approx(30, abs=1e-9), name


@pytest.mark.parametrize("case", ["lobed", "two_maxima", "inner_outlier"])
def test_mic_on_the_reduced_set_equals_the_full_triangulation(case, monkeypatch):
    """The MICI of a large profile is found on the inner envelope (one point per angular bin) with a
    certificate; it must equal the MICI computed by triangulating every point (MIC_BINS raised so that
    the full path runs), centre and radius to 1e-12 mm.
    """
    from borescan.circlefit import inscribed as circlefit

    rng = np.random.default_rng(7)
    n = 40_000
    th = np.sort(rng.uniform(0.0, 2 * np.pi, n))
    R = 137.5
    if case == "lobed":
        r = R + 0.004 * np.cos(3 * th + 0.4) + 0.0015 * rng.standard_normal(n)
    elif case == "two_maxima":  # two flats on opposite sides: two local maxima of f of nearly equal size
        r = R + 0.002 * rng.standard_normal(n)
        r = np.where(np.abs(np.cos(th)) > 0.995, R - 0.02 + 0.002 * np.abs(np.sin(th)), r)
    else:  # a few points well inside the bore (debris): not on the inner envelope of their bins' neighbours
        r = R + 0.002 * rng.standard_normal(n)
        r[rng.choice(n, 5, replace=False)] = R - 0.3
    x, y = 0.4 + r * np.cos(th), -0.2 + r * np.sin(th)
    sizes, triangulate = [], circlefit._local_max_vertices
    monkeypatch.setattr(
        circlefit, "_local_max_vertices", lambda P: (sizes.append(P.shape[0]), triangulate(P))[1]
    )
    reduced = circlefit.max_inscribed_circle(x, y)
    assert max(sizes) < n / 4  # certified on the reduced set, never all points
    monkeypatch.setattr(circlefit, "MIC_BINS", 10 * n)  # n <= 4 MIC_BINS: every point is triangulated
    full = circlefit.max_inscribed_circle(x, y)
    assert np.allclose(reduced.center_xy_mm, full.center_xy_mm, rtol=0, atol=1e-12)
    assert abs(reduced.radius_mm - full.radius_mm) < 1e-12
    # and it is the largest empty circle: no point inside it
    d = np.hypot(x - reduced.center_xy_mm[0], y - reduced.center_xy_mm[1])
    assert d.min() >= reduced.radius_mm - 1e-12


def _awkward_profile(rng, kind: str, n: int, radius_mm: float, noise_mm: float, centre_mm) -> tuple:
    """n points at random angles on a circle with noise, and a shape whose reference circles are
    not set by each angle's extreme points about the LS centre: "noise" (none), "lobes" (2 and 5
    UPR), "bump" (one side, pulls the LS centre away), "outward_spikes" (0.2 % of the points
    30 um out), "spikes" (0.1 % of the points 30 um in or out), "flat" (two opposite flats).
    """
    th = rng.uniform(0, 2 * np.pi, n)
    r = radius_mm + rng.normal(0, noise_mm, n)
    if kind == "lobes":
        r += 0.02 * np.cos(2 * th) + 0.01 * np.cos(5 * th + 1)
    elif kind == "bump":
        r += 0.05 * np.exp(-((th - 1.0) ** 2) / 0.05)
    elif kind == "outward_spikes":
        r += 0.03 * (rng.random(n) < 0.002)
    elif kind == "spikes":
        r += np.where(rng.random(n) < 0.001, rng.normal(0, 0.03, n), 0.0)
    elif kind == "flat":
        r = np.where(np.abs(np.cos(th)) > 0.99, radius_mm - 0.03, r)
    return centre_mm[0] + r * np.cos(th), centre_mm[1] + r * np.sin(th)


@pytest.mark.parametrize("farthest", [8, 64, 2048])
def test_mcci_from_the_farthest_points_is_the_mcci_of_all(monkeypatch, farthest):
    """A long profile's MCCI is found from its points farthest from the LS centre, widened 8-fold
    while a point is left outside: the same circle (to 1e-12 mm) as Welzl on the hull of every
    point, on profiles whose farthest points from the LS centre are not the MCCI's (lobes, an
    off-centre bump, outward spikes), and every point inside it.
    """
    import borescan.circlefit.circumscribed as cf

    rng = np.random.default_rng(20261124)
    for kind in ("noise", "lobes", "bump", "outward_spikes"):
        n = 30_000
        x, y = _awkward_profile(rng, kind, n, 120.0, 0.001, (0.7, -0.4))
        monkeypatch.setattr(cf, "MCCI_FARTHEST", farthest)
        fast = cf.min_circumscribed_circle(x, y)
        monkeypatch.setattr(cf, "MCCI_FARTHEST", 10 * n)  # every point: the hull of all
        full = cf.min_circumscribed_circle(x, y)
        assert np.max(np.abs(fast.center_xy_mm - full.center_xy_mm)) < 1e-12
        assert abs(fast.radius_mm - full.radius_mm) < 1e-12
        assert np.max(np.hypot(x - fast.center_xy_mm[0], y - fast.center_xy_mm[1])) <= fast.radius_mm


@pytest.mark.parametrize("bins", [16, 256, 2048])
def test_mzci_on_the_radial_extremes_is_the_mzci_of_all(monkeypatch, bins):
    """A long profile's MZCI is found by the sequential LP on the innermost and outermost point of
    each angular bin, with the check that every point lies in that zone (points outside are added):
    the same centre and zone width (to 1e-12 mm) as the LP on every point, on profiles whose zone
    is set by points that are not their bin's extremes about the LS centre (lobes, a bump that
    pulls the LS centre, inward and outward spikes, a flat). With 16 bins the first zone leaves
    points outside, so the widening runs.
    """
    import borescan.circlefit.zone as cf

    rng = np.random.default_rng(20261125)
    slp = cf._slp
    for kind in ("noise", "lobes", "bump", "spikes", "flat"):
        n = 40_000
        x, y = _awkward_profile(rng, kind, n, 140.0, 0.002, (-0.3, 0.6))
        sizes = []
        monkeypatch.setattr(
            cf,
            "_slp",
            lambda xs, ys, c0, sizes=sizes, **kw: (sizes.append(xs.size), slp(xs, ys, c0, **kw))[1],
        )
        monkeypatch.setattr(cf, "MZ_BINS", bins)
        fast = cf.min_zone_circle(x, y)
        assert max(sizes) < n / 4  # certified on the reduced set, never all points
        monkeypatch.setattr(cf, "MZ_BINS", 10 * n)  # n <= 4 MZ_BINS: the LP on every point
        full = cf.min_zone_circle(x, y)
        assert np.max(np.abs(fast.center_xy_mm - full.center_xy_mm)) < 1e-12, kind
        assert abs(fast.ront_mm - full.ront_mm) < 1e-12 and abs(fast.radius_mm - full.radius_mm) < 1e-12, kind
        d = np.hypot(x - fast.center_xy_mm[0], y - fast.center_xy_mm[1])
        assert d.max() - d.min() == pytest.approx(fast.ront_mm, abs=1e-12)
