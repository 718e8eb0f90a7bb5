"""The pack preview's grain sizes: the grains whole in view, as the library counts the source's."""

from __future__ import annotations

import numpy as np

from synthpack.library.particles import equivalent_diameter
from synthpack.preview import complete_grain_diameters


def test_the_grains_cut_by_a_face_of_the_volume_are_left_out_of_the_grain_sizes():
    labels = np.zeros((20, 30, 40), dtype=np.int32)
    labels[5:10, 5:10, 5:10] = 1       # whole: 125 voxels
    labels[0:4, 12:16, 12:16] = 2      # cut by the first z face
    labels[8:12, 20:24, 36:40] = 3     # cut by the last x face
    labels[12:14, 20:23, 5:9] = 5      # whole: 24 voxels (label 4 absent)
    diameters = complete_grain_diameters(labels, (2.0, 1.0, 1.0))
    np.testing.assert_allclose(diameters, equivalent_diameter(np.array([125.0, 24.0]) * 2.0))
    assert complete_grain_diameters(labels[:, :, 36:], (1.0, 1.0, 1.0)).size == 0  # every grain cut: none
