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
both reflections are started; exact at phi = d = 0, as is w -> -w, where the solve takes the image
with beta_y >= 0 (``rod_model._canonical_image``), not the one the readings' last bits led to.

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
the data put omega clearly beyond it): see ``rod_deflection._deflected_radii``.
``deflection="mle"`` gives r at |beta_hat|; "none" holds omega = 0.

The holes' coaxiality (``coaxiality_mm``; the pipeline's ``uncertainty.rod_hole_coaxiality_mm``)
fixes w where the ellipse cannot: the centres c_m are relative to the axis at each spot, so
hole_m - hole_1 = c_m - c_1 + (z_m - z_1) sin(omega) u(omega_az), and holes coaxial within t give
w to about t / (z_m - z_1) (``rod_deflection.CoaxialPrior``): on the demo's holds (layers 300 mm
apart, t = 50 um) omega is found within 5 % where the ellipse alone left it anywhere in 0-2 deg.
The posterior then conditions rho and the centres on beta = w^2 and on the coaxial differences.

Start: the rank-2 structure of the readings gives the pose angles up to a
rotation and a reflection (SVD + ellipse fit, below), a linear fit the radii and centres; LM
without deflection from both reflections, then one Gauss-Newton step in beta (the model is
linear in beta) and LM from w = +-sqrt(beta); the lowest cost wins. A per-pose angle profile
(each pose searched on a 1 deg grid with the rest held, LM re-run when a pose moves) frees pose
angles stuck in a local minimum of their own (``_repair_poses``).

Refusals (RodSolveError; those a new hold would fix end with ``rod_eq16.HOLD_FIX``, what hold and
where ``borescan plan --rod-scan`` plans it): fewer readings than unknowns; degenerate geometry
(rank or condition of the column-scaled Jacobian, or u(r) with omega held > ``max_u_ratio``
sigma/sqrt(n): offsets (x_m, y_m) collinear with the axis, a rod parallel to the holes, poses
bunched); a deflection the poses cannot separate from the radii (freeing omega multiplies u(r) by >
``max_deflection_ratio``).

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

from borescan.fit import FitResult, fit_result, jacobian_summary
from borescan.geometry import Hole, RodAxis, RodLayer, rod_readings
from borescan.physics.rod import rod_section_geometry
from borescan.rod_deflection import MAX_DEFLECTION_RAD, _coaxial_rows, _deflection_part, _posterior_vector
from borescan.rod_minima import other_minima
from borescan.rod_eq16 import RodSolveError, _prepare, _unpack, hold_refusal, rod_jacobian, rod_start
from borescan.rod_model import (
    _cov_without_poses,
    _dk,
    _expand,
    _k,
    _RodProblem,
    _rod_param_names,
    _solve_core,
    rod_layers,
)

__all__ = [
    "RodSolveError",
    "RodSolution",
    "solve_rod",
    "solve_rod_pso",
    "rod_crb",
    "rod_cost_mm2",
]


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
    other_minima : other minima within 25 chi^2, with weights (:class:`borescan.rod_minima.RodMinimum`)
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
    other_minima: tuple = ()

    @property
    def diameter_mm(self) -> np.ndarray:
        """Diameters [mm] of the holes."""
        return 2.0 * self.radius_mm

    @property
    def u_diameter_mm(self) -> np.ndarray:
        """Standard uncertainties [mm] of the diameters."""
        return 2.0 * self.u_radius_mm


@dataclass(frozen=True)
class _Limits:
    """The settings of :func:`solve_rod` that act after its minimum is found (its parameters)."""

    u_reading_mm: float | None
    deflection: str = "free"
    max_condition: float = 1e8
    max_u_ratio: float = 50.0
    max_deflection_ratio: float = 10.0
    max_deflection_rad: float = MAX_DEFLECTION_RAD
    coaxiality_mm: float | None = None


