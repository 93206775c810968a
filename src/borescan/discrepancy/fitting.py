"""Least-squares fits, information criterion and noise floor of the discrepancy workflow.

A fit returns the project's one :class:`borescan.fit.FitResult`: parameters, standard
uncertainties, covariance, residuals, RSS, rank, condition and the Bayesian information
criterion ``BIC = n ln(RSS / n) + p ln(n)`` (Gaussian likelihood with the variance profiled out).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

from borescan.fit import FitResult, bic, least_squares_fit
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
    relative step of 1e-4 of the scale give accurate Jacobians (:func:`borescan.fit.least_squares_fit`).
    """
    names = tuple(names)
    fixed = dict(fixed or {})

    def fun(x: np.ndarray) -> np.ndarray:
        p = dict(fixed)
        p.update(zip(names, x))
        return residual_fn(p)

    return least_squares_fit(fun, x0, names, scale=scale, max_nfev=max_nfev)


def dead_zone(r: np.ndarray, half_mm: np.ndarray | None) -> np.ndarray:
    """Return the residuals of cell-valued (quantised) readings.

    Residuals of cell-valued (quantised) readings: 0 inside the cell +-half, else the distance
    to its edge. ``half_mm`` broadcasts against ``r`` (per channel); None leaves ``r`` unchanged.
    """
    if half_mm is None:
        return r
    return np.sign(r) * np.maximum(np.abs(r) - half_mm, 0.0)


def spike_mask(
    residual_mm: np.ndarray, sigma_mm: np.ndarray, *, k_sigma: float = 7.0, window: int = 7
) -> np.ndarray:
    """Return samples that jump away from their neighbours by more than ``k_sigma`` noise levels.

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
    """Return the number of leading samples on an even time grid (spectra need uniform sampling)."""
    t = np.asarray(t_s, dtype=float)
    if t.size < 3:
        return t.size
    dt = np.diff(t)
    step = float(np.median(dt))
    gaps = np.flatnonzero(np.abs(dt - step) > 0.5 * step)
    return int(gaps[0] + 1) if gaps.size else t.size


def block_indices(n: int, max_samples: int, n_blocks: int = 4) -> np.ndarray:
    """Return indices of ``n_blocks`` contiguous blocks spread over ``n`` samples.

    Return indices of ``n_blocks`` contiguous blocks spread evenly over ``n`` samples, ``max_samples`` in
    all.

    Long scans are examined on these blocks: each keeps the sample-to-sample structure (noise
    floor, vibration lines), their spread keeps the time baseline (drift, speed error).
    """
    if n <= max_samples:
        return np.arange(n)
    size = max_samples // n_blocks
    starts = np.linspace(0, n - size, n_blocks).round().astype(int)
    return np.concatenate([np.arange(s, s + size) for s in starts])
