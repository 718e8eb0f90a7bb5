"""The specimen region: what the source statistics describe, without the container and the air around it."""

import numpy as np

from synthpack.scan.samples import sample_scan
from synthpack.measure.specimen import specimen_mask


def test_a_cylinder_of_grains_leaves_out_the_air_around_it():
    labels = np.zeros((4, 60, 60), np.int32)
    zz, yy, xx = np.mgrid[:4, :60, :60]
    rng = np.random.default_rng(0)
    centres = [c for c in rng.uniform(12, 48, (80, 2)) if np.hypot(*(c - 30)) < 17]
    for k, (cy, cx) in enumerate(centres, 1):
        labels[(yy - cy) ** 2 + (xx - cx) ** 2 < 9] = k
    mask = specimen_mask(labels)
    radius = np.hypot(yy - 30, xx - 30)
    assert not mask[radius > 23].any()  # the air and the wall outside the outermost grains
    assert mask[(radius < 12)].all()  # the pores between the grains are inside
    assert mask[labels > 0].all()


def test_a_box_full_of_grains_is_all_specimen_and_empty_slices_are_empty():
    labels = sample_scan("large").labels
    assert specimen_mask(labels).mean() > 0.98
    labels = labels.copy()
    labels[:3] = 0
    mask = specimen_mask(labels)
    assert not mask[:3].any() and mask[3:].mean() > 0.98
