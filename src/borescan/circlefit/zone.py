"""The minimum zone circle (MZCI, ISO 12181) and the exact active-set polish it shares with the MICI.

Sequential linear programming (exact gradients, trust region) on min_c (max_i |p_i - c| - min_i |p_i - c|),
converged to a vertex, then polished by solving the active-set equations exactly (Newton).
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import linprog

from borescan.circlefit.lsq import (
    CLOSED_MAX_GAP_DEG,
    Circle,
    CircleFitError,
    ClosedProfile,
    bin_segments,
    closed_profile,
    make_circle,
)

__all__ = ["min_zone_circle", "mzci_of", "polish_active_set", "MZ_BINS"]


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


def polish_active_set(  # noqa: C901 (the active-set Newton iteration with its exits)
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
    return mzci_of(closed_profile(x_mm, y_mm, ls_center_xy_mm, max_gap_deg, "MZCI", min_points=4))


#: Angular bins of the reduced point set the MZCI's sequential LP runs on first (see :func:`_mzci`).
MZ_BINS = 2048


def _mz_centre(prof: ClosedProfile) -> tuple[np.ndarray, int]:
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
        starts, counts = bin_segments(prof.ths, MZ_BINS)
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


def mzci_of(prof: ClosedProfile) -> Circle:
    """Return the MZCI of a prepared closed profile (:func:`min_zone_circle`)."""
    x, y, shift = prof.x, prof.y, prof.shift
    c, it = _mz_centre(prof)
    c = polish_active_set(x, y, c, "MZCI")
    d = np.hypot(x - c[0], y - c[1])
    return make_circle("MZCI", x, y, shift, c, 0.5 * (d.min() + d.max()), n_iter=it)
