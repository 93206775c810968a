"""Censoring at the sensor range: readings whose fitted value lies near a range limit are set aside.

The sensor nulls a reading whose *noisy* value leaves [0, range], so a valid reading whose true value
lies within a few sigma of a range limit is a censored draw: its noise is biased away from the limit
(E[e | kept] = sigma phi(a) / Phi(a), a = distance / sigma), which biases every beam parameter the
flank near the limit informs. Readings whose fitted value lies within :data:`CENSOR_GUARD_SIGMA` of a
limit (or beyond it) are set aside: a selection on the model, not on the noise, so the rest is an
unbiased sample (:func:`censoring_keep`); the full-data fit is then redone on the rest
(:func:`censored_problem`).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from borescan.calibrate.problem import FullProblem
from borescan.calibrate.residuals import model_readings

__all__ = ["CENSOR_GUARD_SIGMA", "guard_sigma", "censoring_keep", "censored_problem"]

#: readings whose fitted value lies within this many noise sigmas of a sensor range limit are set aside
#: (censoring at the range limits, :func:`censoring_keep`); beyond 4 sigma the bias sigma phi(4) / Phi(4)
#: is 1.3e-4 sigma
CENSOR_GUARD_SIGMA = 4.0


def guard_sigma(floors_k: np.ndarray, sigma: float) -> np.ndarray:
    """Noise sigma per channel for the censoring guard: the channel's own floor, else the pooled one."""
    f = np.asarray(floors_k, dtype=float)
    return np.where(np.isfinite(f) & (f > 0), f, sigma)


def censoring_keep(v_model: np.ndarray, y: np.ndarray, range_mm: np.ndarray, sigma_c: np.ndarray):
    """Return the mask of readings not censored by a sensor range limit.

    Return readings (n, c) not censored by a sensor range limit: True where the model value ``v_model``
    lies more than ``CENSOR_GUARD_SIGMA`` sigma inside [0, range].

    The raw format nulls a reading when the sensor reports no valid value (out of range), which
    the sensor decides on the noisy value; so near a limit the valid readings are a truncated
    sample (biased by up to ~0.8 sigma) and beyond it a few noisy ones stay valid. The selection
    here is on the model, which the noise does not move (to within the fit's own small
    uncertainty), so the kept readings are unbiased. A limit is taken as a censoring limit only
    where no valid reading of the channel lies beyond it (a sensor reporting negative values or
    values above its stated range is not censored there).

    Returns (keep (n, c) bool, limits {"lower": [bool] * c, "upper": [bool] * c}).
    """
    v = np.asarray(v_model, dtype=float)
    yy = np.asarray(y, dtype=float)
    c = v.shape[1]
    rng = np.broadcast_to(np.asarray(range_mm, dtype=float), (c,))
    g = CENSOR_GUARD_SIGMA * np.broadcast_to(np.asarray(sigma_c, dtype=float), (c,))
    keep = np.ones(v.shape, dtype=bool)
    lower, upper = [], []
    with np.errstate(invalid="ignore"):
        for j in range(c):
            ok = np.isfinite(yy[:, j])
            lo = not bool(np.any(yy[ok, j] < 0.0))
            hi = not bool(np.any(yy[ok, j] > rng[j]))
            if lo:
                keep[:, j] &= v[:, j] > g[j]
            if hi:
                keep[:, j] &= v[:, j] < rng[j] - g[j]
            lower.append(lo)
            upper.append(hi)
    return keep, {"lower": lower, "upper": upper}


def censored_problem(pb: FullProblem, x: np.ndarray) -> tuple[FullProblem, dict[str, list[int]]]:
    """Return the problem without the readings censoring sets aside at the solution ``x``.

    Also returns, per scan, how many readings of each channel were set aside.
    """
    beams, nuis = pb.unpack(x)
    masks, censored = [], {}
    for k, nu in enumerate(nuis):
        v_k = model_readings(pb, beams, k, nu)
        keep, _ = censoring_keep(v_k, pb.ys[k], pb.range_mm, guard_sigma(pb.floors[k], pb.sigma))
        censored[pb.scan_ids[k]] = [int(x) for x in (pb.masks[k] & ~keep).sum(axis=0)]
        masks.append(pb.masks[k] & keep)
    return replace(pb, masks=tuple(masks)), censored
