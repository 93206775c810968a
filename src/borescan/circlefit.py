"""Circle fitting: least squares (NIST-conformant) and the ISO 12181 reference circles.

All functions take point coordinates ``x_mm, y_mm`` (n,) and return a :class:`Circle`.
Coordinates are centred on their mean before any arithmetic so that parts far from the
origin (NIST places them up to 1000 mm out) keep full precision.

- :func:`fit_circle_ls`: geometric least squares min sum (|p_i - c| - R)^2 (LSCI), Gauss-Newton
  from the algebraic Kasa start, Levenberg damping only when a step does not descend.
- :func:`min_circumscribed_circle` (MCCI): exact, Welzl's algorithm (move-to-front, seeded).
- :func:`max_inscribed_circle` (MICI): the global maximum of min_i |p_i - c| over centres c
  inside the closed profile polygon: the best Voronoi vertex of the points (a Delaunay
  circumcentre) inside the polygon, then the exact 3-point polish.
- :func:`min_zone_circle` (MZCI): sequential linear programming (exact gradients, trust region)
  on min_c (max_i |p_i - c| - min_i |p_i - c|), converged to a vertex, then polished by solving
  the active-set equations exactly (Newton).
- MZCI, MICI and MCCI need a closed profile: the largest angular gap between consecutive points
  about the least-squares centre must not exceed ``max_gap_deg`` (default
  :data:`CLOSED_MAX_GAP_DEG` = 150 deg); an open arc raises :class:`CircleFitError`
  "profile is not closed (largest gap X deg)". :func:`largest_gap_deg` gives the gap.
- roundness RONt (peak-to-valley of radial deviations) about each centre: :func:`roundness`.
- :func:`harmonic_spectrum`: amplitude per undulations per revolution (UPR), least-squares
  Fourier fit (valid for non-uniform angles).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import linprog
from scipy.spatial import ConvexHull, Delaunay, QhullError

__all__ = [
    "Circle",
    "CircleFitError",
    "CLOSED_MAX_GAP_DEG",
    "largest_gap_deg",
    "fit_circle_ls",
    "fit_circle_kasa",
    "min_circumscribed_circle",
    "max_inscribed_circle",
    "min_zone_circle",
    "roundness",
    "reference_circles",
    "harmonic_spectrum",
]


class CircleFitError(ValueError):
    """Too few points, collinear points, an open profile or a failed iteration."""


CLOSED_MAX_GAP_DEG = 150.0
"""Largest angular gap [deg] between consecutive profile points, seen from the least-squares
centre, for which the profile counts as closed (ISO 12181 reference circles are defined for a
closed profile). The polygon through the points in angular order surrounds the centre exactly
when every gap is below 180 deg; at 180 deg (a half circle) the centre lies on the chord across
the gap and beyond it outside the polygon: an empty circle can then grow out through the gap,
and the circumscribed and minimum zone circles no longer describe the feature. 150 deg keeps the
centre at least R cos 75 deg = 0.26 R inside that chord, a margin against a least-squares
centre pulled by form error on a near-half arc, and still admits the sparsest closed profile,
three points 120 deg apart. The NIST circle2d reference sets that sample the whole circle have
gaps of 1-120 deg (3 to 7 points: 51.5-120 deg); their partial arcs have 179.9-270.2 deg."""


@dataclass(frozen=True)
class Circle:
    """A fitted or reference circle.

    Attributes
    ----------
    center_xy_mm : ndarray (2,) centre [mm]
    radius_mm : radius [mm]; for the minimum zone circle the mean of the two zone radii
    method : "LSCI", "MCCI", "MICI", "MZCI" or "KASA"
    ront_mm : peak-to-valley of radial deviations about the centre (ISO 12181 RONt) [mm]
    rms_mm : RMS of radial deviations about (centre, radius) [mm]
    zone_mm : (r_min, r_max) of the points about the centre [mm]
    cov : (3, 3) covariance of (cx, cy, R) from the residual scatter (LSCI only) else None
    n_iter : iterations used (MICI: number of candidate centres, the Voronoi vertices that are
        local maxima of the inscribed radius inside the profile)
    """

    center_xy_mm: np.ndarray
    radius_mm: float
    method: str
    ront_mm: float
    rms_mm: float
    zone_mm: tuple[float, float]
    cov: np.ndarray | None = None
    n_iter: int = 0

    @property
    def diameter_mm(self) -> float:
        """Diameter [mm], twice the radius."""
        return 2.0 * self.radius_mm

    @property
    def u_diameter_mm(self) -> float:
        """Standard uncertainty of the diameter from the residual scatter (LSCI), else NaN."""
        return float(2.0 * np.sqrt(self.cov[2, 2])) if self.cov is not None else float("nan")


def _prep(x_mm, y_mm, min_points: int = 3) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    x = np.asarray(x_mm, dtype=float).ravel()
    y = np.asarray(y_mm, dtype=float).ravel()
    if x.shape != y.shape:
        raise CircleFitError(f"x and y differ in length ({x.size} vs {y.size})")
    ok = np.isfinite(x) & np.isfinite(y)
    x, y = x[ok], y[ok]
    if x.size < min_points:
        raise CircleFitError(f"need at least {min_points} finite points, got {x.size}")
    shift = np.array([x.mean(), y.mean()])
    return x - shift[0], y - shift[1], shift


def _make(method: str, xc, yc, shift, center, radius, cov=None, n_iter=0) -> Circle:
    d = np.hypot(xc - center[0], yc - center[1])
    return Circle(
        center_xy_mm=np.asarray(center, dtype=float) + shift,
        radius_mm=float(radius),
        method=method,
        ront_mm=float(d.max() - d.min()),
        rms_mm=float(np.sqrt(np.mean((d - radius) ** 2))),
        zone_mm=(float(d.min()), float(d.max())),
        cov=cov,
        n_iter=n_iter,
    )


def _kasa(x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, float]:
    """Algebraic (Kasa) circle: x^2 + y^2 + D x + E y + F = 0 in least squares."""
    A = np.column_stack([x, y, np.ones_like(x)])
    b = -(x * x + y * y)
    (D, E, F), _, rank, sv = np.linalg.lstsq(A, b, rcond=None)
    if rank < 3 or sv[-1] < 1e-12 * sv[0]:
        raise CircleFitError("points are collinear: no algebraic circle")
    c = np.array([-D / 2.0, -E / 2.0])
    r2 = c @ c - F
    if not np.isfinite(r2) or r2 <= 0:
        raise CircleFitError("points are collinear: no algebraic circle")
    return c, float(np.sqrt(r2))


def fit_circle_kasa(x_mm, y_mm) -> Circle:
    """Algebraic Kasa circle (the start value of :func:`fit_circle_ls`)."""
    x, y, shift = _prep(x_mm, y_mm)
    c, r = _kasa(x, y)
    return _make("KASA", x, y, shift, c, r)


def fit_circle_ls(x_mm, y_mm, *, max_iter: int = 200) -> Circle:
    """Geometric least-squares circle (ISO 12181 LSCI; NIST Algorithm Testing System definition).

    Minimises sum_i (|p_i - c| - R)^2 by Gauss-Newton (QR solve) with Levenberg damping when a
    step fails to descend; start from the Kasa algebraic circle. Coordinates centred first.

    Parameters
    ----------
    x_mm, y_mm : array_like (n,), n >= 3 [mm]; non-finite points are dropped.

    Returns
    -------
    Circle with ``cov`` = s^2 (J^T J)^-1 for (cx, cy, R), s^2 = RSS / (n - 3) (NaN when n = 3).
    """
    x, y, shift = _prep(x_mm, y_mm)
    c, r = _kasa(x, y)
    p = np.array([c[0], c[1], r])

    def resid_jac(p):
        dx, dy = x - p[0], y - p[1]
        d = np.hypot(dx, dy)
        J = np.column_stack([-dx / d, -dy / d, -np.ones_like(d)])
        return d - p[2], J

    e, J = resid_jac(p)
    f = e @ e
    lam = 0.0
    it = 0
    for it in range(1, max_iter + 1):  # noqa: B007 (it, the iterations done, is returned)
        if lam == 0.0:
            step, *_ = np.linalg.lstsq(J, -e, rcond=None)
        else:
            A = J.T @ J
            step = np.linalg.solve(A + lam * np.diag(np.diag(A)), -J.T @ e)
        p_new = p + step
        e_new, J_new = resid_jac(p_new)
        f_new = e_new @ e_new
        if f_new <= f * (1 + 1e-15) or np.max(np.abs(step)) < 1e-14 * max(1.0, abs(p[2])):
            small = np.max(np.abs(step)) <= 1e-13 * max(1.0, abs(p[2])) + 1e-300
            p, e, J, f = p_new, e_new, J_new, f_new
            lam = 0.0 if lam < 1e-6 else lam / 10.0
            if small:
                break
        else:
            lam = 1e-3 if lam == 0.0 else lam * 10.0
            if lam > 1e12:
                break
    n = x.size
    cov = None
    if n > 3:
        s2 = f / (n - 3)
        cov = s2 * np.linalg.inv(J.T @ J)
    else:
        cov = np.full((3, 3), np.nan)
    return _make("LSCI", x, y, shift, p[:2], abs(p[2]), cov, it)


# --------------------------------------------------------------------------- closed profile


def _angular_order(x: np.ndarray, y: np.ndarray, c) -> tuple[np.ndarray, np.ndarray, float]:
    """Return the points' angular order about ``c``, their angles and the largest gap.

    Return indices of the points in increasing angle about ``c``, those angles [rad] and the
    largest gap between angularly consecutive points (the wrap-around gap included) [deg].
    """
    th = np.arctan2(y - c[1], x - c[0])
    order = np.argsort(th, kind="stable")
    ths = th[order]
    gaps = np.diff(np.concatenate([ths, ths[:1] + 2.0 * np.pi]))
    return order, ths, float(np.degrees(gaps.max()))


def largest_gap_deg(x_mm, y_mm, center_xy_mm=None) -> float:
    """Largest angular gap between consecutive profile points seen from a centre [deg].

    Parameters
    ----------
    x_mm, y_mm : array_like (n,) [mm]; non-finite points are dropped.
    center_xy_mm : (2,) [mm]; default the least-squares centre.

    Returns
    -------
    The gap [deg], 0 < gap <= 360: <= :data:`CLOSED_MAX_GAP_DEG` for a closed profile.
    """
    x, y, shift = _prep(x_mm, y_mm)
    c = _ls_center(x, y, shift, center_xy_mm)
    return _angular_order(x, y, c)[2]


def _ls_center(x: np.ndarray, y: np.ndarray, shift: np.ndarray, ls_center_xy_mm) -> np.ndarray:
    """Return the least-squares centre in the shifted frame (fitted unless the caller has it)."""
    if ls_center_xy_mm is None:
        return fit_circle_ls(x, y).center_xy_mm
    return np.asarray(ls_center_xy_mm, dtype=float) - shift


def _check_closed(x, y, c, max_gap_deg: float, method: str) -> tuple[np.ndarray, np.ndarray]:
    """Return the angular order about ``c``, or raise when the profile is not closed.

    Angular order about ``c`` (see :func:`_angular_order`), or CircleFitError when the
    largest gap exceeds ``max_gap_deg``.
    """
    order, ths, gap = _angular_order(x, y, c)
    if not gap <= max_gap_deg:
        raise CircleFitError(
            f"{method}: profile is not closed (largest gap {gap:.1f} deg) around its least-squares "
            f"centre; a closed profile has no gap larger than {max_gap_deg:g} deg ({x.size} points)"
        )
    return order, ths


@dataclass(frozen=True)
class _ClosedProfile:
    """A closed profile prepared once for the reference circles.

    Finite points shifted to their mean, the least-squares centre in that frame, the points'
    distances from it and their angular order about it (checked closed): what MZCI, MICI and MCCI
    start from, prepared once for all three by :func:`reference_circles`.
    """

    x: np.ndarray
    y: np.ndarray
    shift: np.ndarray
    c: np.ndarray
    r: np.ndarray
    order: np.ndarray
    ths: np.ndarray


def _closed_profile(
    x_mm, y_mm, ls_center_xy_mm, max_gap_deg: float, method: str, min_points: int = 3
) -> _ClosedProfile:
    x, y, shift = _prep(x_mm, y_mm, min_points=min_points)
    c = _ls_center(x, y, shift, ls_center_xy_mm)
    order, ths = _check_closed(x, y, c, max_gap_deg, method)
    return _ClosedProfile(x, y, shift, c, np.hypot(x - c[0], y - c[1]), order, ths)


# --------------------------------------------------------------------------- MCCI (Welzl)


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
    return _mcci(_closed_profile(x_mm, y_mm, ls_center_xy_mm, max_gap_deg, "MCCI"), seed)


#: MCCI of a long profile: first the circle of this many points farthest from the LS centre
MCCI_FARTHEST = 2048


def _mcci(prof: _ClosedProfile, seed: int = 0) -> Circle:
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
    return _make("MCCI", x, y, shift, c, r)


# --------------------------------------------------------------------------- MZCI (SLP)


def _slp(x, y, c0, max_iter: int = 100) -> tuple[np.ndarray, int]:
    """Sequential LP with a trust region for the minimum zone centre.

    Minimise (s - t) subject to t <= |p_i - c| <= s, linearised about c:
    |p_i - c - dc| ~= d_i - n_i . dc.
    """
    scale = float(np.max(np.hypot(x, y)))
    c = np.array(c0, dtype=float)
    delta = 0.05 * scale

    def objective(c):
        d = np.hypot(x - c[0], y - c[1])
        return d.max() - d.min()

    f = objective(c)
    it = 0
    opts = {"primal_feasibility_tolerance": 1e-10, "dual_feasibility_tolerance": 1e-10}
    for it in range(1, max_iter + 1):  # noqa: B007 (it, the iterations done, is returned)
        dx, dy = x - c[0], y - c[1]
        d = np.hypot(dx, dy)
        nx, ny = dx / d, dy / d
        # work in units of the current zone width about the mean radius so that the LP
        # tolerances (~1e-7 relative) act on the form deviations, not on the radius
        w = max(float(d.max() - d.min()), 1e-12 * scale)
        b = (d - d.mean()) / w
        lim = delta / w
        res = _lp_step(nx, ny, b, lim, opts)
        if res.status != 0:
            raise CircleFitError(f"MZCI: linear program failed: {res.message}")
        step = res.x[:2] * w
        c_new = c + step
        f_new = objective(c_new)
        if f_new <= f + 1e-15 * scale:
            c, f = c_new, f_new
            if np.hypot(*step) < 1e-13 * scale:
                break
            if np.hypot(*step) > 0.5 * delta:
                delta *= 2.0
        else:
            delta *= 0.25
            if delta < 1e-15 * scale:
                break
    return c, it


def _lp_step(nx: np.ndarray, ny: np.ndarray, b: np.ndarray, lim: float, opts: dict, n_seed: int = 128):
    """One linearised minimum zone LP of :func:`_slp`, solved by constraint generation.

    The LP on all points equals the LP on the points whose constraints are active; start from
    the ``n_seed`` most extreme points on either side, solve, add every point whose constraint
    the solution violates, and repeat until none does (then the subset solution is optimal for
    all points: exact, not an approximation). A scan of 10^5 points needs a few LPs of a few
    hundred rows.
    """
    n = b.size
    order = np.argsort(b)
    active = np.unique(np.concatenate([order[:n_seed], order[-n_seed:]]))
    tol = 1e-9
    while True:
        ax, ay, ab = nx[active], ny[active], b[active]
        m = active.size
        # variables (dcx, dcy, t, s); minimise s - t
        A1 = np.column_stack([-ax, -ay, np.zeros(m), -np.ones(m)])  # d - n.dc <= s
        A2 = np.column_stack([ax, ay, np.ones(m), np.zeros(m)])  # t <= d - n.dc
        res = linprog(
            [0, 0, -1.0, 1.0],
            A_ub=np.vstack([A1, A2]),
            b_ub=np.concatenate([-ab, ab]),
            bounds=[(-lim, lim)] * 2 + [(None, None)] * 2,
            method="highs",
            options=opts,
        )
        if res.status != 0 or active.size == n:
            return res
        lin = b - nx * res.x[0] - ny * res.x[1]  # linearised distance of every point
        viol = (lin < res.x[2] - tol) | (lin > res.x[3] + tol)
        viol[active] = False
        if not viol.any():
            return res
        add = np.flatnonzero(viol)
        if add.size > 4 * n_seed:  # keep the LPs small: the worst violators first
            worst = np.abs(lin[add] - np.median(lin))
            add = add[np.argsort(-worst)[: 4 * n_seed]]
        active = np.union1d(active, add)


def _polish(  # noqa: C901 (the active-set Newton iteration with its exits)
    x, y, c, kind: str
) -> np.ndarray:
    """Solve the active-set equations exactly (Newton) from a vertex.

    MICI: three nearest points equidistant; with more than three (cocircular points, e.g. a
    perfect circle) the three most spread of them (a triangle of largest area, so that the
    circumcentre is well conditioned). MZCI: two inner + two outer, or 3 + 1, with equal inner
    distances and equal outer distances (2 equations, 2 unknowns).
    """
    d = np.hypot(x - c[0], y - c[1])
    scale = float(d.max())
    tol = 1e-7 * scale
    if kind == "MICI":
        act = np.flatnonzero(d <= d.min() + tol)
        if act.size < 3:
            return c
        if act.size > 3:
            a = act[0]
            b = act[np.argmax(np.hypot(x[act] - x[a], y[act] - y[a]))]
            area = np.abs((x[b] - x[a]) * (y[act] - y[a]) - (y[b] - y[a]) * (x[act] - x[a]))
            act = np.array([a, b, act[np.argmax(area)]])
        groups = [act]
    else:
        inner = np.flatnonzero(d <= d.min() + tol)
        outer = np.flatnonzero(d >= d.max() - tol)
        if inner.size + outer.size != 4 or inner.size < 1 or outer.size < 1:
            return c
        groups = [g for g in (inner, outer) if g.size >= 2]
    best = c.copy()
    cc = c.copy()
    for _ in range(20):
        F, J = [], []
        for g in groups:
            for k in g[1:]:
                i = g[0]
                # |p_k - c|^2 - |p_i - c|^2 = 0 is linear in c: 2 (p_i - p_k).c + |p_k|^2 - |p_i|^2
                F.append(
                    (x[k] - cc[0]) ** 2 + (y[k] - cc[1]) ** 2 - (x[i] - cc[0]) ** 2 - (y[i] - cc[1]) ** 2
                )
                J.append([2 * (x[i] - x[k]), 2 * (y[i] - y[k])])
        F, J = np.array(F), np.array(J)
        if F.size != 2:
            return c
        try:
            step = np.linalg.solve(J, -F)
        except np.linalg.LinAlgError:
            return c
        cc = cc + step
        if np.hypot(*step) < 1e-15 * scale:
            break

    # accept only if it does not worsen the objective (guards a wrong active set)
    def obj(cv):
        dv = np.hypot(x - cv[0], y - cv[1])
        return -dv.min() if kind == "MICI" else dv.max() - dv.min()

    return cc if obj(cc) <= obj(best) + 1e-15 * scale and np.hypot(*(cc - best)) < tol else best


# --------------------------------------------------------------------------- MICI (Voronoi)


def _local_max_vertices(P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Return the Voronoi vertices that can be local maxima of the distance to the points.

    Voronoi vertices of the points ``P`` (n, 2) that can be local maxima of
    f(c) = min_i |p_i - c|: circumcentres (m, 2) of the Delaunay triangles with no obtuse angle,
    and their circumradii (m,) (>= f there, = f up to rounding: the circle is empty).

    A Voronoi vertex is the centre of an empty circle through the 3 corners of its Delaunay
    triangle; f has a local maximum there exactly when the centre lies in the (closed)
    triangle, i.e. the triangle has no obtuse angle (a right angle puts it on the hypotenuse,
    as for diametrically opposite points). Across the longest side of an obtuse triangle f
    keeps rising along the Voronoi edge, so such a vertex is never the maximum. The angle test
    allows cos >= -1e-9 for rounding. The circumcentre is computed from the triangle's own
    corners (relative to one of them), not taken from Qhull.

    Qhull triangulates joggled input ("QJ", coordinates moved by ~1e-11 of their size): exactly
    cocircular points (a simulated perfect circle) otherwise cost it O(n^2) time (20000 points:
    about 30 s instead of 0.1 s). The triangles are then Delaunay for the original points except
    where 4 or more are cocircular to within the joggle, where any choice gives the same vertex
    to that accuracy; all geometry here uses the original coordinates.
    """
    if P.shape[0] == 3:  # Qhull needs 4 points
        return _circumcentres_non_obtuse(P, np.array([[0, 1, 2]]))
    try:
        tri = Delaunay(P, qhull_options="Qbb Q12 QJ").simplices
    except QhullError as exc:
        raise CircleFitError(f"MICI: no Delaunay triangulation of the {P.shape[0]} points: {exc}") from exc
    return _circumcentres_non_obtuse(P, tri)


