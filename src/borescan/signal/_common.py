"""Array helpers shared by the signal modules: (n,) or (n, c) readings, NaN = missing."""

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
