"""Spikes set aside as NaN: a Hampel test against a robust local-linear (Theil-Sen) reference."""

from __future__ import annotations

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

from borescan.noise import mad_sigma
from borescan.signal._common import _as_2d, _back, _nanmedian_rows
from borescan.sortnet import median_columns

_SPIKE_CANDIDATE_THRESHOLD = 2.5  # chord test of remove_spikes, in MAD scales


def _ll_reference(col_x: np.ndarray, idx: np.ndarray, w: int) -> np.ndarray:
    """Robust local-linear reference of a column at rows ``idx`` (see :func:`remove_spikes`).

    ``col_x`` is the column with excluded samples (nulls, candidates) set to NaN and padded with
    ``w // 2`` NaN at both ends (``idx`` indexes windows of ``w`` samples, i.e. the padded
    position of each window's first sample). Uses the neighbours j = -h..h, j != 0, that are not NaN:
    Theil-Sen slope s (median of pairwise
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
    """Return the median of each row of a NaN-free 2-D array.

    Median of each row of a NaN-free 2-D array (exact: partition for an odd number of columns, a
    selection network on the columns for an even one, where partition needs two ranks).
    """
    m = a.shape[1]
    if m % 2:
        return np.partition(a, m // 2, axis=1)[:, m // 2]
    return median_columns([a[:, k] for k in range(m)])


def _mad_scale(r: np.ndarray, max_n: int = 20_000) -> float:
    """Return 1.4826 x the median absolute deviation of the non-NaN values.

    1.4826 x median absolute deviation of the non-NaN values, on a uniform stride of at most
    ``max_n`` of them (relative standard uncertainty of the scale about 1 / sqrt(0.74 max_n)).
    """
    if r.size > max_n:
        r = r[:: -(-r.size // max_n)]  # ceil: at most max_n values
    r = r[~np.isnan(r)]
    if r.size == 0:
        return float("inf")
    sc = mad_sigma(r)
    return sc if sc > 0 else float(np.finfo(float).tiny)


def remove_spikes(
    values_mm: np.ndarray,
    *,
    window_samples: int = 7,
    threshold: float = 6.0,
    candidate_threshold: float = _SPIKE_CANDIDATE_THRESHOLD,
) -> tuple[np.ndarray, np.ndarray]:
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
    vt = vp[:, h : vp.shape[1] - h]
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
    vp[:, n + h :] = np.nan
    vp[:, h : n + h] = v.T
    return vp


def _despike_rows(
    vp: np.ndarray, h: int, threshold: float, candidate_threshold: float
) -> tuple[list[np.ndarray], np.ndarray]:
    """Remove spikes in place on padded rows.

    :func:`remove_spikes` in place on rows padded by :func:`_padded_rows` (c, n + 2h); ``h`` is
    the half window from :func:`_check_spike_window`.

    Returns the spike indices (into the unpadded row) and the null count of each row.
    """
    res = [_despike_row(row, h, threshold, candidate_threshold) for row in vp]
    return [r[0] for r in res], np.array([r[1] for r in res], dtype=np.int64)


def _despike_row(
    row: np.ndarray, h: int, threshold: float, candidate_threshold: float
) -> tuple[np.ndarray, int]:
    """One padded row of :func:`_despike_rows`: (spike indices, null count); spikes set to NaN in place.

    The candidate test uses the second difference v_{k+1} - 2 v_k + v_{k-1} (= -2 x the chord of
    :func:`remove_spikes`; the test is scale-free). While the row is tested its candidates are NaN
    in place (so the reference skips them); all but the spikes are restored afterwards.
    """
    n = row.size - 2 * h
    col = row[h : h + n]
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
        spike = np.abs(saved - ref[probe.size :]) > threshold * scale
    col[idx[~spike]] = saved[~spike]
    return idx[spike], int(is_null.sum())
