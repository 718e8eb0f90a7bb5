import numpy as np
import pytest
from scipy import ndimage

from synthpack.errors import SynthpackInputError
from synthpack.library.particles import extract_particles
from synthpack.scan.core import Scan
from synthpack.measure import estimate_phases


def _brute_force(labels):
    """Bounding boxes and voxel counts from one full-volume comparison per label."""
    result = {}
    for k in np.unique(labels)[1:]:
        where = np.argwhere(labels == k)
        result[int(k)] = (tuple(where.min(0)) + tuple(where.max(0) + 1), len(where))
    return result


def test_every_label_found_once_with_brute_force_boxes_and_counts(blob_scan):
    crops = extract_particles(blob_scan, min_voxels=1, include_border=True)
    truth = _brute_force(blob_scan.labels)
    assert [c.label for c in crops] == sorted(truth)
    for crop in crops:
        bbox, count = truth[crop.label]
        assert crop.bbox == bbox
        assert crop.voxel_count == count
        assert crop.mask.shape == tuple(b - a for a, b in zip(bbox[:3], bbox[3:]))


def test_border_flag_and_default_exclusion(blob_scan):
    everything = {c.label: c for c in extract_particles(blob_scan, min_voxels=1, include_border=True)}
    assert [k for k, c in everything.items() if c.touches_border] == [4]
    kept = [c.label for c in extract_particles(blob_scan, min_voxels=1)]
    assert kept == [1, 2, 3]


def test_random_volume_matches_brute_force():
    rng = np.random.default_rng(3)
    seeds = np.zeros((24, 26, 28), dtype=np.int32)
    idx = rng.integers(0, seeds.size, 40)
    seeds.flat[idx] = np.arange(1, 41)
    grown = ndimage.grey_dilation(seeds, size=(5, 5, 5))
    tomo = rng.normal(size=grown.shape).astype(np.float32)
    scan = Scan(tomo, grown)
    truth = _brute_force(grown)
    crops = extract_particles(scan, min_voxels=1, include_border=True)
    for crop in crops:
        bbox, count = truth[crop.label]
        assert crop.bbox == bbox
        # a grey-dilated label can be split in pieces: the largest piece is kept
        assert crop.voxel_count <= count
        components, _ = ndimage.label(grown[tuple(slice(a, b) for a, b in zip(bbox[:3], bbox[3:]))] == crop.label)
        assert crop.voxel_count == np.bincount(components.ravel())[1:].max()


def test_clean_crop_masks_out_neighbours_with_background(blob_scan):
    crop = next(c for c in extract_particles(blob_scan, min_voxels=50) if c.label == 2)
    levels = estimate_phases(blob_scan)
    background = levels.pore_mean
    assert background == pytest.approx(0.2)
    assert levels.pore_std == 0.0
    assert levels.grain_mean == pytest.approx(0.81, abs=0.011)
    assert np.all(crop.tomogram[~crop.mask] == np.float32(background))
    assert np.allclose(crop.tomogram[crop.mask], 0.82)


def test_equivalent_diameter_in_physical_units(blob_scan):
    crop = next(c for c in extract_particles(blob_scan, min_voxels=50) if c.label == 1)
    volume = 10 * 10 * 15 * 2.0  # voxels x (2 x 1 x 1) um^3
    assert crop.equivalent_diameter == pytest.approx((6 * volume / np.pi) ** (1 / 3))


def test_min_voxels_filter_and_empty_result_error(blob_scan):
    # voxel counts: box 1 has 1500, ball 2 has 925, box 3 has 216
    assert [c.label for c in extract_particles(blob_scan, min_voxels=217)] == [1, 2]
    assert [c.label for c in extract_particles(blob_scan, min_voxels=1000)] == [1]
    with pytest.raises(SynthpackInputError, match="no particle left"):
        extract_particles(blob_scan, min_voxels=10**6)


def test_sparse_labels_are_renumbered_and_keep_their_values(blob_scan):
    values = np.array([0, 3, 70_000, 4_000_000_000, 5_000_000], dtype=np.uint32)
    sparse = Scan(blob_scan.tomogram, values[blob_scan.labels])
    assert sparse.labels.max() == 4 and sparse.n_particles == 4
    crops = extract_particles(sparse, min_voxels=1, include_border=True)
    dense = extract_particles(blob_scan, min_voxels=1, include_border=True)
    assert [c.label for c in crops] == [3, 70_000, 5_000_000, 4_000_000_000]
    assert sorted(c.bbox for c in crops) == sorted(c.bbox for c in dense)


def test_dense_labels_are_used_as_given_without_a_copy(large_scan):
    assert Scan(large_scan.tomogram, large_scan.labels).labels is large_scan.labels
    assert large_scan.label_values is None
