import json

import numpy as np
import pytest

from synthpack.errors import SynthpackInputError
from synthpack._shared.arrays import cupping_factor
from synthpack.library.core import ParticleLibrary
from synthpack.library.particles import extract_particles
from synthpack.scan.core import Scan
from synthpack.source import measure_source
from synthpack.scan.split import central_block


def test_library_of_sample_has_meshed_particles(large_library, large_scan):
    assert len(large_library) > 30
    assert large_library.source_shape == large_scan.shape
    for particle in large_library:
        assert particle.mesh.is_watertight
        assert not particle.touches_border
        assert particle.mass == pytest.approx(large_library.density * particle.volume)
        # the mesh encloses about the mask's volume (voxel count x voxel volume)
        assert particle.volume == pytest.approx(particle.voxel_count * 1000.0, rel=0.1)
    # the pore intensity of the sample is below the grains'
    assert large_library.statistics.pore_mean < np.median(large_scan.tomogram[large_scan.labels > 0])


def test_save_load_round_trip(large_library, tmp_path):
    out = large_library.save(tmp_path / "lib")
    loaded = ParticleLibrary.load(out)
    assert len(loaded) == len(large_library)
    assert loaded.voxel_size == large_library.voxel_size
    assert loaded.statistics == large_library.statistics
    for a, b in zip(large_library, loaded):
        assert (a.label, a.bbox, a.touches_border) == (b.label, b.bbox, b.touches_border)
        np.testing.assert_array_equal(a.mask, b.mask)
        np.testing.assert_array_equal(a.tomogram, b.tomogram)
        np.testing.assert_array_equal(a.mesh.faces, b.mesh.faces)
        np.testing.assert_allclose(a.center_mass, b.center_mass)
    assert not list(tmp_path.glob(".lib.tmp-*"))


def test_save_replaces_an_existing_library_atomically(large_library, tmp_path):
    large_library[:5].save(tmp_path / "lib")
    large_library[:7].save(tmp_path / "lib")
    assert len(ParticleLibrary.load(tmp_path / "lib")) == 7
    assert [p.name for p in tmp_path.iterdir()] == ["lib"]


def test_sieve_selects_exactly_the_particles_in_range(large_library):
    d = large_library.equivalent_diameters
    lo, hi = np.percentile(d, [25, 75])
    sieved = large_library.sieve(lo, hi)
    expected = [p.label for p in large_library if lo <= p.equivalent_diameter < hi]
    assert [p.label for p in sieved] == expected
    assert 0 < len(sieved) < len(large_library)
    with pytest.raises(SynthpackInputError, match="no particle"):
        large_library.sieve(d.max() + 1, d.max() + 2)
    with pytest.raises(SynthpackInputError, match="d_min < d_max"):
        large_library.sieve(5, 1)


def test_size_distribution_counts_every_particle(large_library):
    counts, edges = large_library.size_distribution()
    assert counts.sum() == len(large_library)
    assert "particles from sample:large" in large_library.summary()


def test_parallel_build_equals_serial(large_scan, large_library):
    parallel = ParticleLibrary.from_scan(large_scan, workers=2, progress=False)
    assert [p.label for p in parallel] == [p.label for p in large_library]
    for a, b in zip(parallel, large_library):
        np.testing.assert_array_equal(a.mesh.vertices, b.mesh.vertices)


def test_load_missing_or_corrupt_library_says_to_rebuild(large_library, tmp_path):
    with pytest.raises(SynthpackInputError, match="does not exist"):
        ParticleLibrary.load(tmp_path / "nowhere")
    out = large_library[:3].save(tmp_path / "lib")
    (out / "meshes.npz").write_bytes(b"not a zip file")
    with pytest.raises(SynthpackInputError, match="corrupt.*rebuild"):
        ParticleLibrary.load(out)
    (out / "meshes.npz").unlink()
    with pytest.raises(SynthpackInputError, match="lacks meshes.npz"):
        ParticleLibrary.load(out)


