"""Labels drawn as a threshold segmentation of the scan draws them (`reconstruct.labels: segmented`)."""

import copy
import dataclasses

import numpy as np
import pytest
import zarr
from scipy import ndimage

from synthpack.errors import SynthpackInputError
from synthpack.pipeline.config import PackConfig
from synthpack.pipeline.generate import build_pack
from synthpack.render import segmented_labels
from synthpack.render.segmented_labels import SegmentedLabels


def _two_blocks(gap: int) -> np.ndarray:
    """Two boxes 12 voxels deep, facing each other across a gap of `gap` voxels, in a 20 x 20 x 40 volume."""
    labels = np.zeros((20, 20, 40), dtype=np.int32)
    labels[4:16, 4:16, 4:20] = 1
    labels[4:16, 4:16, 20 + gap:36] = 2
    return labels


def test_a_gap_narrower_than_the_blur_closes_and_each_side_keeps_its_label():
    labels = _two_blocks(gap=1)
    exact = labels.copy()
    record = SegmentedLabels(1.3).redraw(labels, slab=20, n_labels=2)
    assert np.all(exact[:, :, 20] == 0)
    middle = labels[8:12, 8:12, 19:22]
    assert np.all(middle > 0), "the gap is a shared face, as a segmentation draws it"
    assert np.all(labels[exact == 1] != 2) and np.all(labels[exact == 2] != 1)
    assert np.all(labels[8:12, 8:12, 5:19] == 1) and np.all(labels[8:12, 8:12, 22:35] == 2)
    assert abs(np.count_nonzero(labels) - np.count_nonzero(exact)) <= 0.02 * np.count_nonzero(exact)
    assert record["present"].tolist() == [True, True, True] and 0 < record["changed"] < 0.1


def test_a_gap_wider_than_the_blur_stays_open():
    labels = _two_blocks(gap=6)
    SegmentedLabels(1.0).redraw(labels, slab=20, n_labels=2)
    assert np.all(labels[8:12, 8:12, 22:24] == 0)


def test_the_solid_volume_is_kept_and_tips_are_rounded():
    z, y, x = np.mgrid[:40, :40, :40]
    labels = np.zeros((40, 40, 40), dtype=np.int32)
    labels[np.abs(z - 20) + np.abs(y - 20) + np.abs(x - 20) <= 12] = 1  # an octahedron: six sharp tips
    before = np.count_nonzero(labels)
    tip = labels[20, 20, 32]
    SegmentedLabels(1.5).redraw(labels, slab=40, n_labels=1)
    assert tip == 1 and labels[20, 20, 32] == 0, "a sharp tip falls below the threshold, as in a blurred scan"
    assert abs(np.count_nonzero(labels) - before) <= 0.01 * before


def test_the_result_does_not_depend_on_the_slabs_or_tiles_and_a_zarr_array_gives_the_same(monkeypatch):
    rng = np.random.default_rng(3)
    centres = rng.uniform(0, 48, size=(40, 3))
    grid = np.stack(np.mgrid[:48, :48, :48], axis=-1).astype(float)
    d = np.linalg.norm(grid[..., None, :] - centres, axis=-1)
    labels = np.where(d.min(axis=-1) < 6.5, d.argmin(axis=-1) + 1, 0).astype(np.int32)  # touching spheres
    results = []
    for slab in (1, 5, 16, 48):
        copy = labels.copy()
        SegmentedLabels(1.2).redraw(copy, slab=slab, n_labels=40)
        results.append(copy)
    for other in results[1:]:
        np.testing.assert_array_equal(results[0], other)
    monkeypatch.setattr(segmented_labels, "TILE", 7)  # lateral tiles, each with its halo
    tiled = labels.copy()
    SegmentedLabels(1.2).redraw(tiled, slab=5, n_labels=40)
    np.testing.assert_array_equal(tiled, results[0])
    on_disk = zarr.array(labels, chunks=(8, 48, 48))
    SegmentedLabels(1.2).redraw(on_disk, slab=8, n_labels=40)
    np.testing.assert_array_equal(on_disk[:], results[0])
    assert not np.array_equal(results[0], labels)


def test_the_blur_must_be_positive():
    with pytest.raises(ValueError, match="positive"):
        SegmentedLabels(0.0)


SEGMENTED = PackConfig().replace(pour={"n_particles": 24, "batch_size": 12}, postprocess="none",
                                 reconstruct={"labels": "segmented"})


def test_a_pack_with_segmented_labels_records_them_and_keeps_the_same_pour(large_library):
    exact = build_pack(large_library, SEGMENTED.replace(reconstruct={"labels": "exact"}), seed=5, progress=False)
    segmented = build_pack(large_library, SEGMENTED, seed=5, progress=False)
    np.testing.assert_array_equal(segmented.tomogram, exact.tomogram)  # the image is the render's either way
    assert exact.manifest["segmented_labels"] is None
    record = segmented.manifest["segmented_labels"]
    assert record["sigma"] == pytest.approx(large_library.statistics.edge_sigma)
    assert 0 < record["changed"] < 0.1
    differ = segmented.labels != exact.labels
    assert differ.any()
    boundary = ndimage.binary_dilation(exact.labels > 0) & ~ndimage.binary_erosion(exact.labels > 0)
    assert np.all(ndimage.binary_dilation(boundary, iterations=4)[differ]), "only voxels near a grain boundary change"
    assert segmented.manifest["config"]["reconstruct"]["labels"] == "segmented"


def test_segmented_labels_need_the_sources_edge_spread(large_library):
    library = copy.copy(large_library)
    library.statistics = dataclasses.replace(large_library.statistics, edge_sigma=None)
    with pytest.raises(SynthpackInputError, match="reconstruct.labels: exact"):
        build_pack(library, SEGMENTED, seed=5, progress=False)
