"""The rod's deflection: its prior, what the holes' coaxiality tells, and the radii averaged over it.

See :mod:`borescan.rod`, "Deflection". :func:`_deflected_radii` turns the solve's rho and beta with
their covariance into radii r = rho / k(omega^2) averaged over the posterior of the deflection
vector w (a bound prior on omega, the readings' likelihood of beta, and with :class:`CoaxialPrior`
the centres' evidence); :func:`_coaxial_rows` is the same prior's information for the bound;
:func:`_deflection_part` is the solve's step from its minimum to those radii.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from borescan.rod_eq16 import hold_refusal
from borescan.rod_model import _beta, _dk, _k

__all__ = ["CoaxialPrior", "MAX_DEFLECTION_RAD"]


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


def _quadratic_forms(x: np.ndarray, A: np.ndarray) -> np.ndarray:
    """Return x_i^T A x_i for every row x_i of ``x`` (n, p), A (p, p).

    One matrix product and a row sum: ``np.einsum("ij,jk,ik->i", x, A, x)`` loops over the three indices
    in one unoptimised kernel, 0.38 ms for 12 000 rows of 2 (0.62 ms for rows of 4) where this takes 0.23
    (0.26) ms; the same sums to rounding.
    """
    return np.sum((x @ A) * x, axis=1)


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
    q_lik = _quadratic_forms(d, Sb_inv)
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
        q3 = np.exp(-0.5 * _quadratic_forms(dw, np.linalg.inv(cov_w))) / (
            2 * np.pi * np.sqrt(np.linalg.det(cov_w))
        )
        mix = (prior + 2.0 * np.maximum(o, 1e-300) ** 2 * lik + q3) / 3.0
        v = th[:, m:] @ D.T + (np.sinc(o / np.pi)[:, None] * w) @ Z.T  # hole_m - hole_1 at w
        log_coax = -0.5 * _quadratic_forms(v, S_inv)
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


def _posterior_vector(w_post, w_mle, s) -> np.ndarray:
    """Return the deflection vector reported: the posterior mean, else sqrt(s) along the MLE direction."""
    if w_post is not None:
        return np.asarray(w_post, dtype=float)
    n = float(np.hypot(*w_mle))
    return np.zeros(2) if n == 0 else np.sqrt(max(s, 0.0)) * np.asarray(w_mle) / n


def _deflection_part(
    rho, c, w, cov, lays, deflection, u_fixed, coaxiality_mm, max_deflection_rad, max_deflection_ratio
):
    """Return (s, u(r), u(s), r, posterior w, deflection ratio) of a solve with the deflection free.

    The radii averaged over the deflection (:func:`_deflected_radii`, with the holes' coaxiality
    when given); refused when the readings cannot separate the deflection from the radii
    (:mod:`borescan.rod`, "Refusals").
    """
    m = rho.size
    b = _beta(w)
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
        raise hold_refusal(
            "deflection not separable from the radii: freeing the rod axis deflection multiplies "
            "u(r) by "
            f"{dratio:.1f} (> {max_deflection_ratio:g}); the poses do not span the second harmonic "
            "of the "
            f"tilted section (u(omega^2) = {u_s:.3g} rad^2) - add poses spread around the circle"
        )
    return s, u_r, u_s, r_post, w_post, dratio
