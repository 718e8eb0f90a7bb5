"""The local half-width of the pore space (synthpack.measure.pore_width): thin gaps told from open pores."""

import numpy as np
import pytest
from scipy import ndimage

from synthpack.measure.pore_width import pore_half_widths


@pytest.mark.parametrize("gap, half_width", [(1, 1), (2, 1), (3, 2), (5, 3), (9, 5)])
def test_a_slot_between_two_slabs_is_half_its_width_everywhere(gap, half_width):
    labels = np.ones((24, 24, 40), np.int32)
    labels[:, :, 15:15 + gap] = 0
    widths = pore_half_widths(labels, np.ones(labels.shape, bool))
    assert widths.shape == (24 * 24 * gap,) and np.all(widths == half_width)


def test_a_ball_shaped_pore_is_its_radius_and_the_gaps_by_it_stay_narrow():
    zz, yy, xx = np.mgrid[:40, :40, :60]
    labels = np.ones(zz.shape, np.int32)
    ball = (zz - 20) ** 2 + (yy - 20) ** 2 + (xx - 20) ** 2 <= 8**2
    labels[ball] = 0
    labels[:, :, 40:43] = 0  # a slot 3 voxels wide, apart from the ball
    region = np.ones(labels.shape, bool)
    widths = np.zeros(labels.shape, np.int64)
    widths[(labels == 0) & region] = pore_half_widths(labels, region)
    assert widths[20, 20, 20] == 8 and np.median(widths[ball]) == 8  # the ball's voxels lie in the inscribed ball
    assert np.all(widths[:, :, 40:43] == 2)
    # a region that cuts the ball in half: outside the region counts as no pore
    half = region.copy()
    half[:, :, :20] = False
    cut = np.zeros(labels.shape, np.int64)
    cut[(labels == 0) & half] = pore_half_widths(labels, half)
    assert cut[20, 20, 24] < widths[20, 20, 24]


def test_open_pores_are_wider_than_the_same_porosity_in_thin_gaps():
    rng = np.random.default_rng(0)
    thin = np.ones((30, 60, 60), np.int32)
    thin[:, :, ::4] = 0  # one-voxel gaps: porosity 0.25
    open_ = (ndimage.gaussian_filter(rng.random((30, 60, 60)), 4) > 0.5).astype(np.int32)  # blobs
    region = np.ones(thin.shape, bool)
    assert np.median(pore_half_widths(open_, region)) > np.median(pore_half_widths(thin, region)) == 1
