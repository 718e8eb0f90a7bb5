"""The library's draw weights undo the field of view's bias against large grains (synthpack.library.sampling)."""

import numpy as np
import pytest

from synthpack.library.core import ParticleLibrary
from synthpack.library.sampling import cut_axes, window_weights
from synthpack.physics.container import Tube
from synthpack.physics.plan import make_plan


def _crop_population(rng: np.random.Generator, window: int, sizes: tuple[int, ...], n: int):
    """Grains of `sizes` (cube sides) at uniform positions in a long slab; those whole in the window's crop."""
    side = rng.choice(sizes, n)
    start = rng.integers(-40, window + 40, (n, 3))
    stop = start + side[:, None]
    whole = ((start >= 1) & (stop <= window - 1)).all(axis=1)  # not touching a face of the crop
    return side, np.concatenate([start, stop], axis=1)[whole], side[whole]


def test_weights_give_the_whole_population_its_sizes():
    rng = np.random.default_rng(0)
    side, boxes, kept = _crop_population(rng, 60, (4, 24), 200_000)
    population = (side == 24).mean()
    unweighted = (kept == 24).mean()
    weights = window_weights(boxes, (60, 60, 60), (True, True, True))
    weighted = weights[kept == 24].sum()
    assert unweighted < 0.5 * population  # the crop keeps large grains far less often
    assert weighted == pytest.approx(population, abs=0.01)


def test_axes_that_cut_no_grain_weigh_evenly_and_a_gap_weighs_by_what_it_leaves():
    boxes = [(5, 5, 5, 15, 15, 15), (5, 5, 5, 45, 45, 45)]
    np.testing.assert_allclose(window_weights(boxes, (100, 100, 100), (False, False, False)), [0.5, 0.5])
    # a 20-slice gap along z: a 10-slice grain fits 62 of its 91 positions, a 40-slice one 2 of 61
    gap = window_weights(boxes, (100, 100, 100), (False, False, False), gap=(40, 60), gap_axis=0)
    assert gap[1] / gap[0] == pytest.approx((62 / 91) / (2 / 61))


def test_cut_axes_sees_which_faces_grains_touch():
    labels = np.zeros((6, 7, 8), np.int32)
    labels[2:4, 0:3, 3:5] = 1  # touches a y face only
    assert cut_axes(labels) == (False, True, False)
    labels[5, 3, 7] = 2
    assert cut_axes(labels) == (True, True, True)


def test_a_library_of_an_interior_crop_draws_large_grains_more_often(blob_scan):
    library = ParticleLibrary.from_scan(blob_scan, workers=1, progress=False)
    assert library.settings["cut_axes"] == [True, True, True]  # grain 4 touches three faces
    weights = library.draw_weights
    sides = np.array([np.prod(np.subtract(p.bbox[3:], p.bbox[:3])) for p in library])
    assert weights.sum() == pytest.approx(1.0)
    assert weights[np.argmax(sides)] > weights[np.argmin(sides)]
    tube = Tube(inner_radius=30.0, height=3000.0, wall_thickness=2.0, base_thickness=2.0)
    plan = make_plan(library, 2000, 2000, tube, seed=1)
    drawn = np.bincount(plan.indices, minlength=len(library)) / 2000
    np.testing.assert_allclose(drawn, weights, atol=0.035)
    # a library that keeps the cut grains has no bias to undo
    border = ParticleLibrary.from_scan(blob_scan, workers=1, progress=False, include_border=True)
    np.testing.assert_allclose(border.draw_weights, 1 / len(border))
