"""Shared fixtures: small labelled volumes, the built-in sample library, and the dataset exports' inputs."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy import ndimage

from synthpack.io import write_tiff
from synthpack.pipeline.config import PackConfig
from synthpack.pipeline.generate import generate_packs
from synthpack.library.core import ParticleLibrary
from synthpack.scan.samples import sample_scan
from synthpack.scan.core import Scan


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """Run the test files that hold a `slow` test first, so that the two workers of ``.ci/run``
    (pytest-xdist, a file per worker) end together rather than one waiting on a long file at the end."""
    slow_files = {item.path for item in items if item.get_closest_marker("slow")}
    items.sort(key=lambda item: item.path not in slow_files)  # stable: the order within each group stays


@pytest.fixture(scope="session")
def large_scan() -> Scan:
    """The built-in 'large' sample scan (seed 0)."""
    return sample_scan("large", seed=0)


@pytest.fixture(scope="session")
def large_library(large_scan: Scan) -> ParticleLibrary:
    """The particle library of the 'large' sample, built once per test session."""
    return ParticleLibrary.from_scan(large_scan, workers=1, progress=False)


@pytest.fixture(scope="session")
def even_large_library(large_library: ParticleLibrary) -> ParticleLibrary:
    """The large library as a scan whose faces cut no grain would give it (the concrete cylinder): drawn evenly.

    The pours whose figures some tests hold (a free Blender pour's solid fraction, the spacing
    shells' contacts per bare grain) were measured with even draws of these grains, before the
    draw weights (`synthpack.library.sampling`) gave the large sample's bigger grains more weight.
    """
    library = large_library
    return ParticleLibrary(list(library), voxel_size=library.voxel_size, unit=library.unit, density=library.density,
                           statistics=library.statistics, source_shape=library.source_shape, source=library.source,
                           settings={**library.settings, "cut_axes": [False, False, False]})


@pytest.fixture
def blob_scan() -> Scan:
    """A 30x40x50 scan with four box- and ball-shaped particles, one on the border."""
    return _blob_scan()


@pytest.fixture(scope="session")
def blob_scan_files(tmp_path_factory) -> tuple[Path, Path]:
    """The blob scan written once as ``t.tif`` and ``l.tif`` (its voxel size in the files): (tomogram, labels)."""
    folder = tmp_path_factory.mktemp("blob_scan")
    scan = _blob_scan()
    write_tiff(folder / "t.tif", scan.tomogram, scan.voxel_size, scan.unit)
    write_tiff(folder / "l.tif", scan.labels, scan.voxel_size, scan.unit, labels=True)
    return folder / "t.tif", folder / "l.tif"


def _blob_scan() -> Scan:
    labels = np.zeros((30, 40, 50), dtype=np.int32)
    labels[5:15, 5:15, 5:20] = 1
    zz, yy, xx = np.mgrid[:30, :40, :50]
    labels[(zz - 15) ** 2 + (yy - 25) ** 2 + (xx - 35) ** 2 <= 36] = 2
    labels[20:26, 2:8, 30:36] = 3
    labels[0:6, 30:40, 0:8] = 4  # touches three faces of the volume
    tomogram = np.where(labels > 0, 0.8, 0.2).astype(np.float32) + labels * 0.01
    return Scan(tomogram, labels, voxel_size=(2.0, 1.0, 1.0), unit="um", source="blobs")


@pytest.fixture(scope="session")
def phantom() -> tuple[np.ndarray, np.ndarray]:
    """A smooth 32x64x64 phantom (float32) and its labels: blurred balls on a sloping, rippled background."""
    z, y, x = np.mgrid[:32, :64, :64]
    labels = np.zeros((32, 64, 64), dtype=np.int32)
    for label, (cz, cy, cx, r) in enumerate([(16, 20, 20, 10), (16, 44, 44, 12), (10, 20, 48, 8)], 1):
        labels[(z - cz) ** 2 + (y - cy) ** 2 + (x - cx) ** 2 <= r * r] = label
    clean = ndimage.gaussian_filter(np.where(labels > 0, 0.8, 0.2), 1.0)
    clean = clean + 0.05 * np.sin(x / 9.0) + 0.03 * y / 64
    return clean.astype(np.float32), labels


@pytest.fixture(scope="session")
def export_pack_dir(large_library, tmp_path_factory):
    """One 20-grain pack of the large sample library, for the dataset exports."""
    config = PackConfig().replace(pour={"n_particles": 20, "batch_size": 10})
    (path,) = generate_packs(large_library, tmp_path_factory.mktemp("packs"), 1, config, progress=False)
    return path


@pytest.fixture(scope="session")
def shapes_scan() -> Scan:
    """20 slices of 40x50 holding a U-shaped grain (two arms in slices 2-17), a ring and a C shape."""
    labels = np.zeros((20, 40, 50), np.uint16)
    labels[0:2, 5:25, 5:30] = 1  # the U's base: one part per slice
    labels[2:18, 5:11, 5:30] = 1  # left arm
    labels[2:18, 19:25, 5:30] = 1  # right arm: slices 2-17 cut the U into two parts
    yy, xx = np.mgrid[:40, :50]
    radius = np.hypot(yy - 30, xx - 40)
    labels[:, (radius >= 3) & (radius <= 7)] = 2  # ring: a 29-pixel hole in every slice
    c_shape = np.zeros((40, 50), bool)
    c_shape[28:39, 5:20] = True
    c_shape[31:36, 9:20] = False  # concave outline, one part
    labels[4:16, c_shape] = 3
    tomogram = np.where(labels > 0, 0.8, 0.2).astype(np.float32)
    return Scan(tomogram, labels, voxel_size=(1.0, 1.0, 1.0), unit="px", source="shapes")
