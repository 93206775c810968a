"""Signal stage: filters, null/spike handling, revolutions, sub-sample extrema, Yang §2.3 statuses.

Everything below the entry point :func:`process_scan` is a pure function of numpy arrays
(``(n,)`` or ``(n, c)``, NaN = missing reading), so it can be tested without any file.

Conventions
-----------
- Sample positions are in acquisition ticks (``sample`` of ``borescan-raw/1``), fractional
  where sub-sample. A "revolution coordinate" ``u`` (revolutions since the first sample) maps
  every sample to its revolution, ``revolution = floor(u)``.
- Missing readings are never bridged: filters return NaN wherever the input is NaN, spikes are
  set aside as NaN and counted, and an extremum whose fit window holds too few valid samples is
  dropped (and counted), not interpolated.
- Zero-phase filtering is the default everywhere. A causal filter delays the signal, which moves
  every extremum later by the group delay and so corrupts the feature-point spacing and
  theta_t of Yang 2017, Eq. 15 whenever channels are filtered differently (and the absolute
  angle always). ``filter_performance`` quantifies this.

Advanced / backward (Yang 2017, §2.3)
-------------------------------------
``n`` = samples from a minimum to the next maximum, ``m`` = from a maximum to the next minimum.
The paper's rule: n < m -> "backward", n > m -> "advanced" (counter-clockwise rotation). In the
spec's frame (``F = rho * n_hat``), a ccw turn moves the beam foot point ahead of the line
O'-feature point when rho > 0, and the exact geometry gives n > m for rho > 0: advanced <=> rho > 0
(ccw). For clockwise rotation time runs against the angle, so n and m swap roles: the rule
"n < m -> backward" still reads the status relative to the rotation, but the implied sign of
rho flips (cw: backward <=> rho > 0). :func:`beam_status` returns both.
"""

from __future__ import annotations

import functools
import math
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
import polars as pl
from numpy.lib.stride_tricks import sliding_window_view
from scipy import ndimage

from borescan.sortnet import median_columns

__all__ = [
    "FILTERS",
    "PeriodEstimate",
    "SignalResult",
    "gaussian_transmission",
    "median_filter",
    "moving_average",
    "kalman_filter",
    "gaussian_filter_upr",
    "filter_readings",
    "remove_spikes",
    "period_from_encoder",
    "period_from_readings",
    "find_revolutions",
    "revolution_coordinate",
    "fit_extremum_cubic",
    "find_extrema",
    "n_m_counts",
    "beam_status",
    "feature_spacings",
    "theta_t_rad",
    "process_arrays",
    "process_scan",
    "filter_performance",
]

FILTERS = ("none", "median", "moving_average", "kalman", "gaussian")
_ALPHA_GAUSS = math.sqrt(math.log(2.0) / math.pi)  # ISO 16610-21: 50 % transmission at cutoff
_SPIKE_CANDIDATE_THRESHOLD = 2.5  # chord test of remove_spikes, in MAD scales


def _as_2d(values_mm: np.ndarray) -> tuple[np.ndarray, bool]:
    v = np.asarray(values_mm, dtype=float)
    if v.ndim == 1:
        return v[:, None], True
    if v.ndim != 2:
        raise ValueError(f"readings must have shape (n,) or (n, c), got {v.shape}")
    return v, False


def _back(v: np.ndarray, was_1d: bool) -> np.ndarray:
    return v[:, 0] if was_1d else v


# --------------------------------------------------------------------------- filters


