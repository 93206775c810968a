"""The readings a stage fits: one scan's reading matrix, cleaned once by the configured policy.

Every stage that fits readings (the signal stage's extrema, the full-data calibration, the
rotating and static measurement of a three-sensor scan, the rod's pose means of its calibration
and its measurement) takes them from :func:`prepared_matrix`, so a spike is set aside by the
same rule wherever it is met: the config's ``signal.spike_threshold_mad`` and
``signal.spike_window_samples`` (:func:`cleaning_policy`).

- **Spindle scans** (readings along a revolution): the Hampel test against a robust
  local-linear reference of the neighbours (:func:`borescan.signal.remove_spikes`).
- **Static scans** (three-sensor poses without a spindle, rod poses): within a pose the readings
  are one value plus noise; a reading is a spike when it lies further than the threshold's
  robust standard deviations from the median of the *other* readings of its pose, the scale
  being 1.4826 MAD of those leave-one-out residuals pooled over the channel's poses
  (:func:`static_spikes`). A pose with fewer than three readings of a channel is not tested.

Nulls stay NaN and are never bridged. The discrepancy workflow is the one consumer of raw
readings: ``outliers`` is an effect of its vocabulary, which it estimates from the spikes
themselves (``../shared/spec/geometry-and-effects.md``).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from borescan import rawio
from borescan.config import schema_defaults
from borescan.noise import mad_sigma
from borescan.signal import remove_spikes

__all__ = ["CleaningPolicy", "cleaning_policy", "static_spikes", "clean_matrix", "prepared_matrix"]

#: fewest readings of a channel in a pose for its readings to be tested
MIN_POSE_READINGS = 3


@dataclass(frozen=True)
class CleaningPolicy:
    """How spikes are set aside (config section ``signal``).

    spike_threshold_mad : a reading this many robust standard deviations from its reference is a spike [-]
    spike_window_samples : neighbours of a spindle reading's local-linear reference (odd) [samples]
    """

    spike_threshold_mad: float
    spike_window_samples: int


def cleaning_policy(signal_cfg: dict) -> CleaningPolicy:
    """Return the policy of the config's ``signal`` section (schema defaults filled by the caller)."""
    return CleaningPolicy(float(signal_cfg["spike_threshold_mad"]), int(signal_cfg["spike_window_samples"]))


def static_spikes(values_mm: np.ndarray, pose: np.ndarray, threshold_mad: float) -> np.ndarray:
    """Spikes of static readings (see the module docstring): bool (n, c), True where set aside.

    ``values_mm`` (n, c) readings with NaN for null [mm]; ``pose`` (n,) the pose of each sample
    (all one pose for a static three-sensor scan without the column; negative: no pose, untested).
    """
    v = np.asarray(values_mm, dtype=float)
    pose = np.asarray(pose)
    resid = np.full(v.shape, np.nan)
    for p in np.unique(pose[pose >= 0]):
        rows = np.flatnonzero(pose == p)
        for j in range(v.shape[1]):
            ok = rows[np.isfinite(v[rows, j])]
            if ok.size >= MIN_POSE_READINGS:
                resid[ok, j] = v[ok, j] - _median_of_others(v[ok, j])
    spikes = np.zeros(v.shape, dtype=bool)
    for j in range(v.shape[1]):
        r = resid[:, j]
        tested = np.isfinite(r)
        if not tested.any():
            continue
        scale = mad_sigma(r[tested], center=0.0)
        if scale > 0:
            spikes[tested, j] = np.abs(r[tested]) > threshold_mad * scale
    return spikes


def _median_of_others(x: np.ndarray) -> np.ndarray:
    """For each element of ``x`` (n >= 2), the median of the other n - 1 elements."""
    order = np.argsort(x, kind="stable")
    s = x[order]
    n = s.size
    rank = np.empty(n, dtype=np.int64)
    rank[order] = np.arange(n)

    def other(k: int) -> np.ndarray:  # k-th smallest of the others of each element
        return np.where(k < rank, s[k], s[np.minimum(k + 1, n - 1)])

    m = n - 1
    return other(m // 2) if m % 2 else 0.5 * (other(m // 2 - 1) + other(m // 2))


def clean_matrix(
    mat: rawio.LdsMatrix, policy: CleaningPolicy, *, spindle: bool
) -> tuple[rawio.LdsMatrix, np.ndarray]:
    """``mat`` with its spikes set to NaN, and the spike mask (n, c).

    ``spindle``: readings along revolutions (Hampel test); otherwise static poses (``mat.pose``;
    all samples one pose where it is null).
    """
    v = np.asarray(mat.values_mm, dtype=float)
    if spindle:
        clean, spikes = remove_spikes(
            v, window_samples=policy.spike_window_samples, threshold=policy.spike_threshold_mad
        )
    else:
        pose = np.asarray(mat.pose)
        spikes = static_spikes(
            v, np.zeros_like(pose) if np.all(pose < 0) else pose, policy.spike_threshold_mad
        )
        clean = np.where(spikes, np.nan, v)
    return replace(mat, values_mm=clean), spikes


def prepared_matrix(scan: rawio.RawScan, policy: CleaningPolicy | None = None) -> rawio.LdsMatrix:
    """Return the reading matrix of ``scan`` cleaned by ``policy``.

    Return the reading matrix of ``scan`` (:func:`borescan.rawio.lds_matrix`) cleaned by ``policy``
    (the schema's defaults when None): a scan with a spindle stream by the spindle rule, any
    other by the static rule.
    """
    spindle = scan.spindle is not None and scan.spindle.height > 1
    policy = policy or cleaning_policy(schema_defaults()["signal"])
    return clean_matrix(rawio.lds_matrix(scan), policy, spindle=spindle)[0]
