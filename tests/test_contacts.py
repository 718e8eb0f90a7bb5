"""Grain contacts (synthpack.measure.contacts): shared voxel faces, on the complete grains centred in a region."""

from pathlib import Path

import numpy as np
import pytest

from synthpack.measure.contacts import centred_grains, coordination_numbers, mean_coordination
from synthpack.measure.specimen import specimen_mask

CONCRETE = Path(__file__).resolve().parents[2] / "shared" / "data" / "concrete"


def _cubes() -> np.ndarray:
    """Grains 1-2-3 in a row (face to face), 4 one pore voxel from 3, 5 touching 4 by an edge only."""
    labels = np.zeros((20, 20, 40), dtype=np.int32)
    labels[5:10, 5:10, 2:7] = 1
    labels[5:10, 5:10, 7:12] = 2
    labels[5:10, 5:10, 12:17] = 3
    labels[5:10, 5:10, 18:23] = 4
    labels[10:15, 10:15, 23:28] = 5
    return labels


def test_grains_that_share_a_face_touch_and_no_others():
    coordination = coordination_numbers(_cubes())
    assert coordination.tolist() == [0, 1, 2, 1, 0, 0]


def test_two_touching_cubes_have_one_contact_each():
    labels = np.zeros((10, 10, 10), dtype=np.int16)
    labels[2:5, 2:8, 2:8], labels[5:8, 2:8, 2:8] = 7, 3
    assert coordination_numbers(labels)[[3, 7]].tolist() == [1, 1]
    assert mean_coordination(labels, np.ones(labels.shape, bool)) == 1.0


def test_only_complete_grains_centred_in_the_region_are_counted():
    labels = _cubes()
    labels[0:3, 0:3, 0:3] = 6  # on a face of the volume: cut, so left out
    everywhere = np.ones(labels.shape, dtype=bool)
    assert centred_grains(labels, everywhere).tolist() == [1, 2, 3, 4, 5]
    assert mean_coordination(labels, everywhere) == pytest.approx(4 / 5)
    left = np.zeros(labels.shape, dtype=bool)
    left[:, :, :10] = True  # holds the centroids of 1 and 2 (x 4 and 9), not of 3 (x 14)
    assert centred_grains(labels, left).tolist() == [1, 2]
    assert mean_coordination(labels, left) == pytest.approx(1.5)  # grain 2 still counts its contact with 3
    assert mean_coordination(labels, np.zeros(labels.shape, dtype=bool)) is None


def test_grains_reaching_voxels_that_may_not_be_read_are_left_out_and_not_read():
    labels = _cubes()
    readable = np.ones(labels.shape, dtype=bool)
    readable[:, :, 12:] = False  # a held-out block: grains 3, 4 and 5 lie in it
    everywhere = np.ones(labels.shape, dtype=bool)
    assert centred_grains(labels, everywhere, readable).tolist() == [1, 2]
    assert mean_coordination(labels, everywhere, readable) == pytest.approx(1.0)  # 2's contact with 3 is not read


@pytest.mark.skipif(not CONCRETE.is_dir(), reason="the real concrete scan (../shared/data/concrete) is absent")
def test_the_concrete_scans_aggregates_touch_about_once_each():
    tifffile = pytest.importorskip("tifffile")
    labels = tifffile.imread(CONCRETE / "concrete_neutron_labels_watershed.tif")
    region = specimen_mask(labels)
    coordination = coordination_numbers(labels)[centred_grains(labels, region)]
    assert len(coordination) > 300 and 0.9 < coordination.mean() < 1.2  # 1.05, aggregates floating in paste
    assert 0.3 < np.mean(coordination == 0) < 0.5  # many touch no other
