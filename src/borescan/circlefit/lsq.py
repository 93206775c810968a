"""Least-squares circles (NIST-conformant), the closed-profile check, roundness and harmonics.

The shared pieces of :mod:`borescan.circlefit`: :class:`Circle`, points centred on their mean
(:func:`prepare_points`), the closed profile the reference circles start from (:func:`closed_profile`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = [
    "Circle",
    "CircleFitError",
    "CLOSED_MAX_GAP_DEG",
    "ClosedProfile",
    "bin_segments",
    "closed_profile",
    "fit_circle_kasa",
    "fit_circle_ls",
    "harmonic_spectrum",
    "largest_gap_deg",
    "make_circle",
    "prepare_points",
    "roundness",
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


def prepare_points(x_mm, y_mm, min_points: int = 3) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Return the finite points centred on their mean, and the mean: (x, y, shift) [mm]."""
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


def make_circle(method: str, xc, yc, shift, center, radius, cov=None, n_iter=0) -> Circle:
    """Return the :class:`Circle` of a centre and radius in the shifted frame, with its deviations."""
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
    x, y, shift = prepare_points(x_mm, y_mm)
    c, r = _kasa(x, y)
    return make_circle("KASA", x, y, shift, c, r)


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
    x, y, shift = prepare_points(x_mm, y_mm)
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
    return make_circle("LSCI", x, y, shift, p[:2], abs(p[2]), cov, it)


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
    x, y, shift = prepare_points(x_mm, y_mm)
    c = ls_center(x, y, shift, center_xy_mm)
    return _angular_order(x, y, c)[2]


def ls_center(x: np.ndarray, y: np.ndarray, shift: np.ndarray, ls_center_xy_mm) -> np.ndarray:
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
class ClosedProfile:
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


def closed_profile(
    x_mm, y_mm, ls_center_xy_mm, max_gap_deg: float, method: str, min_points: int = 3
) -> ClosedProfile:
    """Return the :class:`ClosedProfile` of the points, or raise when the profile is not closed."""
    x, y, shift = prepare_points(x_mm, y_mm, min_points=min_points)
    c = ls_center(x, y, shift, ls_center_xy_mm)
    order, ths = _check_closed(x, y, c, max_gap_deg, method)
    return ClosedProfile(x, y, shift, c, np.hypot(x - c[0], y - c[1]), order, ths)


# --------------------------------------------------------------------------- MCCI (Welzl)


def bin_segments(ths: np.ndarray, bins: int) -> tuple[np.ndarray, np.ndarray]:
    """Return the non-empty angular bins as runs of a profile's angular order.

    Return the non-empty ones of ``bins`` equal angular bins over [-pi, pi) as runs of a profile's
    angular order: start positions and lengths along ``ths`` (increasing angles [rad]).
    """
    b = np.minimum(((ths + np.pi) / (2 * np.pi) * bins).astype(np.int64), bins - 1)  # non-decreasing
    starts = np.flatnonzero(np.r_[True, b[1:] != b[:-1]])
    return starts, np.diff(np.r_[starts, b.size])


def roundness(x_mm, y_mm, center_xy_mm) -> float:
    """RONt about a given centre: max_i |p_i - c| - min_i |p_i - c| [mm] (ISO 12181-1)."""
    x = np.asarray(x_mm, dtype=float)
    y = np.asarray(y_mm, dtype=float)
    d = np.hypot(x - center_xy_mm[0], y - center_xy_mm[1])
    return float(np.nanmax(d) - np.nanmin(d))


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
