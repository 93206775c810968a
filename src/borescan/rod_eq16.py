"""Wang 2017 Eq. 16 of the measuring rod and the solve's start (used by :mod:`borescan.rod`).

Eq. 16 helpers (``rod_residuals``, ``rod_jacobian``, ``rod_start``; pose-0 frame, x_m, y_m the
axis minus the centre): unknowns r_m, x_m, y_m (3m) and a_n (n - 1). To first order
l_nm = r_m - x_m cos a_n - y_m sin a_n, so the column-centred reading matrix has rank 2; its two
leading left singular vectors, scaled, lie on an ellipse that is an affine image of
(cos a_n, sin a_n). An algebraic ellipse fit undoes the affine map, giving a_n up to a rotation
and a reflection (:mod:`borescan.rod`, "Start"). ``_prepare`` checks that the readings can
determine the unknowns at all.
"""

from __future__ import annotations

import numpy as np

__all__ = ["RodSolveError", "HOLD_FIX", "hold_refusal", "rod_residuals", "rod_jacobian", "rod_start"]


class RodSolveError(ValueError):
    """The rod equations cannot determine the radii (too few readings or degenerate geometry)."""


#: what would give radii where a hold's poses do not: said by every refusal that a new hold would fix
HOLD_FIX = (
    "a new hold: the rod deflected across its eccentricity (skew to the holes' axis), the poses spread "
    "round the circle; `borescan plan --rod-scan <its folder>` gives the poses and spread that bring its "
    "u(D) to a target"
)


def hold_refusal(reason: str) -> RodSolveError:
    """Return the refusal of a hold whose poses cannot give the radii: ``reason``, then :data:`HOLD_FIX`."""
    return RodSolveError(f"{reason}; {HOLD_FIX}")


def _unpack(p, m, n, fix):
    r, x, y = p[:m], p[m : 2 * m], p[2 * m : 3 * m]
    alpha = np.insert(p[3 * m :], fix, 0.0)
    return r, x, y, alpha


def rod_residuals(p, L, mask, fix=0):
    r"""Residuals e_nm (Wang Eq. 16) of the observed entries, parameter order [r, x, y, alpha\fix].

    L : (n, m) l = l0 + v [mm] (any value where ``mask`` is False).
    """
    n, m = L.shape
    r, x, y, a = _unpack(p, m, n, fix)
    c, s = np.cos(a)[:, None], np.sin(a)[:, None]
    e = np.hypot(x + L * c, y + L * s) - r
    return e[mask]


def rod_jacobian(p, L, mask, fix=0):
    """Exact Jacobian of :func:`rod_residuals`, shape (n_obs, 3m + n - 1)."""
    n, m = L.shape
    r, x, y, a = _unpack(p, m, n, fix)
    c, s = np.cos(a)[:, None], np.sin(a)[:, None]
    X, Y = x + L * c, y + L * s
    rho = np.hypot(X, Y)
    J = np.zeros((n, m, 3 * m + n))
    idx = np.arange(m)
    J[:, idx, idx] = -1.0
    J[:, idx, m + idx] = X / rho
    J[:, idx, 2 * m + idx] = Y / rho
    da = L * (y * c - x * s) / rho  # (n, m)
    J[np.arange(n)[:, None], idx[None, :], 3 * m + np.arange(n)[:, None]] = da
    J = np.delete(J, 3 * m + fix, axis=2)
    return J[mask]


def _ellipse_angles(Q: np.ndarray) -> np.ndarray | None:
    """Angles a_n with Q_n = A (cos a_n, sin a_n) + q0 (algebraic conic fit); None if no ellipse."""
    q1, q2 = Q[:, 0], Q[:, 1]
    sc = np.sqrt(np.mean(q1**2 + q2**2))
    if not np.isfinite(sc) or sc == 0:
        return None
    q1, q2 = q1 / sc, q2 / sc
    D = np.column_stack([q1 * q1, q1 * q2, q2 * q2, q1, q2])
    coef, *_ = np.linalg.lstsq(D, np.ones_like(q1), rcond=None)
    a, b, c, d, e = coef
    M = np.array([[a, b / 2], [b / 2, c]])
    g = np.array([d, e])
    try:
        q0 = -0.5 * np.linalg.solve(M, g)
    except np.linalg.LinAlgError:
        return None
    k = 1.0 + q0 @ M @ q0
    P = M / k
    w, V = np.linalg.eigh(P)
    if np.any(w <= 0):
        return None
    G = V @ np.diag(np.sqrt(w)) @ V.T
    U = (np.column_stack([q1, q2]) - q0) @ G.T
    return np.arctan2(U[:, 1], U[:, 0])


