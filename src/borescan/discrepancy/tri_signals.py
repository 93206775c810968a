"""Signals of a three-sensor spindle scan the examination reads before it fits: speeds, lines, localisation.

Whether the scan turns at more than one speed (then a delay is not a beam direction), the vibration line
off the rotation harmonics, the rotation line (a large speed error's start), the k = 2 lobing as an axis
tilt's start, and where the base residual sits (channels, part of the revolution, spectrum).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

import numpy as np

from borescan.discrepancy.fitting import leading_block

if TYPE_CHECKING:
    from borescan.discrepancy.tri import TriData, TriModel

__all__ = [
    "SAME_WITHIN",
    "relative_spread",
    "signed_speeds",
    "speeds_differ",
    "vibration_peak",
    "localise",
    "tilt_start",
    "rotation_eps",
]


#: two values are "the same" (one speed, one radius) when their spread is below this share of their mean
SAME_WITHIN = 0.05


def relative_spread(x: np.ndarray) -> float:
    """Spread (peak to peak) of values relative to their mean magnitude (0 for one value)."""
    x = np.asarray(x, dtype=float)
    m = float(np.mean(np.abs(x))) if x.size else 0.0
    return float(np.ptp(x) / m) if x.size and m > 0 else 0.0


def signed_speeds(data: "TriData") -> np.ndarray:
    """Signed angular speed of a scan at its samples (direction d(turned)/dt) [rad/s]."""
    t = data.t_s
    if t.size < 2:
        return np.array([data.direction * data.omega_rad_s])
    return data.direction * np.gradient(data.turned_rad(t), t)


def speeds_differ(data: "TriData") -> bool:
    """Return True when the scan turns at more than one speed (spread above :data:`SAME_WITHIN`).

    Then a channel's delay is no longer a change of its beam direction beta (the registry's
    ``absorbed_unless``): a freed beta does not hide it.
    """
    return relative_spread(signed_speeds(data)) > SAME_WITHIN


def vibration_peak(model: "TriModel", r: np.ndarray) -> tuple[float | None, float]:
    """Frequency [Hz] of the strongest residual line that is not a whole multiple of the rotation."""
    d = model.data
    n = leading_block(d.t_s)
    r_all, r = r, r[:n]
    if n < 16:
        return None, 0.0
    dt = float(np.median(np.diff(d.t_s[:n])))
    rr = np.where(np.isfinite(r), r, 0.0)
    rr = rr - rr.mean(axis=0)
    nfft = 1 << int(math.ceil(math.log2(n * 8)))
    spec = np.abs(np.fft.rfft(rr, nfft, axis=0)) ** 2
    power = spec.sum(axis=1)
    f = np.fft.rfftfreq(nfft, dt)
    upr = f / d.rev_hz
    far = np.abs(upr - np.round(upr)) > 0.25
    far &= upr > 0.5
    if not far.any():
        return None, 0.0
    i = int(np.argmax(np.where(far, power, -1.0)))
    f0 = float(f[i])
    if 0 < i < power.size - 1:
        a, b, c = power[i - 1], power[i], power[i + 1]
        den = a - 2 * b + c
        off = 0.5 * (a - c) / den if den != 0 else 0.0
        f0 = float(f[i] + off * (f[1] - f[0]))
    return _refined_over_blocks(d.t_s, np.where(np.isfinite(r_all), r_all, 0.0), f0, 1.0 / (n * dt)), float(
        power[i]
    )


def _refined_over_blocks(t: np.ndarray, r: np.ndarray, f0: float, df_block: float) -> float:
    """Return the frequency of the largest line power of all the examined samples within a block's bin of f0.

    The leading block fixes the line to about a tenth of its bin (1 / its duration); over a scan examined
    in blocks spread across it, that error winds the line's phase by a good part of a cycle, and the screen,
    which holds the frequency at its start, then sees little of it (a vibration of z 14, 0.03 Hz off over
    26 s, screened at Delta BIC -12). The power of the residuals at the sample times (a direct transform;
    the blocks are not contiguous) is searched within +-1 bin of f0 on a grid of a quarter of the
    whole span's bin, and the peak refined by a parabola.
    """
    span = float(t[-1] - t[0])
    if span <= 0 or not np.isfinite(f0):
        return f0
    step = 0.25 / span
    grid = f0 + np.arange(-df_block, df_block + step, step)
    power = _line_power(t - t[0], r - r.mean(axis=0), grid[0], step, grid.size)
    k = int(np.argmax(power))
    if 0 < k < grid.size - 1:
        a, b, c = power[k - 1], power[k], power[k + 1]
        den = a - 2 * b + c
        return float(grid[k] + (0.5 * (a - c) / den if den != 0 else 0.0) * step)
    return float(grid[k])


def _line_power(t: np.ndarray, rc: np.ndarray, f_first: float, step: float, n: int) -> np.ndarray:
    """Return sum over channels of |sum_t rc(t) exp(-2 pi i f t)|^2 at f = f_first + k step, k < n.

    The phasors of one frequency are those of the previous one turned by exp(-2 pi i step t): a
    product per sample and frequency instead of a complex exponential and a (frequencies, samples)
    matrix (on 50 000 samples, 3 channels and 100 frequencies: 480 -> 16 ms, the same powers to 1.5e-14
    of the largest).
    """
    z = np.exp(-2j * np.pi * f_first * t)
    turn = np.exp(-2j * np.pi * step * t)
    power = np.empty(n)
    for k in range(n):
        power[k] = float(np.sum(np.abs(z @ rc) ** 2))
        z *= turn
    return power


def localise(model: "TriModel", r: np.ndarray, sigma: np.ndarray) -> dict:
    """Where the base residual sits: channels, part of the revolution, UPR spectrum, trends."""
    d = model.data
    out: dict[str, Any] = {"channels": {}, "revolution": {}, "spectrum_upr": []}
    phi = np.mod(d.direction * d.omega_rad_s * d.t_s, 2 * np.pi)
    for j, ch in enumerate(d.channels):
        ok = np.isfinite(r[:, j]) & model.mask[:, j]
        x = r[ok, j]
        rms = float(np.sqrt(np.mean(x**2))) if x.size else float("nan")
        tt = d.t_s[ok]
        vv = d.values_mm[ok, j]
        slope_t = float(np.polyfit(tt, x, 1)[0]) if x.size > 2 and np.ptp(tt) > 0 else 0.0
        slope_v = float(np.polyfit(vv, x, 1)[0]) if x.size > 2 and np.ptp(vv) > 0 else 0.0
        out["channels"][str(ch)] = {
            "rms_mm": rms,
            "mean_mm": float(np.mean(x)) if x.size else float("nan"),
            "noise_mm": float(sigma[j]),
            "excess": rms / max(float(sigma[j]), 1e-12),
            "trend_mm_per_s": slope_t,
            "trend_per_mm_reading": slope_v,
        }
    bins = np.linspace(0, 2 * np.pi, 13)
    ib = np.clip(np.digitize(phi, bins) - 1, 0, 11)
    rr = np.where(model.mask, r, np.nan)
    for b in range(12):
        seg = rr[ib == b]
        seg = seg[np.isfinite(seg)]
        out["revolution"][f"{int(round(np.degrees(bins[b])))}-{int(round(np.degrees(bins[b + 1])))}deg"] = (
            float(np.sqrt(np.mean(seg**2))) if seg.size else float("nan")
        )
    n = leading_block(d.t_s)
    if n >= 16:
        dt = float(np.median(np.diff(d.t_s[:n])))
        z = np.where(np.isfinite(rr[:n]), rr[:n], 0.0)
        z = z - z.mean(axis=0)
        nfft = 1 << int(math.ceil(math.log2(n * 4)))
        amp = 2.0 * np.abs(np.fft.rfft(z, nfft, axis=0)) / n
        upr = np.fft.rfftfreq(nfft, dt) / d.rev_hz
        tot = np.sqrt((amp**2).sum(axis=1))
        peaks = [i for i in range(1, tot.size - 1) if tot[i] >= tot[i - 1] and tot[i] > tot[i + 1]]
        peaks.sort(key=lambda i: -tot[i])
        for i in peaks[:5]:
            out["spectrum_upr"].append(
                {
                    "upr": float(upr[i]),
                    "amplitude_mm": {str(ch): float(amp[i, j]) for j, ch in enumerate(d.channels)},
                }
            )
    return out


def tilt_start(lobing_start: dict, data: "TriData") -> dict:
    """Start of an axis_tilt fit from a k = 2 lobing start.

    The ellipse is r ~ R + (R beta^2 / 4)(1 + cos 2(theta - azimuth)): beta^2 = 4 a / R.
    """
    A, B = lobing_start["bore_lobing[k=2].A"], lobing_start["bore_lobing[k=2].B"]
    st = {n: v for n, v in lobing_start.items() if not n.startswith("bore_lobing[k=2]")}
    m = 4.0 / data.radius_mm
    st.update({"axis_tilt.p": m * A, "axis_tilt.q": m * B})
    return st


def rotation_eps(model: "TriModel") -> float | None:
    """Return the relative speed error from the readings' rotation line, or None.

    Relative speed error from the strongest line of the readings within +-30 % of the nominal
    rotation frequency (the eccentricity undulates once per revolution); None without one.
    """
    d = model.data
    n = leading_block(d.t_s)
    if n < 32:
        return None
    dt = float(np.median(np.diff(d.t_s[:n])))
    v = np.where(model.valid[:n], d.values_mm[:n], np.nan)
    v = v - np.nanmean(v, axis=0)
    v = np.where(np.isfinite(v), v, 0.0)
    nfft = 1 << int(math.ceil(math.log2(n * 16)))
    power = (np.abs(np.fft.rfft(v, nfft, axis=0)) ** 2).sum(axis=1)
    f = np.fft.rfftfreq(nfft, dt)
    band = (f > 0.7 * d.rev_hz) & (f < 1.3 * d.rev_hz)
    if not band.any():
        return None
    i = int(np.argmax(np.where(band, power, -1.0)))
    if 0 < i < power.size - 1:
        a, b, c = power[i - 1], power[i], power[i + 1]
        den = a - 2 * b + c
        fi = f[i] + (0.5 * (a - c) / den if den != 0 else 0.0) * (f[1] - f[0])
    else:
        fi = f[i]
    return float(fi / d.rev_hz - 1.0)