def test_truncated_metadata_is_reported_as_corrupt(large_library, tmp_path):
    out = large_library[:3].save(tmp_path / "lib")
    text = (out / "library.json").read_text()
    (out / "library.json").write_text(text[: len(text) // 2])
    with pytest.raises(SynthpackInputError, match="corrupt"):
        ParticleLibrary.load(out)
    meta = json.loads(text)
    meta["format"] = "something else"
    (out / "library.json").write_text(json.dumps(meta))
    with pytest.raises(SynthpackInputError, match="not a synthpack particle library"):
        ParticleLibrary.load(out)


@pytest.mark.parametrize("version", [None, 0, 9, 11, "10"])
def test_library_of_another_format_version_says_to_rebuild(large_library, tmp_path, version):
    out = large_library[:3].save(tmp_path / "lib")
    meta = json.loads((out / "library.json").read_text())
    assert meta["version"] == 10
    if version is None:
        del meta["version"]
    else:
        meta["version"] = version
    (out / "library.json").write_text(json.dumps(meta))
    with pytest.raises(SynthpackInputError, match=f"format version {version!r}, but this synthpack reads "
                                                  "version 10: rebuild it with `synthpack library build`"):
        ParticleLibrary.load(out)


def test_library_stores_its_source_statistics_under_phases(large_library, tmp_path):
    out = large_library.save(tmp_path / "lib")
    meta = json.loads((out / "library.json").read_text())
    assert meta["phases"] == large_library.statistics.to_dict()
    assert list(meta["phases"]) == ["pore_mean", "pore_std", "grain_mean", "noise_std", "edge_width", "edge_shift",
                                    "edge_sigma", "noise_grain_std", "noise_pore_std", "nps_grains", "nps_pores",
                                    "pore_spectrum", "pore_quantiles", "scan_axis", "cupping_error",
                                    "solid_fraction", "histogram_grains", "histogram_pores",
                                    "histogram_edges", "coordination", "edge_coverage", "semivariogram_grains",
                                    "semivariogram_pores", "edge_steepness",
                                    "band_histograms", "patch_window", "patch_features",
                                    "logistic_floor", "volume_spectra"]  # no scanner artefact
    assert large_library[:2].statistics is large_library.statistics


def test_bad_arguments(large_scan):
    with pytest.raises(SynthpackInputError, match="density"):
        ParticleLibrary.from_scan(large_scan, density=0)
    with pytest.raises(SynthpackInputError, match="workers"):
        ParticleLibrary.from_scan(large_scan, workers=0)


@pytest.mark.parametrize("axis", [0, 2])
def test_exclude_slices_keeps_the_test_block_out_of_the_library(large_scan, axis):
    start, stop = central_block(large_scan.shape[axis])
    library = ParticleLibrary.from_scan(large_scan, workers=1, progress=False, exclude_slices=(start, stop),
                                        axis=axis)
    full = ParticleLibrary.from_scan(large_scan, workers=1, progress=False, target_faces=None)
    assert 0 < len(library) < len(full)
    for particle in library:
        assert particle.bbox[axis + 3] <= start or particle.bbox[axis] >= stop
    # every particle of the full library that stays clear of the block is kept
    clear = {p.label for p in full if p.bbox[axis + 3] <= start or p.bbox[axis] >= stop}
    assert {p.label for p in library} == clear
    # no intensity statistic reads the test block: changing its voxels changes none of them
    block = [slice(None)] * 3
    block[axis] = slice(start, stop)
    scrambled = large_scan.tomogram.copy()
    scrambled[tuple(block)] = np.random.default_rng(0).permutation(scrambled[tuple(block)].ravel()).reshape(
        scrambled[tuple(block)].shape)
    assert measure_source(Scan(scrambled, large_scan.labels), (start, stop), axis) == library.statistics
    assert library.settings["exclude_slices"] == [start, stop]


def test_exclude_slices_must_leave_some_slices(large_scan):
    with pytest.raises(SynthpackInputError, match="central_block"):
        ParticleLibrary.from_scan(large_scan, workers=1, progress=False, exclude_slices=(0, 128))


def test_crops_of_a_cupped_scan_are_cut_with_the_cupping_divided_out(large_scan):
    strength = 0.15
    factor = cupping_factor(large_scan.shape, strength)
    cupped = Scan(large_scan.tomogram * factor, large_scan.labels, voxel_size=large_scan.voxel_size)
    library = ParticleLibrary.from_scan(cupped, workers=1, progress=False, target_faces=200)
    assert library.statistics.cupping_strength == pytest.approx(strength, abs=0.03)

    def level_ratio(scan: Scan, crops) -> float:
        """Median grain level near the axis over that near the rim of the field of view."""
        ny, nx = scan.shape[1:]
        radius = [np.hypot((c.bbox[1] + c.bbox[4]) / 2 - (ny - 1) / 2, (c.bbox[2] + c.bbox[5]) / 2 - (nx - 1) / 2)
                  for c in crops]
        levels = np.array([np.median(c.tomogram[c.mask]) for c in crops])
        inner, outer = np.asarray(radius) < np.percentile(radius, 30), np.asarray(radius) > np.percentile(radius, 70)
        return float(np.median(levels[inner]) / np.median(levels[outer]))

    raw = extract_particles(cupped, min_voxels=50, background=library.statistics.pore_mean)
    assert level_ratio(cupped, raw) < 0.95  # the cupping darkens the grains near the axis
    assert level_ratio(cupped, library) == pytest.approx(level_ratio(large_scan, extract_particles(
        large_scan, min_voxels=50, background=library.statistics.pore_mean)), abs=0.02)
