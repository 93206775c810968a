"""Measuring rod: joint solve of all hole radii and pose angles (Wang 2017, Eq. 16).

Model (phi_m = 0, Wang Eq. 16): for hole m and pose n with l_nm = l0_m + v_nm,

    e_nm = sqrt((x_m + l_nm cos a_n)^2 + (y_m + l_nm sin a_n)^2) - r_m = 0.

Unknowns r_m, x_m, y_m (3m) and a_n (n); a global rotation leaves every e_nm unchanged, so
one pose angle is fixed (a_0 = 0) and 3m + n - 1 unknowns remain (the paper counts 3m + n).
Solved by Levenberg-Marquardt (``scipy.optimize.least_squares``) with the exact Jacobian

    de/dr_m = -1,  de/dx_m = (x_m + l c)/rho,  de/dy_m = (y_m + l s)/rho,
    de/da_n = l (y_m c - x_m s)/rho,   rho = |(x_m + l c, y_m + l s)|.

Start values (no search): to first order l_nm = r_m - x_m cos a_n - y_m sin a_n, so the
column-centred reading matrix has rank 2; its two leading left singular vectors, scaled,
lie on an ellipse that is an affine image of (cos a_n, sin a_n). An algebraic ellipse fit
undoes the affine map, giving a_n up to a rotation (the gauge) and a reflection; a linear
least-squares fit then gives (r_m, x_m, y_m).

Identifiability (first order): the 2-vectors p_m = (x_m, y_m) must not all lie on one line
through the origin, i.e. the rod axis must be skew to the holes' axis. A rod parallel to the
holes (p_m all equal), or one whose axis meets the holes' axis, leaves a one-parameter family
(|p| and r trade against the pose angles) broken only by terms of order |p|^2 / r, and is
refused. A centred rod (readings constant within the noise) has undetermined angles; the
radii are then the mean readings (``method="centred"``), which assumes the poses were
spread around the circle as the procedure prescribes (otherwise an off-centre rod with all
poses at one angle explains the same data).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

__all__ = ["RodSolveError", "RodSolution", "rod_residuals", "rod_jacobian", "rod_start", "solve_rod", "solve_rod_pso", "rod_crb"]


class RodSolveError(ValueError):
    """The rod equations cannot determine the radii (too few readings or degenerate geometry)."""


@dataclass(frozen=True)
class RodSolution:
    """Result of :func:`solve_rod` / :func:`solve_rod_pso`.

    radius_mm, u_radius_mm, diameter_mm, u_diameter_mm : (m,) [mm] (k = 1)
    xy_mm : (m, 2) offset of hole m's centre from the axis foot, in the pose-0 frame [mm]
    alpha_rad : (n,) pose angles, alpha_rad[fix_pose] = 0 (NaN for the centred case)
    residual_rms_mm : RMS of e_nm; sigma_mm : noise used for the covariance
    rank, n_params, condition : of the (column-scaled) Jacobian at the solution
    cov : (p, p) covariance of the parameter vector [r (m), x (m), y (m), alpha (n - 1)]
    method : "joint" | "centred" | "pso"; nfev : function evaluations
    """

    radius_mm: np.ndarray
    u_radius_mm: np.ndarray
    xy_mm: np.ndarray
    alpha_rad: np.ndarray
    residual_rms_mm: float
    sigma_mm: float
    rank: int
    n_params: int
    condition: float
    cov: np.ndarray | None
    method: str
    nfev: int

    @property
    def diameter_mm(self) -> np.ndarray:
        return 2.0 * self.radius_mm

    @property
    def u_diameter_mm(self) -> np.ndarray:
        return 2.0 * self.u_radius_mm


def _unpack(p, m, n, fix):
    r, x, y = p[:m], p[m : 2 * m], p[2 * m : 3 * m]
    alpha = np.insert(p[3 * m :], fix, 0.0)
    return r, x, y, alpha


def rod_residuals(p, L, mask, fix=0):
    """Residuals e_nm (Wang Eq. 16) of the observed entries, parameter order [r, x, y, alpha\\fix].

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
    """Start values [r, x, y, alpha\\fix] from the rank-2 structure of the readings (module doc).

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
    r, x, y = np.empty(m), np.empty(m), np.empty(m)
    A = np.column_stack([np.ones(n), -np.cos(alpha), -np.sin(alpha)])
    for j in range(m):
        ok = mask[:, j]
        (r[j], x[j], y[j]), *_ = np.linalg.lstsq(A[ok], L[ok, j], rcond=None)
    return np.concatenate([r, x, y, np.delete(alpha, fix)]), S


def _prepare(readings_mm, l0_mm):
    """l = l0 + v, the observation mask and the poses kept (those with >= 2 readings: a pose
    seen by one layer only determines its own angle and nothing else, so it is dropped)."""
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
    n_par = 3 * m + n - 1
    if m < 2:
        raise RodSolveError(
            f"underdetermined: one hole gives {int(np.isfinite(v).sum())} readings for 3 + n - 1 unknowns; "
            "Wang Eq. 16 needs at least two layers sharing the pose angles"
        )
    if n_obs < n_par:
        raise RodSolveError(
            f"underdetermined: {n_obs} readings < 3m + n - 1 = {n_par} unknowns "
            f"(m = {m} holes, n = {n} poses with >= 2 readings; need n >= {int(np.ceil((3 * m - 1) / (m - 1)))} complete poses)"
        )
    per_hole = mask.sum(axis=0)
    if np.any(per_hole < 3):
        raise RodSolveError(f"underdetermined: holes {list(np.flatnonzero(per_hole < 3) + 1)} have fewer than 3 readings")
    return L, mask, keep


def solve_rod(
    readings_mm,
    l0_mm,
    *,
    u_reading_mm: float | None = None,
    fix_pose: int = 0,
    max_condition: float = 1e8,
    max_u_ratio: float = 50.0,
    centred: str = "refuse",
) -> RodSolution:
    """Solve Wang 2017 Eq. 16 for all holes at once (exact-Jacobian Levenberg-Marquardt).

    Parameters
    ----------
    readings_mm : ndarray (n, m) readings v per pose n and layer/hole m [mm]; NaN = missing
    l0_mm : (m,) calibrated base length of each layer (l = l0 + v is the distance from the axis)
    u_reading_mm : standard uncertainty of one reading [mm]; if None the residual RMS is used
        (with the degrees of freedom), which needs more readings than unknowns
    fix_pose : index (among the kept poses) of the pose whose angle is fixed at 0
    centred : what to do when the readings are constant within the noise ("refuse" or "mean").
        The data cannot tell a centred rod (angles undetermined, r = mean l) from an eccentric
        rod with all poses at one angle (r undetermined); "mean" asserts the poses were spread
        around the circle and returns r_m = mean_n l_nm, u = sigma / sqrt(n_m)
    max_condition : refuse when the column-scaled Jacobian is worse conditioned than this
    max_u_ratio : refuse when some u(r_m) exceeds this multiple of sigma / sqrt(n_m), the
        uncertainty of a centred rod's mean reading (a near-degenerate, not a singular, geometry)

    Returns
    -------
    RodSolution (covariance sigma^2 (J^T J)^-1; u(diameter) = 2 u(r))

    Raises
    ------
    RodSolveError
        fewer readings than 3m + n - 1 unknowns, a single hole, or degenerate geometry (rank
        deficient or ill-conditioned Jacobian: poses bunched at one angle, rod axis parallel
        to or intersecting the holes' axis).
    """
    L, mask, keep = _prepare(readings_mm, l0_mm)
    n, m = L.shape
    n_obs = int(mask.sum())
    n_par = 3 * m + n - 1
    p0, S = rod_start(L, mask, fix_pose)
    # Noise reference for the centred test: the given u, else the third singular value (m >= 3)
    sig_ref = u_reading_mm if u_reading_mm is not None else (S[2] / np.sqrt(max(n - 2, 1)) if S.size > 2 else None)
    if sig_ref is not None and S[0] < 5.0 * sig_ref * np.sqrt(n):
        if centred != "mean":
            raise RodSolveError(
                "degenerate geometry: readings constant within the noise - either the rod is centred "
                "(angles undetermined; pass centred='mean' if the poses were spread around the circle) "
                "or all poses are at nearly one angle (radii undetermined)"
            )
        # centred rod: every layer reads its radius; angles undetermined
        Lf = np.where(mask, L, np.nan)
        r = np.nanmean(Lf, axis=0)
        cnt = mask.sum(axis=0)
        sd = np.nanstd(Lf, axis=0, ddof=1)
        sig = np.full(m, u_reading_mm) if u_reading_mm is not None else sd
        return RodSolution(
            radius_mm=r, u_radius_mm=sig / np.sqrt(cnt), xy_mm=np.zeros((m, 2)), alpha_rad=np.full(keep.size, np.nan),
            residual_rms_mm=float(np.sqrt(np.nanmean((Lf - r) ** 2))), sigma_mm=float(np.mean(sig)),
            rank=m, n_params=n_par, condition=float("inf"), cov=None, method="centred", nfev=0,
        )
    sol = least_squares(
        rod_residuals, p0, jac=rod_jacobian, args=(L, mask, fix_pose), method="lm",
        xtol=1e-15, ftol=1e-15, gtol=1e-15, max_nfev=200 * n_par,
    )
    p = sol.x
    J = rod_jacobian(p, L, mask, fix_pose)
    col = np.linalg.norm(J, axis=0)
    col[col == 0] = 1.0
    sv = np.linalg.svd(J / col, compute_uv=False)
    rank = int(np.sum(sv > sv[0] * 1e-12))
    cond = float(sv[0] / sv[-1]) if sv[-1] > 0 else float("inf")
    if rank < n_par or cond > max_condition:
        raise RodSolveError(
            f"degenerate geometry: Jacobian rank {rank} of {n_par}, condition {cond:.3g} "
            f"(poses bunched at one angle, or the rod axis parallel to / intersecting the holes' axis "
            "so that the offsets (x_m, y_m) are collinear with the axis)"
        )
    e = sol.fun
    rms = float(np.sqrt(np.mean(e**2)))
    dof = n_obs - n_par
    if u_reading_mm is not None:
        sigma = float(u_reading_mm)
    elif dof > 0:
        sigma = float(np.sqrt(e @ e / dof))
    else:
        sigma = float("nan")
    Js = J / col
    cov = sigma**2 * (np.linalg.pinv(Js.T @ Js) / np.outer(col, col))
    r, x, y, a = _unpack(p, m, n, fix_pose)
    u_r = np.sqrt(np.diag(cov)[:m])
    ratio = u_r / (sigma / np.sqrt(mask.sum(axis=0)))
    if np.any(ratio > max_u_ratio):
        raise RodSolveError(
            f"degenerate geometry: radii ill-determined, u(r) = {np.array2string(u_r, precision=4)} mm is up to "
            f"{ratio.max():.0f} x sigma/sqrt(n) (condition {cond:.3g}); the offsets (x_m, y_m) are nearly collinear "
            "with the axis (rod parallel to, or intersecting, the holes' axis) or the poses are bunched"
        )
    return RodSolution(
        radius_mm=np.abs(r), u_radius_mm=u_r, xy_mm=np.column_stack([x, y]),
        alpha_rad=_expand(np.mod(a + np.pi, 2 * np.pi) - np.pi, keep), residual_rms_mm=rms, sigma_mm=sigma, rank=rank,
        n_params=n_par, condition=cond, cov=cov, method="joint", nfev=int(sol.nfev),
    )


def _expand(a, keep):
    out = np.full(keep.size, np.nan)
    out[keep] = a
    return out


def rod_crb(alpha_rad, l_mm, xy_mm, radius_mm, sigma_mm: float, fix_pose: int = 0) -> np.ndarray:
    """Cramér-Rao bound on the radii for Gaussian reading noise sigma (exact model at the truth).

    Readings enter Eq. 16 through l, so the residual noise of e_nm is sigma * de/dl with
    de/dl = (X c + Y s)/rho; CRB = (J^T W J)^-1, W = diag(1 / (sigma de/dl)^2).

    Returns
    -------
    ndarray (m,) standard deviation bound of each radius [mm]
    """
    a = np.asarray(alpha_rad, float)
    L = np.asarray(l_mm, float)
    n, m = L.shape
    xy = np.asarray(xy_mm, float)
    p = np.concatenate([radius_mm, xy[:, 0], xy[:, 1], np.delete(a - a[fix_pose], fix_pose)])
    mask = np.ones_like(L, dtype=bool)
    J = rod_jacobian(p, L, mask, fix_pose)
    c, s = np.cos(a - a[fix_pose])[:, None], np.sin(a - a[fix_pose])[:, None]
    X, Y = xy[:, 0] + L * c, xy[:, 1] + L * s
    dedl = ((X * c + Y * s) / np.hypot(X, Y))[mask]
    F = J.T @ (J / (sigma_mm * dedl)[:, None] ** 2)
    return np.sqrt(np.diag(np.linalg.inv(F))[:m])


def solve_rod_pso(
    readings_mm,
    l0_mm,
    *,
    seed: int | np.random.Generator = 0,
    n_particles: int = 80,
    n_iter: int = 1500,
    xy_bound_mm: float = 5.0,
    inertia: float = 0.7298,
    c_cognitive: float = 1.49618,
    c_social: float = 1.49618,
) -> RodSolution:
    """Global-best particle swarm on Wang Eq. 16 (the paper's solver; benchmark baseline only).

    Minimises sum e_nm^2 over [r, x, y, alpha\\0] in the box r in [min l - 1, max l + 1],
    |x|, |y| <= ``xy_bound_mm``, alpha in [-pi, pi]; Clerc-Kennedy constriction weights;
    vectorised over particles. No covariance (u = NaN).
    """
    L, mask, keep = _prepare(readings_mm, l0_mm)
    n, m = L.shape
    rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
    Lf = np.where(mask, L, np.nan)
    lo = np.concatenate([np.nanmin(Lf, axis=0) - 1.0, np.full(2 * m, -xy_bound_mm), np.full(n - 1, -np.pi)])
    hi = np.concatenate([np.nanmax(Lf, axis=0) + 1.0, np.full(2 * m, xy_bound_mm), np.full(n - 1, np.pi)])
    d = lo.size
    L0 = np.where(mask, L, 0.0)
    W = mask.astype(float)

    def cost(P):  # P (k, d)
        r, x, y = P[:, :m], P[:, m : 2 * m], P[:, 2 * m : 3 * m]
        a = np.concatenate([np.zeros((P.shape[0], 1)), P[:, 3 * m :]], axis=1)  # pose 0 fixed
        c, s = np.cos(a)[:, :, None], np.sin(a)[:, :, None]
        e = np.hypot(x[:, None, :] + L0 * c, y[:, None, :] + L0 * s) - r[:, None, :]
        return np.sum(W * e * e, axis=(1, 2))

    X = lo + (hi - lo) * rng.random((n_particles, d))
    V = 0.1 * (hi - lo) * (rng.random((n_particles, d)) - 0.5)
    f = cost(X)
    pb, pf = X.copy(), f.copy()
    g = pb[np.argmin(pf)].copy()
    gf = pf.min()
    vmax = 0.2 * (hi - lo)
    nfev = n_particles
    for _ in range(n_iter):
        r1, r2 = rng.random((2, n_particles, d))
        V = inertia * V + c_cognitive * r1 * (pb - X) + c_social * r2 * (g - X)
        V = np.clip(V, -vmax, vmax)
        X = np.clip(X + V, lo, hi)
        f = cost(X)
        nfev += n_particles
        better = f < pf
        pb[better], pf[better] = X[better], f[better]
        k = np.argmin(pf)
        if pf[k] < gf:
            g, gf = pb[k].copy(), pf[k]
    r, x, y, a = _unpack(g, m, n, 0)
    return RodSolution(
        radius_mm=r, u_radius_mm=np.full(m, np.nan), xy_mm=np.column_stack([x, y]), alpha_rad=_expand(a, keep),
        residual_rms_mm=float(np.sqrt(gf / mask.sum())), sigma_mm=float("nan"), rank=-1, n_params=d,
        condition=float("nan"), cov=None, method="pso", nfev=nfev,
    )
