"""A rod's pose means and the sensors' data-sheet inputs (repeatability, linearity, resolution) of a budget.

Part of :mod:`borescan.measure` (package doc).
"""

from __future__ import annotations

import math
import numpy as np
from ..uncertainty import Budget, Input, Term

__all__ = [
    "pose_means",
    "reading_u_mm",
    "mean_reading_u_mm",
    "sensor_ranges_mm",
    "sensor_terms",
    "linearity_change_mm",
    "hold_readings",
    "linearity_terms",
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


def reading_u_mm(sensors: dict, channels, *, linearity: bool = True) -> np.ndarray:
    """Return standard uncertainty of one reading per channel from the sensors' data sheet [mm].

    u = hypot(linearity_fs * range_mm / sqrt(3), repeatability_mm): the stated linearity is a
    rectangular +-a (GUM 4.3.7), the repeatability a standard deviation. Missing values count 0.
    ``sensors`` maps channel -> the ``scan.json`` sensor entry. ``linearity=False``: the
    repeatability alone (a rod, whose budget carries the linearity as the systematic curve it is,
    :func:`linearity_change_mm`, instead of a scatter that averages out over readings).
    """

    def one(ch: int) -> float:
        s = sensors.get(ch, {})
        lin = (s.get("linearity_fs") or 0.0) * (s.get("range_mm") or 0.0) if linearity else 0.0
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


def _markov_mm(a_mm: float, range_mm: float, degree: int, k: int) -> float:
    """Return Markov's bound on the k-th derivative of a degree-n polynomial with |f| <= a on a range R.

    T_n^(k)(1) (2 / R)^k a, T_n^(k)(1) = prod_{j < k} (n^2 - j^2) / (2 j + 1); 0 for k > n.
    """
    if k > degree:
        return 0.0
    t = 1.0
    for j in range(k):
        t *= (degree**2 - j**2) / (2 * j + 1)
    return float(t * (2.0 / range_mm) ** k * a_mm)


def linearity_change_mm(a_mm: float, range_mm: float, cal: dict, here: dict, degree: int) -> float:
    """Bound on the change of a sensor's linearity deviation between two holds' readings [mm].

    A data sheet's linearity +-a is a bound on one systematic curve f(v) of the sensor over its
    range R, not a scatter: every hold of a rod reads the same curve. A calibration on gauges
    absorbs the hold's mean of f into l0, so a later hold's radius is off by the change of that
    mean, E_m f - E_c f. f is taken as a polynomial of degree n <= ``degree``
    (``uncertainty.linearity_curve_degree``: 3 covers a bow and an S-shape) bounded by a on the
    range: Markov's inequality bounds its derivatives, |f^(k)| <= S_k (:func:`_markov_mm`). For a
    hold whose pose means have mean v, variance s2 and third central moment m3 (``cal``, ``here``:
    :func:`hold_readings` of one layer), E f = f(v) + f2(v) s2 / 2 + f3 m3 / 6 exactly for n <= 3
    (f2, f3 the second and third derivatives), so

        |E_m f - E_c f| <= S1 |dv| + S2 |s2_m - s2_c| / 2 + S3 (|dv| max(s2) / 2 + |m3_m - m3_c| / 6),

    dv = v_m - v_c; for n > 3 the remainder form S1 |dv| + S2 (s2_m + s2_c) / 2. Never more than 2 a.
    Returns the half-width of the rectangular distribution (u = bound / sqrt 3, GUM 4.3.7).
    """
    if a_mm <= 0 or range_mm <= 0:
        return 0.0
    s1, s2, s3 = (_markov_mm(a_mm, range_mm, degree, k) for k in (1, 2, 3))
    dv = abs(here["mean_mm"] - cal["mean_mm"])
    if degree <= 3:
        b = (
            s1 * dv
            + 0.5 * s2 * abs(here["var_mm2"] - cal["var_mm2"])
            + s3
            * (0.5 * dv * max(here["var_mm2"], cal["var_mm2"]) + abs(here["m3_mm3"] - cal["m3_mm3"]) / 6.0)
        )
    else:
        b = s1 * dv + 0.5 * s2 * (here["var_mm2"] + cal["var_mm2"])
    return float(min(2.0 * a_mm, b))


def hold_readings(means_mm) -> dict[str, list[float]]:
    """Return where a hold reads in each sensor's range: the pose means' mean and variance per layer.

    ``means_mm`` (n, m) pose means. {"mean_mm", "var_mm2", "m3_mm3"}: each (m,), the mean,
    variance and third central moment over the poses; what
    :func:`borescan.measure.linearity_change_mm` compares between a calibration and a later hold.
    """
    v = np.asarray(means_mm, dtype=float)
    c = v - np.nanmean(v, axis=0)
    return {
        "mean_mm": [float(x) for x in np.nanmean(v, axis=0)],
        "var_mm2": [float(x) for x in np.nanmean(c**2, axis=0)],
        "m3_mm3": [float(x) for x in np.nanmean(c**3, axis=0)],
    }


def linearity_terms(
    sensors: dict,
    channel: int,
    j: int,
    here: dict,
    cal_budget: Budget | None,
    cal_hold: dict | None,
    cal_channels: list[int],
    scan_id: str,
    degree: int,
) -> list[tuple[Input, float]]:
    """Return the linearity inputs of one rod diameter, as (input, dD_T / d input) for ``extra_terms``.

    The sensor's data-sheet curve f (+-a = linearity_fs x range) is the same in every hold. The
    calibration's l0 took up its mean over the calibration hold (the input
    ``linearity:rodcal:<scan>:ch<c>`` of :func:`borescan.rod_calibration.rod_calibration_budget`,
    sensitivity -2 on D through l0); this hold reads the same
    curve, so that input enters again with +2 and cancels, and what is left is the curve's change
    between the two holds' readings (``here`` and ``cal_hold``: :func:`hold_readings`), rectangular
    within :func:`borescan.measure.linearity_change_mm`. Without a calibration (design geometry),
    or one that did not record its hold, the whole curve: +-a, sensitivity 2.
    """
    s = sensors.get(int(channel), {}) or {}
    range_mm = float(s.get("range_mm") or 0.0)
    a = float(s.get("linearity_fs") or 0.0) * range_mm
    label = f"{s.get('model', 'sensor')} {s.get('serial', '')}".strip()
    src = f"data sheet of {label}: +-{s.get('linearity_fs')} x {range_mm:g} mm full scale (scan.json sensors)"
    cal_key = None
    if cal_budget is not None and cal_hold is not None:
        cal_key = next(
            (
                t.input
                for t in cal_budget.terms
                if t.input.key.startswith("linearity:") and t.input.key.endswith(f":ch{int(channel)}")
            ),
            None,
        )
    if cal_key is None:
        return [
            (
                Input(
                    f"linearity:{scan_id}:ch{int(channel)}",
                    f"linearity deviation, channel {int(channel)} (measurement; nothing absorbed it)",
                    f"e_lin,{int(channel)}",
                    "mm",
                    0.0,
                    a / np.sqrt(3.0),
                    "rectangular",
                    source=src,
                ),
                2.0,
            )
        ]
    k = cal_channels.index(int(channel))
    at_cal = {q: v[k] for q, v in cal_hold.items()}
    at_here = {q: v[j] for q, v in here.items()}
    dv = at_here["mean_mm"] - at_cal["mean_mm"]
    half = linearity_change_mm(a, range_mm, at_cal, at_here, degree)
    return [
        (cal_key, 2.0),
        (
            Input(
                f"linearity:{scan_id}:ch{int(channel)}",
                f"linearity curve's change from the calibration's readings, channel {int(channel)}",
                f"Delta e_lin,{int(channel)}",
                "mm",
                0.0,
                half / np.sqrt(3.0),
                "rectangular",
                source=f"{src}; curve of degree <= {degree}, mean reading {dv * 1e3:+.1f} um from the "
                f"calibration's (borescan.measure.linearity_change_mm)",
            ),
            2.0,
        ),
    ]
