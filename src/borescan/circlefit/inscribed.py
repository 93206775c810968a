"""The maximum inscribed circle (MICI, ISO 12181).

The global maximum of min_i |p_i - c| over centres c inside the closed profile polygon: the best Voronoi
vertex of the points (a Delaunay circumcentre) inside the polygon, then the exact 3-point polish.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import Delaunay, QhullError

from borescan.circlefit.lsq import (
    CLOSED_MAX_GAP_DEG,
    Circle,
    CircleFitError,
    ClosedProfile,
    bin_segments,
    closed_profile,
    make_circle,
)
from borescan.circlefit.zone import polish_active_set

__all__ = ["max_inscribed_circle", "mici_of", "MIC_BINS"]


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
        starts, counts = bin_segments(ths, MIC_BINS)
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
    return mici_of(closed_profile(x_mm, y_mm, ls_center_xy_mm, max_gap_deg, "MICI"))


def mici_of(prof: ClosedProfile) -> Circle:
    """Return the MICI of a prepared closed profile (:func:`max_inscribed_circle`)."""
    x, y, shift, c0, order, ths = prof.x, prof.y, prof.shift, prof.c, prof.order, prof.ths
    P = np.column_stack([x, y])
    c_best, n_cand = _mic_centre(P, order, ths, c0, prof.r)
    c = polish_active_set(x, y, c_best, "MICI")
    r = float(np.min(np.hypot(x - c[0], y - c[1])))
    V = P[order]
    edge_mm = float(np.max(np.hypot(*(np.roll(V, -1, axis=0) - V).T)))
    if edge_mm > 2.0 * r:  # see Notes: f on that edge could exceed r
        raise CircleFitError(
            f"MICI: profile too sparse: an edge of the profile polygon ({edge_mm:.6g} mm) is longer than "
            f"the inscribed diameter found ({2.0 * r:.6g} mm), the circle could be centred on that edge"
        )
    return make_circle("MICI", x, y, shift, c, r, n_iter=n_cand)
