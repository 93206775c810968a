"""Rotation period (from the encoder or from the readings, with its uncertainty) and revolutions."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np
import polars as pl

from borescan.signal._common import _as_2d


@dataclass(frozen=True)
class PeriodEstimate:
    """Rotation period in samples with its standard uncertainty and provenance.

    ``period_disagrees_with_nominal`` is True when |P - P_nominal| > 3 u(P), with
    P_nominal = 60 f_s / rpm_nominal.
    """

    samples_per_rev: float
    u_samples_per_rev: float
    source: str  # "encoder" | "readings" | "profile"
    samples_per_rev_nominal: float | None
    period_disagrees_with_nominal: bool
    direction: str  # "ccw" | "cw"

    def to_dict(self) -> dict:
        """Return the estimate as a dict of its fields."""
        return asdict(self)


def _nominal(sample_rate_hz: float | None, rpm_nominal: float | None) -> float | None:
    if sample_rate_hz is None or rpm_nominal is None or not rpm_nominal:
        return None
    return 60.0 * float(sample_rate_hz) / abs(float(rpm_nominal))


def _disagrees(p: float, u: float, nominal: float | None) -> bool:
    return bool(nominal is not None and abs(p - nominal) > 3.0 * u)


def period_from_encoder(
    t_s: np.ndarray,
    angle_rad: np.ndarray,
    sample_times_s: np.ndarray,
    *,
    rpm_nominal: float | None = None,
    sample_rate_hz: float | None = None,
) -> PeriodEstimate:
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
    if not (omega != 0.0 and math.isfinite(omega) and dt > 0.0):
        raise ValueError(f"spindle.parquet: angle_rad does not turn (speed {omega:g} rad/s): no period")
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


def period_from_readings(
    values_mm: np.ndarray,
    *,
    samples_per_rev_guess: float | None = None,
    n_harmonics: int = 3,
    trend: bool = True,
    max_samples: int = 10_000,
    rpm_nominal: float | None = None,
    sample_rate_hz: float | None = None,
    direction: str = "ccw",
) -> PeriodEstimate:
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
        la, lb, lc = np.log(spec[i - 1 : i + 2] + 1e-300)
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
        dcoef[0::2] = coef[n0 + 1 :: 2]
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


def revolution_coordinate(
    n_samples: int,
    period: PeriodEstimate,
    *,
    sample_times_s: np.ndarray | None = None,
    encoder_t_s: np.ndarray | None = None,
    encoder_angle_rad: np.ndarray | None = None,
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
    return pl.DataFrame(
        {
            "revolution": r,
            "first_sample": (starts + sample0).astype(np.int64),
            "last_sample": (ends + sample0).astype(np.int64),
            "n_samples": (ends - starts + 1).astype(np.int64),
            "complete": complete,
        }
    )
