"""Array helpers shared by the signal modules.

Array helpers shared by the signal modules: (n,) or (n, c) readings, NaN = missing; the NaN-aware
median of rows that the running median and the spike reference both use.
"""

from __future__ import annotations

import numpy as np


def _as_2d(values_mm: np.ndarray) -> tuple[np.ndarray, bool]:
    v = np.asarray(values_mm, dtype=float)
    if v.ndim == 1:
        return v[:, None], True
    if v.ndim != 2:
        raise ValueError(f"readings must have shape (n,) or (n, c), got {v.shape}")
    return v, False


def _back(v: np.ndarray, was_1d: bool) -> np.ndarray:
    return v[:, 0] if was_1d else v


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
