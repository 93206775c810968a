"""The one robust noise scale (:mod:`borescan.noise`) against its definition and known distributions."""

from __future__ import annotations

import math

import numpy as np
import pytest

from borescan.noise import MAD_TO_SD, mad_sigma, median, noise_floor_mm, robust_sigma


@pytest.mark.parametrize("n", [1, 2, 7, 8, 1001])
def test_median_by_partition_is_numpys(n):
    x = np.random.default_rng(n).normal(size=n)
    assert median(x) == float(np.median(x))


def test_mad_sigma_is_the_scaled_median_absolute_deviation():
    x = np.random.default_rng(1).normal(3.0, 0.5, 20_001)
    assert mad_sigma(x) == MAD_TO_SD * float(np.median(np.abs(x - np.median(x))))
    assert mad_sigma(x, center=3.0) == MAD_TO_SD * float(np.median(np.abs(x - 3.0)))
    # a normal sample's scale: relative standard error of the MAD ~ 1.17 / sqrt(n) = 0.8 %
    assert mad_sigma(x) == pytest.approx(0.5, rel=4 * 1.17 / math.sqrt(x.size))
    assert MAD_TO_SD == pytest.approx(1.0 / 0.6744897501960817, abs=5e-5)


def test_robust_sigma_ignores_nan_and_needs_three_values():
    assert robust_sigma(np.array([1.0, np.nan, 2.0])) == 0.0
    x = np.array([1.0, np.nan, 2.0, 4.0, 7.0])
    assert robust_sigma(x) == mad_sigma(x[np.isfinite(x)])


def test_noise_floor_keeps_only_the_differences_asked_for():
    """Within-pose differences of white noise on pose levels 1 mm apart: the jumps between poses are
    not noise; the floor is the noise's sigma (first differences, sqrt 2).
    """
    rng = np.random.default_rng(2)
    pose = np.repeat(np.arange(50), 40)
    v = pose[:, None] * 1.0 + rng.normal(0.0, 0.003, (pose.size, 2))
    keep = pose[1:] == pose[:-1]
    floor = noise_floor_mm(v, order=1, keep=keep)
    # relative standard error of the MAD scale of 1950 differences ~ 1.17 / sqrt(1950) = 2.6 %
    assert floor == pytest.approx([0.003, 0.003], rel=0.11)
    assert np.all(noise_floor_mm(v, order=1) > floor)  # the jumps, few as they are, raise it when kept
