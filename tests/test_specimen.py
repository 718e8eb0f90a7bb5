"""The specimen region: what the source statistics describe, without the container and the air around it."""

from pathlib import Path

import numpy as np
import pytest
import tifffile

from synthpack.measure.specimen import INTERIOR_COVERAGE, edge_coverage, is_interior_crop, specimen_mask
from synthpack.render.config import ReconstructConfig
from synthpack.scan.core import Scan
from synthpack.scan.samples import sample_scan
from synthpack.source import measure_source

DATA = Path(__file__).resolve().parents[2] / "shared" / "data"
SAND, CONCRETE = DATA / "sand", DATA / "concrete"


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


def _balls(shape: tuple[int, int, int], inside, seed: int = 0) -> np.ndarray:
    """Labels of random balls (radius 4) whose centres `inside(z, y, x)` allows, in a volume of `shape`."""
    rng = np.random.default_rng(seed)
    zz, yy, xx = np.indices(shape)
    labels = np.zeros(shape, np.int32)
    centres = [c for c in rng.uniform(0, shape, (600, 3)) if inside(*c)]
    for k, (cz, cy, cx) in enumerate(centres, 1):
        labels[((zz - cz) ** 2 + (yy - cy) ** 2 + (xx - cx) ** 2 < 16) & (labels == 0)] = k
    return labels


def test_grains_to_the_edges_make_an_interior_crop_unless_a_wall_is_in_view():
    block = _balls((12, 48, 48), lambda z, y, x: True)
    coverage = edge_coverage(specimen_mask(block))
    assert coverage > 0.9
    assert is_interior_crop(coverage, wall=False)
    assert not is_interior_crop(coverage, wall=True)  # a container in view: the tube, whatever the coverage
    cylinder = _balls((12, 48, 48), lambda z, y, x: np.hypot(y - 23.5, x - 23.5) < 16)
    coverage = edge_coverage(specimen_mask(cylinder))
    assert coverage == 0.0 and not is_interior_crop(coverage, wall=False)
    half = block.copy()
    half[:, :, 16:] = 0  # grains in the left third only: one face, a third of two others
    assert INTERIOR_COVERAGE > edge_coverage(specimen_mask(half)) > 0.2


@pytest.mark.skipif(not SAND.is_dir(), reason="the sand scan (../shared/data/sand) is absent")
def test_the_real_sand_scan_is_an_interior_crop():
    scan = Scan(tifffile.imread(SAND / "sand.tif").astype(np.float32),
                tifffile.imread(SAND / "sand_labels_watershed.tif").astype(np.int32), (1.0, 1.0, 1.0), "px")
    statistics = measure_source(scan)
    assert statistics.wall_intensity is None and statistics.edge_coverage > 0.8
    assert statistics.interior_crop
    assert ReconstructConfig().view_of(statistics) == "interior"
    assert ReconstructConfig(view="tube").view_of(statistics) == "tube"


@pytest.mark.skipif(not CONCRETE.is_dir(), reason="the concrete scans (../shared/data/concrete) are absent")
def test_the_real_concrete_scan_in_its_cylinder_is_not():
    scan = Scan(tifffile.imread(CONCRETE / "concrete_neutron.tif").astype(np.float32),
                tifffile.imread(CONCRETE / "concrete_neutron_labels_watershed.tif").astype(np.int32),
                (1.0, 1.0, 1.0), "px")
    statistics = measure_source(scan)
    assert statistics.edge_coverage < 0.1 and statistics.wall_intensity is not None
    assert not statistics.interior_crop and ReconstructConfig().view_of(statistics) == "tube"


def test_the_built_in_samples_are_interior_crops(large_library):
    assert large_library.statistics.interior_crop  # a block of grains to its edges, no wall
    assert ReconstructConfig().view_of(large_library.statistics) == "interior"
