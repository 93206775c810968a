"""The rod solve's forward model in its unknowns and its multi-start Levenberg-Marquardt.

:class:`_RodProblem` gives the exact readings (:func:`borescan.geometry.rod_readings`) in the
unknowns [rho (m), cx (m), cy (m), alpha (n - 1), w (2)] and their Jacobian (with
:func:`_cov_without_poses`, the bound of the unknowns other than the pose angles); :func:`_solve_core`
runs the starts and repairs that :func:`borescan.rod.solve_rod` describes ("Start").
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace

import numpy as np
from scipy.optimize import least_squares

from borescan.geometry import RodLayer, rod_layer_arrays
from borescan.physics.rod import rod_section_readings
from borescan.rod_eq16 import _linear_start

__all__ = ["rod_layers"]


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
        self._arrays = rod_layer_arrays(self.layers)

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
        """Return the readings (n, m) at the unknowns, or (B, n, m) at B sets of them stacked.

        :func:`borescan.physics.rod.rod_section_readings` (rho over the deflection's factor is the
        radius): rho (..., m), c (..., m, 2), alpha (..., n), w (..., 2).
        """
        w = np.asarray(w, dtype=float)
        s = w[..., 0] ** 2 + w[..., 1] ** 2
        r = rho / _k(s)[..., None]
        return rod_section_readings(alpha, self._arrays, c, r, w)

    def residual(self, p):
        e = np.where(self.mask, self.V - self.readings(*self.unpack(p)), 0.0)
        return e[self.mask]

    def jac(self, p, beta_step=None):
        """Return d(model)/dp by central differences in blocks.

        d(model)/dp by central differences in blocks (a pose angle moves its row only, a hole's
        unknowns its column only: 12 model evaluations, made in one call of :meth:`readings`).
        With ``beta_step`` the last two columns are secants in beta = w^2 (complex square) instead:
        the statistics' coordinates.
        """
        rho, c, alpha, w = self.unpack(p)
        n, m = self.n, self.m
        h, hr = 1e-6, 1e-5
        ex, ey = np.array([1.0, 0.0]), np.array([0.0, 1.0])
        # (step, unknowns stepped +, unknowns stepped -): the poses, the radii, the centres' x and y
        # (every hole's at once), then w or beta
        pairs = [
            (h, (rho, c, alpha + h, w), (rho, c, alpha - h, w)),
            (hr, (rho + hr, c, alpha, w), (rho - hr, c, alpha, w)),
            *((hr, (rho, c + hr * e, alpha, w), (rho, c - hr * e, alpha, w)) for e in (ex, ey)),
        ]
        if self.deflection and beta_step is None:
            pairs += [(h, (rho, c, alpha, w + h * e), (rho, c, alpha, w - h * e)) for e in (ex, ey)]
        elif self.deflection:
            b, bs = _beta(w), beta_step
            pairs += [
                (bs, (rho, c, alpha, _w_of_beta(b + bs * e, w)), (rho, c, alpha, _w_of_beta(b - bs * e, w)))
                for e in (ex, ey)
            ]
        stacked = [u for _step, plus, minus in pairs for u in (plus, minus)]
        F = self.readings(*(np.stack(x) for x in zip(*stacked)))
        D = [(F[2 * i] - F[2 * i + 1]) / (2 * step) for i, (step, _plus, _minus) in enumerate(pairs)]
        J = np.zeros((n, m, self.n_par))
        free = np.delete(np.arange(n), self.fix)
        J[free, :, 3 * m + np.arange(n - 1)] = D[0][free]
        idx = np.arange(m)
        J[:, idx, idx] = D[1]
        J[:, idx, m + idx] = D[2]
        J[:, idx, 2 * m + idx] = D[3]
        if self.deflection:
            J[:, :, -2] = D[4]
            J[:, :, -1] = D[5]
        return -J[self.mask]  # residual = V - model


def _cov_without_poses(J: np.ndarray, i0: int, n_alpha: int) -> np.ndarray:
    """Return the covariance bound of the unknowns other than the pose angles (Fisher matrix J^T J).

    The pose angles are columns ``i0 .. i0 + n_alpha`` of ``J``; each moves only its own pose's
    readings, so their block of the (column-scaled) Fisher matrix is diagonal and eliminating
    them leaves the Schur complement A - B D^-1 B^T of the other unknowns: its pseudo-inverse is
    their block of the full matrix's inverse, at a cost linear in the number of poses instead of
    cubic. Where an angle has no information (a zero diagonal) or the block is not diagonal, the
    full Fisher matrix is pseudo-inverted instead.
    """
    col = np.linalg.norm(J, axis=0)
    col[col == 0] = 1.0
    Js = J / col
    ia = np.arange(i0, i0 + n_alpha)
    io = np.delete(np.arange(J.shape[1]), ia)
    Ja, Jo = Js[:, ia], Js[:, io]
    d = np.einsum("ij,ij->j", Ja, Ja)
    diagonal = np.count_nonzero(Ja, axis=1).max(initial=0) <= 1
    if diagonal and np.all(d > 1e-12):
        B = Jo.T @ Ja
        cov = np.linalg.pinv(Jo.T @ Jo - (B / d) @ B.T)
    else:
        cov = np.linalg.pinv(Js.T @ Js)[np.ix_(io, io)]
    return cov / np.outer(col[io], col[io])


def _beta(w):
    """beta = w^2 as a complex square: omega^2 (cos 2 omega_az, sin 2 omega_az)."""
    return np.array([w[0] ** 2 - w[1] ** 2, 2 * w[0] * w[1]])


def _w_of_beta(b, w_ref):
    """Complex square root of beta on the branch nearest ``w_ref``."""
    z = np.sqrt(complex(b[0], b[1]))
    if z.real * w_ref[0] + z.imag * w_ref[1] < 0:
        z = -z
    return np.array([z.real, z.imag])


def _lm(prob, p0, n_par, tol: float = 1e-14, nfev_per_par: int = 100):
    sol = least_squares(
        prob.residual,
        p0,
        jac=prob.jac,
        method="lm",
        x_scale="jac",
        xtol=tol,
        ftol=tol,
        gtol=tol,
        max_nfev=nfev_per_par * n_par,
    )
    return sol.x, float(sol.fun @ sol.fun), int(sol.nfev)


#: largest deflection a start may take [rad] (5.7 deg; the contract's rods deflect <= 1 deg)
_MAX_START_RAD = 0.1


#: pose-angle grid of the per-pose profile (module doc, "Start")
_POSE_GRID = np.linspace(-np.pi, np.pi, 360, endpoint=False)


def _repair_poses(prob, p, max_rounds: int = 3, nfev_per_par: int = 100):
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
        G = prob.readings(rho, c, _POSE_GRID, w)  # (g, m): every pose angle of the grid
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
            p0 = prob.pack(rho, c, alpha, w if prob.deflection else None)
            p1, cost1, kf = _lm(prob, p0, prob.n_par, 1e-14, nfev_per_par)
        except ValueError:
            break
        nfev += kf
        if not (np.isfinite(cost1) and cost1 < cost):
            break
        p, cost = p1, cost1
    return p, cost, nfev


def _solve_core(  # noqa: C901 (the multi-start with its deflection starts and repairs)
    prob, L, mask, starts_alpha, deflection, minima: list | None = None, nfev_per_par: int = 100
):
    """Run the multi-start LM of the rod solve.

    Multi-start LM: every start (both reflections) first without deflection, then from the
    closed-form deflection start +-sqrt(beta_lin) (a Gauss-Newton step in beta at w = 0); the
    lowest cost wins, then the per-pose angle profile (:func:`_repair_poses`). ``minima``: when
    given, every start's LM minimum (p, cost) is appended to it (:mod:`borescan.rod_minima`). Each LM
    stops after ``nfev_per_par`` evaluations per parameter (a start's budget; a solve's default 100).
    """
    kw = {"tol": 1e-14, "nfev_per_par": nfev_per_par}
    best, nfev = None, 0
    flat = _RodProblem(prob.V, mask, prob.layers, prob.fix, False)
    for alpha0 in starts_alpha:
        r0, c0 = _linear_start(L, mask, alpha0, prob.layers)
        p, cost, k = _lm(flat, flat.pack(r0, c0, alpha0), flat.n_par, **kw)
        nfev += k
        p, cost, k = _repair_poses(flat, p, nfev_per_par=nfev_per_par)
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
                    p1, cost1, k = _lm(prob, prob.pack(rho, c, alpha, sgn * w0), prob.n_par, **kw)
                except ValueError:  # the start puts a beam outside its hole
                    continue
                nfev += k
                # a minimum beyond _MAX_START_RAD is a low-signal wander, not a hand-held rod: not taken
                if np.isfinite(cost1) and np.hypot(*prob.unpack(p1)[3]) <= _MAX_START_RAD:
                    cand.append((p1, cost1))
        if minima is not None:  # the LM minima (with deflection: not the w = 0 start point)
            minima.extend(cand[1:] if deflection else cand)
        for p1, cost1 in cand:
            if best is None or cost1 < best[1]:
                best = (p1, cost1)
    p, cost = best
    if deflection:
        try:
            p1, cost1, k = _repair_poses(prob, p, nfev_per_par=nfev_per_par)
            nfev += k
            if cost1 < cost and np.hypot(*prob.unpack(p1)[3]) <= _MAX_START_RAD:
                p, cost = p1, cost1
        except ValueError:
            pass
    p, cost = _canonical_image(prob, p, cost)
    return p, cost, nfev


#: two minima whose costs agree to this relative amount are one minimum seen in a symmetry's images
_IMAGE_RTOL = 1e-9


def _images(prob, p) -> list:
    """Return ``p`` and its images under the model's symmetries that hold at the design layers.

    The mirror y -> -y (alpha -> -alpha, cy -> -cy, w_y -> -w_y; exact where every layer has
    phi = d = 0 and the fixed pose is at 0) and the deflection's sign (w -> -w: the same beta).
    Whether an image is a minimum as low is for the caller to check.
    """
    rho, c, alpha, w = prob.unpack(p)
    mirror = prob.alpha_fix == 0.0
    out = []
    for flip in (False, True) if mirror else (False,):
        for sign in (1.0, -1.0) if prob.deflection else (1.0,):
            cm = np.column_stack([c[:, 0], -c[:, 1]]) if flip else c
            am = -alpha if flip else alpha
            wm = sign * (np.array([w[0], -w[1]]) if flip else w)
            out.append(prob.pack(rho, cm, am, wm if prob.deflection else None))
    return out


def _image_key(prob, p) -> tuple:
    """Order the images of one minimum: beta_y > 0 first, then sum sin(alpha) > 0, then w_x > 0."""
    _rho, _c, alpha, w = prob.unpack(p)
    nw = float(w @ w)
    by = 2.0 * w[0] * w[1]
    sa = float(np.sum(np.sin(alpha)))

    def sign(x: float, scale: float) -> int:
        return 0 if abs(x) <= 1e-9 * scale else int(np.sign(x))

    return (sign(by, nw), sign(sa, prob.n), sign(w[0], np.sqrt(nw)), sign(w[1], np.sqrt(nw)))


def _canonical_image(prob, p, cost: float) -> tuple[np.ndarray, float]:
    """Return the canonical one of the minimum's images that are as low (:func:`_images`).

    At the design layers the mirror image of a minimum is an exact minimum as low, and the
    multi-start finds either, decided by the last bits of the readings; what follows the solve
    (the radii averaged over the deflection by sampling, the layer-geometry draws refined from it)
    is not exactly symmetric, so the image is chosen by sign (:func:`_image_key`), not by those
    bits. Images whose cost is not within ``_IMAGE_RTOL`` of ``cost`` (the symmetry broken by the
    layers) are not taken.
    """
    tied = [(p, cost)]
    for q in _images(prob, p)[1:]:
        try:
            r = prob.residual(q)
        except ValueError:  # an image that puts a beam outside its hole
            continue
        cq = float(r @ r)
        if np.isfinite(cq) and abs(cq - cost) <= _IMAGE_RTOL * cost:
            tied.append((q, cq))
    return max(tied, key=lambda t: _image_key(prob, t[0]))


def _rod_param_names(m: int, n: int, fix_pose: int, deflection: bool) -> tuple[str, ...]:
    """Names of the joint solve's parameter vector [rho (m), cx (m), cy (m), alpha (n - 1), w (2)]."""
    names = [f"rho_{j + 1}_mm" for j in range(m)] + [f"cx_{j + 1}_mm" for j in range(m)]
    names += [f"cy_{j + 1}_mm" for j in range(m)] + [f"alpha_{i}_rad" for i in range(n) if i != fix_pose]
    return tuple(names + (["w_x_rad", "w_y_rad"] if deflection else []))


def _expand(a, keep):
    out = np.full(keep.size, np.nan)
    out[keep] = a
    return out
