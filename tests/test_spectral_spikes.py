"""Spectral spikes (synthpack.measure.spectral_spikes): periodic patterns found, none in random fields, none in packs.

A pack's pore phase must hold no periodic pattern that its source does not: on the built-in
`large` sample and on the real concrete and sand scans (read from ``../shared/data``, skipped
where absent).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import tifffile
from scipy import ndimage

from synthpack.library.core import ParticleLibrary
from synthpack.measure.edges import signed_distance
from synthpack.measure.spectral_spikes import MIN_SLICE_VOXELS, SpectralSpikes, slice_power_spectrum, spectral_spikes
from synthpack.measure.spectrum import phase_interiors
from synthpack.pipeline.config import PackConfig
from synthpack.pipeline.generate import build_pack
from synthpack.realism.region import Specimen, bulk_region
from synthpack.scan.core import Scan

DATA = Path(__file__).resolve().parents[2] / "shared" / "data"
SHAPE = (40, 96, 96)


def _smooth_noise(sigma: float, seed: int, shape=SHAPE) -> np.ndarray:
    """White noise smoothed by a Gaussian of `sigma` voxels (0: white), unit std, plus 5 % white noise."""
    rng = np.random.default_rng(seed)
    field = ndimage.gaussian_filter(rng.standard_normal(shape), sigma) if sigma else rng.standard_normal(shape)
    return field / field.std() + 0.05 * rng.standard_normal(shape)


def _holes(shape=SHAPE, seed=1) -> np.ndarray:
    """A pore-interior-like mask: the volume less balls of radius 8 about 100 random voxels."""
    centres = np.zeros(shape, bool)
    centres.ravel()[np.random.default_rng(seed).choice(centres.size, 100, replace=False)] = True
    return ndimage.distance_transform_edt(~centres) > 8


def _found(spikes: SpectralSpikes, frequency: tuple[float, float], tolerance: float = 0.015) -> bool:
    reference = SpectralSpikes(np.array([frequency]), np.ones(1), 1.0, 1)
    return len(spikes.not_in(reference, tolerance)) < len(spikes)


@pytest.mark.parametrize("masked", [False, True])
def test_an_injected_checkerboard_and_stripes_are_found(masked):
    mask = _holes() if masked else np.ones(SHAPE, bool)
    _, y, x = np.indices(SHAPE)
    field = _smooth_noise(2.0, 5)
    checkerboard = spectral_spikes(field + 0.01 * (-1.0) ** (y + x), mask)  # 1 % of the field's std
    assert _found(checkerboard, (0.5, 0.5))
    assert checkerboard.height.max() > 5
    stripes = spectral_spikes(field + 0.03 * np.cos(2 * np.pi * 0.25 * x), mask)
    assert _found(stripes, (0.0, 0.25))
    assert len(stripes.not_in(SpectralSpikes(np.array([[0.0, 0.25]]), np.ones(1), 1.0, 1), 0.04)) == 0
    assert len(spectral_spikes(field, mask)) == 0  # and none without them


@pytest.mark.parametrize("sigma", [0.0, 1.0, 2.0, 4.0])
def test_no_spikes_in_gaussian_random_fields(sigma):
    holes = _holes()
    for seed in range(2):
        field = _smooth_noise(sigma, seed)
        for mask in (np.ones(SHAPE, bool), holes):
            spikes = spectral_spikes(field, mask)
            assert len(spikes) == 0, (sigma, seed, spikes.frequency, spikes.height)
            assert spikes.slices == SHAPE[0] and spikes.threshold > 1


def test_the_spectrum_holds_the_variance_and_a_thin_mask_measures_nothing():
    field = np.random.default_rng(3).standard_normal(SHAPE)
    power, slices = slice_power_spectrum(field, np.ones(SHAPE, bool))
    assert slices == SHAPE[0] and power.shape == SHAPE[1:]
    # the spectrum of the Laplacian of white noise of variance 1: 20 on average
    assert power.mean() == pytest.approx(20.0, rel=0.05)
    thin = np.zeros(SHAPE, bool)
    thin[:, 10, :MIN_SLICE_VOXELS - 1] = True  # too few voxels in every slice
    assert len(spectral_spikes(field, thin)) == 0 and spectral_spikes(field, thin).slices == 0
    thin[:, 10, MIN_SLICE_VOXELS - 1] = True
    assert slice_power_spectrum(field, thin)[1] == SHAPE[0]


def _pore_spikes(tomogram: np.ndarray, labels: np.ndarray, region: np.ndarray) -> SpectralSpikes:
    return spectral_spikes(tomogram, phase_interiors(signed_distance(labels), region)["pores"])


def _pack_spikes_not_in_source(scan: Scan, library: ParticleLibrary, config: PackConfig) -> dict[str, SpectralSpikes]:
    """The spikes of a pack's pore interior, clean and post-processed, that the source's pore interior lacks."""
    source = Specimen.from_scan(scan)
    reference = _pore_spikes(source.tomogram, source.labels, source.region)
    pack = build_pack(library, config, seed=2, progress=False)
    region = bulk_region(pack.labels.shape, tuple(pack.grid.origin), pack.grid.voxel_size,
                         pack.manifest["pour_checks"]["packing_region"])
    found = {name: _pore_spikes(np.asarray(volume), pack.labels, region)
             for name, volume in (("clean", pack.clean), ("tomogram", pack.tomogram))}
    assert all(spikes.slices >= 10 for spikes in found.values())  # a pore phase to look at
    return {name: spikes.not_in(reference) for name, spikes in found.items()}


@pytest.mark.slow
def test_a_pack_of_the_sample_has_no_pore_spike_that_the_source_lacks(large_scan, large_library):
    config = PackConfig().replace(pour={"n_particles": 60, "batch_size": 30, "tube_radius": 400.0})  # a bulk
    for name, extra in _pack_spikes_not_in_source(large_scan, large_library, config).items():
        assert len(extra) == 0, (name, extra.frequency, extra.height)


@pytest.mark.slow
@pytest.mark.parametrize("name, files, side", [
    ("concrete", ("concrete_neutron.tif", "concrete_neutron_labels_watershed.tif"), 100),
    ("sand", ("sand.tif", "sand_labels_watershed.tif"), 128),  # a 100 x 128 x 128 corner: half the particles
])
def test_a_pack_of_a_real_scan_has_no_pore_spike_that_the_scan_lacks(name, files, side):
    folder = DATA / name
    if not folder.is_dir():
        pytest.skip(f"the {name} scan ({folder}) is absent")
    tomogram, labels = (tifffile.imread(folder / file)[:, :side, :side] for file in files)
    scan = Scan(tomogram.astype(np.float32), labels, voxel_size=(1.0, 1.0, 1.0), unit="px", source=name)
    library = ParticleLibrary.from_scan(scan, workers=1, progress=False)
    # few grains in a tube six grain diameters across: deep enough for a bulk with pores to look at
    radius = 3.0 * float(np.median(library.equivalent_diameters))
    config = PackConfig().replace(pour={"n_particles": 80, "batch_size": 40, "tube_radius": radius})
    for volume, extra in _pack_spikes_not_in_source(scan, library, config).items():
        assert len(extra) == 0, (volume, extra.frequency, extra.height)
