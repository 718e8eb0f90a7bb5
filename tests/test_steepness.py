"""Tests of synthpack.measure.steepness: the upper tail of the neighbour steps, read without labels."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import ndimage, special

from synthpack.measure.steepness import (MIN_STEEPNESS_PAIRS, STEEPNESS_PROBABILITIES, edge_steepness,
                                         neighbour_steps, steepness_distance)


def _blurred_balls(sigma: float) -> np.ndarray:
    """Balls of level 1 in 0 on a 40x96x96 grid, blurred by a Gaussian of `sigma` voxels."""
    z, y, x = np.mgrid[:40, :96, :96]
    balls = np.zeros((40, 96, 96))
    for cz, cy, cx in [(20, 24, 24), (20, 24, 72), (20, 72, 24), (20, 72, 72)]:
        balls[(z - cz) ** 2 + (y - cy) ** 2 + (x - cx) ** 2 <= 15**2] = 1.0
    return ndimage.gaussian_filter(balls, sigma)


def test_neighbour_steps_are_the_in_slice_differences_inside_the_region():
    volume = np.zeros((2, 3, 3))
    volume[:, :, 2] = 5.0  # a step between x = 1 and x = 2
    volume[1] += 100.0  # slices differ: no step across slices is counted
    region = np.ones(volume.shape, bool)
    steps = neighbour_steps(volume, region)
    assert steps.size == 2 * (3 * 2 + 2 * 3) and sorted(set(steps.tolist())) == [0.0, 5.0]
    region[:, :, 2] = False
    assert np.all(neighbour_steps(volume, region) == 0.0)


def test_the_steepest_step_of_a_blurred_edge_is_that_of_a_gaussian_step():
    sigma = 1.0
    tail = edge_steepness(_blurred_balls(sigma), np.ones((40, 96, 96), bool))
    assert tail.shape == STEEPNESS_PROBABILITIES.shape and np.all(np.diff(tail) >= 0)
    # the largest neighbour step across a unit step blurred by sigma: Phi(1/2 sigma) - Phi(-1/2 sigma)
    steepest = special.ndtr(0.5 / sigma) - special.ndtr(-0.5 / sigma)
    assert tail[-1] == pytest.approx(steepest, rel=0.05)


def test_a_softer_edge_is_less_steep_and_the_distance_grows_with_the_difference():
    region = np.ones((40, 96, 96), bool)
    tails = [edge_steepness(_blurred_balls(sigma), region) for sigma in (0.8, 1.0, 1.4)]
    assert np.all(tails[0][-10:] > tails[1][-10:]) and np.all(tails[1][-10:] > tails[2][-10:])
    assert steepness_distance(tails[1], tails[1], 1.0) == 0.0
    assert 0 < steepness_distance(tails[0], tails[1], 1.0) < steepness_distance(tails[0], tails[2], 1.0)
    assert steepness_distance(tails[0], tails[2], -2.0) == pytest.approx(steepness_distance(tails[0], tails[2], 1.0) / 2)


def test_too_few_pairs_give_no_steepness():
    volume = _blurred_balls(1.0)
    region = np.zeros(volume.shape, bool)
    region[20, :50, :50] = True  # 4,900 pairs
    assert 2 * 50 * 49 < MIN_STEEPNESS_PAIRS and edge_steepness(volume, region) is None
