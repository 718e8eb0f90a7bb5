"""Tests of synthpack.measure.scanner: cupping, rings and the container wall, measured about the rotation axis."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import tifffile
from scipy import ndimage

from synthpack.artefacts import BeamHardening, RingArtefacts
from synthpack.errors import SynthpackInputError
from synthpack.scan.core import Scan
from synthpack.source import measure_source
from synthpack.measure.edges import signed_distance
from synthpack.measure.scanner import measure_scanner
from synthpack.measure.specimen import specimen_mask

CONCRETE = Path(__file__).resolve().parents[2] / "shared" / "data" / "concrete"
SAND = Path(__file__).resolve().parents[2] / "shared" / "data" / "sand"
PORE, GRAIN, NOISE = 0.2, 0.75, 0.03


def _cylinder_of_balls(seed: int = 0, shape: tuple[int, int, int] = (40, 96, 96), radius: float = 42.0,
                       sizes: tuple[float, float] = (2.5, 4.0)):
    """A specimen of random balls (radii in `sizes`) in a cylinder about the slice centre: clean float32, labels."""
    rng = np.random.default_rng(seed)
    centres = rng.uniform((0, 0, 0), shape, size=(3000, 3))
    centre = ((shape[1] - 1) / 2, (shape[2] - 1) / 2)
    centres = centres[np.hypot(centres[:, 1] - centre[0], centres[:, 2] - centre[1]) <= radius]
    z, y, x = np.indices(shape)
    labels = np.zeros(shape, np.int32)
    for label, (c, r) in enumerate(zip(centres, rng.uniform(*sizes, len(centres))), 1):
        box = tuple(slice(max(int(a - r), 0), min(int(a + r) + 2, n)) for a, n in zip(c, shape))
        ball = (z[box] - c[0]) ** 2 + (y[box] - c[1]) ** 2 + (x[box] - c[2]) ** 2 <= r * r
        labels[box][ball & (labels[box] == 0)] = label
    clean = ndimage.gaussian_filter(np.where(labels > 0, GRAIN, PORE), 0.8)
    return (clean + rng.normal(0.0, NOISE, shape)).astype(np.float32), labels


@pytest.fixture(scope="module")
def specimen():
    tomogram, labels = _cylinder_of_balls()
    return tomogram, labels, specimen_mask(labels), signed_distance(labels)


def _measure(tomogram, specimen):
    _, labels, mask, distance = specimen
    return measure_scanner(tomogram, labels, mask, distance, pore_level=PORE, grain_level=GRAIN)


def test_a_volume_without_artefacts_shows_none(specimen):
    found = _measure(specimen[0], specimen)
    assert found.axis == pytest.approx((47.5, 47.5), abs=0.5)
    assert not found.cupping.significant
    assert found.rings.radii == ()
    assert found.rings.floor < 0.02 * (GRAIN - PORE)  # rings of 2 % of the contrast would be found
    assert found.wall is None
    fields = found.statistics_fields()
    assert fields["cupping_strength"] is None and fields["ring_radii"] is None and fields["wall_intensity"] is None


def test_known_cupping_is_recovered(specimen):
    found = _measure(BeamHardening(strength=0.1)(specimen[0], 0), specimen)
    assert found.cupping.significant
    assert found.cupping.strength == pytest.approx(0.1, abs=0.005)
    assert found.rings.radii == ()


def test_a_brighter_centre_is_a_negative_strength(specimen):
    found = _measure(BeamHardening(strength=-0.05)(specimen[0], 0), specimen)
    assert found.cupping.significant and found.cupping.strength == pytest.approx(-0.05, abs=0.005)


def test_known_rings_and_cupping_are_recovered(specimen):
    rings = RingArtefacts(radii=[12.0, 30.5], amplitudes=[0.04, -0.03], width=1.5)
    found = _measure(rings(BeamHardening(strength=0.1)(specimen[0], 0), 0), specimen)
    assert found.rings.radii == pytest.approx((12.0, 30.5), abs=0.3)
    assert found.rings.amplitudes == pytest.approx((0.04, -0.03), rel=0.25)
    assert found.rings.width == pytest.approx(1.5, rel=0.25)
    assert found.cupping.significant and found.cupping.strength == pytest.approx(0.1, abs=0.02)
    fields = found.statistics_fields()
    assert fields["ring_radii"] == found.rings.radii and fields["cupping_strength"] == found.cupping.strength


def test_a_wall_around_the_specimen_is_measured(specimen):
    tomogram, labels, mask, distance = specimen
    r = np.hypot(*np.meshgrid(np.arange(96) - 47.5, np.arange(96) - 47.5, indexing="ij"))
    ring = np.where(r > 50, 0.0, np.where(r >= 47, 1.0, PORE))  # pores, a 3-voxel wall, air outside
    walled = np.where(labels > 0, GRAIN, ring[None]).astype(np.float32)
    walled = ndimage.gaussian_filter(walled, 0.8) + np.random.default_rng(1).normal(0, NOISE, walled.shape)
    found = measure_scanner(walled.astype(np.float32), labels, mask, distance, pore_level=PORE, grain_level=GRAIN)
    assert found.wall.intensity == pytest.approx(1.0, abs=0.1)
    assert found.wall.thickness == pytest.approx(3.0, abs=0.75)
    assert found.wall.inner_radius == pytest.approx(47.0, abs=0.75)
    assert found.wall.air == pytest.approx(0.0, abs=0.05)  # the air outside the wall
    assert found.statistics_fields()["air_intensity"] == found.wall.air
    assert found.rings.radii == () and not found.cupping.significant  # the wall is not in the specimen


def test_rings_need_their_amplitudes_paired_with_radii():
    with pytest.raises(SynthpackInputError, match="one value per ring"):
        RingArtefacts(radii=[3.0, 5.0], amplitudes=[0.1])
    out = RingArtefacts(radii=[10.0], amplitudes=[-0.5], width=2.0)(np.zeros((1, 41, 41), np.float32), 0)
    assert out[0, 20, 30] == pytest.approx(-0.5, abs=1e-3)


def test_the_source_statistics_hold_the_scanner_fields_and_read_back():
    tomogram, labels = _cylinder_of_balls(seed=2, sizes=(4.0, 7.0))
    rings = RingArtefacts(radii=[20.0], amplitudes=[0.05], width=1.5)
    statistics = measure_source(Scan(rings(BeamHardening(strength=0.1)(tomogram, 0), 0), labels))
    assert statistics.scan_axis == pytest.approx((47.5, 47.5), abs=0.5)
    assert statistics.cupping_strength == pytest.approx(0.1, abs=0.02)
    assert statistics.ring_radii == pytest.approx((20.0,), abs=0.3)
    assert statistics.wall_intensity is None
    assert type(statistics).from_dict(statistics.to_dict()) == statistics


@pytest.mark.skipif(not CONCRETE.is_dir(), reason="the concrete scans (../shared/data/concrete) are absent")
def test_the_concrete_neutron_scan_shows_its_wall():
    tomogram = tifffile.imread(CONCRETE / "concrete_neutron.tif")
    labels = tifffile.imread(CONCRETE / "concrete_neutron_labels_watershed.tif").astype(np.int32)
    statistics = measure_source(Scan(tomogram, labels))
    # the bright cylindrical wall (README): brighter than the paste, outside the labelled aggregates
    assert statistics.wall_intensity > statistics.pore_mean + 0.25 * abs(statistics.contrast)
    assert 1.0 < statistics.wall_thickness < 8.0 and statistics.wall_gap > 0
    assert statistics.air_intensity < statistics.grain_mean < statistics.pore_mean  # air, aggregates, paste


@pytest.mark.skipif(not SAND.is_dir(), reason="the sand scan (../shared/data/sand) is absent")
def test_the_edge_of_a_real_specimen_in_a_container_is_no_ring():
    """The real sand micro-CT as if scanned in a container: grains and labels cut at a radius of 86 voxels, a gap of
    pore level, a wall and air. The step at the specimen's edge was read as 32 rings at its last radii (amplitudes of
    1e11 grey levels, cancelling); a ring is looked for only where the profile holds it on both sides."""
    tomogram = tifffile.imread(SAND / "sand.tif").astype(np.float32)
    labels = tifffile.imread(SAND / "sand_labels_watershed.tif").astype(np.int32)
    r = np.hypot(*np.meshgrid(np.arange(200) - 99.5, np.arange(200) - 99.5, indexing="ij"))[None]
    pore, grain = float(np.median(tomogram[labels == 0])), float(np.median(tomogram[labels > 0]))
    walled = np.where(r < 86, tomogram, np.where(r < 90, pore, np.where(r < 94, 1.3 * grain, 0.3 * pore)))
    walled = ndimage.gaussian_filter(walled, 0.7) + np.random.default_rng(0).normal(0.0, 1.0, walled.shape)
    labels = np.where(r < 86, labels, 0)
    mask = specimen_mask(labels)
    found = measure_scanner(walled.astype(np.float32), labels, mask, signed_distance(labels), pore_level=pore,
                            grain_level=grain)
    assert found.rings.radii == ()
    assert found.wall.inner_radius == pytest.approx(90.0, abs=1.0)
