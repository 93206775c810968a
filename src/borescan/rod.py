"""Measuring rod: joint solve of the hole radii, pose angles and rod axis deflection.

Model (spec "Measuring rod"; Wang 2017 Eq. 16 with the beam geometry of Eqs. 5-6 and the axis
deflection of Section 3.4). Layer m has in-plane angle phi_m, beam offset d_m, tilt gamma_m,
base length l0_m (device.nominal or a rod calibration); at pose n the reading is the exact
ray-cylinder distance of :func:`borescan.geometry.rod_readings`,

    v_nm = F(alpha_n; layer m, hole m, axis) ,   e_nm = v_nm(observed) - v_nm(model),

and the solve minimises sum e_nm^2 (Levenberg-Marquardt, central-difference Jacobian in blocks).
With d = gamma = omega = 0, phi = 0 this is Wang Eq. 16,
(x_m + l cos a_n)^2 + (y_m + l sin a_n)^2 = r_m^2.

Unknowns (3m + n - 1 + 2): per hole the mean section radius rho_m and the centre c_m = (cx, cy)
(relative to the point where the rod axis crosses the height of layer m's spot); the pose
angles alpha_n with one fixed; the deflection vector w = omega (cos omega_az, sin omega_az).
The hole radius is r_m = rho_m / k(omega^2), k(s) = 1 + s/4 + 5 s^2/48 = (1 + 1/cos omega)/2 + O(s^3).

Gauge freedoms (removed, not estimated): a rotation of the whole set-up about the part z axis
(alpha_fix = 0); a translation (the axis passes through the origin at z = 0, so the eccentricity
(dx, dy) is reported relative to hole 1's centre: ``eccentricity_mm``); and the axis shift
z_m tan(omega) at each layer, which is exactly a centre shift and is moved into c_m. The
mirror image (alpha -> -alpha) is a near-symmetry (broken by d, phi only at second order):
both reflections are started.

Deflection (identifiability). With the centres free, what is left of omega is the tilt of the
beam plane against the hole: the section is an ellipse, semi-axes r/cos(omega) along omega_az
and r across, i.e. a mean radius r k(omega^2) = rho and a second harmonic
(r/4) omega^2 cos 2(theta - omega_az). In beta = w^2 = omega^2 (cos 2 omega_az, sin 2 omega_az)
(a complex square) the readings are linear in beta near 0 (rho absorbs the mean), so the
maximum-likelihood beta is nearly Gaussian with covariance Sigma_beta and the Jacobian, rank
and condition are taken in [rho, c, alpha, beta]. The radius needs |beta| = omega^2, whose
direction the data may barely see; the local Cramer-Rao bound at the truth depends on that
direction (through the rho-beta correlation) and is not attainable by any estimator when
|beta| is below its noise. The default ("free") averages r = rho(beta) / k(|beta|) over the
posterior of w under a bounded prior (omega ~ U(0, ``MAX_DEFLECTION_RAD`` = 2 deg), widened when
the data put omega clearly beyond it): see ``_deflected_radii``. ``deflection="mle"`` gives r at
|beta_hat|; "none" holds omega = 0.

Start: the rank-2 structure of the readings gives the pose angles up to a
rotation and a reflection (SVD + ellipse fit, below), a linear fit the radii and centres; LM
without deflection from both reflections, then one Gauss-Newton step in beta (the model is
linear in beta) and LM from w = +-sqrt(beta); the lowest cost wins. A per-pose angle profile
(each pose searched on a 1 deg grid with the rest held, LM re-run when a pose moves) frees pose
angles stuck in a local minimum of their own (``_repair_poses``).

Refusals (RodSolveError): fewer readings than unknowns; degenerate geometry (rank or condition of
the column-scaled Jacobian, or u(r) with omega held > ``max_u_ratio`` sigma/sqrt(n): offsets
(x_m, y_m) collinear with the axis, a rod parallel to the holes, poses bunched); a deflection the
poses cannot separate from the radii (freeing omega multiplies u(r) by > ``max_deflection_ratio``).

Eq. 16 helpers (``rod_residuals``, ``rod_jacobian``, ``rod_start``; pose-0 frame, x_m, y_m the
axis minus the centre): unknowns r_m, x_m, y_m (3m) and a_n (n - 1). To first order
l_nm = r_m - x_m cos a_n - y_m sin a_n, so the column-centred reading matrix has rank 2; its two
leading left singular vectors, scaled, lie on an ellipse that is an affine image of
(cos a_n, sin a_n). An algebraic ellipse fit undoes the affine map, giving a_n up to a rotation
and a reflection. The 2-vectors p_m = (x_m, y_m) must not all lie on one line through the
origin (rod axis skew to the holes' axis); a centred rod (readings constant within the noise)
has undetermined angles: the radii are then the mean readings (``method="centred"``), which
assumes the poses were spread around the circle as the procedure prescribes.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import numpy as np
from scipy.optimize import least_squares

from borescan.fit import FitResult, fit_result, jacobian_summary
from borescan.geometry import Hole, RodAxis, RodLayer, rod_readings
from borescan.physics.rod import rod_section_geometry

__all__ = [
    "RodSolveError",
    "RodSolution",
    "rod_residuals",
    "rod_jacobian",
    "rod_start",
    "solve_rod",
    "solve_rod_pso",
    "rod_crb",
    "rod_layers",
    "rod_section_geometry",
    "rod_cost_mm2",
]


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
    cov : (p, p) covariance of the parameter vector [rho (m), cx (m), cy (m), alpha (n - 1), beta (2)]
        (Eq. 16 order [r, x, y, alpha] for "pso"; no beta for "eq16")
    method : "joint" (deflection free, debiased omega^2) | "joint-mle" | "eq16" (omega = 0) |
        "centred" | "pso"; nfev : function evaluations
    center_xy_mm : (m, 2) hole centre relative to the axis at the spot height (= -xy_mm)
    deflection_xy_rad : (2,) maximum-likelihood w = omega (cos omega_az, sin omega_az) [rad]
    deflection_rad, deflection_az_rad : omega (from the debiased omega^2, 0 if negative), omega_az
    deflection_posterior_xy_rad : (2,) the posterior mean of w with the coaxial prior (the centres
        fix its sign), else sqrt(s) along the maximum-likelihood w [rad]
    deflection_sq_rad2, u_deflection_sq_rad2 : the estimate s of omega^2 (may be < 0) and its u
    eccentricity_mm, u_eccentricity_mm : (2,) axis at z = 0 minus hole 1's centre [mm]
    radius_mle_mm : (m,) radii at the maximum-likelihood omega; deflection_ratio : max u(r) with
        omega free / u(r) with omega held; cost_mm2 : sum of squared residuals at the solution
    layers : the layer geometry used
    fit : the joint solve's :class:`borescan.fit.FitResult` (parameter order as ``cov``; None for
        "centred" and "pso")
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
    center_xy_mm: np.ndarray | None = None
    deflection_xy_rad: np.ndarray = field(default_factory=lambda: np.zeros(2))
    deflection_rad: float = 0.0
    deflection_az_rad: float = 0.0
    deflection_sq_rad2: float = 0.0
    deflection_posterior_xy_rad: np.ndarray = field(default_factory=lambda: np.zeros(2))
    u_deflection_sq_rad2: float = float("nan")
    eccentricity_mm: np.ndarray | None = None
    u_eccentricity_mm: np.ndarray | None = None
    radius_mle_mm: np.ndarray | None = None
    deflection_ratio: float = float("nan")
    cost_mm2: float = float("nan")
    layers: tuple = ()
    fit: FitResult | None = None

    @property
    def diameter_mm(self) -> np.ndarray:
        """Diameters [mm] of the holes."""
        return 2.0 * self.radius_mm

    @property
    def u_diameter_mm(self) -> np.ndarray:
        """Standard uncertainties [mm] of the diameters."""
        return 2.0 * self.u_radius_mm


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
        raise RodSolveError(
            f"underdetermined: {n_obs} readings < {label} = {n_par} unknowns "
            f"(m = {m} holes, n = {n} poses with >= 2 readings; need n >= {need} complete poses)"
        )
    per_hole = mask.sum(axis=0)
    if np.any(per_hole < 3):
        raise RodSolveError(
            f"underdetermined: holes {list(np.flatnonzero(per_hole < 3) + 1)} have fewer than 3 readings"
        )
    return L, mask, keep


# --------------------------------------------------------------------------- deflection-aware model


def _k(s):
    """Mean-radius factor of the tilted section, s = omega^2 [rad^2]: (1 + 1/cos omega) / 2 to O(s^2).

    Analytic in s, so a negative s (the debiased estimate of a small omega^2) is allowed.
    """
    return 1.0 + s / 4.0 + 5.0 * s * s / 48.0


def _dk(s):
    return 0.25 + 5.0 * s / 24.0


def rod_layers(
    l0_mm=None, layers: Sequence[RodLayer] | None = None, m: int | None = None
) -> tuple[RodLayer, ...]:
    """Return the layer geometry for the solve.

    Layer geometry for the solve: ``layers`` (device nominal or a rod calibration), their l0
    replaced by ``l0_mm`` when both are given; l0 alone gives phi = d = gamma = 0 (Wang Eq. 16).
    """
    if layers is None:
        if l0_mm is None:
            raise ValueError("rod_layers needs l0_mm or layers")
        l0 = np.broadcast_to(np.asarray(l0_mm, dtype=float), (m,) if m is not None else np.shape(l0_mm))
        return tuple(RodLayer(channel=j + 1, h_mm=0.0, l0_mm=float(x)) for j, x in enumerate(l0))
    out = tuple(layers)
    if l0_mm is not None:
        l0 = np.broadcast_to(np.asarray(l0_mm, dtype=float), (len(out),))
        out = tuple(replace(lay, l0_mm=float(x)) for lay, x in zip(out, l0))
    return out


class _RodProblem:
    r"""Exact forward model in the solver's unknowns p = [rho (m), cx (m), cy (m), alpha\fix (n-1), w (2)].

    rho_m = r_m k(omega^2) is the mean radius of section m; w the deflection vector (omitted when
    ``deflection`` is False). Readings from :func:`borescan.geometry.rod_readings` only.
    """

    def __init__(self, V, mask, layers, fix, deflection, alpha_fix=0.0):
        self.V, self.mask, self.layers, self.fix = V, mask, tuple(layers), fix
        self.n, self.m = V.shape
        self.deflection = deflection
        self.alpha_fix = alpha_fix
        self.n_par = 3 * self.m + self.n - 1 + (2 if deflection else 0)
        self.Vz = np.where(mask, V, 0.0)

    def unpack(self, p):
        m, n = self.m, self.n
        rho, cx, cy = p[:m], p[m : 2 * m], p[2 * m : 3 * m]
        alpha = np.insert(p[3 * m : 3 * m + n - 1], self.fix, self.alpha_fix)
        w = p[3 * m + n - 1 :] if self.deflection else np.zeros(2)
        return rho, np.column_stack([cx, cy]), alpha, np.asarray(w, dtype=float)

    def pack(self, rho, c, alpha, w=None):
        parts = [rho, c[:, 0], c[:, 1], np.delete(alpha, self.fix)]
        if self.deflection:
            parts.append(np.zeros(2) if w is None else w)
        return np.concatenate(parts)

    def readings(self, rho, c, alpha, w):
        s = w[0] ** 2 + w[1] ** 2
        holes, axis = rod_section_geometry(self.layers, c, rho / _k(s), w)
        return rod_readings(alpha, list(self.layers), holes, axis)

    def residual(self, p):
        e = np.where(self.mask, self.V - self.readings(*self.unpack(p)), 0.0)
        return e[self.mask]

    def jac(self, p, beta_step=None):
        """Return d(model)/dp by central differences in blocks.

        d(model)/dp by central differences in blocks (a pose angle moves its row only, a hole's
        unknowns its column only: 12 model evaluations). With ``beta_step`` the last two columns
        are secants in beta = w^2 (complex square) instead: the statistics' coordinates.
        """
        rho, c, alpha, w = self.unpack(p)
        n, m = self.n, self.m
        J = np.zeros((n, m, self.n_par))
        f = self.readings
        h = 1e-6
        d = (f(rho, c, alpha + h, w) - f(rho, c, alpha - h, w)) / (2 * h)
        free = np.delete(np.arange(n), self.fix)
        J[free, :, 3 * m + np.arange(n - 1)] = d[free]
        idx = np.arange(m)
        hr = 1e-5
        J[:, idx, idx] = (f(rho + hr, c, alpha, w) - f(rho - hr, c, alpha, w)) / (2 * hr)
        for k in range(2):
            e = np.zeros((1, 2))
            e[0, k] = hr
            J[:, idx, (1 + k) * m + idx] = (f(rho, c + e, alpha, w) - f(rho, c - e, alpha, w)) / (2 * hr)
        if self.deflection:
            if beta_step is None:
                for k in range(2):
                    e = np.zeros(2)
                    e[k] = h
                    J[:, :, -2 + k] = (f(rho, c, alpha, w + e) - f(rho, c, alpha, w - e)) / (2 * h)
            else:
                b = _beta(w)
                for k in range(2):
                    e = np.zeros(2)
                    e[k] = beta_step
                    J[:, :, -2 + k] = (
                        f(rho, c, alpha, _w_of_beta(b + e, w)) - f(rho, c, alpha, _w_of_beta(b - e, w))
                    ) / (2 * beta_step)
        return -J[self.mask]  # residual = V - model


def _beta(w):
    """beta = w^2 as a complex square: omega^2 (cos 2 omega_az, sin 2 omega_az)."""
    return np.array([w[0] ** 2 - w[1] ** 2, 2 * w[0] * w[1]])


def _w_of_beta(b, w_ref):
    """Complex square root of beta on the branch nearest ``w_ref``."""
    z = np.sqrt(complex(b[0], b[1]))
    if z.real * w_ref[0] + z.imag * w_ref[1] < 0:
        z = -z
    return np.array([z.real, z.imag])


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


def _lm(prob, p0, n_par):
    sol = least_squares(
        prob.residual,
        p0,
        jac=prob.jac,
        method="lm",
        x_scale="jac",
        xtol=1e-14,
        ftol=1e-14,
        gtol=1e-14,
        max_nfev=100 * n_par,
    )
    return sol.x, float(sol.fun @ sol.fun), int(sol.nfev)


def _magnitude(b, half_tr):
    """Debiased signed magnitude of beta (module doc): sign(q) sqrt|q|, q = |b|^2 - tr(Sigma)/2."""
    q = b[..., 0] ** 2 + b[..., 1] ** 2 - half_tr
    return np.sign(q) * np.sqrt(np.abs(q))


@dataclass(frozen=True)
class CoaxialPrior:
    """What the holes' common axis tells about the deflection (module doc, "Deflection").

    The holes a rod measures are coaxial: every hole's centre lies within +-``tolerance_mm`` of
    their common axis in each coordinate (rectangular, standard uncertainty tolerance / sqrt(3),
    independent between holes). The solve's centres are relative to the rod axis at each spot,
    so hole_m - hole_1 = c_m - c_1 + (z_m - z_1) sin(omega) (cos omega_az, sin omega_az): the
    centres fix the deflection vector to about tolerance / (z_m - z_1).

    center_mm : (m, 2) the solve's centres c_m; spot_z_mm : (m,) height of each spot along the rod
    """

    center_mm: np.ndarray
    spot_z_mm: np.ndarray
    tolerance_mm: float


def _coaxial_terms(coax: CoaxialPrior, m: int):
    """Linear pieces of the coaxial prior in the stacked centres [cx (m), cy (m)].

    Returns (D, Z, S0): D (2(m-1), 2m) hole-minus-hole-1 differences, Z (2(m-1), 2) the axis
    term per unit w, S0 the differences' prior covariance.
    """
    D1 = np.hstack([-np.ones((m - 1, 1)), np.eye(m - 1)])
    D = np.block([[D1, np.zeros_like(D1)], [np.zeros_like(D1), D1]])
    dz = coax.spot_z_mm[1:] - coax.spot_z_mm[0]
    Z = np.zeros((2 * (m - 1), 2))
    Z[: m - 1, 0] = dz
    Z[m - 1 :, 1] = dz
    S0 = (coax.tolerance_mm**2 / 3.0) * (D @ D.T)
    return D, Z, S0


#: bound of the deflection prior [rad]: a hand-held rod deflects by a few degrees at most (the
#: contract's rods <= 1 deg; 2 deg leaves a factor 2). A deflection the data put clearly beyond it
#: (|beta_hat| - 3 sd > bound^2) widens the bound to cover the likelihood: never truncated.
MAX_DEFLECTION_RAD = float(np.deg2rad(2.0))


def _deflected_radii(
    rho, b, cov, m, mode, max_deflection_rad=MAX_DEFLECTION_RAD, n_draw: int = 4000, coax=None
):
    """omega^2 estimate s, u(r_m) and u(s) for r_m = rho_m / k(omega^2) (module doc, "Deflection").

    "free": the readings are linear in beta near 0, so the likelihood of beta (the other unknowns
    profiled) is N(beta_hat, Sigma_beta) and, given beta, rho_m(beta) = rho_hat_m - K_m (beta_hat - beta)
    (K = Sigma_rho,beta Sigma_beta^-1) with variance Sigma_rho|beta. r is averaged over the posterior
    of w under the prior omega ~ U(0, ``max_deflection_rad``) (widened when the data demand), azimuth uniform
    (importance sampling
    from a fixed-seed mixture of the prior and the likelihood): r_m = E[rho_m(beta) / k(|beta|)],
    u^2 = Var[rho_m(beta) / k] + Sigma_rho|beta / k^2, s = E[omega^2], u(s) its posterior SD.
    The direction of a deflection that the data barely see is averaged over instead of fixed at
    its noisy estimate. "mle": s = |beta_hat|, u by the delta method along beta_hat.
    """
    idx = np.r_[np.arange(m), cov.shape[0] - 2, cov.shape[0] - 1]
    C = cov[np.ix_(idx, idx)]
    Sb = C[-2:, -2:]
    nb = float(np.hypot(*b))
    uhat = b / nb if nb > 0 else np.array([1.0, 0.0])
    if mode == "mle":
        s = nb
        G = np.zeros((m, m + 2))
        G[np.arange(m), np.arange(m)] = 1.0 / _k(s)
        G[:, -2:] = -(rho * _dk(s) / _k(s) ** 2)[:, None] * uhat[None, :]
        return (
            s,
            np.sqrt(np.clip(np.diag(G @ C @ G.T), 0.0, None)),
            float(np.sqrt(max(uhat @ Sb @ uhat, 0.0))),
        )
    return _posterior_radii(rho, b, cov, m, max_deflection_rad, n_draw, coax)


def _posterior_radii(rho, b, cov, m, max_deflection_rad, n_draw, coax):  # noqa: C901
    """Average the radii over the posterior of w ("free" branch of :func:`_deflected_radii`).

    Proposals (each n_draw): the bound prior, the likelihood of beta pushed to w (either root),
    and, with a coaxial prior, the deflection the centres imply. Given w, the other unknowns are
    Gaussian (the fit's covariance conditioned on beta = w^2, then on the coaxial differences).
    """
    P = cov.shape[0]
    ib = np.array([P - 2, P - 1])
    it = np.arange(3 * m) if coax is not None else np.arange(m)
    Sb = cov[np.ix_(ib, ib)]
    Sb_inv = np.linalg.pinv(Sb)
    Ctb = cov[np.ix_(it, ib)]
    K = Ctb @ Sb_inv
    Ctt = cov[np.ix_(it, it)] - K @ Ctb.T  # the unknowns given beta
    nb = float(np.hypot(*b))
    ev, V = np.linalg.eigh(Sb)
    ev = np.clip(ev, 0.0, None)
    W = float(max_deflection_rad)
    if nb - 3.0 * np.sqrt(ev[-1]) > W**2:  # the data put omega clearly beyond the bound
        W = float(np.sqrt(nb + 3.0 * np.sqrt(ev[-1])))
    rng = np.random.default_rng(0)
    # proposal 1: the prior (omega uniform on [0, W], azimuth uniform)
    om = W * rng.random(n_draw)
    az = rng.uniform(0.0, 2 * np.pi, n_draw)
    w1 = np.column_stack([om * np.cos(az), om * np.sin(az)])
    # proposal 2: the likelihood N(beta_hat, Sigma_beta), pushed to w = +-sqrt(beta)
    B = b + (rng.standard_normal((n_draw, 2)) * np.sqrt(ev)) @ V.T
    zc = np.sqrt(B[:, 0] + 1j * B[:, 1])
    w2 = np.column_stack([zc.real, zc.imag]) * rng.choice([-1.0, 1.0], n_draw)[:, None]
    parts = [w1, w2]
    if coax is not None:
        D, Z, S0 = _coaxial_terms(coax, m)
        Ccc = Ctt[m:, m:]
        S = D @ Ccc @ D.T + S0
        S_inv = np.linalg.inv(S)
        c_hat = np.concatenate([coax.center_mm[:, 0], coax.center_mm[:, 1]])
        Fw = Z.T @ S_inv @ Z
        cov_w = 4.0 * np.linalg.inv(Fw)  # twice the SD: a proposal wider than the posterior
        w_c = -np.linalg.solve(Fw, Z.T @ S_inv @ (D @ c_hat))
        parts.append(rng.multivariate_normal(w_c, cov_w, n_draw, method="cholesky"))
    w = np.vstack(parts)
    o = np.hypot(w[:, 0], w[:, 1])
    beta = np.column_stack([w[:, 0] ** 2 - w[:, 1] ** 2, 2 * w[:, 0] * w[:, 1]])
    d = beta - b
    q_lik = np.einsum("ij,jk,ik->i", d, Sb_inv, d)
    lik = np.exp(-0.5 * q_lik) / (2 * np.pi * np.sqrt(max(ev[0] * ev[1], 1e-300)))
    # densities per unit area of the w plane: prior 1 / (2 pi W omega); likelihood 2 omega^2 N(beta)
    prior = np.where(o <= W, 1.0 / (2 * np.pi * W * np.maximum(o, 1e-300)), 0.0)
    if coax is None:
        mix = 0.5 * prior + np.maximum(o, 1e-300) ** 2 * lik
        log_coax = np.zeros(o.size)
        cond = np.clip(np.diag(Ctt), 0.0, None)
    else:
        th = np.concatenate([rho, c_hat])[None, :] + d @ K.T  # the unknowns at beta: hat - K (b - beta)
        dw = w - w_c
        q3 = np.exp(-0.5 * np.einsum("ij,jk,ik->i", dw, np.linalg.inv(cov_w), dw)) / (
            2 * np.pi * np.sqrt(np.linalg.det(cov_w))
        )
        mix = (prior + 2.0 * np.maximum(o, 1e-300) ** 2 * lik + q3) / 3.0
        v = th[:, m:] @ D.T + (np.sinc(o / np.pi)[:, None] * w) @ Z.T  # hole_m - hole_1 at w
        log_coax = -0.5 * np.einsum("ij,jk,ik->i", v, S_inv, v)
        G = Ctt[:m, m:] @ D.T @ S_inv  # rho's update by the coaxial differences
        theta = th[:, :m] - v @ G.T
        cond = np.clip(np.diag(Ctt[:m, :m] - G @ D @ Ctt[m:, :m]), 0.0, None)
    target = prior * lik * np.exp(log_coax - np.max(log_coax, initial=0.0))
    wt = target / (mix + 1e-300)
    if not np.isfinite(wt.sum()) or wt.sum() <= 0:  # the likelihood lies far outside the prior
        wt = (o <= W) * np.exp(-0.5 * (q_lik - np.min(q_lik)) + log_coax - np.max(log_coax))
    wt = wt / wt.sum()
    s2 = o**2
    if coax is None:
        theta = rho[None, :] + d @ K.T
    R = theta / _k(s2)[:, None]
    r = wt @ R
    sm = float(wt @ s2)
    u_r = np.sqrt(wt @ (R - r) ** 2 + cond / _k(sm) ** 2)
    w_mean = wt @ w if coax is not None else None  # without the centres, w and -w are alike
    return sm, u_r, float(np.sqrt(wt @ (s2 - sm) ** 2)), r, w_mean


#: largest deflection a start may take [rad] (5.7 deg; the contract's rods deflect <= 1 deg)
_MAX_START_RAD = 0.1
#: pose-angle grid of the per-pose profile (module doc, "Start")
_POSE_GRID = np.linspace(-np.pi, np.pi, 360, endpoint=False)


def _repair_poses(prob, p, max_rounds: int = 3):
    """Repair the pose angles by a per-pose profile.

    Per-pose angle profile: with the holes and the axis held, each pose angle is searched on a
    grid over the whole circle; a pose whose grid minimum is clearly below its current cost is
    moved there and the joint LM re-run. A single pose angle can sit in a local minimum of its
    own (its readings are periodic in alpha_n) which LM cannot leave; this finds it.
    """
    cost = float(prob.residual(p) @ prob.residual(p))
    nfev = 0
    for _ in range(max_rounds):
        rho, c, alpha, w = prob.unpack(p)
        s = float(w @ w)
        holes, axis = rod_section_geometry(prob.layers, c, rho / _k(s), w)
        G = rod_readings(_POSE_GRID, list(prob.layers), holes, axis)  # (g, m)
        cur = np.where(prob.mask, prob.V - prob.readings(rho, c, alpha, w), 0.0)
        cur = np.sum(cur**2, axis=1)
        d = np.where(prob.mask[:, None, :], prob.Vz[:, None, :] - G[None, :, :], 0.0)
        grid_cost = np.sum(d**2, axis=2)  # (n, g)
        k = np.argmin(grid_cost, axis=1)
        best = grid_cost[np.arange(prob.n), k]
        move = best < 0.5 * cur  # a clear improvement: the pose sits in another basin
        move[prob.fix] = False
        if not np.any(move):
            break
        alpha = alpha.copy()
        alpha[move] = _POSE_GRID[k[move]]
        try:
            p1, cost1, kf = _lm(prob, prob.pack(rho, c, alpha, w if prob.deflection else None), prob.n_par)
        except ValueError:
            break
        nfev += kf
        if not (np.isfinite(cost1) and cost1 < cost):
            break
        p, cost = p1, cost1
    return p, cost, nfev


def _solve_core(  # noqa: C901 (the multi-start with its deflection starts and repairs)
    prob, L, mask, starts_alpha, deflection
):
    """Run the multi-start LM of the rod solve.

    Multi-start LM: every start (both reflections) first without deflection, then from the
    closed-form deflection start +-sqrt(beta_lin) (a Gauss-Newton step in beta at w = 0); the
    lowest cost wins, then the per-pose angle profile (:func:`_repair_poses`).
    """
    best, nfev = None, 0
    flat = _RodProblem(prob.V, mask, prob.layers, prob.fix, False)
    for alpha0 in starts_alpha:
        r0, c0 = _linear_start(L, mask, alpha0, prob.layers)
        p, cost, k = _lm(flat, flat.pack(r0, c0, alpha0), flat.n_par)
        nfev += k
        p, cost, k = _repair_poses(flat, p)
        nfev += k
        cand = [(p, cost)]
        if deflection:
            rho, c, alpha, _ = flat.unpack(p)
            full = prob.pack(rho, c, alpha, np.zeros(2))
            J = prob.jac(full, beta_step=1e-4)
            step, *_ = np.linalg.lstsq(J, -prob.residual(full), rcond=None)
            b = step[-2:]
            w0 = _w_of_beta(b, np.array([1.0, 0.0]))
            om0 = float(np.hypot(*w0))
            if om0 < 1e-4:
                w0 = np.array([1e-3, 0.0])
            elif om0 > _MAX_START_RAD:  # an ill-conditioned step: keep the rays inside the holes
                w0 = w0 * (_MAX_START_RAD / om0)
            cand = [(full, float(prob.residual(full) @ prob.residual(full)))]
            for sgn in (1.0, -1.0):
                try:
                    p1, cost1, k = _lm(prob, prob.pack(rho, c, alpha, sgn * w0), prob.n_par)
                except ValueError:  # the start puts a beam outside its hole
                    continue
                nfev += k
                # a minimum beyond _MAX_START_RAD is a low-signal wander, not a hand-held rod: not taken
                if np.isfinite(cost1) and np.hypot(*prob.unpack(p1)[3]) <= _MAX_START_RAD:
                    cand.append((p1, cost1))
        for p1, cost1 in cand:
            if best is None or cost1 < best[1]:
                best = (p1, cost1)
    p, cost = best
    if deflection:
        try:
            p1, cost1, k = _repair_poses(prob, p)
            nfev += k
            if cost1 < cost and np.hypot(*prob.unpack(p1)[3]) <= _MAX_START_RAD:
                p, cost = p1, cost1
        except ValueError:
            pass
    return p, cost, nfev


def solve_rod(  # noqa: C901 (input checks and one branch per deflection option)
    readings_mm,
    l0_mm=None,
    *,
    layers: Sequence[RodLayer] | None = None,
    u_reading_mm: float | None = None,
    fix_pose: int = 0,
    deflection: str = "free",
    max_condition: float = 1e8,
    max_u_ratio: float = 50.0,
    max_deflection_ratio: float = 10.0,
    max_deflection_rad: float = MAX_DEFLECTION_RAD,
    coaxiality_mm: float | None = None,
    centred: str = "refuse",
) -> RodSolution:
    r"""Solve the exact rod model (spec "Measuring rod"; Wang 2017 Eq. 16 generalised) jointly.

    Parameters
    ----------
    readings_mm : ndarray (n, m) readings v per pose n and layer/hole m [mm]; NaN = missing
    l0_mm : (m,) base length of each layer [mm] (replaces the layers' l0 when both are given)
    layers : RodLayer per column (phi, d, gamma, h, l0 from device.nominal or a rod calibration);
        None: phi = d = gamma = 0 (Wang Eq. 16)
    u_reading_mm : standard uncertainty of one reading [mm]; if None the residual RMS is used
        (with the degrees of freedom), which needs more readings than unknowns
    fix_pose : index (among the kept poses) of the pose whose angle is fixed at 0
    deflection : "free" (default: w unknown, radii with the debiased omega^2 of the module doc,
        method "joint"), "mle" (w unknown, radii at the maximum-likelihood omega^2, method
        "joint-mle": biased low by up to ~0.9 u at small omega), "none" (omega = 0: Wang Eq. 16
        with the layer geometry, method "eq16"; biased by -r omega^2 / 4 on a deflected rod)
    centred : what to do when the readings are constant within the noise ("refuse" or "mean").
        The data cannot tell a centred rod (angles undetermined, r = mean l) from an eccentric
        rod with all poses at one angle (r undetermined); "mean" asserts the poses were spread
        around the circle and returns r_m = mean_n l_nm, u = sigma / sqrt(n_m)
    max_condition : refuse when the column-scaled Jacobian is worse conditioned than this
    max_u_ratio : refuse when some u(r_m) with omega held exceeds this multiple of
        sigma / sqrt(n_m), the uncertainty of a centred rod's mean reading
    max_deflection_ratio : refuse when freeing the deflection multiplies some u(r_m) by more than
        this (the poses do not separate the section's ellipse from the radius)
    max_deflection_rad : bound of the deflection prior [rad] (``MAX_DEFLECTION_RAD``)
    coaxiality_mm : the holes share one axis within this tolerance [mm] (each centre within +- it,
        per coordinate): the centres then fix the deflection (:class:`CoaxialPrior`); None: the
        deflection is constrained by the readings' ellipse and the bound only

    Returns
    -------
    RodSolution (covariance sigma^2 (J^T J)^-1 in [rho, cx, cy, alpha\fix, beta]; u(diameter) = 2 u(r))

    Raises
    ------
    RodSolveError
        fewer readings than unknowns, a single hole, degenerate geometry (rank deficient or
        ill-conditioned Jacobian: poses bunched at one angle, rod axis parallel to or
        intersecting the holes' axis), or a deflection the poses cannot separate from the radii.
    """
    if deflection not in ("free", "mle", "none"):
        raise ValueError(f"deflection must be 'free', 'mle' or 'none', got {deflection!r}")
    v_in = np.asarray(readings_mm, dtype=float)
    m_in = v_in.shape[1] if v_in.ndim == 2 else None
    lays = rod_layers(l0_mm, layers, m_in)
    if m_in is not None and len(lays) != m_in:
        raise RodSolveError(f"{len(lays)} layers for {m_in} reading columns")
    l0 = np.array([lay.l0_mm for lay in lays])
    defl = deflection != "none"
    L, mask, keep = _prepare(v_in, l0, 2 if defl else 0)
    n, m = L.shape
    n_obs = int(mask.sum())
    p0, S = rod_start(L, mask, fix_pose)
    # Noise reference for the centred test: the given u, else the third singular value (m >= 3)
    sig_ref = (
        u_reading_mm if u_reading_mm is not None else (S[2] / np.sqrt(max(n - 2, 1)) if S.size > 2 else None)
    )
    if sig_ref is not None and S[0] < 5.0 * sig_ref * np.sqrt(n):
        if centred != "mean":
            raise RodSolveError(
                "degenerate geometry: readings constant within the noise - either the rod is centred "
                "(angles undetermined; pass centred='mean' if the poses were spread around the circle) "
                "or all poses are at nearly one angle (radii undetermined)"
            )
        Lf = np.where(mask, L, np.nan)
        r = np.nanmean(Lf, axis=0)
        cnt = mask.sum(axis=0)
        sd = np.nanstd(Lf, axis=0, ddof=1)
        sig = np.full(m, u_reading_mm) if u_reading_mm is not None else sd
        return RodSolution(
            radius_mm=r,
            u_radius_mm=sig / np.sqrt(cnt),
            xy_mm=np.zeros((m, 2)),
            alpha_rad=np.full(keep.size, np.nan),
            residual_rms_mm=float(np.sqrt(np.nanmean((Lf - r) ** 2))),
            sigma_mm=float(np.mean(sig)),
            rank=m,
            n_params=3 * m + n - 1 + (2 if defl else 0),
            condition=float("inf"),
            cov=None,
            method="centred",
            nfev=0,
        )
    a0 = np.insert(p0[3 * m :], fix_pose, 0.0)
    V = L - l0
    prob = _RodProblem(V, mask, lays, fix_pose, defl)
    p, cost, nfev = _solve_core(prob, L, mask, [a0, -a0], defl)
    n_par = prob.n_par
    J = prob.jac(p, beta_step=1e-4 if defl else None)
    js = jacobian_summary(J, rtol=1e-12)
    rank, cond = js.rank, js.condition
    if rank < n_par or cond > max_condition:
        raise RodSolveError(
            f"degenerate geometry: Jacobian rank {rank} of {n_par}, condition {cond:.3g} "
            f"(poses bunched at one angle, or the rod axis parallel to / intersecting the holes' axis "
            "so that the offsets (x_m, y_m) are collinear with the axis)"
        )
    e = prob.residual(p)
    rms = float(np.sqrt(np.mean(e**2)))
    dof = n_obs - n_par
    if u_reading_mm is not None:
        sigma = float(u_reading_mm)
    elif dof > 0:
        sigma = float(np.sqrt(e @ e / dof))
    else:
        sigma = float("nan")
    fit = fit_result(
        _rod_param_names(m, n, fix_pose, defl),
        p,
        e,
        J,
        sigma=sigma,
        success=True,
        nfev=nfev,
        rtol=1e-12,
        message=f"rod solve, deflection {deflection!r}",
    )
    cov = fit.cov
    rho, c, alpha, w = prob.unpack(p)
    ref = sigma / np.sqrt(mask.sum(axis=0))
    if defl:
        nb = n_par - 2
        cov0 = sigma**2 * jacobian_summary(J[:, :nb], rtol=1e-12).cov_unit
        u_fixed = np.sqrt(np.diag(cov0)[:m])
    else:
        u_fixed = np.sqrt(np.diag(cov)[:m])
    ratio = u_fixed / ref
    if np.any(ratio > max_u_ratio):
        raise RodSolveError(
            f"degenerate geometry: radii ill-determined, u(r) = {np.array2string(u_fixed, precision=4)} "
            "mm is up to "
            f"{ratio.max():.0f} x sigma/sqrt(n) (condition {cond:.3g}); the offsets (x_m, y_m) are "
            "nearly collinear "
            "with the axis (rod parallel to, or intersecting, the holes' axis) or the poses are bunched"
        )
    b = _beta(w)
    if defl:
        coax = None
        if coaxiality_mm is not None and deflection == "free":
            spot_z = np.array([lay.h_mm for lay in lays]) + rho * np.tan([lay.gamma_rad for lay in lays])
            if np.ptp(spot_z) > 0:
                coax = CoaxialPrior(c, spot_z, float(coaxiality_mm))
        out = _deflected_radii(rho, b, cov, m, deflection, max_deflection_rad, coax=coax)
        s, u_r, u_s = out[:3]
        r_post = out[3] if len(out) > 3 else None
        w_post = out[4] if len(out) > 4 else None
        # linearised, worst deflection direction: u(r) with omega free over u(r) with it held, from
        # the readings alone (with the coaxial prior too: where the readings cannot separate the
        # deflection, their beta is far from linear and the prior's beta would move rho along a
        # false line)
        q = rho / 4.0
        Crb = cov[:m, -2:]
        lam = float(np.linalg.eigvalsh(cov[-2:, -2:])[-1])
        u_lin = np.sqrt(np.diag(cov)[:m] + 2 * q * np.linalg.norm(Crb, axis=1) + q**2 * max(lam, 0.0))
        with np.errstate(invalid="ignore", divide="ignore"):
            dratio = float(np.nanmax(u_lin / u_fixed))
        if dratio > max_deflection_ratio:
            raise RodSolveError(
                "deflection not separable from the radii: freeing the rod axis deflection multiplies "
                "u(r) by "
                f"{dratio:.1f} (> {max_deflection_ratio:g}); the poses do not span the second harmonic "
                "of the "
                f"tilted section (u(omega^2) = {u_s:.3g} rad^2) - add poses spread around the circle"
            )
    else:
        s, u_s, dratio, r_post, w_post = 0.0, 0.0, 1.0, None, None
        u_r = u_fixed
    r = rho / _k(s) if r_post is None else r_post
    holes, _ = rod_section_geometry(lays, c, rho / _k(float(w @ w)), w)
    ecc = -np.array(holes[0].center_xy_mm)
    u_ecc = np.sqrt(np.clip(np.diag(cov)[[m, 2 * m]], 0.0, None))
    meth = {"free": "joint", "mle": "joint-mle", "none": "eq16"}[deflection]
    return RodSolution(
        radius_mm=np.abs(r),
        u_radius_mm=u_r,
        xy_mm=-c,
        alpha_rad=_expand(np.mod(alpha + np.pi, 2 * np.pi) - np.pi, keep),
        residual_rms_mm=rms,
        sigma_mm=sigma,
        rank=rank,
        n_params=n_par,
        condition=cond,
        cov=cov,
        method=meth,
        nfev=nfev,
        center_xy_mm=c,
        deflection_xy_rad=w.copy(),
        deflection_rad=float(np.sqrt(max(s, 0.0))),
        deflection_az_rad=float(np.arctan2(w[1], w[0])) if np.any(w != 0) else 0.0,
        deflection_sq_rad2=s,
        deflection_posterior_xy_rad=_posterior_vector(w_post, w, s),
        u_deflection_sq_rad2=float(u_s),
        eccentricity_mm=ecc,
        u_eccentricity_mm=u_ecc,
        radius_mle_mm=rho / _k(float(w @ w)),
        deflection_ratio=dratio,
        cost_mm2=cost,
        layers=lays,
        fit=fit,
    )


def _posterior_vector(w_post, w_mle, s) -> np.ndarray:
    """Return the deflection vector reported: the posterior mean, else sqrt(s) along the MLE direction."""
    if w_post is not None:
        return np.asarray(w_post, dtype=float)
    n = float(np.hypot(*w_mle))
    return np.zeros(2) if n == 0 else np.sqrt(max(s, 0.0)) * np.asarray(w_mle) / n


def _rod_param_names(m: int, n: int, fix_pose: int, deflection: bool) -> tuple[str, ...]:
    """Names of the joint solve's parameter vector [rho (m), cx (m), cy (m), alpha (n - 1), w (2)]."""
    names = [f"rho_{j + 1}_mm" for j in range(m)] + [f"cx_{j + 1}_mm" for j in range(m)]
    names += [f"cy_{j + 1}_mm" for j in range(m)] + [f"alpha_{i}_rad" for i in range(n) if i != fix_pose]
    return tuple(names + (["w_x_rad", "w_y_rad"] if deflection else []))


def _expand(a, keep):
    out = np.full(keep.size, np.nan)
    out[keep] = a
    return out


def rod_cost_mm2(readings_mm, alpha_rad, layers, holes, axis) -> float:
    """Return the sum of squared residuals against the exact forward model.

    Sum of squared residuals of ``readings_mm`` (n, m; NaN skipped) against the exact forward
    model at the given geometry (e.g. the truth of a simulated scan) [mm^2].
    """
    v = np.asarray(readings_mm, dtype=float)
    e = v - rod_readings(alpha_rad, list(layers), list(holes), axis)
    e = e[np.isfinite(e)]
    return float(e @ e)


def rod_crb(
    alpha_rad,
    l_mm=None,
    xy_mm=None,
    radius_mm=None,
    sigma_mm: float | None = None,
    fix_pose: int = 0,
    *,
    layers: Sequence[RodLayer] | None = None,
    holes: Sequence[Hole] | None = None,
    axis: RodAxis | None = None,
    deflection: bool = True,
    coaxiality_mm: float | None = None,
) -> np.ndarray:
    r"""Cramér-Rao bound on the radii for Gaussian reading noise sigma.

    Exact model (``layers``, ``holes``, ``axis`` given): Fisher information sigma^-2 J^T J of the
    readings in the solver's unknowns [rho, cx, cy, alpha\fix, beta] at the truth, then
    r = rho / k(|beta|) by the delta method along the true beta direction (the bound of the
    deflection-free unknowns with ``deflection=False``). The bound is the same in any
    parameterisation and tends to a finite limit as omega -> 0.

    Legacy form (``l_mm`` (n, m) = l0 + v, ``xy_mm``, ``radius_mm``): Wang Eq. 16 (no deflection),
    with the noise of e_nm = sigma de/dl, de/dl = (X c + Y s)/rho; CRB = (J^T W J)^-1.

    ``coaxiality_mm`` adds the information of the holes' coaxiality (:class:`CoaxialPrior`, the
    solve's prior of the same name): the bound the solve with that prior can reach.

    Returns
    -------
    ndarray (m,) standard deviation bound of each radius [mm]
    """
    a = np.asarray(alpha_rad, float)
    if layers is not None:
        lays = tuple(layers)
        ax = axis or RodAxis()
        V = rod_readings(a, list(lays), list(holes), ax)
        n, m = V.shape
        w = ax.omega_rad * np.array([np.cos(ax.omega_az_rad), np.sin(ax.omega_az_rad)])
        r = np.array([h.radius_mm for h in holes])
        # the solver's gauge: axis through the origin at z = 0, centres relative to the axis at the
        # spot height
        z = np.array([lay.h_mm for lay in lays]) + r * np.tan([lay.gamma_rad for lay in lays])
        c = (
            np.array([h.center_xy_mm for h in holes])
            - [ax.dx_mm, ax.dy_mm]
            - (z * np.sinc(ax.omega_rad / np.pi))[:, None] * w[None, :]
        )
        prob = _RodProblem(V, np.ones_like(V, dtype=bool), lays, fix_pose, deflection, alpha_fix=a[fix_pose])
        s = float(w @ w)
        p = prob.pack(r * _k(s), c, a, w)
        J = prob.jac(p, beta_step=1e-4 if deflection else None) / sigma_mm
        if deflection and coaxiality_mm is not None:
            J = np.vstack([J, _coaxial_rows(lays, r, c, w, coaxiality_mm, prob.n_par)])
        col = np.linalg.norm(J, axis=0)
        col[col == 0] = 1.0
        F = (J / col).T @ (J / col)
        cov = np.linalg.pinv(F) / np.outer(col, col)
        G = np.zeros((m, prob.n_par))
        rho = r * _k(s)
        G[np.arange(m), np.arange(m)] = 1.0 / _k(s)
        if deflection:
            G[:, -2:] = (
                -(rho * _dk(s) / _k(s) ** 2)[:, None]
                * np.array([np.cos(2 * ax.omega_az_rad), np.sin(2 * ax.omega_az_rad)])[None, :]
            )
        return np.sqrt(np.diag(G @ cov @ G.T))
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


def _coaxial_rows(layers, r, c, w, tolerance_mm, n_par) -> np.ndarray:
    """Whitened rows of the coaxial prior (:class:`CoaxialPrior`) in [rho, cx, cy, alpha, beta].

    d(hole_m - hole_1)/d(c, beta) at the deflection vector w, whitened by the prior's covariance;
    beta = w^2 (complex), so d w / d beta = 1 / (2 w) (large when the deflection is small: then
    the centres fix beta = w^2 all the better).
    """
    m = len(layers)
    z = np.array([lay.h_mm for lay in layers]) + r * np.tan([lay.gamma_rad for lay in layers])
    coax = CoaxialPrior(np.asarray(c, float), z, float(tolerance_mm))
    D, Z, S0 = _coaxial_terms(coax, m)
    wz = complex(max(float(np.hypot(*w)), 1e-9), 0.0) if not np.any(w) else complex(w[0], w[1])
    inv = 1.0 / (2.0 * wz)  # d w / d beta as a complex number
    dw_db = np.array([[inv.real, -inv.imag], [inv.imag, inv.real]])
    rows = np.zeros((2 * (m - 1), n_par))
    rows[:, m : 3 * m] = D
    rows[:, -2:] = Z @ dw_db * np.sinc(float(np.hypot(*w)) / np.pi)
    Lc = np.linalg.cholesky(S0)
    return np.linalg.solve(Lc, rows)


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
    r"""Global-best particle swarm on Wang Eq. 16 (the paper's solver; benchmark baseline only).

    Minimises sum e_nm^2 over [r, x, y, alpha\0] in the box r in [min l - 1, max l + 1],
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
        radius_mm=r,
        u_radius_mm=np.full(m, np.nan),
        xy_mm=np.column_stack([x, y]),
        alpha_rad=_expand(a, keep),
        residual_rms_mm=float(np.sqrt(gf / mask.sum())),
        sigma_mm=float("nan"),
        rank=-1,
        n_params=d,
        condition=float("nan"),
        cov=None,
        method="pso",
        nfev=nfev,
    )