def median_filter(values_mm: np.ndarray, window_samples: int = 5, *, causal: bool = False) -> np.ndarray:
    """Running median over ``window_samples`` (odd) samples, NaN-aware.

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
        win = padded[touched[:, None] + np.arange(w)]
        cnt = np.sum(~np.isnan(win), axis=1)
        srt = np.sort(win, axis=1)  # NaN sort last
        lo = srt[np.arange(len(touched)), np.maximum((cnt - 1) // 2, 0)]
        hi = srt[np.arange(len(touched)), np.maximum(cnt // 2, 0)]
        med[touched] = np.where(cnt > 0, 0.5 * (lo + hi), np.nan)
        out[:, j] = med
    return out


def _ll_reference(col_x: np.ndarray, idx: np.ndarray, w: int) -> np.ndarray:
    """Robust local-linear reference of a column at rows ``idx`` (see :func:`remove_spikes`).

    ``col_x`` is the column with excluded samples (nulls, candidates) set to NaN and padded with
    ``w // 2`` NaN at both ends (``idx`` indexes windows of ``w`` samples, i.e. the padded
    position of each window's first sample). Uses the neighbours j = -h..h, j != 0, that are not NaN: Theil-Sen slope s (median of pairwise
    slopes), reference = median_j (v_{k+j} - j s). NaN when fewer than two neighbours are usable.
    """
    h = w // 2
    offs_i = np.concatenate([np.arange(-h, 0), np.arange(1, h + 1)])
    offs = offs_i.astype(float)
    win = sliding_window_view(col_x, w)[idx]  # (places, w), the centre sample in column h
    ii, jj = np.triu_indices(offs.size, 1)
    nan_nb = np.isnan(win)
    nan_nb[:, h] = False
    full = ~nan_nb.any(axis=1)
    ref = np.empty(idx.size)
    if full.any():  # every neighbour usable (most rows): pair slopes as one product
        wf = win[full]
        wf[:, h] = 0.0  # the centre (NaN at candidates) takes no part: its row of ``pairs`` is zero
        pairs = np.zeros((w, ii.size))
        d = offs[jj] - offs[ii]
        pairs[offs_i[jj] + h, np.arange(ii.size)] = 1.0 / d
        pairs[offs_i[ii] + h, np.arange(ii.size)] = -1.0 / d
        slope = _median_rows_full(wf @ pairs)
        # median of the 2h offsets: a selection network on the columns (np.partition with two
        # ranks along a short axis costs ~7x more)
        ref[full] = median_columns([wf[:, h + j] - j * slope for j in offs_i.tolist()])
    part = ~full
    if part.any():
        wp = win[part][:, offs_i + h]
        slope = _nanmedian_rows((wp[:, jj] - wp[:, ii]) / (offs[jj] - offs[ii]))
        rp = _nanmedian_rows(wp - offs * slope[:, None])
        rp[np.sum(~np.isnan(wp), axis=1) < 2] = np.nan
        ref[part] = rp
    return ref


def _median_rows_full(a: np.ndarray) -> np.ndarray:
    """Median of each row of a NaN-free 2-D array (exact: partition for an odd number of columns, a
    selection network on the columns for an even one, where partition needs two ranks)."""
    m = a.shape[1]
    if m % 2:
        return np.partition(a, m // 2, axis=1)[:, m // 2]
    return median_columns([a[:, k] for k in range(m)])


def _nanmedian_rows(a: np.ndarray) -> np.ndarray:
    """Median of each row ignoring NaN (NaN for an all-NaN row); sort-based, no warnings."""
    srt = np.sort(a, axis=1)  # NaN sort last
    cnt = a.shape[1] - np.count_nonzero(np.isnan(a), axis=1)
    r = np.arange(a.shape[0])
    lo = srt[r, np.maximum((cnt - 1) // 2, 0)]
    hi = srt[r, np.minimum(cnt // 2, a.shape[1] - 1)]
    med = np.where(cnt % 2 == 1, lo, 0.5 * (lo + hi))
    med[cnt == 0] = np.nan
    return med


def _median(x: np.ndarray) -> float:
    """Median of a NaN-free 1-D array by partition (np.median's checks cost ~5x here)."""
    m = x.size
    if m % 2:
        return float(np.partition(x, m // 2)[m // 2])
    p = np.partition(x, (m // 2 - 1, m // 2))
    return 0.5 * float(p[m // 2 - 1] + p[m // 2])


def _mad_scale(r: np.ndarray, max_n: int = 20_000) -> float:
    """1.4826 x median absolute deviation of the non-NaN values, on a uniform stride of at most
    ``max_n`` of them (relative standard uncertainty of the scale about 1 / sqrt(0.74 max_n))."""
    if r.size > max_n:
        r = r[:: -(-r.size // max_n)]  # ceil: at most max_n values
    r = r[~np.isnan(r)]
    if r.size == 0:
        return float("inf")
    sc = 1.4826 * _median(np.abs(r - _median(r)))
    return sc if sc > 0 else float(np.finfo(float).tiny)


def moving_average(values_mm: np.ndarray, window_samples: int = 15, *, causal: bool = False) -> np.ndarray:
    """Moving average over ``window_samples`` samples, NaN-aware (mean of the valid ones).

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


def kalman_filter(
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
            out[m:] = res[m - (n - m):]
    out[~ok] = np.nan
    return _back(out, one)


def filter_readings(values_mm: np.ndarray, *, method: str = "median", samples_per_rev: float | None = None,
                    **params: Any) -> np.ndarray:
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


def remove_spikes(values_mm: np.ndarray, *, window_samples: int = 7, threshold: float = 6.0,
                  candidate_threshold: float = _SPIKE_CANDIDATE_THRESHOLD) -> tuple[np.ndarray, np.ndarray]:
    """Set spikes aside as NaN: Hampel test against a robust local-linear reference.

    1. Candidates: |v_k - (v_{k-1} + v_{k+1}) / 2| > ``candidate_threshold`` x its MAD scale, and
       every valid sample next to a null or at an end.
    2. Reference at each candidate from its w - 1 neighbours that are neither null nor candidates:
       Theil-Sen slope s, ref = median_j (v_{k+j} - j s) (a plain running median is no reference on
       the steep flanks of the once-per-rev signal, 22 um per sample at 2.3 mm eccentricity and
       660 samples/rev: there it returns v_k itself).
    3. Spike: |v_k - ref| > ``threshold`` x 1.4826 MAD, the MAD of the same residual over (a
       stride of) the non-candidate samples of the channel.
    Nulls (NaN) are not spikes. A candidate with fewer than two usable neighbours is kept.

    Returns
    -------
    cleaned : ndarray like ``values_mm`` with spikes set to NaN [mm]
    spikes : bool ndarray like ``values_mm``
    """
    v, one = _as_2d(values_mm)
    h = _check_spike_window(window_samples)
    vp = _padded_rows(v, h)
    found, _ = _despike_rows(vp, h, threshold, candidate_threshold)
    vt = vp[:, h: vp.shape[1] - h]
    spikes = np.zeros(vt.shape, dtype=bool)
    for j, idx in enumerate(found):
        spikes[j, idx] = True
    return _back(vt.T, one), _back(spikes.T, one)


def _check_spike_window(window_samples: int) -> int:
    w = int(window_samples)
    if w < 3 or w % 2 == 0:
        raise ValueError(f"window_samples must be odd and >= 3, got {window_samples}")
    return w // 2


def _padded_rows(v: np.ndarray, h: int) -> np.ndarray:
    """Copy of (n, c) readings as (c, n + 2h) rows, NaN in the h columns at each end."""
    n, c = v.shape
    vp = np.empty((c, n + 2 * h))
    vp[:, :h] = np.nan
    vp[:, n + h:] = np.nan
    vp[:, h: n + h] = v.T
    return vp


def _despike_rows(vp: np.ndarray, h: int, threshold: float, candidate_threshold: float
                  ) -> tuple[list[np.ndarray], np.ndarray]:
    """:func:`remove_spikes` in place on rows padded by :func:`_padded_rows` (c, n + 2h); ``h`` is
    the half window from :func:`_check_spike_window`.

    Returns the spike indices (into the unpadded row) and the null count of each row.
    """
    res = [_despike_row(row, h, threshold, candidate_threshold) for row in vp]
    return [r[0] for r in res], np.array([r[1] for r in res], dtype=np.int64)


def _despike_row(row: np.ndarray, h: int, threshold: float, candidate_threshold: float
                 ) -> tuple[np.ndarray, int]:
    """One padded row of :func:`_despike_rows`: (spike indices, null count); spikes set to NaN in place.

    The candidate test uses the second difference v_{k+1} - 2 v_k + v_{k-1} (= -2 x the chord of
    :func:`remove_spikes`; the test is scale-free). While the row is tested its candidates are NaN
    in place (so the reference skips them); all but the spikes are restored afterwards.
    """
    n = row.size - 2 * h
    col = row[h: h + n]
    if n < 3:
        return np.zeros(0, dtype=np.int64), int(np.isnan(col).sum())
    d1 = np.subtract(col[1:], col[:-1])
    d2 = np.empty(n)
    np.subtract(d1[1:], d1[:-1], out=d2[1:-1])
    d2[0] = d2[-1] = np.nan
    sc_c = _mad_scale(d2)
    np.abs(d2, out=d2)
    with np.errstate(invalid="ignore"):
        ok = d2 <= candidate_threshold * sc_c  # NaN (nulls, their neighbours, ends) -> False
    idx = np.flatnonzero(~ok)
    saved = col[idx]
    is_null = np.isnan(saved)
    idx, saved = idx[~is_null], saved[~is_null]  # candidates
    col[idx] = np.nan
    probe = np.arange(0, n, max(1, n // 5_000))
    probe = probe[ok[probe]]
    ref = _ll_reference(row, np.concatenate([probe, idx]), 2 * h + 1)  # one call for probes and candidates
    scale = _mad_scale(col[probe] - ref[: probe.size], max_n=probe.size)
    with np.errstate(invalid="ignore"):
        spike = np.abs(saved - ref[probe.size:]) > threshold * scale
    col[idx[~spike]] = saved[~spike]
    return idx[spike], int(is_null.sum())


# --------------------------------------------------------------------------- period / revolutions


@dataclass(frozen=True)
class PeriodEstimate:
    """Rotation period in samples with its standard uncertainty and provenance.

    ``period_disagrees_with_nominal`` is True when |P - P_nominal| > 3 u(P), with
    P_nominal = 60 f_s / rpm_nominal.
    """

    samples_per_rev: float
    u_samples_per_rev: float
    source: str  # "encoder" | "readings"
    samples_per_rev_nominal: float | None
    period_disagrees_with_nominal: bool
    direction: str  # "ccw" | "cw"

    def to_dict(self) -> dict:
        return asdict(self)


def _nominal(sample_rate_hz: float | None, rpm_nominal: float | None) -> float | None:
    if sample_rate_hz is None or rpm_nominal is None or not rpm_nominal:
        return None
    return 60.0 * float(sample_rate_hz) / abs(float(rpm_nominal))


def _disagrees(p: float, u: float, nominal: float | None) -> bool:
    return bool(nominal is not None and abs(p - nominal) > 3.0 * u)


def period_from_encoder(t_s: np.ndarray, angle_rad: np.ndarray, sample_times_s: np.ndarray, *,
                        rpm_nominal: float | None = None,
                        sample_rate_hz: float | None = None) -> PeriodEstimate:
    """Period in samples from a linear fit of the unwrapped encoder angle against time.

    angle = a + omega t (least squares); the sample interval dt comes from a linear fit of the
    LDS sample times; P = 2 pi / (|omega| dt), u(P) = P u(omega) / |omega|.
    The rotation direction is the sign of omega (ccw when positive).
    """
    t = np.asarray(t_s, dtype=float)
    a = np.asarray(angle_rad, dtype=float)
    ok = ~np.isnan(a)
    t, a = t[ok], a[ok]
    if t.size < 3:
        raise ValueError("encoder stream has fewer than 3 angles")
    tc = t - t.mean()
    omega = float(np.dot(tc, a - a.mean()) / np.dot(tc, tc))
    resid = a - a.mean() - omega * tc
    s2 = float(np.dot(resid, resid) / max(t.size - 2, 1))
    u_omega = math.sqrt(s2 / np.dot(tc, tc))
    ts = np.asarray(sample_times_s, dtype=float)
    k = np.arange(ts.size, dtype=float)
    kc = k - k.mean()
    dt = float(np.dot(kc, ts - ts.mean()) / np.dot(kc, kc)) if ts.size > 1 else 1.0 / float(sample_rate_hz)
    p = 2.0 * math.pi / (abs(omega) * dt)
    u = p * u_omega / abs(omega)
    nom = _nominal(sample_rate_hz if sample_rate_hz else 1.0 / dt, rpm_nominal)
    return PeriodEstimate(p, u, "encoder", nom, _disagrees(p, u, nom), "ccw" if omega > 0 else "cw")


def _lsq(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Least squares via the normal equations (bases here are well conditioned: cos/sin/const)."""
    return np.linalg.solve(a.T @ a, a.T @ b)


def _harmonic_basis(x: np.ndarray, omega: float, n_harmonics: int, trend: bool) -> np.ndarray:
    """Columns [1, (x / max|x|), cos(h w x), sin(h w x) for h = 1..H] (harmonics by angle addition)."""
    n0 = 2 if trend else 1
    b = np.empty((x.size, n0 + 2 * n_harmonics), order="F")  # column-major: each column written contiguously
    b[:, 0] = 1.0
    if trend:
        b[:, 1] = x / max(float(np.abs(x).max()), 1.0) if x.size else x
    wx = omega * x
    c1, s1 = np.cos(wx), np.sin(wx)
    ch, sh = c1, s1
    for h in range(1, n_harmonics + 1):
        if h > 1:  # angle addition: cos((h-1)a + a), sin((h-1)a + a)
            ch, sh = ch * c1 - sh * s1, sh * c1 + ch * s1
        b[:, n0 + 2 * h - 2] = ch
        b[:, n0 + 2 * h - 1] = sh
    return b


def period_from_readings(values_mm: np.ndarray, *, samples_per_rev_guess: float | None = None,
                         n_harmonics: int = 3, trend: bool = True, max_samples: int = 10_000,
                         rpm_nominal: float | None = None, sample_rate_hz: float | None = None,
                         direction: str = "ccw") -> PeriodEstimate:
    """Rotation period in samples from the readings: FFT peak, refined by nonlinear least squares.

    Model per channel c (k = sample index): v_c(k) = a_c + b_c k + sum_{h<=H} [A_ch cos(h w k) +
    B_ch sin(h w k)], one frequency w shared by all channels (variable projection; Gauss-Newton
    on w with the linear parameters profiled out). u(w) is the marginal standard uncertainty
    from the full covariance s^2 (J^T J)^-1 (Schur complement), P = 2 pi / w,
    u(P) = P u(w) / w. The fit uses a uniform stride of at most ``max_samples`` rows, of which
    rows with any NaN are left out; the uncertainty accounts for the rows used. 10 000 rows give
    u(P) / P ~ 1e-8 on a 600-revolution scan (the period moves an extremum prediction by
    n u(P) / P^2 ~ 1e-5 revolutions); 20 000 rows would halve u(P)^2 at three times the cost
    (the design no longer fits the cache).
    """
    v, _ = _as_2d(values_mm)
    n = v.shape[0]
    stride = max(1, int(math.ceil(n / max_samples)))
    rows = np.arange(0, n, stride)
    y = np.array(v[::stride])  # a strided slice: faster than gathering by index
    keep = ~np.isnan(y).any(axis=1)
    if keep.sum() < 16:
        rows_all = np.flatnonzero(~np.isnan(v).any(axis=1))  # sparse complete rows: use them all
        if rows_all.size < 16:
            raise ValueError("too few complete rows to estimate the rotation period")
        rows = rows_all[:: max(1, int(math.ceil(rows_all.size / max_samples)))]
        y = v[rows]
    else:
        rows, y = rows[keep], y[keep]
    x = rows.astype(float)
    x = x - x.mean()
    # coarse: FFT of a uniformly indexed copy (NaN -> channel mean), peak near the guess
    # decimate for the coarse FFT, keeping the 3rd harmonic of the guess below Nyquist
    sf = max(1, n // 16_384)
    if samples_per_rev_guess:
        sf = max(1, min(sf, int(samples_per_rev_guess // 8)))
    full = v.T[:, ::sf].T - y.mean(axis=0)
    full[np.isnan(full)] = 0.0  # NaN -> the channel mean
    spec = np.sum(np.abs(np.fft.rfft(full, axis=0)), axis=1)
    freqs = np.fft.rfftfreq(full.shape[0], d=sf)
    sel = freqs > 1.5 / (full.shape[0] * sf)
    if samples_per_rev_guess:
        f0 = 1.0 / samples_per_rev_guess
        sel &= (freqs > 0.7 * f0) & (freqs < 1.3 * f0)
    i = int(np.flatnonzero(sel)[np.argmax(spec[sel])])
    if 0 < i < spec.size - 1:
        la, lb, lc = np.log(spec[i - 1: i + 2] + 1e-300)
        den = la - 2 * lb + lc
        d = 0.5 * (la - lc) / den if den != 0 else 0.0
    else:
        d = 0.0
    omega = 2.0 * math.pi * (i + float(np.clip(d, -0.5, 0.5))) / (full.shape[0] * sf)
    n0 = 2 if trend else 1
    hh = np.repeat(np.arange(1, n_harmonics + 1), 2).astype(float)
    for _ in range(30):
        basis = _harmonic_basis(x, omega, n_harmonics, trend)
        btb = basis.T @ basis
        coef = np.linalg.solve(btb, basis.T @ y)
        resid = y - basis @ coef
        # d model / d omega per channel: d/dw [A cos(hwx) + B sin(hwx)] = h x (-A sin + B cos)
        harm = basis[:, n0:]
        dcoef = np.empty_like(coef[n0:])
        dcoef[0::2] = coef[n0 + 1::2]
        dcoef[1::2] = -coef[n0::2]
        g = x[:, None] * (harm @ (hh[:, None] * dcoef))
        gp = g - basis @ np.linalg.solve(btb, basis.T @ g)
        gg = float(np.sum(gp * gp))
        step = float(np.sum(gp * resid)) / gg
        omega += step
        # s^2 with one more parameter (w) than the linear ones
        s2 = float(np.sum(resid * resid)) / max(y.size - coef.size - 1, 1)
        if abs(step) < 1e-2 * math.sqrt(s2 / gg) or abs(step) < 1e-15 * abs(omega):
            break  # the last step moved w by < 1 % of u(w): s^2 and gg of this iterate stand for the result
    u_omega = math.sqrt(s2 / gg)
    p = 2.0 * math.pi / omega
    u = p * u_omega / omega
    nom = _nominal(sample_rate_hz, rpm_nominal)
    return PeriodEstimate(p, u, "readings", nom, _disagrees(p, u, nom), direction)


def revolution_coordinate(n_samples: int, period: PeriodEstimate, *, sample_times_s: np.ndarray | None = None,
                          encoder_t_s: np.ndarray | None = None, encoder_angle_rad: np.ndarray | None = None,
                          ) -> np.ndarray:
    """Revolutions since the first sample, u(k); ``revolution = floor(u)``.

    Encoder: u = s (angle(t_k) - angle(t_0)) / 2 pi with the angle linearly interpolated at the
    sample times and s = +1 (ccw) or -1 (cw). Readings only: u = k / P.
    """
    if encoder_angle_rad is not None and sample_times_s is not None:
        et = np.asarray(encoder_t_s, dtype=float)
        ea = np.asarray(encoder_angle_rad, dtype=float)
        ok = ~np.isnan(ea)
        ang = np.interp(np.asarray(sample_times_s, dtype=float), et[ok], ea[ok])
        sign = 1.0 if period.direction == "ccw" else -1.0
        return sign * (ang - ang[0]) / (2.0 * math.pi)
    return np.arange(n_samples, dtype=float) / period.samples_per_rev


def find_revolutions(u_rev: np.ndarray, sample0: int = 0) -> pl.DataFrame:
    """Revolutions table from the revolution coordinate: revolution = floor(u).

    Returns
    -------
    polars.DataFrame: revolution, first_sample, last_sample, n_samples, complete (the
    revolution is covered from u = r to u = r + 1).
    """
    u = np.asarray(u_rev, dtype=float)
    if u.size > 1 and bool((u[1:] >= u[:-1]).all()):  # non-decreasing: revolution starts by bisection
        r_all = np.arange(math.floor(u[0]), math.floor(u[-1]) + 1)
        st = np.searchsorted(u, r_all.astype(float), side="left")
        st[0] = 0
        nonempty = np.diff(np.append(st, u.size)) > 0
        starts, r = st[nonempty], r_all[nonempty]
        ends = np.concatenate([starts[1:] - 1, [u.size - 1]])
    else:
        rev = np.floor(u).astype(np.int64)
        starts = np.flatnonzero(np.concatenate([[True], np.diff(rev) != 0]))
        ends = np.concatenate([starts[1:] - 1, [rev.size - 1]])
        r = rev[starts]
    complete = (np.arange(r.size) > 0) & (np.arange(r.size) < r.size - 1)
    return pl.DataFrame({
        "revolution": r,
        "first_sample": (starts + sample0).astype(np.int64),
        "last_sample": (ends + sample0).astype(np.int64),
        "n_samples": (ends - starts + 1).astype(np.int64),
        "complete": complete,
    })


# --------------------------------------------------------------------------- extrema


def _cubic_design(half_window: int) -> np.ndarray:
    x = np.arange(-half_window, half_window + 1, dtype=float)
    return np.stack([np.ones_like(x), x, x * x, x ** 3], axis=1)


@functools.lru_cache(maxsize=8)
def _cubic_fit_matrices(half_window: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Design X (2W+1, 4), its pseudo-inverse and (X^T X)^-1 for complete windows (read-only)."""
    X = _cubic_design(half_window)
    out = (X, np.linalg.pinv(X), np.linalg.inv(X.T @ X))
    for a in out:
        a.flags.writeable = False
    return out


def _cubic_stationary(coef: np.ndarray) -> np.ndarray:
    """Root of c1 + 2 c2 x + 3 c3 x^2 = 0 nearest 0 (Newton from the parabola vertex)."""
    c1, c2, c3 = coef[..., 1], coef[..., 2], coef[..., 3]
    with np.errstate(divide="ignore", invalid="ignore"):
        x = -c1 / (2.0 * c2)
        for _ in range(4):
            x = x - (c1 + 2 * c2 * x + 3 * c3 * x * x) / (2 * c2 + 6 * c3 * x)
    return x


def fit_extremum_cubic(y_mm: np.ndarray, *, kind: str, sigma_mm: float | None = None) -> dict:
    """Sub-sample extremum of one window (2W+1 samples centred on the coarse extremum).

    Least-squares cubic v = c0 + c1 x + c2 x^2 + c3 x^3 (x in samples from the centre); the
    extremum is the stationary point x* (c1 + 2 c2 x + 3 c3 x^2 = 0). The cubic term absorbs
    the waveform's asymmetry (skew), so x* is unbiased for asymmetric waveforms to third order.
    u(x*) by implicit differentiation, gradient -[0, 1, 2x, 3x^2] / (2 c2 + 6 c3 x) with
    Cov(c) = s^2 (X^T X)^-1; u(v*) with gradient [1, x, x^2, x^3].
    """
    y = np.asarray(y_mm, dtype=float)
    w = (y.size - 1) // 2
    X = _cubic_design(w)
    ok = ~np.isnan(y)
    coef, *_ = np.linalg.lstsq(X[ok], y[ok], rcond=None)
    r = y[ok] - X[ok] @ coef
    s2 = sigma_mm ** 2 if sigma_mm is not None else float(r @ r) / max(ok.sum() - 4, 1)
    cov = s2 * np.linalg.inv(X[ok].T @ X[ok])
    x = float(_cubic_stationary(coef))
    gx = -np.array([0.0, 1.0, 2 * x, 3 * x * x]) / (2 * coef[2] + 6 * coef[3] * x)
    gv = np.array([1.0, x, x * x, x ** 3])
    good = (coef[2] > 0) if kind == "min" else (coef[2] < 0)
    return {"x": x, "u_x": math.sqrt(gx @ cov @ gx), "value": float(gv @ coef),
            "u_value": math.sqrt(gv @ cov @ gv),
            "ok": bool(good and abs(x) <= w)}


def _masked_xtx(X: np.ndarray, m: np.ndarray) -> np.ndarray:
    """Normal matrices X^T diag(m_r) X of the design ``X`` (k, 4) for each row of the 0/1 masks ``m`` (R, k)."""
    return np.einsum("ki,kj,rk->rij", X, X, m)


def _row_windows(vt: np.ndarray, k: int) -> tuple[np.ndarray, int | None]:
    """Windows of ``k`` samples of each row of ``vt`` (c, n), for :func:`_fit_windows`.

    When the rows are contiguous and equally spaced in one buffer (the channel rows of
    :func:`process_arrays`), returns ``sliding_window_view`` of one flat view spanning them all and
    the row step (elements from one row's start to the next): a window is then gathered as one
    contiguous run, several times faster than indexing a 3-D window view. Otherwise returns
    ``(sliding_window_view(vt, k, axis=1), None)``. Windows never cross rows: callers keep every
    window inside its row.
    """
    c, n = vt.shape
    isz = vt.itemsize
    if c and n >= k and vt.strides[1] == isz and vt.strides[0] >= n * isz and vt.strides[0] % isz == 0:
        step = vt.strides[0] // isz
        flat = np.lib.stride_tricks.as_strided(vt, shape=((c - 1) * step + n,), strides=(isz,), writeable=False)
        return sliding_window_view(flat, k), step
    return sliding_window_view(vt, k, axis=1), None


def _fit_windows(windows: tuple[np.ndarray, int | None], chan: np.ndarray, centers: np.ndarray, w: int,
                 pinv: np.ndarray, X: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Cubic least-squares fits of the windows of rows ``chan`` centred on ``centers``.

    ``windows`` comes from :func:`_row_windows` on the channel rows (c, n) with 2w+1 samples
    (the window of row j at k holds samples k..k+2w). Returns coef (R, 4) (NaN where fewer than 8
    valid samples), the windows Y (R, 2w+1) and their NaN mask. Complete windows use the
    pseudo-inverse ``pinv`` of the design ``X``; windows with NaN are solved from their own
    masked normal equations (batched).
    """
    win, step = windows
    Y = win[chan, centers - w] if step is None else win[chan * step + centers - w]
    bad = np.isnan(Y)
    rows_bad = bad.any(axis=1)
    if not rows_bad.any():
        return Y @ pinv.T, Y, bad
    coef = np.empty((centers.size, 4))
    coef[~rows_bad] = Y[~rows_bad] @ pinv.T
    ib = np.flatnonzero(rows_bad)
    ok_b = ~bad[ib]
    enough = ok_b.sum(axis=1) >= 8
    coef[ib[~enough]] = np.nan
    ib, ok_b = ib[enough], ok_b[enough]
    if ib.size:
        m = ok_b.astype(float)
        xtx = _masked_xtx(X, m)
        xty = np.einsum("ki,rk->ri", X, m * np.where(ok_b, Y[ib], 0.0))
        coef[ib] = np.linalg.solve(xtx, xty[..., None])[..., 0]
    return coef, Y, bad


def _sample_at(u: np.ndarray, targets: np.ndarray) -> np.ndarray:
    """Fractional sample index where the (increasing) revolution coordinate ``u`` equals ``targets``."""
    i = np.clip(np.searchsorted(u, targets, side="right"), 1, u.size - 1)
    u0, u1 = u[i - 1], u[i]
    with np.errstate(divide="ignore", invalid="ignore"):
        f = np.where(u1 > u0, (targets - u0) / (u1 - u0), 0.0)
    return (i - 1) + np.clip(f, 0.0, 1.0)


def _u_at(u: np.ndarray, pos: np.ndarray) -> np.ndarray:
    """Revolution coordinate at fractional sample positions (linear between samples)."""
    i = np.clip(np.floor(pos).astype(np.int64), 0, u.size - 2)
    return u[i] + (pos - i) * (u[i + 1] - u[i])


def _predicted_centers(vt: np.ndarray, u: np.ndarray, w: int, n_harmonics: int
                       ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Step 1 of :func:`find_extrema`: per channel row of ``vt`` (c, n), the sample nearest each
    predicted minimum and maximum (windows of 2w+1 inside the record).

    Returns (channel row, centre, is_min) of every window and a bool per channel row: True where
    the row had enough valid samples for the harmonic prediction.
    """
    c, n = vt.shape
    rows = np.arange(0, n, max(1, n // 10_000))
    basis = _harmonic_basis(u[rows], 2.0 * math.pi, n_harmonics, False)
    grid = np.linspace(0.0, 1.0, 3600, endpoint=False)
    gb = _harmonic_basis(grid, 2.0 * math.pi, n_harmonics, False)
    revs = np.arange(math.floor(u[0]) - 1, math.ceil(u[-1]) + 1)
    yr = vt[:, rows].T  # (rows, c)
    okr = ~np.isnan(yr)
    usable = okr.sum(axis=0) >= 2 * n_harmonics + 2
    coef_h = np.full((basis.shape[1], c), np.nan)
    if okr.all():
        coef_h[:] = _lsq(basis, yr)
    elif usable.any():  # each channel's own rows: the normal equations less its few missing rows
        btb_all = basis.T @ basis
        bty = basis.T @ np.where(okr, yr, 0.0)
        for j in np.flatnonzero(usable):
            bb = basis[~okr[:, j]]
            coef_h[:, j] = np.linalg.solve(btb_all - bb.T @ bb, bty[:, j])
    model = gb @ coef_h  # (grid, c)
    ue = np.concatenate([grid[np.argmin(model, axis=0)], grid[np.argmax(model, axis=0)]])  # (2c,) min then max
    targets = ue[:, None] + revs[None, :]
    inside = (targets >= u[0]) & (targets <= u[-1])
    inside[np.tile(~usable, 2)] = False
    which, r_i = np.nonzero(inside)
    tg = targets[which, r_i]
    order = np.argsort(tg, kind="stable")  # sorted keys: searchsorted narrows from the last hit
    ck = np.empty(tg.size, dtype=np.int64)
    ck[order] = np.round(_sample_at(u, tg[order])).astype(np.int64)
    keep = (ck - w >= 0) & (ck + w < n)
    which, ck = which[keep], ck[keep]
    return which % c, ck, which < c, usable


def find_extrema(values_mm: np.ndarray, u_rev: np.ndarray, *, half_window_samples: int | None = None,
                 samples_per_rev: float, min_valid_fraction: float = 0.8, n_harmonics: int = 3,
                 channels: tuple[int, ...] | None = None, sample0: int = 0) -> tuple[pl.DataFrame, dict]:
    """Minima and maxima per revolution and channel at sub-sample precision.

    1. Predict: a harmonic model in the revolution coordinate u (linear least squares on a stride
       of at most 10 000 samples) gives the phase of each channel's minimum and maximum; their
       predicted sample positions are where u = u_ext + r.
    2. Refine: cubic least-squares fit over 2W+1 samples around the prediction
       (:func:`fit_extremum_cubic`), re-centred on the rounded optimum until it stays
       (|x*| <= 0.6). s^2 is pooled per channel over all windows (dof = sum(n_i - 4)).
    A window with fewer than ``min_valid_fraction`` valid samples, or no valid samples on one
    side of the extremum, is dropped and counted (never interpolated). All channels are fitted
    in one batch.

    Returns
    -------
    extrema : polars.DataFrame channel, revolution, kind ("min"/"max"), sample_pos, u_sample_pos,
        value_mm, u_value_mm, n_valid
    info : dict with ``dropped`` per channel and ``sigma_mm`` per channel
    """
    v, _ = _as_2d(values_mm)
    n, c = v.shape
    vt = v.T
    chans = tuple(channels) if channels is not None else tuple(range(1, c + 1))
    u = np.asarray(u_rev, dtype=float)
    w = int(half_window_samples) if half_window_samples else max(4, int(round(samples_per_rev / 16.0)))
    info = {"dropped": {}, "sigma_mm": {}, "half_window_samples": w}
    schema = {"channel": pl.Int64, "revolution": pl.Int64, "kind": pl.Utf8, "sample_pos": pl.Float64,
              "u_sample_pos": pl.Float64, "value_mm": pl.Float64, "u_value_mm": pl.Float64,
              "n_valid": pl.Int64}
    X, pinv, xtx_inv = _cubic_fit_matrices(w)
    ch, centers, is_min, usable = _predicted_centers(vt, u, w, n_harmonics)
    if not ch.size:
        for j, name in enumerate(chans):
            info["dropped"][name] = 0
            info["sigma_mm"][name] = 0.0 if usable[j] else float("nan")
        return pl.DataFrame(schema=schema), info
    windows = _row_windows(vt, 2 * w + 1)
    coef, Y, bad = _fit_windows(windows, ch, centers, w, pinv, X)
    x = _cubic_stationary(coef)
    for _ in range(8):
        # re-centre on the rounded optimum; hysteresis (|x| > 0.6) stops 0.5-toggling
        move = np.where(np.isfinite(x) & (np.abs(x) > 0.6), np.clip(np.round(x), -w, w), 0).astype(np.int64)
        mv = np.flatnonzero(move)
        new = np.clip(centers[mv] + move[mv], w, n - w - 1)
        mv, new = mv[new != centers[mv]], new[new != centers[mv]]
        if not mv.size:
            break
        centers[mv] = new  # refit only the windows that moved
        coef[mv], Y[mv], bad[mv] = _fit_windows(windows, ch[mv], new, w, pinv, X)
        x[mv] = _cubic_stationary(coef[mv])
    # windows that converged onto the same centre (per channel and kind) are one extremum
    _, keep = np.unique((ch * n + centers) * 2 + is_min, return_index=True)
    ch, centers, coef, Y, bad, x, is_min = ch[keep], centers[keep], coef[keep], Y[keep], bad[keep], x[keep], is_min[keep]
    nvalid = (2 * w + 1) - bad.sum(axis=1)
    resid = coef @ X.T
    np.subtract(Y, resid, out=resid)
    resid[bad] = 0.0
    rss = np.einsum("ij,ij->i", resid, resid)
    fin = np.isfinite(rss)
    # pooled noise variance over all windows of each channel
    rss_c = np.bincount(ch[fin], weights=rss[fin], minlength=c)
    dof_c = np.bincount(ch[fin], weights=nvalid[fin] - 4, minlength=c)
    s2_c = rss_c / np.maximum(dof_c, 1)
    s2 = s2_c[ch]
    xx = np.where(np.isfinite(x), x, 0.0)
    sign_ok = np.where(is_min, coef[:, 2] > 0, coef[:, 2] < 0)
    left = ~bad[:, :w].all(axis=1)
    right = ~bad[:, w + 1:].all(axis=1)
    enough = nvalid >= min_valid_fraction * (2 * w + 1)
    good = np.isfinite(x) & sign_ok & (np.abs(x) <= 1.0) & enough & left & right
    gx = -np.stack([np.zeros_like(xx), np.ones_like(xx), 2 * xx, 3 * xx * xx], 1) / (
        2 * coef[:, 2:3] + 6 * coef[:, 3:4] * xx[:, None])
    gv = np.stack([np.ones_like(xx), xx, xx * xx, xx ** 3], 1)
    cov = np.broadcast_to(xtx_inv, (xx.size, 4, 4)).copy()
    part = np.flatnonzero(bad.any(axis=1) & good)
    if part.size:  # windows with nulls: their own (X^T X)^-1
        m = (~bad[part]).astype(float)
        cov[part] = np.linalg.inv(_masked_xtx(X, m))
    ux = np.sqrt(s2 * np.einsum("ri,rij,rj->r", gx, cov, gx))
    uv = np.sqrt(s2 * np.einsum("ri,rij,rj->r", gv, cov, gv))
    dropped = np.bincount(ch[~good], minlength=c)
    for j, name in enumerate(chans):
        info["dropped"][name] = int(dropped[j])
        info["sigma_mm"][name] = math.sqrt(s2_c[j]) if usable[j] else float("nan")
    pos_g = (centers + xx)[good]
    ch_g = ch[good]
    order = np.lexsort((pos_g, ch_g))
    g = np.flatnonzero(good)[order]
    pos_g, ch_g = pos_g[order], ch_g[order]
    chan_names = np.asarray(chans, dtype=np.int64)
    return pl.DataFrame({
        "channel": chan_names[ch_g],
        "revolution": np.floor(_u_at(u, pos_g)).astype(np.int64),
        "kind": pl.Series(["max", "min"])[is_min[g].astype(np.int64)],
        "sample_pos": (pos_g + sample0).astype(float),
        "u_sample_pos": ux[g],
        "value_mm": np.einsum("ri,ri->r", gv[g], coef[g]),
        "u_value_mm": uv[g],
        "n_valid": nvalid[g].astype(np.int64),
    }, schema=schema), info


def n_m_counts(min_pos: np.ndarray, max_pos: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Yang §2.3 counts: n_i = samples from each minimum to the next maximum, m_i = from each
    maximum to the next minimum (positions in samples, any order)."""
    mn = np.sort(np.asarray(min_pos, dtype=float))
    mx = np.sort(np.asarray(max_pos, dtype=float))
    i = np.searchsorted(mx, mn, side="right")
    n = mx[i[i < mx.size]] - mn[i < mx.size]
    jdx = np.searchsorted(mn, mx, side="right")
    m = mn[jdx[jdx < mn.size]] - mx[jdx < mn.size]
    return n, m


def beam_status(n_mean: float, m_mean: float, direction: str = "ccw") -> dict:
    """Advanced/backward status of a beam from the mean counts (Yang 2017, §2.3).

    n < m -> "backward", n > m -> "advanced", equal -> "undetermined" (status relative to the
    rotation, as the paper defines it). Implied sign of rho in the spec frame: ccw: advanced ->
    +1, backward -> -1; cw: flipped.
    """
    if direction not in ("ccw", "cw"):
        raise ValueError(f"direction must be 'ccw' or 'cw', got {direction!r}")
    if n_mean < m_mean:
        status = "backward"
    elif n_mean > m_mean:
        status = "advanced"
    else:
        status = "undetermined"
    sign = {"advanced": 1, "backward": -1, "undetermined": 0}[status]
    return {"status": status, "rho_sign": sign if direction == "ccw" else -sign}


def theta_t_rad(spacing_samples: float | np.ndarray, samples_per_rev: float) -> float | np.ndarray:
    """Yang 2017, Eq. 15 in samples: theta_t = Delta t omega = spacing * 2 pi / P [rad]."""
    return np.asarray(spacing_samples, dtype=float) * 2.0 * math.pi / float(samples_per_rev)


def feature_spacings(min_pos: dict[int, np.ndarray], samples_per_rev: float, u_samples_per_rev: float = 0.0
                     ) -> pl.DataFrame:
    """Feature-point (minimum) spacings between channels and theta_t (Yang 2017, Eq. 15).

    For each ordered pair (i, j) of consecutive channels (1->2, 2->3, ..., last->first) the
    spacing is the number of samples from each minimum of i to the next minimum of j, in
    [0, P); mean, standard uncertainty of the mean, and theta_t = spacing 2 pi / P with
    u(theta_t) from both.
    """
    chans = sorted(min_pos)
    rows = []
    for a, b in zip(chans, chans[1:] + chans[:1]):
        if a == b:
            continue
        pa = np.sort(np.asarray(min_pos[a], dtype=float))
        pb = np.sort(np.asarray(min_pos[b], dtype=float))
        if pa.size == 0 or pb.size == 0:
            continue
        i = np.searchsorted(pb, pa, side="right")
        okk = i < pb.size
        d = pb[i[okk]] - pa[okk]
        d = d[d < samples_per_rev * 1.0 + 0.5]
        if d.size == 0:
            continue
        mean = float(d.mean())
        u = float(d.std(ddof=1) / math.sqrt(d.size)) if d.size > 1 else float("nan")
        th = float(theta_t_rad(mean, samples_per_rev))
        u_th = th * math.hypot(u / mean, u_samples_per_rev / samples_per_rev) if mean else float("nan")
        rows.append({"from_channel": a, "to_channel": b, "spacing_samples": mean, "u_spacing_samples": u,
                     "count": int(d.size), "theta_t_rad": th, "u_theta_t_rad": u_th})
    schema = {"from_channel": pl.Int64, "to_channel": pl.Int64, "spacing_samples": pl.Float64,
              "u_spacing_samples": pl.Float64, "count": pl.Int64, "theta_t_rad": pl.Float64,
              "u_theta_t_rad": pl.Float64}
    return pl.DataFrame(rows, schema=schema)


# --------------------------------------------------------------------------- result + entry points


@dataclass
class SignalResult:
    """Everything the signal stage produces for one scan (see :func:`process_arrays`)."""

    scan_id: str
    channels: tuple[int, ...]
    sample: np.ndarray
    despiked_mm: np.ndarray
    period: PeriodEstimate
    revolutions: pl.DataFrame
    extrema: pl.DataFrame
    summary: pl.DataFrame
    spacings: pl.DataFrame
    set_aside: pl.DataFrame
    config: dict = field(default_factory=dict)

    @functools.cached_property
    def filtered_mm(self) -> np.ndarray:
        """The despiked readings through the configured filter (``config["filter"]``, zero-phase) [mm].

        Computed on first use: with ``extrema_on="despiked"`` (the default) nothing else needs it.
        """
        if self.config.get("filter", "none") == "none":
            return self.despiked_mm
        return filter_readings(self.despiked_mm, method=self.config["filter"],
                               samples_per_rev=self.period.samples_per_rev, **self.config.get("filter_params", {}))

    def to_frames(self) -> dict[str, pl.DataFrame]:
        """Tables for Parquet: revolutions, extrema, summary, spacings, period, set_aside (with scan_id)."""
        sid = pl.lit(self.scan_id).alias("scan_id")
        per = pl.DataFrame([self.period.to_dict()])
        out = {"revolutions": self.revolutions, "extrema": self.extrema, "summary": self.summary,
               "spacings": self.spacings, "period": per, "set_aside": self.set_aside}
        return {k: (f if "scan_id" in f.columns else f.select(sid, pl.all())) for k, f in out.items()}


def _mean_u(a: np.ndarray) -> tuple[float, float]:
    """Mean and its standard uncertainty s / sqrt(k) (NaN where undefined)."""
    if a.size == 0:
        return float("nan"), float("nan")
    return float(a.mean()), (float(a.std(ddof=1) / math.sqrt(a.size)) if a.size > 1 else float("nan"))


def process_arrays(
    values_mm: np.ndarray,
    *,
    sample_rate_hz: float,
    rpm_nominal: float | None = None,
    direction: str = "ccw",
    scan_id: str = "",
    channels: tuple[int, ...] | None = None,
    sample0: int = 0,
    t_s: np.ndarray | None = None,
    encoder_t_s: np.ndarray | None = None,
    encoder_angle_rad: np.ndarray | None = None,
    filter: str = "none",
    filter_params: dict | None = None,
    spike_window_samples: int = 7,
    spike_threshold: float = 6.0,
    half_window_samples: int | None = None,
    extrema_on: str = "despiked",
    n_harmonics: int = 3,
) -> SignalResult:
    """The whole signal stage on plain arrays.

    nulls counted -> spikes set aside (:func:`remove_spikes`) -> period (encoder when given,
    else :func:`period_from_readings`) and revolution coordinate -> extrema
    (:func:`find_extrema`, on the despiked readings by default because filtering correlates the
    noise that the fit uncertainty assumes white; ``extrema_on="filtered"`` fits them on the
    readings through ``filter`` with ``filter_params``, zero-phase) -> n, m, status, spacings.
    With the default the filter is computed only when ``SignalResult.filtered_mm`` is read.

    The summary keeps the paper's rule for ``status`` (n < m -> backward) and adds
    ``n_minus_m_samples`` with its standard uncertainty and ``status_significant`` (|n - m| >= 3u):
    the geometric asymmetry is small (0.29 samples at 660 samples/rev for r = 5.5 mm).
    """
    v, _ = _as_2d(values_mm)
    n, c = v.shape
    chans = tuple(channels) if channels is not None else tuple(range(1, c + 1))
    h = _check_spike_window(spike_window_samples)
    vp = _padded_rows(v, h)  # own copy, one contiguous row per channel
    spike_idx, nulls = _despike_rows(vp, h, spike_threshold, _SPIKE_CANDIDATE_THRESHOLD)
    clean = vp[:, h: h + n].T
    nom = _nominal(sample_rate_hz, rpm_nominal)
    if t_s is None:
        t_s = np.arange(n) / float(sample_rate_hz)
    enc = None if encoder_angle_rad is None else np.asarray(encoder_angle_rad, dtype=float)
    if enc is not None and np.any(~np.isnan(enc)):
        period = period_from_encoder(encoder_t_s, enc, t_s, rpm_nominal=rpm_nominal,
                                     sample_rate_hz=sample_rate_hz)
        u = revolution_coordinate(n, period, sample_times_s=t_s, encoder_t_s=encoder_t_s,
                                  encoder_angle_rad=enc)
    else:
        period = period_from_readings(clean, samples_per_rev_guess=nom, rpm_nominal=rpm_nominal,
                                      sample_rate_hz=sample_rate_hz, direction=direction,
                                      n_harmonics=n_harmonics)
        u = revolution_coordinate(n, period)
    spr = period.samples_per_rev
    if extrema_on not in ("despiked", "filtered"):
        raise ValueError(f"extrema_on must be 'despiked' or 'filtered', got {extrema_on!r}")
    if filter not in FILTERS:
        raise ValueError(f"unknown filter {filter!r}; valid: {', '.join(FILTERS)}")
    filtered = None
    if extrema_on == "filtered":  # otherwise the filter runs only if SignalResult.filtered_mm is read
        filtered = clean if filter == "none" else filter_readings(clean, method=filter, samples_per_rev=spr,
                                                                    **(filter_params or {}))
    src = clean if filtered is None else filtered
    ext, info = find_extrema(src, u, half_window_samples=half_window_samples, samples_per_rev=spr,
                             channels=chans, sample0=sample0, n_harmonics=n_harmonics)
    e_ch = ext["channel"].to_numpy()
    e_min = (ext["kind"] == "min").to_numpy()
    e_pos = ext["sample_pos"].to_numpy()
    e_val = ext["value_mm"].to_numpy()
    ext = ext.select(pl.lit(scan_id).alias("scan_id"), pl.all())
    srows = []
    min_pos = {}
    for ch in chans:
        in_ch = e_ch == ch
        mn, mx = in_ch & e_min, in_ch & ~e_min
        min_pos[ch] = e_pos[mn]
        nn, mm = n_m_counts(e_pos[mn], e_pos[mx])
        dmin, u_dmin = _mean_u(e_val[mn])
        dmax, u_dmax = _mean_u(e_val[mx])
        n_mean, u_n = _mean_u(nn)
        m_mean, u_m = _mean_u(mm)
        if nn.size and mm.size:
            st = beam_status(n_mean, m_mean, period.direction)
        else:
            st = {"status": "undetermined", "rho_sign": 0}
        # n_i - m_i = 2 max_i - min_i - min_{i+1}: neighbours share a minimum (lag-1 correlation 1/6),
        # so the uncertainty of the mean is sqrt(8/6) x s / sqrt(k)
        k = min(nn.size, mm.size)
        nm, u_nm = _mean_u(nn[:k] - mm[:k])
        u_nm *= math.sqrt(8.0 / 6.0)
        srows.append({
            "channel": ch, "d_min_mm": dmin, "u_d_min_mm": u_dmin, "d_max_mm": dmax, "u_d_max_mm": u_dmax,
            "n_revolutions_min": int(mn.sum()), "n_revolutions_max": int(mx.sum()),
            "n_samples": n_mean, "u_n_samples": u_n, "m_samples": m_mean, "u_m_samples": u_m,
            "n_minus_m_samples": nm, "u_n_minus_m_samples": u_nm,
            "status": st["status"], "status_significant": bool(abs(nm) >= 3 * u_nm) if k > 1 else False,
            "rho_sign": st["rho_sign"], "sigma_fit_mm": info["sigma_mm"].get(ch),
            "extrema_dropped": info["dropped"].get(ch, 0),
        })
    columns = {k: [r[k] for r in srows] for k in (srows[0] if srows else {})}  # by column: faster than rows
    summary = pl.DataFrame({"scan_id": [scan_id] * len(srows)} | columns)
    spac = feature_spacings(min_pos, spr, period.u_samples_per_rev)
    revs = find_revolutions(u, sample0)
    set_aside = pl.DataFrame({"channel": list(chans), "nulls": nulls.astype(np.int64),
                              "spikes": np.array([i.size for i in spike_idx], dtype=np.int64)})
    cfg = {"filter": filter, "filter_params": filter_params or {},
           "spike_window_samples": spike_window_samples, "spike_threshold": spike_threshold,
           "half_window_samples": info["half_window_samples"],
           "extrema_on": extrema_on, "n_harmonics": n_harmonics}
    res = SignalResult(scan_id, chans, np.arange(n, dtype=np.int64) + sample0, clean, period, revs, ext,
                       summary, spac, set_aside, cfg)
    if filtered is not None:
        res.__dict__["filtered_mm"] = filtered  # computed already (the cached property's slot)
    return res


def process_scan(scan: Any, matrix: Any = None, **cfg: Any) -> SignalResult:
    """Signal stage of one ``borescan.rawio.RawScan`` (keyword ``cfg`` as :func:`process_arrays`).

    Uses ``rawio.lds_matrix(scan)`` (or ``matrix``, when the caller has built it already);
    missing ticks in ``sample`` become NaN rows (counted as nulls). The encoder angle is used
    when the spindle stream has a non-null ``angle_rad``; otherwise the period comes from the
    readings. ``scan.json`` gives ``sample_rate_hz`` and ``spindle.rpm_nominal``/``direction``.
    """
    from borescan import rawio

    mat = rawio.lds_matrix(scan) if matrix is None else matrix
    sample = np.asarray(mat.sample, dtype=np.int64)
    vals = np.asarray(mat.values_mm, dtype=float)
    t_s = np.asarray(mat.t_s, dtype=float)
    full = np.arange(sample[0], sample[-1] + 1)
    if full.size != sample.size:
        v2 = np.full((full.size, vals.shape[1]), np.nan)
        v2[sample - sample[0]] = vals
        vals = v2
        t_s = np.interp(full, sample, t_s)
    meta = scan.meta
    sp = meta.get("spindle") or {}
    enc_t = enc_a = None
    if scan.spindle is not None and "angle_rad" in scan.spindle.columns:
        a = scan.spindle["angle_rad"].cast(pl.Float64).to_numpy()
        if np.any(~np.isnan(a)):
            enc_t = scan.spindle["t_ns"].to_numpy().astype(float) * 1e-9
            enc_a = a
    kw = dict(sample_rate_hz=float(meta["sample_rate_hz"]), rpm_nominal=sp.get("rpm_nominal"),
              direction=sp.get("direction", "ccw"), scan_id=scan.scan_id, channels=tuple(mat.channels),
              sample0=int(full[0]), t_s=t_s, encoder_t_s=enc_t, encoder_angle_rad=enc_a)
    kw.update(cfg)
    return process_arrays(vals, **kw)


# --------------------------------------------------------------------------- filter quantification


def _fundamental(y: np.ndarray, samples_per_rev: float) -> tuple[float, float]:
    """Amplitude [mm] and phase [rad] of the 1-UPR term (fit with 2nd/3rd harmonics and mean)."""
    k = np.arange(y.size, dtype=float)
    ok = ~np.isnan(y)
    b = _harmonic_basis(k, 2 * math.pi / samples_per_rev, 3, False)
    coef = np.linalg.lstsq(b[ok], y[ok], rcond=None)[0]
    return float(math.hypot(coef[1], coef[2])), float(math.atan2(coef[2], coef[1]))


def filter_performance(*, revolutions: int = 8, samples_per_rev: int = 660, noise_mm: float = 0.0025,
                       seed: int = 0, filters: dict | None = None) -> pl.DataFrame:
    """Scatter reduction, phase lag and amplitude loss of each filter on a simulated scan.

    Yang-like device (Table 1 beams, P1/P0 of §3.1, gauge 275.029 mm) at 60 rpm with
    ``samples_per_rev`` samples per revolution (f_s = samples_per_rev Hz) and white Gaussian
    reading noise ``noise_mm`` (2.5 um gives a ~15 um peak-to-peak beat per revolution, the
    paper's §4 figure). For channel 1 and each filter: ``beat_um`` = mean per-revolution
    peak-to-peak of (filtered - truth), ``scatter_um`` its RMS, ``lag_rad``/``lag_samples`` the
    phase delay of the 1-UPR term, ``amplitude_loss_um`` its amplitude change and
    ``min_shift_samples`` the mean shift of the sub-sample minimum (cubic fit) vs truth.
    """
    from borescan.geometry import Beams, Bore, tri_spindle_readings

    beams = Beams((1, 2, 3), np.array([0.3, 2.4, 4.5]), np.array([5.5484, -2.5295, 1.5262]),
                  np.array([132.6718, 132.8883, 134.1108]))
    n = revolutions * samples_per_rev
    k = np.arange(n)
    truth = tri_spindle_readings(2 * math.pi * k / samples_per_rev, np.array([262.955, -275.502]), beams,
                                 Bore((262.833, -273.182), 275.029 / 2))[:, 0]
    rng = np.random.default_rng(seed)
    y = truth + rng.normal(0.0, noise_mm, n)
    if filters is None:
        filters = {
            "raw": ("none", {}),
            "median 5": ("median", {"window_samples": 5}),
            "median 25": ("median", {"window_samples": 25}),
            "moving average 25": ("moving_average", {"window_samples": 25}),
            "moving average 25 causal": ("moving_average", {"window_samples": 25, "causal": True}),
            "kalman rw causal q=1e-6": ("kalman", {"model": "random_walk", "q_mm2": 1e-6, "smooth": False}),
            "kalman rw smoothed q=1e-6": ("kalman", {"model": "random_walk", "q_mm2": 1e-6}),
            "kalman cv causal q=1e-9": ("kalman", {"model": "constant_velocity", "q_mm2": 1e-9,
                                                   "smooth": False}),
            "kalman cv smoothed q=1e-9": ("kalman", {"model": "constant_velocity", "q_mm2": 1e-9}),
            "gaussian 50 UPR": ("gaussian", {"cutoff_upr": 50.0}),
            "gaussian 30 UPR": ("gaussian", {"cutoff_upr": 30.0}),
        }
    w = samples_per_rev // 16
    mins_t = _mins(truth, samples_per_rev, w)
    rows = []
    trim = samples_per_rev  # leave the first/last revolution out of the scatter (filter start-up)
    for name, (method, params) in filters.items():
        f = filter_readings(y, method=method, samples_per_rev=samples_per_rev, **params)
        e = (f - truth)[trim: n - trim].reshape(-1, samples_per_rev)
        a_f, ph_f = _fundamental(f[trim: n - trim], samples_per_rev)
        a_t2, ph_t2 = _fundamental(truth[trim: n - trim], samples_per_rev)
        lag = (ph_f - ph_t2 + math.pi) % (2 * math.pi) - math.pi
        mins_f = _mins(f, samples_per_rev, w)
        rows.append({"filter": name, "beat_um": float(np.mean(np.nanmax(e, 1) - np.nanmin(e, 1))) * 1e3,
                     "scatter_um": float(np.sqrt(np.nanmean(e * e))) * 1e3,
                     "lag_rad": lag, "lag_samples": lag * samples_per_rev / (2 * math.pi),
                     "amplitude_loss_um": (a_t2 - a_f) * 1e3,
                     "min_shift_samples": float(np.nanmean(mins_f - mins_t))})
    return pl.DataFrame(rows)


def _mins(y: np.ndarray, samples_per_rev: int, w: int) -> np.ndarray:
    """Sub-sample minimum per inner revolution (cubic fit), NaN where not found."""
    u = np.arange(y.size) / samples_per_rev
    ext, _ = find_extrema(y, u, samples_per_rev=samples_per_rev, half_window_samples=w)
    mn = ext.filter(pl.col("kind") == "min")
    out = np.full(y.size // samples_per_rev, np.nan)
    r = mn["revolution"].to_numpy()
    keep = (r >= 1) & (r < out.size - 1)
    out[r[keep]] = mn["sample_pos"].to_numpy()[keep]
    return out[1:-1]


def feature_points(extrema: pl.DataFrame, samples_per_rev: float) -> pl.DataFrame:
    """Feature point (minimum) of each channel as a phase in samples within one revolution.

    The circular mean over revolutions of ``sample_pos mod samples_per_rev`` (the common origin
    is sample 0), with its standard uncertainty (circular scatter / sqrt(revolutions)). The
    differences between channels are the spacings of Yang 2017 Eq. 15.

    Returns
    -------
    polars.DataFrame: channel, feature_sample, u_feature_sample, n_revolutions
    """
    rows = []
    is_min = (extrema["kind"] == "min").to_numpy()
    chan = extrema["channel"].to_numpy()[is_min]
    pos_all = extrema["sample_pos"].to_numpy()[is_min].astype(float)
    for ch in np.unique(chan).tolist():
        pos = pos_all[chan == ch]
        ang = 2.0 * np.pi * np.mod(pos, samples_per_rev) / samples_per_rev
        mean_ang = math.atan2(np.sin(ang).mean(), np.cos(ang).mean())
        dev = np.angle(np.exp(1j * (ang - mean_ang)))
        u = float(dev.std(ddof=1) / math.sqrt(dev.size)) if dev.size > 1 else float("nan")
        rows.append({"channel": int(ch), "feature_sample": float(np.mod(mean_ang, 2 * np.pi) * samples_per_rev / (2 * np.pi)),
                     "u_feature_sample": u * samples_per_rev / (2 * np.pi), "n_revolutions": int(dev.size)})
    return pl.DataFrame(rows, schema={"channel": pl.Int64, "feature_sample": pl.Float64,
                                      "u_feature_sample": pl.Float64, "n_revolutions": pl.Int64})
