"""Selection networks against sorting: exhaustively by the 0-1 principle, then on random reals."""

import itertools

import numpy as np
import pytest

from borescan.sortnet import batcher_pairs, median_columns, select_ranks, selection_ops


@pytest.mark.parametrize("n", range(1, 17))
def test_batcher_network_sorts_every_binary_input(n):
    """0-1 principle: a comparator network that sorts all 2^n binary inputs sorts every input."""
    v = np.array(list(itertools.product((0, 1), repeat=n)), dtype=np.int8).T.copy()  # (n, 2^n)
    for i, j in batcher_pairs(n):
        lo, hi = np.minimum(v[i], v[j]), np.maximum(v[i], v[j])
        v[i], v[j] = lo, hi
    assert (np.diff(v, axis=0) >= 0).all()


@pytest.mark.parametrize("n", [2, 3, 6, 7, 10, 15, 16])
def test_pruned_network_selects_the_wanted_ranks_of_every_binary_input(n):
    ranks = (n // 2,) if n % 2 else (n // 2 - 1, n // 2)
    v = list(np.array(list(itertools.product((0, 1), repeat=n)), dtype=np.int8).T)
    expect = np.sort(np.array(v), axis=0)
    for r, got in zip(ranks, select_ranks(v, ranks)):
        np.testing.assert_array_equal(got, expect[r])
    # pruning really prunes (from 3 elements on): fewer min/max operations than the full network
    n_ops = sum(km + kx for _, _, km, kx in selection_ops(n, ranks))
    assert n_ops < 2 * len(batcher_pairs(n)) if n > 2 else n_ops == 2


@pytest.mark.parametrize("k", [1, 2, 5, 6, 15])
def test_median_columns_equals_numpy_median_bit_for_bit(k):
    rng = np.random.default_rng(k)
    cols = [rng.normal(size=1000) for _ in range(k)]
    cols[0][:10] = cols[-1][:10]  # ties
    before = [c.copy() for c in cols]
    got = median_columns(cols)
    np.testing.assert_array_equal(got, np.median(np.stack(cols), axis=0))
    for a, b in zip(cols, before):  # inputs untouched
        np.testing.assert_array_equal(a, b)


def test_selection_ops_rejects_ranks_out_of_range():
    with pytest.raises(ValueError, match="out of range"):
        selection_ops(6, (6,))