def _circumcentres_non_obtuse(P: np.ndarray, tri: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Return circumcentres and circumradii of the triangles with no obtuse angle.

    Circumcentres (m, 2) and circumradii (m,) of the triangles ``P[tri]`` with no obtuse
    angle (cos >= -1e-9 allowed for rounding), computed relative to a corner.
    """
    a = P[tri[:, 0]]
    b = P[tri[:, 1]] - a
    c = P[tri[:, 2]] - a
    bc = c - b
    b2, c2, bc2 = np.einsum("ij,ij->i", b, b), np.einsum("ij,ij->i", c, c), np.einsum("ij,ij->i", bc, bc)
    eps = 1e-9
    ok = (
        (np.einsum("ij,ij->i", b, c) >= -eps * np.sqrt(b2 * c2))  # angle at a
        & (-np.einsum("ij,ij->i", b, bc) >= -eps * np.sqrt(b2 * bc2))  # angle at b
        & (np.einsum("ij,ij->i", c, bc) >= -eps * np.sqrt(c2 * bc2))  # angle at c
    )
    a, b, c, b2, c2 = a[ok], b[ok], c[ok], b2[ok], c2[ok]
    d = 2.0 * (b[:, 0] * c[:, 1] - b[:, 1] * c[:, 0])
    with np.errstate(divide="ignore", invalid="ignore"):
        u = np.column_stack([c[:, 1] * b2 - b[:, 1] * c2, b[:, 0] * c2 - c[:, 0] * b2]) / d[:, None]
    cc = a + u
    fin = np.all(np.isfinite(cc), axis=1)
    return cc[fin], np.hypot(u[fin, 0], u[fin, 1])


def _best_empty_centre(cand: np.ndarray, bound: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Return the candidate centre with the largest empty circle.

    Return the candidate centre (m, 2) with the largest f(c) = min_i |p_i - c|, f evaluated exactly
    (distances to all points; near a ring's centre every point is about as far, so a tree search
    would visit them all anyway), in order of decreasing upper bound ``bound`` >= f, stopping
    once no remaining bound can beat the best f found.
    """
    order = np.argsort(-bound, kind="stable")
    slack = 1e-12 * float(np.max(np.abs(bound)))  # rounding of the bounds
    step = max(1, (1 << 22) // max(x.size, 1))
    best, best_c = -np.inf, cand[order[0]]
    for i in range(0, order.size, step):
        idx = order[i : i + step]
        if bound[idx[0]] + slack < best:
            break
        q = cand[idx]
        f = np.sqrt(np.min((q[:, :1] - x) ** 2 + (q[:, 1:] - y) ** 2, axis=1))
        j = int(np.argmax(f))
        if f[j] > best:
            best, best_c = float(f[j]), q[j]
    return best_c


def _inside_star_polygon(q: np.ndarray, V: np.ndarray, th: np.ndarray, c) -> np.ndarray:
    """Return which points lie strictly inside a star-shaped polygon.

    Which points ``q`` (m, 2) lie strictly inside the polygon ``V`` (n, 2), whose vertices
    are in increasing angle ``th`` [rad] about ``c`` with every gap < 180 deg (star-shaped
    about c): q is inside when it lies on c's side of the edge spanning its own angle.
    """
    n = V.shape[0]
    phi = np.arctan2(q[:, 1] - c[1], q[:, 0] - c[0])
    k = np.searchsorted(th, phi, side="right") - 1  # -1: the wrap-around edge V[n-1] -> V[0]
    a, b = V[k % n], V[(k + 1) % n]
    cross = (b[:, 0] - a[:, 0]) * (q[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (q[:, 0] - a[:, 0])
    return cross > 0.0


def _bin_segments(ths: np.ndarray, bins: int) -> tuple[np.ndarray, np.ndarray]:
    """Return the non-empty angular bins as runs of a profile's angular order.

    Return the non-empty ones of ``bins`` equal angular bins over [-pi, pi) as runs of a profile's
    angular order: start positions and lengths along ``ths`` (increasing angles [rad]).
    """
    b = np.minimum(((ths + np.pi) / (2 * np.pi) * bins).astype(np.int64), bins - 1)  # non-decreasing
    starts = np.flatnonzero(np.r_[True, b[1:] != b[:-1]])
    return starts, np.diff(np.r_[starts, b.size])


#: Angular bins of the reduced point set the MICI triangulates first (see :func:`_mic_centre`).
MIC_BINS = 2048


def _mic_centre(
    P: np.ndarray, order: np.ndarray, ths: np.ndarray, c0, d0: np.ndarray
) -> tuple[np.ndarray, int]:
    """Return the centre of the largest empty circle in the profile polygon.

    Return the centre of the largest empty circle centred in the profile polygon, and the number of
    candidate vertices examined (:func:`max_inscribed_circle`), computed on a reduced point set
    with a certificate that the answer is the one of all points.

    ``d0`` (n,): the points' distances from ``c0`` [mm].

    S = the point of smallest radius about ``c0`` in each of :data:`MIC_BINS` angular bins (the
    inner envelope that bounds an inscribed circle). With f_S(c) = min over S of |p - c| >= f(c),
    let c_S be the best Voronoi vertex of S inside the polygon (the full profile's). If no point
    of P lies closer to c_S than f_S(c_S), then f(c_S) = f_S(c_S) = max f_S >= max f, so c_S is the
    global maximum of f, exactly as with every point triangulated. That needs max f_S over the
    polygon to be at an S vertex, not on the polygon's boundary: on an edge (p, q) f_S is at most
    |edge| / 2 + |p - s(p)| (s(p) the kept point of p's bin), checked against f_S(c_S). Points
    closer than f_S(c_S) are added to S and the search repeats; a profile with fewer points than
    bins, or one where the checks keep failing, is triangulated whole.
    """
    n = P.shape[0]
    if n > 4 * MIC_BINS:
        starts, counts = _bin_segments(ths, MIC_BINS)
        ds = d0[order]
        inner = np.flatnonzero(ds == np.repeat(np.minimum.reduceat(ds, starts), counts))
        seg = np.searchsorted(starts, inner, side="right") - 1
        first = inner[np.r_[True, seg[1:] != seg[:-1]]]  # sorted position of each bin's innermost point
        keep = np.zeros(n, dtype=bool)
        keep[order[first]] = True
        V = P[order]
        near_sorted = np.hypot(*(V - P[np.repeat(order[first], counts)]).T)  # |p - s(p)|, angular order
        edge = np.hypot(*(np.roll(V, -1, axis=0) - V).T)
        boundary_bound = float(np.max(0.5 * edge + np.maximum(near_sorted, np.roll(near_sorted, -1))))
        for _ in range(8):
            S = P[keep]
            cand, bound = _local_max_vertices(S)
            inside = _inside_star_polygon(cand, V, ths, c0)
            cand, bound = cand[inside], bound[inside]
            if cand.shape[0] == 0:
                break
            c_s = _best_empty_centre(cand, bound, S[:, 0], S[:, 1])
            f_s = float(np.min(np.hypot(S[:, 0] - c_s[0], S[:, 1] - c_s[1])))
            d_all = np.hypot(P[:, 0] - c_s[0], P[:, 1] - c_s[1])
            closer = (d_all < f_s) & ~keep
            if not closer.any() and f_s > boundary_bound:
                return c_s, int(cand.shape[0])
            if not closer.any():
                break  # the boundary check failed: triangulate every point
            keep |= closer
    cand, bound = _local_max_vertices(P)
    inside = _inside_star_polygon(cand, P[order], ths, c0)
    cand, bound = cand[inside], bound[inside]
    if cand.shape[0] == 0:
        raise CircleFitError(f"MICI: no Voronoi vertex of the {n} points lies inside the profile")
    return _best_empty_centre(cand, bound, P[:, 0], P[:, 1]), int(cand.shape[0])


def max_inscribed_circle(
    x_mm, y_mm, ls_center_xy_mm=None, *, max_gap_deg: float = CLOSED_MAX_GAP_DEG
) -> Circle:
    """Maximum inscribed circle (ISO 12181 MICI) of a closed profile: the global maximum.

    The largest circle whose centre lies inside the profile polygon (the points joined in
    angular order about the least-squares centre) and that contains no profile point:
    max over c in the polygon of f(c) = min_i |p_i - c|. Inside the polygon f has its maxima at
    vertices of the Voronoi diagram of the points, i.e. circumcentres of the Delaunay triangles
    (circles through 3 points, empty of points), and only at those whose triangle contains its
    circumcentre (no obtuse angle). Every such vertex inside the polygon is a candidate; f is
    evaluated exactly (distances to all points) in order of decreasing circumradius (an upper
    bound of f) until no candidate left can beat the best, which is polished exactly (3-point
    circumcentre). f may have many local maxima; this is the largest, not the one nearest a
    start.

    Parameters
    ----------
    x_mm, y_mm : array_like (n,), n >= 3 [mm]; non-finite points are dropped.
    ls_center_xy_mm : (2,) least-squares centre [mm] when the caller has it (else fitted): the
        closed-profile check and the angular order of the polygon are taken about it.
    max_gap_deg : largest angular gap of a closed profile [deg] (:data:`CLOSED_MAX_GAP_DEG`).

    Returns
    -------
    Circle with ``n_iter`` = the number of candidate centres (Voronoi vertices inside the
    polygon that are local maxima of f).

    Raises
    ------
    CircleFitError
        "profile is not closed (largest gap X deg)" for an open arc; "profile too sparse" (Notes).

    Notes
    -----
    On the polygon's edges f is at most half the edge length (the distance to the nearer
    end); a maximum there instead of at a Voronoi vertex needs points so sparse that an edge
    is longer than the inscribed diameter, which a closed profile (gaps <= 150 deg about the
    centre, radius varying by much less than R) does not have; such a profile raises
    CircleFitError "profile too sparse".
    """
    return _mici(_closed_profile(x_mm, y_mm, ls_center_xy_mm, max_gap_deg, "MICI"))


def _mici(prof: _ClosedProfile) -> Circle:
    x, y, shift, c0, order, ths = prof.x, prof.y, prof.shift, prof.c, prof.order, prof.ths
    P = np.column_stack([x, y])
    c_best, n_cand = _mic_centre(P, order, ths, c0, prof.r)
    c = _polish(x, y, c_best, "MICI")
    r = float(np.min(np.hypot(x - c[0], y - c[1])))
    V = P[order]
    edge_mm = float(np.max(np.hypot(*(np.roll(V, -1, axis=0) - V).T)))
    if edge_mm > 2.0 * r:  # see Notes: f on that edge could exceed r
        raise CircleFitError(
            f"MICI: profile too sparse: an edge of the profile polygon ({edge_mm:.6g} mm) is longer than "
            f"the inscribed diameter found ({2.0 * r:.6g} mm), the circle could be centred on that edge"
        )
    return _make("MICI", x, y, shift, c, r, n_iter=n_cand)


def min_zone_circle(x_mm, y_mm, ls_center_xy_mm=None, *, max_gap_deg: float = CLOSED_MAX_GAP_DEG) -> Circle:
    """Minimum zone circles (ISO 12181 MZCI): concentric pair of least radial separation.

    Sequential LP from the least-squares centre, then the exact active-set polish.

    Parameters
    ----------
    x_mm, y_mm : array_like (n,), n >= 4 [mm]; non-finite points are dropped.
    ls_center_xy_mm : (2,) least-squares centre [mm] when the caller has it (else fitted): the
        start, and the centre of the closed-profile check.
    max_gap_deg : largest angular gap of a closed profile [deg] (:data:`CLOSED_MAX_GAP_DEG`).

    Returns
    -------
    Circle with the common centre, radius = mean of the inner and outer zone radii and
    ``ront_mm`` = the zone width (the smallest RONt of any centre).

    Raises
    ------
    CircleFitError
        "profile is not closed (largest gap X deg)" for an open arc.
    """
    return _mzci(_closed_profile(x_mm, y_mm, ls_center_xy_mm, max_gap_deg, "MZCI", min_points=4))


#: Angular bins of the reduced point set the MZCI's sequential LP runs on first (see :func:`_mzci`).
MZ_BINS = 2048


def _mz_centre(prof: _ClosedProfile) -> tuple[np.ndarray, int]:
    """Return the minimum zone centre of a profile.

    Return the minimum zone centre of a profile by :func:`_slp`, run on a reduced point set with a
    certificate that the answer is the one of all points.

    S = the innermost and the outermost point about the LS centre in each of :data:`MZ_BINS`
    angular bins. The zone width of S at any centre is at most that of all points, so a centre
    c_S where S's width is least and every point lies within S's zone (between its inner and
    outer circle) has the least width of all points too: it is their minimum zone centre, as the
    LP on every point would find. Points outside that zone are added to S and the LP repeats; a
    profile with fewer points than 4 x MZ_BINS, or where the check keeps failing, is solved whole.
    """
    x, y = prof.x, prof.y
    n = x.size
    if n > 4 * MZ_BINS:
        starts, counts = _bin_segments(prof.ths, MZ_BINS)
        ds = prof.r[prof.order]
        ext = (ds == np.repeat(np.minimum.reduceat(ds, starts), counts)) | (
            ds == np.repeat(np.maximum.reduceat(ds, starts), counts)
        )
        keep = np.zeros(n, dtype=bool)
        keep[prof.order[ext]] = True
        tol = 1e-12 * float(prof.r.max())  # rounding of the distances, far below any zone width
        for _ in range(8):
            c, it = _slp(x[keep], y[keep], prof.c)
            da = np.hypot(x - c[0], y - c[1])
            dk = da[keep]
            outside = (da < dk.min() - tol) | (da > dk.max() + tol)
            if not outside.any():
                return c, it
            keep |= outside
    return _slp(x, y, prof.c)


def _mzci(prof: _ClosedProfile) -> Circle:
    x, y, shift = prof.x, prof.y, prof.shift
    c, it = _mz_centre(prof)
    c = _polish(x, y, c, "MZCI")
    d = np.hypot(x - c[0], y - c[1])
    return _make("MZCI", x, y, shift, c, 0.5 * (d.min() + d.max()), n_iter=it)


def roundness(x_mm, y_mm, center_xy_mm) -> float:
    """RONt about a given centre: max_i |p_i - c| - min_i |p_i - c| [mm] (ISO 12181-1)."""
    x = np.asarray(x_mm, dtype=float)
    y = np.asarray(y_mm, dtype=float)
    d = np.hypot(x - center_xy_mm[0], y - center_xy_mm[1])
    return float(np.nanmax(d) - np.nanmin(d))


def reference_circles(x_mm, y_mm, *, max_gap_deg: float = CLOSED_MAX_GAP_DEG) -> dict[str, Circle]:
    """All four ISO 12181 reference circles: {"LSCI", "MZCI", "MICI", "MCCI"}.

    Raises CircleFitError "profile is not closed (largest gap X deg)" when the largest angular
    gap about the least-squares centre exceeds ``max_gap_deg`` [deg].
    """
    ls = fit_circle_ls(x_mm, y_mm)
    # one preparation (finite points, shift, closed-profile check and angular order about the LS
    # centre) for all three: the same as each function's own, checked as min_zone_circle would
    prof = _closed_profile(x_mm, y_mm, ls.center_xy_mm, max_gap_deg, "MZCI", min_points=4)
    return {"LSCI": ls, "MZCI": _mzci(prof), "MICI": _mici(prof), "MCCI": _mcci(prof)}


def _fourier_lsq(th: np.ndarray, r: np.ndarray, K: int) -> np.ndarray:
    """Coefficients [a_0, a_1..a_K, b_1..b_K] of the least-squares Fourier series of r(theta).

    The normal equations are assembled from the power sums P_m = sum_i exp(i m theta_i),
    m = 0..2K, and Q_k = sum_i r_i exp(i k theta_i) (cos j cos k = (cos(j-k) + cos(j+k)) / 2 and
    alike), so the work is O(n K) with no n x (2K + 1) design matrix. The (2K + 1)-square
    system is solved by SVD; when it is ill-conditioned (cond > 1e8, e.g. angles bunched in a
    short arc) the design matrix is solved directly instead, as the normal equations would
    square its condition number.
    """
    r0 = float(np.median(r))
    dr = r - r0
    z = np.exp(1j * th)
    P = np.empty(2 * K + 1, dtype=complex)
    Q = np.empty(K + 1, dtype=complex)
    w = np.ones_like(z)
    for m in range(2 * K + 1):
        P[m] = w.sum()
        if m <= K:
            Q[m] = (dr * w).sum()
        w *= z
    k = np.arange(1, K + 1)
    jm, km = np.meshgrid(k, k, indexing="ij")
    Pdiff = P[np.abs(jm - km)]
    Pdiff_im = np.sign(jm - km) * Pdiff.imag  # Im P_{j-k} with P_{-m} = conj(P_m)
    Psum = P[jm + km]
    N = np.empty((2 * K + 1, 2 * K + 1))
    N[0, 0] = P[0].real
    N[0, 1 : K + 1] = N[1 : K + 1, 0] = P[1 : K + 1].real
    N[0, K + 1 :] = N[K + 1 :, 0] = P[1 : K + 1].imag
    N[1 : K + 1, 1 : K + 1] = 0.5 * (Pdiff.real + Psum.real)  # cos j cos k
    N[K + 1 :, K + 1 :] = 0.5 * (Pdiff.real - Psum.real)  # sin j sin k
    N[1 : K + 1, K + 1 :] = 0.5 * (Psum.imag - Pdiff_im)  # cos j sin k
    N[K + 1 :, 1 : K + 1] = N[1 : K + 1, K + 1 :].T
    rhs = np.concatenate([[Q[0].real], Q[1:].real, Q[1:].imag])
    if np.linalg.cond(N) > 1e8:
        A = np.column_stack([np.ones_like(th), np.cos(np.outer(th, k)), np.sin(np.outer(th, k))])
        coef, *_ = np.linalg.lstsq(A, dr, rcond=None)
    else:
        coef = np.linalg.solve(N, rhs)
    coef[0] += r0
    return coef


def harmonic_spectrum(
    theta_rad, r_mm, max_upr: int | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Amplitude per undulations per revolution (UPR) of a radial profile r(theta).

    Least-squares fit r = a_0 + sum_k a_k cos(k theta) + b_k sin(k theta), k = 1..K; for
    uniform sampling this equals the DFT amplitudes 2|R_k|/n.

    Parameters
    ----------
    theta_rad, r_mm : array_like (n,) polar angle [rad] and radius [mm]
    max_upr : highest UPR K (default min(50, (n - 1) // 2))

    Returns
    -------
    upr : ndarray (K + 1,) 0..K; amplitude_mm : ndarray (K + 1,) (amplitude_mm[0] = mean radius);
    phase_rad : ndarray (K + 1,) so that the term is amplitude cos(k theta - phase)
    """
    th = np.asarray(theta_rad, dtype=float).ravel()
    r = np.asarray(r_mm, dtype=float).ravel()
    ok = np.isfinite(th) & np.isfinite(r)
    th, r = th[ok], r[ok]
    K = min(50, (th.size - 1) // 2) if max_upr is None else int(max_upr)
    if 2 * K + 1 > th.size:
        raise CircleFitError(f"max_upr={K} needs at least {2 * K + 1} points, got {th.size}")
    coef = _fourier_lsq(th, r, K)
    a, b = coef[1 : K + 1], coef[K + 1 :]
    amp = np.concatenate([[coef[0]], np.hypot(a, b)])
    phase = np.concatenate([[0.0], np.arctan2(b, a)])
    return np.arange(K + 1), amp, phase