def solve_rod(  # noqa: C901 (input checks and one branch per deflection option)
    readings_mm,
    l0_mm=None,
    *,
    layers: Sequence[RodLayer] | None = None,
    u_reading_mm: float | None = None,
    fix_pose: int = 0,
    deflection: str = "free",
    max_condition: float = _Limits.max_condition,
    max_u_ratio: float = _Limits.max_u_ratio,
    max_deflection_ratio: float = _Limits.max_deflection_ratio,
    max_deflection_rad: float = _Limits.max_deflection_rad,
    coaxiality_mm: float | None = None,
    centred: str = "refuse",
    nfev_per_par: int = 100,
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
    nfev_per_par : each LM of the multi-start stops after this many evaluations per unknown (a start's
        budget where the minimum need not be reached exactly)
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
    p0, S = rod_start(L, mask, fix_pose)
    if _readings_constant(S, n, u_reading_mm, centred):
        return _centred_solution(L, mask, keep, u_reading_mm, 3 * m + n - 1 + (2 if defl else 0))
    a0 = np.insert(p0[3 * m :], fix_pose, 0.0)
    V = L - l0
    prob = _RodProblem(V, mask, lays, fix_pose, defl)
    starts: list = []
    p, cost, nfev = _solve_core(prob, L, mask, [a0, -a0], defl, starts, nfev_per_par)
    lim = _Limits(
        u_reading_mm,
        deflection,
        max_condition,
        max_u_ratio,
        max_deflection_ratio,
        max_deflection_rad,
        coaxiality_mm,
    )
    sol = _solution(prob, p, cost, nfev, keep, lim)
    alpha_of, radii_at = (
        (lambda q: prob.unpack(q)[2]),
        (lambda q, c: _solution(prob, q, c, 0, keep, lim).radius_mm),
    )
    return replace(sol, other_minima=other_minima(starts, p, cost, sol, alpha_of, radii_at))


def _solution(prob: _RodProblem, p, cost: float, nfev: int, keep, lim: _Limits) -> RodSolution:
    """Return the solve's result at its minimum ``p``: covariance, refusals, radii over the deflection."""
    mask, lays, deflection, defl = prob.mask, prob.layers, lim.deflection, prob.deflection
    n, m = prob.n, prob.m
    n_obs = int(mask.sum())
    u_reading_mm, coaxiality_mm = lim.u_reading_mm, lim.coaxiality_mm
    n_par = prob.n_par
    J = prob.jac(p, beta_step=1e-4 if defl else None)
    js = jacobian_summary(J, rtol=1e-12)
    rank, cond = js.rank, js.condition
    if rank < n_par or cond > lim.max_condition:
        raise hold_refusal(
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
        _rod_param_names(m, n, prob.fix, defl),
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
    u_fixed = _u_radii_held(J, cov, sigma, mask, defl, lim.max_u_ratio, cond)
    if defl:
        s, u_r, u_s, r_post, w_post, dratio = _deflection_part(
            rho,
            c,
            w,
            cov,
            lays,
            deflection,
            u_fixed,
            coaxiality_mm,
            lim.max_deflection_rad,
            lim.max_deflection_ratio,
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


def _readings_constant(S, n, u_reading_mm, centred) -> bool:
    """Return whether the readings are constant within the noise (centred rod); refused unless "mean".

    The noise reference: the given u, else the third singular value S[2] of the centred readings (m >= 3).
    """
    sig_ref = (
        u_reading_mm if u_reading_mm is not None else (S[2] / np.sqrt(max(n - 2, 1)) if S.size > 2 else None)
    )
    if sig_ref is None or S[0] >= 5.0 * sig_ref * np.sqrt(n):
        return False
    if centred != "mean":
        raise hold_refusal(
            "degenerate geometry: readings constant within the noise - either the rod is centred "
            "(angles undetermined; pass centred='mean' if the poses were spread around the circle) "
            "or all poses are at nearly one angle (radii undetermined)"
        )
    return True


def _centred_solution(L, mask, keep, u_reading_mm, n_par) -> RodSolution:
    """Return the radii of a centred rod: the mean readings, u = sigma / sqrt(n_m) (``centred="mean"``)."""
    m = L.shape[1]
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
        n_params=n_par,
        condition=float("inf"),
        cov=None,
        method="centred",
        nfev=0,
    )


def _u_radii_held(J, cov, sigma, mask, defl, max_u_ratio, cond) -> np.ndarray:
    """Return u(r_m) with the deflection held; refuse radii the geometry leaves ill-determined."""
    m = mask.shape[1]
    n_par = J.shape[1]
    ref = sigma / np.sqrt(mask.sum(axis=0))
    if defl:
        nb = n_par - 2
        cov0 = sigma**2 * jacobian_summary(J[:, :nb], rtol=1e-12).cov_unit
        u_fixed = np.sqrt(np.diag(cov0)[:m])
    else:
        u_fixed = np.sqrt(np.diag(cov)[:m])
    ratio = u_fixed / ref
    if np.any(ratio > max_u_ratio):
        raise hold_refusal(
            f"degenerate geometry: radii ill-determined, u(r) = {np.array2string(u_fixed, precision=4)} "
            "mm is up to "
            f"{ratio.max():.0f} x sigma/sqrt(n) (condition {cond:.3g}); the offsets (x_m, y_m) are "
            "nearly collinear "
            "with the axis (rod parallel to, or intersecting, the holes' axis) or the poses are bunched"
        )
    return u_fixed


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
        cov = _cov_without_poses(J, 3 * m, n - 1)
        G = np.zeros((m, prob.n_par))
        rho = r * _k(s)
        G[np.arange(m), np.arange(m)] = 1.0 / _k(s)
        if deflection:
            G[:, -2:] = (
                -(rho * _dk(s) / _k(s) ** 2)[:, None]
                * np.array([np.cos(2 * ax.omega_az_rad), np.sin(2 * ax.omega_az_rad)])[None, :]
            )
        G = np.delete(G, np.s_[3 * m : 3 * m + n - 1], axis=1)
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