def rod_start(L: np.ndarray, mask: np.ndarray, fix: int = 0) -> tuple[np.ndarray, np.ndarray]:
    r"""Start values [r, x, y, alpha\fix] from the rank-2 structure of the readings (module doc).

    Returns
    -------
    p0 : ndarray (3m + n - 1,); singular values of the column-centred reading matrix
    """
    n, m = L.shape
    Lf = np.where(mask, L, np.nan)
    mu = np.nanmean(Lf, axis=0)
    Lc = np.where(mask, L - mu, 0.0)
    U, S, _ = np.linalg.svd(Lc, full_matrices=False)
    alpha = None
    if m >= 2 and S.size >= 2:
        alpha = _ellipse_angles(U[:, :2] * S[:2])
    if alpha is None:
        alpha = np.linspace(0, 2 * np.pi, n, endpoint=False)
    alpha = np.mod(alpha - alpha[fix] + np.pi, 2 * np.pi) - np.pi
    r, p = _first_harmonic(L, mask, [alpha] * m)
    return np.concatenate([r, p[:, 0], p[:, 1], np.delete(alpha, fix)]), S


def _prepare(readings_mm, l0_mm, n_extra: int = 0):
    """Return l = l0 + v, the observation mask and the poses kept.

    l = l0 + v, the observation mask and the poses kept (those with >= 2 readings: a pose
    seen by one layer only determines its own angle and nothing else, so it is dropped).
    ``n_extra`` unknowns beyond Wang's 3m + n - 1 (2 for the deflection).
    """
    v = np.asarray(readings_mm, dtype=float)
    if v.ndim != 2:
        raise RodSolveError(f"readings must be (poses, holes), got shape {v.shape}")
    m = v.shape[1]
    L = v + np.broadcast_to(np.asarray(l0_mm, dtype=float), (m,))
    keep = np.isfinite(L).sum(axis=1) >= 2
    L = L[keep]
    mask = np.isfinite(L)
    n = L.shape[0]
    n_obs = int(mask.sum())
    n_par = 3 * m + n - 1 + n_extra
    if m < 2:
        raise RodSolveError(
            f"underdetermined: one hole gives {int(np.isfinite(v).sum())} readings for 3 + n - 1 unknowns; "
            "Wang Eq. 16 needs at least two layers sharing the pose angles"
        )
    if n_obs < n_par:
        label = "3m + n - 1" + (f" + {n_extra}" if n_extra else "")
        need = int(np.ceil((3 * m - 1 + n_extra) / (m - 1)))
        raise hold_refusal(
            f"underdetermined: {n_obs} readings < {label} = {n_par} unknowns "
            f"(m = {m} holes, n = {n} poses with >= 2 readings; need n >= {need} complete poses)"
        )
    per_hole = mask.sum(axis=0)
    if np.any(per_hole < 3):
        raise hold_refusal(
            f"underdetermined: holes {list(np.flatnonzero(per_hole < 3) + 1)} have fewer than 3 readings"
        )
    return L, mask, keep


def _first_harmonic(L, mask, angles):
    """Return the rod's linear start, per layer r (m,) and p (m, 2).

    Per layer j, l = r_j - p_j . u(a_j) by linear least squares (Eq. 16 to first order in the eccentricity),
    a_j = ``angles[j]`` (n,): the one linear start of the rod. Returns r (m,), p (m, 2).
    """
    n, m = L.shape
    r, p = np.empty(m), np.empty((m, 2))
    for j in range(m):
        A = np.column_stack([np.ones(n), -np.cos(angles[j]), -np.sin(angles[j])])
        ok = mask[:, j]
        (r[j], p[j, 0], p[j, 1]), *_ = np.linalg.lstsq(A[ok], L[ok, j], rcond=None)
    return r, p


def _linear_start(L, mask, alpha, layers):
    """Per layer, l = r - p . u(alpha + phi) (:func:`_first_harmonic`); centre = -p."""
    r, p = _first_harmonic(L, mask, [alpha + lay.phi_rad for lay in layers])
    return r, -p
