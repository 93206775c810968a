"""A rod's pose means and the sensors' data-sheet inputs (repeatability, linearity, resolution) of a budget.

Part of :mod:`borescan.measure` (package doc).
"""

from __future__ import annotations

import math
import numpy as np
from ..uncertainty import Input, Term

__all__ = [
    "pose_means",
    "reading_u_mm",
    "mean_reading_u_mm",
    "sensor_ranges_mm",
    "sensor_terms",
]


# --------------------------------------------------------------------------- readings per pose (rod)


def pose_means(values_mm, pose) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Mean reading per pose and channel, and how many readings each mean has.

    Parameters
    ----------
    values_mm : (n, c) readings, NaN where null [mm].
    pose : (n,) pose number of each sample (-1 or below: no pose, left out).

    Returns
    -------
    poses (k,), means (k, c) [mm] (NaN where a pose has no reading of a channel), counts (k, c).
    """
    v = np.asarray(values_mm, dtype=float)
    pose = np.asarray(pose)
    poses = np.unique(pose[pose >= 0])
    means = np.vstack([np.nanmean(v[pose == p], axis=0) for p in poses])
    counts = np.vstack([np.sum(np.isfinite(v[pose == p]), axis=0) for p in poses])
    return poses, means, counts


def reading_u_mm(sensors: dict, channels) -> np.ndarray:
    """Return standard uncertainty of one reading per channel from the sensors' data sheet [mm].

    u = hypot(linearity_fs * range_mm / sqrt(3), repeatability_mm): the stated linearity is a
    rectangular +-a (GUM 4.3.7), the repeatability a standard deviation. Missing values count 0.
    ``sensors`` maps channel -> the ``scan.json`` sensor entry.
    """

    def one(ch: int) -> float:
        s = sensors.get(ch, {})
        lin = (s.get("linearity_fs") or 0.0) * (s.get("range_mm") or 0.0)
        return float(np.hypot(lin / np.sqrt(3), s.get("repeatability_mm") or 0.0))

    return np.array([one(int(ch)) for ch in channels])


def mean_reading_u_mm(u_one_mm, counts) -> float | None:
    """One standard uncertainty for every mean of :func:`pose_means`: the largest u / sqrt(n) [mm].

    ``u_one_mm`` (c,) from :func:`reading_u_mm`; ``counts`` (k, c). n is each channel's fewest
    readings in a pose (at least 1). None when no sensor states an uncertainty.
    """
    u = np.asarray(u_one_mm, dtype=float)
    if not np.any(u > 0):
        return None
    return float(np.max(u / np.sqrt(np.maximum(np.asarray(counts).min(axis=0), 1))))


# --------------------------------------------------------------------------- GUM budget of a diameter


def sensor_ranges_mm(sensors: dict, channels) -> list[float]:
    """Return each channel's measuring range [mm] from scan.json.

    Each channel's measuring range [mm] from scan.json ``sensors`` (channel -> entry); 10 mm where
    a sensor does not state one.
    """
    return [float((sensors.get(int(ch)) or {}).get("range_mm") or 10.0) for ch in channels]


def sensor_terms(
    sensors: dict,
    channels,
    sensitivity: np.ndarray,
    key: str,
    noise_mm,
    default_resolution_mm: float,
    what: str,
) -> list[Term]:
    """Linearity and resolution terms of the sensors of one set of readings (Type B, rectangular).

    Parameters
    ----------
    sensors : channel -> scan.json sensor entry (``linearity_fs``, ``range_mm``, optional ``resolution_mm``)
    channels : channel numbers, in the order of ``sensitivity``'s columns
    sensitivity : (m, c) d outputs / d (a constant error of every reading of channel c)
    key : identity of this set of readings (a scan or calibration id): an error here is
        independent of the same sensor's error elsewhere in its range
    noise_mm : (c,) the readings' own scatter (dithering check), or None
    default_resolution_mm : ``uncertainty.sensor_resolution_mm``
    what : text naming the readings (``"calibration"``, ``"measurement"``)

    Notes
    -----
    Linearity: the data sheet's +-linearity_fs x range_mm, u = a / sqrt 3 (GUM 4.3.7). Resolution
    delta: u = delta / sqrt 12, counted only where the readings' noise is below delta / 2; with more
    noise the quantisation error is dithered, varies from reading to reading and is part of the
    Type A scatter (GUM F.2.2.1), so its term has sensitivity 0 and says so.
    """
    sens = np.atleast_2d(np.asarray(sensitivity, dtype=float))
    noise = None if noise_mm is None else np.broadcast_to(np.asarray(noise_mm, float), (len(channels),))
    terms = []
    for j, ch in enumerate(channels):
        s = sensors.get(int(ch), {}) or {}
        rng_mm = float(s.get("range_mm") or 0.0)
        lin = float(s.get("linearity_fs") or 0.0) * rng_mm
        label = f"{s.get('model', 'sensor')} {s.get('serial', '')}".strip()
        terms.append(
            Term(
                Input(
                    f"linearity:{key}:ch{int(ch)}",
                    f"linearity deviation, channel {int(ch)} ({what})",
                    f"e_lin,{int(ch)}",
                    "mm",
                    0.0,
                    lin / math.sqrt(3.0),
                    "rectangular",
                    source=f"data sheet of {label}: +-{s.get('linearity_fs')} x "
                    f"{rng_mm:g} mm full scale (scan.json sensors)",
                ),
                sens[:, j],
            )
        )
        res = s.get("resolution_mm")
        src = "scan.json sensors resolution_mm" if res is not None else "uncertainty.sensor_resolution_mm"
        delta = float(res if res is not None else default_resolution_mm)
        dithered = noise is not None and np.isfinite(noise[j]) and noise[j] >= 0.5 * delta
        terms.append(
            Term(
                Input(
                    f"resolution:{key}:ch{int(ch)}",
                    f"resolution, channel {int(ch)} ({what})",
                    f"e_res,{int(ch)}",
                    "mm",
                    0.0,
                    delta / math.sqrt(12.0),
                    "rectangular",
                    source=f"{delta:g} mm ({src})",
                ),
                np.zeros(sens.shape[0]) if dithered else sens[:, j],
                note=(
                    f"dithered by the readings' noise ({noise[j] * 1e3:.2f} um >= half the resolution): "
                    "part of the Type A scatter (GUM F.2.2.1)"
                )
                if dithered
                else "",
            )
        )
    return terms
