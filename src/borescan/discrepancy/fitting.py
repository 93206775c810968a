"""Least-squares fits, information criterion and noise floor of the discrepancy workflow.

A fit returns one :class:`FitResult` (lmfit style): parameters, standard uncertainties,
residuals, RSS and the Bayesian information criterion
``BIC = n ln(RSS / n) + p ln(n)`` (Gaussian likelihood with the variance profiled out).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares

from borescan.noise import noise_floor_mm, robust_sigma  # noqa: F401  (re-exported: the discrepancy workflow names them here)

__all__ = [
    "leading_block",
    "block_indices",
    "FitResult",
    "fit_least_squares",
    "bic",
    "noise_floor_mm",
    "robust_sigma",
    "spike_mask",
]


@dataclass
class FitResult:
    """Result of one least-squares fit.

    Attributes
    ----------
    names : free parameter names, in ``x`` order.
    x : best-fit values (physical units).
    u : standard uncertainties (physical units), from (J^T J)^-1 s^2.
    residual : weighted residual vector at the optimum.
    rss : sum of squared weighted residuals.
    n : number of residuals; p : number of free parameters.
    bic : n ln(RSS/n) + p ln(n).
    success, message : optimiser status.
    """

    names: tuple[str, ...]
    x: np.ndarray
    u: np.ndarray
    residual: np.ndarray
    rss: float
    n: int
    p: int
    bic: float
    success: bool = True
    message: str = ""
    extra: dict = field(default_factory=dict)

    def values(self) -> dict[str, float]:
        """Parameter name -> value."""
        return {k: float(v) for k, v in zip(self.names, self.x)}

    def uncertainties(self) -> dict[str, float]:
        """Parameter name -> standard uncertainty."""
        return {k: float(v) for k, v in zip(self.names, self.u)}


def bic(rss: float, n: int, p: int) -> float:
    """Bayesian information criterion of a Gaussian least-squares fit: n ln(RSS/n) + p ln(n)."""
    return float(n * np.log(max(rss, 1e-300) / n) + p * np.log(n))


def fit_least_squares(
    residual_fn: Callable[[dict[str, float]], np.ndarray],
    names: Sequence[str],
    x0: Sequence[float],
    scale: Sequence[float],
    *,
    fixed: dict[str, float] | None = None,
    max_nfev: int = 60,
) -> FitResult:
    """Minimise ``sum(residual_fn(params)**2)`` over ``names`` (others from ``fixed``).

    Parameters are scaled by ``scale`` (typical magnitudes) so that forward differences with a
    relative step of 1e-4 of the scale give accurate Jacobians.
    """
    names = tuple(names)
    fixed = dict(fixed or {})
    scale = np.asarray(scale, dtype=float)
    z0 = np.asarray(x0, dtype=float) / scale

    def fun(z: np.ndarray) -> np.ndarray:
        p = dict(fixed)
        p.update(zip(names, z * scale))
        return residual_fn(p)

    def jac(z: np.ndarray) -> np.ndarray:
        f0 = fun(z)
        J = np.empty((f0.size, z.size))
        for i in range(z.size):
            zz = z.copy()
            h = 1e-4
            zz[i] += h
            J[:, i] = (fun(zz) - f0) / h
        return J

    if z0.size:
        res = least_squares(fun, z0, jac=jac, method="lm", max_nfev=max_nfev, xtol=1e-10, ftol=1e-12)
        z, r, J, ok, msg = res.x, res.fun, res.jac, bool(res.success), str(res.message)
    else:
        z, r, J, ok, msg = z0, fun(z0), np.zeros((0, 0)), True, "nothing to fit"
    n, p = r.size, z.size
    rss = float(r @ r)
    if p:
        s2 = rss / max(n - p, 1)
        try:
            cov = np.linalg.pinv(J.T @ J) * s2
            u = np.sqrt(np.clip(np.diag(cov), 0.0, None)) * scale
        except np.linalg.LinAlgError:
            u = np.full(p, np.nan)
    else:
        u = np.zeros(0)
    return FitResult(names, z * scale, u, r, rss, n, p, bic(rss, n, p), ok, msg)


def dead_zone(r: np.ndarray, half_mm: np.ndarray | None) -> np.ndarray:
    """Residuals of cell-valued (quantised) readings: 0 inside the cell +-half, else the distance
    to its edge. ``half_mm`` broadcasts against ``r`` (per channel); None leaves ``r`` unchanged."""
    if half_mm is None:
        return r
    return np.sign(r) * np.maximum(np.abs(r) - half_mm, 0.0)


def spike_mask(
    residual_mm: np.ndarray, sigma_mm: np.ndarray, *, k_sigma: float = 7.0, window: int = 7
) -> np.ndarray:
    """Samples that jump away from their neighbours by more than ``k_sigma`` noise levels.

    The residual minus its running median (``window`` samples) keeps isolated jumps and removes
    smooth misfit, so a model error is not taken for an outlier.

    Returns
    -------
    ndarray (n, c) bool
    """
    from scipy.ndimage import median_filter

    r = np.asarray(residual_mm, dtype=float)
    out = np.zeros(r.shape, dtype=bool)
    for j in range(r.shape[1]):
        ok = np.isfinite(r[:, j])
        if ok.sum() < window:
            continue
        rc = r[ok, j]
        dev = rc - median_filter(rc, size=window, mode="nearest")
        hit = np.abs(dev) > k_sigma * max(float(sigma_mm[j]), 1e-12)
        col = np.zeros(r.shape[0], dtype=bool)
        col[np.flatnonzero(ok)[hit]] = True
        out[:, j] = col
    return out


def leading_block(t_s: np.ndarray) -> int:
    """Number of leading samples on an even time grid (spectra need uniform sampling)."""
    t = np.asarray(t_s, dtype=float)
    if t.size < 3:
        return t.size
    dt = np.diff(t)
    step = float(np.median(dt))
    gaps = np.flatnonzero(np.abs(dt - step) > 0.5 * step)
    return int(gaps[0] + 1) if gaps.size else t.size


def block_indices(n: int, max_samples: int, n_blocks: int = 4) -> np.ndarray:
    """Indices of ``n_blocks`` contiguous blocks spread evenly over ``n`` samples, ``max_samples`` in all.

    Long scans are examined on these blocks: each keeps the sample-to-sample structure (noise
    floor, vibration lines), their spread keeps the time baseline (drift, speed error).
    """
    if n <= max_samples:
        return np.arange(n)
    size = max_samples // n_blocks
    starts = np.linspace(0, n - size, n_blocks).round().astype(int)
    return np.concatenate([np.arange(s, s + size) for s in starts])
