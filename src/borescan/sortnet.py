"""Medians of many small groups at once, by comparator (selection) networks.

The spike test of :mod:`borescan.signal` needs the median of its 6 residuals at some 30 000
places per scan. ``np.partition`` with the two middle ranks along a short axis pays a per-row cost;
a comparator network applies the same few ``np.minimum`` / ``np.maximum`` operations to whole
columns instead (one array per group member, one element per place): ~7x faster for 6 values,
and exact, since a comparator network only moves values, so what it returns is bit-identical to a
sort. For the odd median of the 15 pair slopes ``np.partition`` with one rank stays faster (the
network needs 84 operations there), so the signal stage uses it.

Networks: Batcher's odd-even merge sort for any size, pruned backwards to the comparators (and
the halves of comparators) that reach the wanted ranks. Correctness for every input follows from
the 0-1 principle (a comparator network that selects rank k of every 0/1 input selects rank k
of every input), which the tests check exhaustively.
"""

from __future__ import annotations

import functools

import numpy as np

__all__ = ["batcher_pairs", "selection_ops", "select_ranks", "median_columns"]


def batcher_pairs(n: int) -> tuple[tuple[int, int], ...]:
    """Return comparators (i, j), i < j, of Batcher's odd-even merge sort of ``n`` elements, in order.

    After all comparators (each puts the smaller value at i, the larger at j) the values are
    sorted ascending.
    """
    pairs = []
    p = 1
    while p < n:
        k = p
        while k >= 1:
            for j in range(k % p, n - k, 2 * k):
                for i in range(min(k, n - j - k)):
                    if (i + j) // (2 * p) == (i + j + k) // (2 * p):
                        pairs.append((i + j, i + j + k))
            k //= 2
        p *= 2
    return tuple(pairs)


@functools.lru_cache(maxsize=32)
def selection_ops(n: int, ranks: tuple[int, ...]) -> tuple[tuple[int, int, bool, bool], ...]:
    """Batcher's network for ``n`` elements pruned to what reaches positions ``ranks``.

    Each op is (i, j, keep_min, keep_max): write min(v_i, v_j) to i if ``keep_min``, and
    max(v_i, v_j) to j if ``keep_max``. After the ops, position r holds the value of rank r
    (0-based, ascending) for every r in ``ranks``.
    """
    if any(not 0 <= r < n for r in ranks):
        raise ValueError(f"ranks {ranks} out of range for {n} elements")
    need = set(ranks)
    ops = []
    for i, j in reversed(batcher_pairs(n)):
        keep_min, keep_max = i in need, j in need
        if keep_min or keep_max:
            ops.append((i, j, keep_min, keep_max))
            need |= {i, j}
    return tuple(reversed(ops))


def select_ranks(cols: list[np.ndarray], ranks: tuple[int, ...]) -> list[np.ndarray]:
    """Return element-wise order statistics of k arrays.

    Element-wise order statistics of k equally shaped NaN-free arrays: one array per rank in
    ``ranks`` (0-based, ascending), by the pruned network; the inputs are not modified (a rank
    no comparator touches comes back as the input array itself).
    """
    v = list(cols)
    for i, j, keep_min, keep_max in selection_ops(len(v), tuple(ranks)):
        a, b = v[i], v[j]
        if keep_min:
            v[i] = np.minimum(a, b)
        if keep_max:
            v[j] = np.maximum(a, b)
    return [v[r] for r in ranks]


def median_columns(cols: list[np.ndarray]) -> np.ndarray:
    """Return the element-wise median of k arrays.

    Element-wise median of k equally shaped NaN-free arrays (mean of the two middle ranks for
    even k), by a selection network; the inputs are not modified.
    """
    k = len(cols)
    if k == 0:
        raise ValueError("median of no values")
    if k % 2:
        (mid,) = select_ranks(cols, (k // 2,))
        return np.array(mid, copy=True) if mid is cols[k // 2] else mid
    lo, hi = select_ranks(cols, (k // 2 - 1, k // 2))
    return 0.5 * (lo + hi)
