"""Reading filters of Yang 2017 §4 and the ISO 16610-21 Gaussian.

Reading filters of Yang 2017 §4 (median, moving average, Kalman) and the ISO 16610-21 Gaussian
in undulations per revolution; all NaN-aware (a missing reading stays missing), zero-phase by default.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from scipy import ndimage

from borescan.signal._common import _as_2d, _back, _nanmedian_rows

FILTERS = ("none", "median", "moving_average", "kalman", "gaussian")
_ALPHA_GAUSS = math.sqrt(math.log(2.0) / math.pi)  # ISO 16610-21: 50 % transmission at cutoff


def median_filter(values_mm: np.ndarray, window_samples: int = 5, *, causal: bool = False) -> np.ndarray:
    """Return the running median over ``window_samples`` (odd) samples, NaN-aware.

    Centred (zero-phase) by default; ``causal=True`` uses the trailing window (delay
    (w - 1) / 2 samples). NaN inputs stay NaN; NaN neighbours are left out of the median.

    Parameters
    ----------
    values_mm : ndarray (n,) or (n, c) [mm]
    window_samples : int, odd, >= 1

    Returns
    -------
    ndarray like ``values_mm`` [mm]
    """
    w = int(window_samples)
    if w < 1 or w % 2 == 0:
        raise ValueError(f"window_samples must be odd and >= 1, got {window_samples}")
    v, one = _as_2d(values_mm)
    out = _running_median(v, w)
    if causal:
        h = (w - 1) // 2
        out = np.concatenate([np.full((h, v.shape[1]), np.nan), out[: v.shape[0] - h]], axis=0)
        out = out[: v.shape[0]]
    out[np.isnan(v)] = np.nan
    return _back(out, one)


def _running_median(v: np.ndarray, w: int) -> np.ndarray:
    """Centred running median per column; windows touching NaN use the valid samples only."""
    n, c = v.shape
    out = np.empty_like(v)
    h = w // 2
    for j in range(c):
        col = v[:, j]
        bad = np.isnan(col)
        if not bad.any():
            out[:, j] = ndimage.median_filter(col, size=w, mode="nearest")
            continue
        filled = np.where(bad, 0.0, col)
        med = ndimage.median_filter(filled, size=w, mode="nearest")
        touched = np.flatnonzero(ndimage.maximum_filter1d(bad.astype(np.uint8), size=w, mode="nearest"))
        padded = np.concatenate([np.full(h, col[0]), col, np.full(h, col[-1])])
        med[touched] = _nanmedian_rows(padded[touched[:, None] + np.arange(w)])
        out[:, j] = med
    return out


def moving_average(values_mm: np.ndarray, window_samples: int = 15, *, causal: bool = False) -> np.ndarray:
    """Return the moving average over ``window_samples`` samples, NaN-aware (mean of the valid ones).

    Centred (zero-phase, odd window) by default. Gain on a sinusoid of period N samples:
    H = sin(pi w / N) / (w sin(pi / N)); a causal (trailing) window adds a delay of
    (w - 1) / 2 samples. NaN inputs stay NaN.
    """
    w = int(window_samples)
    if w < 1 or (not causal and w % 2 == 0):
        raise ValueError(f"window_samples must be >= 1 (odd unless causal), got {window_samples}")
    v, one = _as_2d(values_mm)
    n = v.shape[0]
    ok = ~np.isnan(v)
    cs = np.concatenate([np.zeros((1, v.shape[1])), np.cumsum(np.where(ok, v, 0.0), axis=0)])
    cc = np.concatenate([np.zeros((1, v.shape[1])), np.cumsum(ok, axis=0)])
    idx = np.arange(n)
    if causal:
        lo, hi = np.maximum(idx - w + 1, 0), idx + 1
    else:
        h = w // 2
        lo, hi = np.maximum(idx - h, 0), np.minimum(idx + h + 1, n)
    s = cs[hi] - cs[lo]
    cnt = cc[hi] - cc[lo]
    with np.errstate(invalid="ignore", divide="ignore"):
        out = s / cnt
    out[~ok] = np.nan
    return _back(out, one)


def kalman_filter(  # noqa: C901 (two state models, each filtered and smoothed)
    values_mm: np.ndarray,
    *,
    model: str = "random_walk",
    q_mm2: float = 1e-6,
    r_mm2: float = 6.25e-6,
    smooth: bool = True,
) -> np.ndarray:
    """Scalar Kalman filter per channel; Rauch-Tung-Striebel smoothed (zero-phase) by default.

    Models (per sample k, reading z_k = x_k + v_k, var(v) = r):

    - ``"random_walk"``: x_k = x_{k-1} + w_k, var(w) = q. Causal steady state is an
      exponential smoother (lags a sinusoid).
    - ``"constant_velocity"``: state (x, x'), x_k = x_{k-1} + x'_{k-1}, white-noise
      acceleration with spectral density q: Q = q [[1/3, 1/2], [1/2, 1]].

    The paper (Yang 2017, §4) uses a Kalman filter without stating its model. NaN readings skip
    the update (prediction only) and stay NaN in the output. ``smooth=False`` returns the causal
    filtered estimate. Pure-Python loop over samples (vectorised over channels): a few us per
    sample, meant for analysis, not the default of :func:`process_scan`.

    Parameters
    ----------
    q_mm2, r_mm2 : process and measurement variance per sample [mm^2].
    """
    v, one = _as_2d(values_mm)
    n, c = v.shape
    ok = ~np.isnan(v)
    if model == "random_walk":
        xf = np.empty((n, c))
        pf = np.empty((n, c))
        xp = np.empty((n, c))
        pp = np.empty((n, c))
        first = np.array([v[ok[:, j], j][0] if ok[:, j].any() else 0.0 for j in range(c)])
        x, p = first.copy(), np.full(c, r_mm2)
        for k in range(n):
            if k:
                p = p + q_mm2
            xp[k], pp[k] = x, p
            z = v[k]
            g = np.where(ok[k], p / (p + r_mm2), 0.0)
            x = np.where(ok[k], x + g * (z - x), x)
            p = (1.0 - g) * p
            xf[k], pf[k] = x, p
        if smooth:
            xs = xf.copy()
            for k in range(n - 2, -1, -1):
                a = pf[k] / pp[k + 1]
                xs[k] = xf[k] + a * (xs[k + 1] - xp[k + 1])
            xf = xs
    elif model == "constant_velocity":
        F = np.array([[1.0, 1.0], [0.0, 1.0]])
        Q = q_mm2 * np.array([[1.0 / 3.0, 0.5], [0.5, 1.0]])
        xs_f = np.empty((n, c, 2))
        ps_f = np.empty((n, c, 2, 2))
        xs_p = np.empty((n, c, 2))
        ps_p = np.empty((n, c, 2, 2))
        first = np.array([v[ok[:, j], j][0] if ok[:, j].any() else 0.0 for j in range(c)])
        x = np.stack([first, np.zeros(c)], axis=-1)
        p = np.broadcast_to(np.diag([r_mm2, 1e-2]), (c, 2, 2)).copy()
        for k in range(n):
            if k:
                x = x @ F.T
                p = F @ p @ F.T + Q
            xs_p[k], ps_p[k] = x, p
            s = p[:, 0, 0] + r_mm2
            g = p[:, :, 0] / s[:, None]
            g = np.where(ok[k][:, None], g, 0.0)
            innov = np.where(ok[k], v[k] - x[:, 0], 0.0)
            x = x + g * innov[:, None]
            p = p - g[:, :, None] * p[:, 0, :][:, None, :]
            xs_f[k], ps_f[k] = x, p
        if smooth:
            xs = xs_f.copy()
            for k in range(n - 2, -1, -1):
                a = ps_f[k] @ F.T @ np.linalg.inv(ps_p[k + 1])
                xs[k] = xs_f[k] + np.einsum("cij,cj->ci", a, xs[k + 1] - xs_p[k + 1])
            xs_f = xs
        xf = xs_f[:, :, 0]
    else:
        raise ValueError(f"unknown Kalman model {model!r}; valid: 'random_walk', 'constant_velocity'")
    out = np.where(ok, xf, np.nan)
    return _back(out, one)


def gaussian_transmission(f_upr: np.ndarray, cutoff_upr: float) -> np.ndarray:
    """ISO 16610-21 Gaussian amplitude transmission H(f) = exp(-pi (alpha f / f_c)^2).

    alpha = sqrt(ln 2 / pi), so H(f_c) = 0.5 (50 % transmission at the cutoff); f in
    undulations per revolution (UPR).
    """
    return np.exp(-np.pi * (_ALPHA_GAUSS * np.asarray(f_upr, dtype=float) / float(cutoff_upr)) ** 2)


def gaussian_filter_upr(values_mm: np.ndarray, *, cutoff_upr: float, samples_per_rev: float) -> np.ndarray:
    """ISO 16610-21 Gaussian low-pass of a closed profile, cutoff in UPR, via FFT.

    The record is treated as closed over the longest whole number K of revolutions,
    M = round(K * samples_per_rev) samples; FFT bin q lies at q P / M UPR (P = samples_per_rev) and is
    weighted by :func:`gaussian_transmission` (zero phase). A tail beyond M samples is filtered
    with the last M samples. NaN samples: normalised convolution (filter(v * mask) /
    filter(mask)); outputs at NaN inputs stay NaN.

    Parameters
    ----------
    cutoff_upr : cutoff f_c [UPR], 50 % transmission.
    samples_per_rev : rotation period [samples].
    """
    v, one = _as_2d(values_mm)
    n = v.shape[0]
    k_rev = int(n // samples_per_rev)
    if k_rev < 1:
        raise ValueError(f"need at least one whole revolution ({samples_per_rev:.1f} samples), got {n}")
    m = int(round(k_rev * samples_per_rev))
    m = min(m, n)
    f_upr = np.fft.rfftfreq(m, d=1.0) * samples_per_rev  # cycles/sample * samples/rev
    h = gaussian_transmission(f_upr, cutoff_upr)
    ok = ~np.isnan(v)
    out = np.empty_like(v)
    segs = [(0, m)] if m == n else [(0, m), (n - m, n)]
    for s0, s1 in segs:
        seg = v[s0:s1]
        okc = ok[s0:s1]
        num = np.fft.irfft(np.fft.rfft(np.where(okc, seg, 0.0), axis=0) * h[:, None], n=m, axis=0)
        if okc.all():
            res = num
        else:
            den = np.fft.irfft(np.fft.rfft(okc.astype(float), axis=0) * h[:, None], n=m, axis=0)
            with np.errstate(invalid="ignore", divide="ignore"):
                res = num / den
        if s0 == 0:
            out[:m] = res
        else:
            out[m:] = res[m - (n - m) :]
    out[~ok] = np.nan
    return _back(out, one)


def filter_readings(
    values_mm: np.ndarray, *, method: str = "median", samples_per_rev: float | None = None, **params: Any
) -> np.ndarray:
    """Apply one filter by name (``FILTERS``) with its keyword parameters.

    ``median``/``moving_average``: ``window_samples``, ``causal``; ``kalman``: ``model``,
    ``q_mm2``, ``r_mm2``, ``smooth``; ``gaussian``: ``cutoff_upr`` (needs ``samples_per_rev``);
    ``none``: copy. Unknown names raise ``ValueError`` listing the valid ones.
    """
    if method == "none":
        return np.array(values_mm, dtype=float, copy=True)
    if method == "median":
        return median_filter(values_mm, **params)
    if method == "moving_average":
        return moving_average(values_mm, **params)
    if method == "kalman":
        return kalman_filter(values_mm, **params)
    if method == "gaussian":
        if samples_per_rev is None:
            raise ValueError("the gaussian filter needs samples_per_rev")
        return gaussian_filter_upr(values_mm, samples_per_rev=samples_per_rev, **params)
    raise ValueError(f"unknown filter {method!r}; valid: {', '.join(FILTERS)}")
