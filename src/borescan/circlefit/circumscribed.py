"""The minimum circumscribed circle (MCCI, ISO 12181): exact, Welzl's algorithm (move-to-front, seeded)."""

from __future__ import annotations

import numpy as np
from scipy.spatial import ConvexHull

from borescan.circlefit.lsq import CLOSED_MAX_GAP_DEG, Circle, ClosedProfile, closed_profile, make_circle

__all__ = ["min_circumscribed_circle", "mcci_of", "MCCI_FARTHEST"]


def _circle2(a, b):
    c = 0.5 * (a + b)
    return c, float(np.hypot(*(a - c)))


def _circle3(a, b, c):
    bx, by = b - a
    cx, cy = c - a
    d = 2.0 * (bx * cy - by * cx)
    if d == 0.0:
        return None
    b2, c2 = bx * bx + by * by, cx * cx + cy * cy
    ux = (cy * b2 - by * c2) / d
    uy = (bx * c2 - cx * b2) / d
    return a + np.array([ux, uy]), float(np.hypot(ux, uy))


def _first_outside(P: np.ndarray, lo: int, hi: int, c: np.ndarray, r: float, tol: float) -> int:
    """Index of the first point of P[lo:hi] farther than r + tol from c, else hi (one vectorised scan)."""
    if hi <= lo:
        return hi
    out = np.flatnonzero(np.hypot(P[lo:hi, 0] - c[0], P[lo:hi, 1] - c[1]) > r + tol)
    return lo + int(out[0]) if out.size else hi


def _welzl(P: np.ndarray, tol: float) -> tuple[np.ndarray, float]:
    """Return iterative Welzl: smallest enclosing circle of points P (n, 2).

    The classic three nested loops over the points in order; each loop jumps to its next point
    outside the current circle by a vectorised scan (:func:`_first_outside`), so the Python work
    is per circle update, not per point (the same circles in the same order as point by point).
    """
    n = len(P)
    c, r = P[0].copy(), 0.0
    i = _first_outside(P, 1, n, c, r, tol)
    while i < n:
        c, r = P[i].copy(), 0.0
        j = _first_outside(P, 0, i, c, r, tol)
        while j < i:
            c, r = _circle2(P[i], P[j])
            k = _first_outside(P, 0, j, c, r, tol)
            while k < j:
                res = _circle3(P[i], P[j], P[k])
                if res is None:  # collinear: the farthest pair spans it
                    pairs = [(P[i], P[j]), (P[i], P[k]), (P[j], P[k])]
                    c, r = max((_circle2(a, b) for a, b in pairs), key=lambda t: t[1])
                else:
                    c, r = res
                k = _first_outside(P, k + 1, j, c, r, tol)
            j = _first_outside(P, j + 1, i, c, r, tol)
        i = _first_outside(P, i + 1, n, c, r, tol)
    return c, r


def min_circumscribed_circle(
    x_mm, y_mm, ls_center_xy_mm=None, *, seed: int = 0, max_gap_deg: float = CLOSED_MAX_GAP_DEG
) -> Circle:
    """Minimum circumscribed circle (ISO 12181 MCCI), exact (Welzl, expected linear time).

    The smallest circle containing every point; defined by 2 or 3 points on it.

    Parameters
    ----------
    x_mm, y_mm : array_like (n,), n >= 3 [mm]; non-finite points are dropped.
    ls_center_xy_mm : (2,) least-squares centre [mm] when the caller has it (else fitted); the
        closed-profile check is made about it.
    seed : seed of the random point order of Welzl's algorithm (the result does not depend on it).
    max_gap_deg : largest angular gap of a closed profile [deg] (:data:`CLOSED_MAX_GAP_DEG`).

    Raises
    ------
    CircleFitError
        "profile is not closed (largest gap X deg)" for an open arc.
    """
    return mcci_of(closed_profile(x_mm, y_mm, ls_center_xy_mm, max_gap_deg, "MCCI"), seed)


#: MCCI of a long profile: first the circle of this many points farthest from the LS centre
MCCI_FARTHEST = 2048


def mcci_of(prof: ClosedProfile, seed: int = 0) -> Circle:
    """Return Welzl's circle of the profile's convex hull.

    Welzl's circle of the profile's convex hull. A long profile's circle is first found from its
    :data:`MCCI_FARTHEST` points farthest from the least-squares centre (8 times more while it
    leaves a point outside): a circle that is the smallest around a subset and encloses every point
    is the smallest around them all (the hull of 120 000 points costs ~50 ms, a subset's ~1 ms).
    """
    x, y, shift = prof.x, prof.y, prof.shift
    n = x.size
    scale = float(max(np.max(np.abs(x)), np.max(np.abs(y)))) or 1.0
    tol = 1e-12 * scale
    k = MCCI_FARTHEST
    while True:
        idx = np.argpartition(prof.r, n - k)[n - k :] if k < n else np.arange(n)
        P = np.column_stack([x[idx], y[idx]])
        if P.shape[0] > 50:  # the enclosing circle of a set is that of its convex hull
            try:
                P = P[ConvexHull(P).vertices]
            except Exception:  # noqa: BLE001 - degenerate hull (collinear): Welzl copes with all points
                pass
        order = np.random.default_rng(seed).permutation(len(P))
        c, r = _welzl(P[order], tol=tol)
        if k >= n or np.all(np.hypot(x - c[0], y - c[1]) <= r + tol):
            break
        k *= 8
    # the enclosing radius is the farthest point from c (removes the tolerance slack)
    r = float(np.max(np.hypot(x - c[0], y - c[1])))
    return make_circle("MCCI", x, y, shift, c, r)


# --------------------------------------------------------------------------- MZCI (SLP)
