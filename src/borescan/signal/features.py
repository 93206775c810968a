"""Yang 2017 §2.3 n/m counts, statuses, feature points and theta_t.

Yang 2017 §2.3 n/m counts and advanced/backward status, feature points, their spacings and
theta_t (Eq. 15).
"""

from __future__ import annotations

import math

import numpy as np
import polars as pl


def n_m_counts(min_pos: np.ndarray, max_pos: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Return Yang's §2.3 n/m counts.

    Yang §2.3 counts: n_i = samples from each minimum to the next maximum, m_i = from each
    maximum to the next minimum (positions in samples, any order).
    """
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


def feature_spacings(
    min_pos: dict[int, np.ndarray], samples_per_rev: float, u_samples_per_rev: float = 0.0
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
        rows.append(
            {
                "from_channel": a,
                "to_channel": b,
                "spacing_samples": mean,
                "u_spacing_samples": u,
                "count": int(d.size),
                "theta_t_rad": th,
                "u_theta_t_rad": u_th,
            }
        )
    schema = {
        "from_channel": pl.Int64,
        "to_channel": pl.Int64,
        "spacing_samples": pl.Float64,
        "u_spacing_samples": pl.Float64,
        "count": pl.Int64,
        "theta_t_rad": pl.Float64,
        "u_theta_t_rad": pl.Float64,
    }
    return pl.DataFrame(rows, schema=schema)


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
        rows.append(
            {
                "channel": int(ch),
                "feature_sample": float(np.mod(mean_ang, 2 * np.pi) * samples_per_rev / (2 * np.pi)),
                "u_feature_sample": u * samples_per_rev / (2 * np.pi),
                "n_revolutions": int(dev.size),
            }
        )
    return pl.DataFrame(
        rows,
        schema={
            "channel": pl.Int64,
            "feature_sample": pl.Float64,
            "u_feature_sample": pl.Float64,
            "n_revolutions": pl.Int64,
        },
    )
