"""Minima and maxima per revolution and channel at sub-sample precision (cubic fits)."""

from __future__ import annotations

import functools
import math

import numpy as np
import polars as pl
from numpy.lib.stride_tricks import sliding_window_view

from borescan.signal._common import _as_2d
from borescan.signal.period import _harmonic_basis, _lsq


def _cubic_design(half_window: int) -> np.ndarray:
    x = np.arange(-half_window, half_window + 1, dtype=float)
    return np.stack([np.ones_like(x), x, x * x, x**3], axis=1)


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
    s2 = sigma_mm**2 if sigma_mm is not None else float(r @ r) / max(ok.sum() - 4, 1)
    cov = s2 * np.linalg.inv(X[ok].T @ X[ok])
    x = float(_cubic_stationary(coef))
    gx = -np.array([0.0, 1.0, 2 * x, 3 * x * x]) / (2 * coef[2] + 6 * coef[3] * x)
    gv = np.array([1.0, x, x * x, x**3])
    good = (coef[2] > 0) if kind == "min" else (coef[2] < 0)
    return {
        "x": x,
        "u_x": math.sqrt(gx @ cov @ gx),
        "value": float(gv @ coef),
        "u_value": math.sqrt(gv @ cov @ gv),
        "ok": bool(good and abs(x) <= w),
    }


def _masked_xtx(X: np.ndarray, m: np.ndarray) -> np.ndarray:
    """Return the normal matrices of ``X`` for each row of the masks ``m``.

    Return normal matrices X^T diag(m_r) X of the design ``X`` (k, 4) for each row of the 0/1 masks ``m``
    (R,
    k).
    """
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
        flat = np.lib.stride_tricks.as_strided(
            vt, shape=((c - 1) * step + n,), strides=(isz,), writeable=False
        )
        return sliding_window_view(flat, k), step
    return sliding_window_view(vt, k, axis=1), None


def _fit_windows(
    windows: tuple[np.ndarray, int | None],
    chan: np.ndarray,
    centers: np.ndarray,
    w: int,
    pinv: np.ndarray,
    X: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
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


def _predicted_centers(
    vt: np.ndarray, u: np.ndarray, w: int, n_harmonics: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Return the samples nearest each predicted minimum and maximum.

    Step 1 of :func:`find_extrema`: per channel row of ``vt`` (c, n), the sample nearest each
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
    ue = np.concatenate(
        [grid[np.argmin(model, axis=0)], grid[np.argmax(model, axis=0)]]
    )  # (2c,) min then max
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


def find_extrema(
    values_mm: np.ndarray,
    u_rev: np.ndarray,
    *,
    half_window_samples: int | None = None,
    samples_per_rev: float,
    min_valid_fraction: float = 0.8,
    n_harmonics: int = 3,
    channels: tuple[int, ...] | None = None,
    sample0: int = 0,
) -> tuple[pl.DataFrame, dict]:
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
    schema = {
        "channel": pl.Int64,
        "revolution": pl.Int64,
        "kind": pl.Utf8,
        "sample_pos": pl.Float64,
        "u_sample_pos": pl.Float64,
        "value_mm": pl.Float64,
        "u_value_mm": pl.Float64,
        "n_valid": pl.Int64,
    }
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
    ch, centers, coef, Y, bad, x, is_min = (
        ch[keep],
        centers[keep],
        coef[keep],
        Y[keep],
        bad[keep],
        x[keep],
        is_min[keep],
    )
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
    right = ~bad[:, w + 1 :].all(axis=1)
    enough = nvalid >= min_valid_fraction * (2 * w + 1)
    good = np.isfinite(x) & sign_ok & (np.abs(x) <= 1.0) & enough & left & right
    gx = -np.stack([np.zeros_like(xx), np.ones_like(xx), 2 * xx, 3 * xx * xx], 1) / (
        2 * coef[:, 2:3] + 6 * coef[:, 3:4] * xx[:, None]
    )
    gv = np.stack([np.ones_like(xx), xx, xx * xx, xx**3], 1)
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
    return pl.DataFrame(
        {
            "channel": chan_names[ch_g],
            "revolution": np.floor(_u_at(u, pos_g)).astype(np.int64),
            "kind": pl.Series(["max", "min"])[is_min[g].astype(np.int64)],
            "sample_pos": (pos_g + sample0).astype(float),
            "u_sample_pos": ux[g],
            "value_mm": np.einsum("ri,ri->r", gv[g], coef[g]),
            "u_value_mm": uv[g],
            "n_valid": nvalid[g].astype(np.int64),
        },
        schema=schema,
    ), info
