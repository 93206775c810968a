"""Least-squares fits, information criterion and noise floor of the discrepancy workflow.

A fit returns the project's one :class:`borescan.fit.FitResult`: parameters, standard
uncertainties, covariance, residuals, RSS, rank, condition and the Bayesian information
criterion ``BIC = n ln(RSS / n) + p ln(n)`` (Gaussian likelihood with the variance profiled out).
"""

from __future__ import annotations

import re
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
    "residual_sparsity",
]


def fit_least_squares(
    residual_fn: Callable[[dict[str, float]], np.ndarray],
    names: Sequence[str],
    x0: Sequence[float],
    scale: Sequence[float],
    *,
    fixed: dict[str, float] | None = None,
    max_nfev: int = 60,
    sparsity: np.ndarray | None = None,
    ftol: float = 1e-8,
    xtol: float = 1e-8,
    residual_stack_fn: Callable[[dict[str, float], list[dict[str, float]]], list[np.ndarray]] | None = None,
) -> FitResult:
    """Minimise ``sum(residual_fn(params)**2)`` over ``names`` (others from ``fixed``).

    Parameters are scaled by ``scale`` (typical magnitudes) so that forward differences with a
    relative step of 1e-4 of the scale give accurate Jacobians (:func:`borescan.fit.least_squares_fit`);
    ``sparsity`` (:func:`residual_sparsity`) lets parameters of different poses or channels share a step;
    ``residual_stack_fn(p, ps)`` (``residual_fn`` at the forward differences' steps ``ps`` from ``p``, in one
    call) evaluates the steps together.
    """
    names = tuple(names)
    fixed = dict(fixed or {})

    def fun(x: np.ndarray) -> np.ndarray:
        p = dict(fixed)
        p.update(zip(names, x))
        return residual_fn(p)

    def fun_stack(x: np.ndarray, xs: list[np.ndarray]) -> list[np.ndarray]:
        return residual_stack_fn(
            {**fixed, **dict(zip(names, x))}, [{**fixed, **dict(zip(names, y))} for y in xs]
        )

    return least_squares_fit(
        fun,
        x0,
        names,
        scale=scale,
        max_nfev=max_nfev,
        sparsity=sparsity,
        ftol=ftol,
        xtol=xtol,
        fun_stack=fun_stack if residual_stack_fn is not None else None,
    )


#: base parameters of one pose (rod pose angle, static device position) and of one channel
#: (three-sensor beam geometry, a rod layer's hole centre and radius), by name
_POSE_PARAM = re.compile(r"^(?:alpha|sx|sy)\[(\d+)\]$")
_CHANNEL_PARAM = re.compile(r"^(?:dpsi|dg|drho|cx|cy|dr)\[(\d+)\]$")
#: a term on one channel: ``<effect>@<channel>[k=..].<name>``
_CHANNEL_TERM = re.compile(r"^[A-Za-z_]+@(\d+)(?:\[k=\d+\])?\.")


def residual_sparsity(
    names: Sequence[str], mask: np.ndarray, channels: Sequence[int], pose_index: np.ndarray | None = None
) -> np.ndarray:
    """Which residuals each parameter of the discrepancy models can move: (residuals, parameters) bool.

    The residual vector is a model's (samples, channels) residual over ``mask`` (row-major, as
    ``model.residual`` returns it). A pose's parameters (``alpha[k]``, ``sx[k]``, ``sy[k]``) move
    the samples of pose k (``pose_index``), a channel's (``dpsi[j]``, ``dg[j]``, ``drho[j]``;
    a rod layer's ``cx[j]``, ``cy[j]``, ``dr[j]``: j the channel's position) and a term on one
    channel (``sensor_gain@2.h``) that channel's; every other parameter every residual.
    """
    mask = np.asarray(mask, dtype=bool)
    n, c = mask.shape
    out = np.ones((int(mask.sum()), len(names)), dtype=bool)
    chans = [int(ch) for ch in channels]
    for i, name in enumerate(names):
        support = None
        m = _POSE_PARAM.match(name)
        if m and pose_index is not None:
            support = np.broadcast_to((np.asarray(pose_index) == int(m.group(1)))[:, None], (n, c))
        elif (m := _CHANNEL_PARAM.match(name)) is not None:
            support = np.zeros((n, c), dtype=bool)
            support[:, int(m.group(1))] = True
        elif (m := _CHANNEL_TERM.match(name)) is not None and int(m.group(1)) in chans:
            support = np.zeros((n, c), dtype=bool)
            support[:, chans.index(int(m.group(1)))] = True
        if support is not None:
            out[:, i] = support[mask]
    return out


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
