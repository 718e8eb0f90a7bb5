"""Tests of the built-in stand-in sample scans (synthpack.scan.samples)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import ndimage
from skimage.measure import regionprops

from synthpack.errors import SynthpackInputError
from synthpack.scan.samples import SAMPLE_NAMES, sample_scan
from synthpack.scan.core import Scan


@pytest.fixture(scope="module")
def large() -> Scan:
    return sample_scan("large", seed=0)


@pytest.fixture(scope="module")
def small() -> Scan:
    return sample_scan("small", seed=0)


@pytest.fixture(scope="module", params=SAMPLE_NAMES)
def sample(request, large, small) -> Scan:
    return {"large": large, "small": small}[request.param]


def _border_labels(labels: np.ndarray) -> np.ndarray:
    """Boolean per label (index = label) telling whether it touches the volume border."""
    border = np.zeros(labels.max() + 1, dtype=bool)
    for face in (labels[0], labels[-1], labels[:, 0], labels[:, -1], labels[:, :, 0], labels[:, :, -1]):
        border[np.unique(face)] = True
    border[0] = False
    return border


def _touching_labels(labels: np.ndarray) -> np.ndarray:
    """Boolean per label: has a face neighbour that belongs to another grain."""
    touching = np.zeros(labels.max() + 1, dtype=bool)
    for axis in range(3):
        moved = np.moveaxis(labels, axis, 0)
        a, b = moved[1:], moved[:-1]
        meet = (a != b) & (a > 0) & (b > 0)
        touching[a[meet]] = True
        touching[b[meet]] = True
    return touching


def test_names_listed():
    assert SAMPLE_NAMES == ("large", "small")


def test_same_seed_gives_identical_arrays(large):
    again = sample_scan("large", seed=0)
    assert again.tomogram.tobytes() == large.tomogram.tobytes()
    assert again.labels.tobytes() == large.labels.tobytes()
    assert again.metadata == large.metadata


def test_other_seed_gives_other_scan(large):
    other = sample_scan("large", seed=1)
    assert other.labels.shape == large.labels.shape
    assert np.mean(other.labels != large.labels) > 0.3
    assert not np.array_equal(other.tomogram, large.tomogram)
    assert other.metadata["seed"] == 1


def test_scan_fields(sample):
    name = sample.metadata["sample"]
    assert sample.shape == (128, 128, 128)
    assert sample.tomogram.dtype == np.float32
    assert sample.labels.dtype == np.int32
    assert sample.unit == "um"
    assert sample.voxel_size == {"large": (10.0, 10.0, 10.0), "small": (5.0, 5.0, 5.0)}[name]
    assert sample.source == f"sample:{name}"
    assert sample.metadata["seed"] == 0
    assert sample.metadata["stand_in"] is True
    assert sample.metadata["n_grains"] == sample.n_particles
    assert np.all(np.isfinite(sample.tomogram))


def test_grain_counts(large, small):
    assert 250 <= large.n_particles <= 400
    assert small.n_particles > 3 * large.n_particles


def test_labels_consecutive(sample):
    n = int(sample.labels.max())
    assert sample.labels.min() == 0
    assert np.array_equal(np.unique(sample.labels), np.arange(n + 1))


def test_every_label_one_face_connected_component(sample):
    labels = sample.labels
    for index, box in enumerate(ndimage.find_objects(labels), start=1):
        _, pieces = ndimage.label(labels[box] == index)
        assert pieces == 1, f"label {index} has {pieces} face-connected pieces"


def test_packing_fraction(sample):
    fraction = np.count_nonzero(sample.labels) / sample.labels.size
    assert 0.55 <= fraction <= 0.65
    assert sample.metadata["packing_fraction_achieved"] == pytest.approx(fraction, abs=1e-3)


def test_grain_sizes(sample):
    name = sample.metadata["sample"]
    lo, hi = {"large": (18.0, 26.0), "small": (9.0, 13.0)}[name]
    sizes = np.bincount(sample.labels.ravel())[1:]
    whole = ~_border_labels(sample.labels)[1:]
    diameters = np.cbrt(6.0 * sizes[whole] / np.pi)
    assert lo <= np.median(diameters) <= hi
    assert np.mean((diameters > lo - 3) & (diameters < hi + 3)) > 0.8


def test_grains_touch(sample):
    touching = _touching_labels(sample.labels)[1:]
    assert touching.mean() > 0.8


def test_grains_not_spherical(large):
    border = _border_labels(large.labels)
    props = [p for p in regionprops(large.labels) if not border[p.label]]
    ratios = [p.axis_major_length / p.axis_minor_length for p in props]
    assert len(ratios) > 30
    assert np.median(ratios) > 1.2


def test_some_grains_cut_by_every_face(sample):
    labels = sample.labels
    for face in (labels[0], labels[-1], labels[:, 0], labels[:, -1], labels[:, :, 0], labels[:, :, -1]):
        assert len(np.unique(face[face > 0])) >= 5


def test_intensity_contrast_and_partial_volume(sample):
    image, labels = sample.tomogram, sample.labels
    solid = labels > 0
    core = ndimage.binary_erosion(solid, iterations=2)
    pore_core = ndimage.binary_erosion(~solid, iterations=2)
    grain_level = float(image[core].mean())
    pore_level = float(image[pore_core].mean())
    assert grain_level - pore_level > 0.35
    # Noise and texture: grain cores are not flat, but vary by only a few % of the contrast.
    assert 0.01 < float(image[core].std()) / (grain_level - pore_level) < 0.15
    # Grains differ from each other in mean intensity.
    core_labels = np.where(core, labels, 0)
    means = ndimage.mean(image, labels=core_labels, index=np.unique(core_labels[core_labels > 0]))
    assert np.std(means) > 0.005
    # Partial volume: grain voxels next to the pore lie between the two levels.
    edge = solid & ~ndimage.binary_erosion(solid)
    edge_level = float(image[edge].mean())
    assert pore_level + 0.1 < edge_level < grain_level - 0.05


def test_unknown_name_lists_valid_ones():
    with pytest.raises(SynthpackInputError, match="large, small"):
        sample_scan("medium")


@pytest.mark.parametrize("seed", [-1, 1.5, "0", True])
def test_bad_seed(seed):
    with pytest.raises(SynthpackInputError, match="non-negative integer"):
        sample_scan("large", seed=seed)
