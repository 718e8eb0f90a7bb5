"""The 3D power spectrum about the slice normal, the filter that matches it, and the calibration's guard of it."""

import numpy as np
import pytest
from scipy import ndimage

from synthpack.artefacts import Compose, GaussianNoise, SpectrumMatch, from_config
from synthpack.artefacts.band_map import BandMap, fit_band_map
from synthpack.artefacts.blockwise import apply_blockwise
from synthpack.artefacts.guard import SPECTRUM_MATCH_STRENGTHS, guard_spectrum_match
from synthpack.artefacts.spectrum_match import MAX_POWER_GAIN, fit_gain
from synthpack.errors import SynthpackInputError
from synthpack.measure.edges import signed_distance
from synthpack.measure.patch_features import LOGISTIC_AUC_MARGIN, PatchReference
from synthpack.measure.phase_histograms import band_quantiles
from synthpack.measure.volume_spectrum import MIN_CUBES, TILE, cube_corners, cylindrical_spectrum, radii


def _noise(shape, seed, sigma=(0.0, 0.0, 0.0), std=1.0):
    field = ndimage.gaussian_filter(np.random.default_rng(seed).normal(size=shape), sigma, mode="wrap")
    return (field * std / field.std()).astype(np.float32)


def test_white_noise_reads_its_variance_at_every_frequency():
    table = cylindrical_spectrum(_noise((64, 80, 80), 0, std=2.0), np.ones((64, 80, 80), bool))
    assert table.shape == (TILE // 2 + 1, radii(TILE)) and table[0, 0] == 0
    # the bins within the slices' circle, away from frequency 0 (which the window's main lobe and each
    # cube's mean removed bias)
    error = np.abs(table[2:, 2:TILE // 2 + 1] / 4.0 - 1)
    assert np.median(error) < 0.05 and np.all(error < 0.3), error


def test_the_table_keeps_a_blur_along_the_slices_apart_from_one_across_them():
    table = cylindrical_spectrum(_noise((64, 80, 80), 1, sigma=(0, 1.2, 1.2)), np.ones((64, 80, 80), bool))
    # smooth within slices, white across them: power falls with the in-slice frequency, not with |f_z|
    assert table[1, 12] < table[1, 2] / 20
    assert table[14, 2] == pytest.approx(table[1, 2], rel=0.3)


def test_cubes_lie_wholly_in_the_region_and_a_small_region_is_read_in_half_cubes():
    region = np.zeros((40, 70, 70), bool)
    region[4:38, 3:69, 3:69] = True
    corners = cube_corners(region)
    assert len(corners) and all(region[z:z + TILE, y:y + TILE, x:x + TILE].all() for z, y, x in corners)
    assert sorted(set(corners[:, 0].tolist())) == [4, 6]  # from the region's first slice, and one flush with its end
    small = np.zeros((30, 30, 30), bool)
    small[2:28, 2:28, 2:28] = True  # no cube of 32; of 16: at 2, 10 and 12 (flush) on each axis
    assert len(cube_corners(small)) == 0 and len(cube_corners(small, TILE // 2)) == 27 >= MIN_CUBES
    table = cylindrical_spectrum(_noise(small.shape, 2), small)
    assert table.shape == (TILE // 4 + 1, radii(TILE // 2))
    assert cylindrical_spectrum(_noise(small.shape, 2), small & (np.indices(small.shape)[1] < 12)) is None


@pytest.mark.parametrize("sigma", [(0.6, 0.6, 0.6), (0.0, 0.8, 0.8), (1.0, 0.0, 0.0)])
def test_the_filter_gives_white_noise_the_target_spectrum(sigma):
    shape, region = (64, 96, 96), np.ones((64, 96, 96), bool)
    target = cylindrical_spectrum(_noise(shape, 3, sigma), region)
    white = _noise(shape, 4)
    before = cylindrical_spectrum(white, region)
    gain = fit_gain(target, before)
    out = SpectrumMatch(gain=gain.ravel().tolist(), level=0.0)(white, 0)
    assert out.dtype == np.float32 and out.shape == shape
    assert float(out.mean()) == pytest.approx(float(white.mean()), abs=1e-3)
    got = cylindrical_spectrum(out, region)
    # where the asked change is within the filter's bounds (and away from the clipped bins' smoothing)
    reachable = ndimage.minimum_filter(target > before * 2 / MAX_POWER_GAIN, size=3)
    reachable[0, 0] = False
    ratio = got[reachable] / target[reachable]
    assert np.median(np.abs(np.log(ratio))) < 0.1 and np.all(np.abs(np.log(ratio)) < 0.5), ratio


def test_the_filter_is_the_same_block_by_block_and_keeps_a_flat_volume_flat():
    shape = (40, 48, 56)
    region = np.ones((64, 64, 64), bool)
    gain = fit_gain(cylindrical_spectrum(_noise((64,) * 3, 5, (0.5, 1.0, 1.0)), region),
                    cylindrical_spectrum(_noise((64,) * 3, 6), region))
    match = SpectrumMatch(gain=gain.ravel().tolist(), level=3.5)
    volume = _noise(shape, 7) + np.linspace(0, 5, shape[2], dtype=np.float32)
    whole = match(volume, 0)
    blocks = np.zeros(shape, np.float32)
    apply_blockwise(Compose([match]), volume, blocks, 0, (16, 20, 24))
    np.testing.assert_allclose(blocks, whole, rtol=0, atol=1e-4)
    np.testing.assert_allclose(match(np.full(shape, 3.5, np.float32), 0), 3.5, atol=1e-5)
    assert from_config(match.to_dict()) == match
    assert match(volume[5], 0).shape == volume[5].shape  # a slice: the kernel summed along z


def test_a_gain_table_of_another_size_is_refused():
    with pytest.raises(SynthpackInputError, match="spectrum_match takes 408 or 117 gains"):
        SpectrumMatch(gain=[1.0] * 100)


def _phantom(noise: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Spheres (100) in pores (20) with `noise`: the intensities and the labels."""
    shape = noise.shape
    rng = np.random.default_rng(11)
    labels = np.zeros(shape, np.int32)
    grid = np.indices(shape)
    for label, centre in enumerate(rng.uniform(6, np.array(shape) - 6, size=(40, 3)), start=1):
        inside = np.sum((grid - centre[:, None, None, None]) ** 2, axis=0) < rng.uniform(4, 7) ** 2
        labels[inside & (labels == 0)] = label
    clean = np.where(labels > 0, 100.0, 20.0).astype(np.float32)
    return ndimage.gaussian_filter(clean, 0.8) + noise, labels


def test_the_guard_applies_the_filter_where_it_brings_the_patches_closer_and_records_why():
    shape = (64, 64, 64)
    region = np.ones(shape, bool)
    source, _ = _phantom(_noise(shape, 8, (0.0, 0.6, 0.6), std=6.0))  # in-slice correlated noise
    pack, labels = _phantom(_noise(shape, 9, std=6.0))  # white noise of the same level
    reference = PatchReference.measure(source, region)
    record = guard_spectrum_match([], pack, labels, region, [cylindrical_spectrum(source, region)],
                                  histograms={}, noise={}, contrast=80.0, patches=reference)
    assert record["status"] == "applied", record["logistic"]
    assert record["logistic"]["with"] <= record["logistic"]["without"] - LOGISTIC_AUC_MARGIN
    assert len(record["gain"]) == (TILE // 2 + 1) * radii(TILE) and record["cubes"] == 27
    assert record["strength"] == 1.0 and [t["strength"] for t in record["tried"]] == [1.0]
    full = np.asarray(record["gain"])
    # the same noise as the source's: nothing to gain, so nothing applied
    same, labels = _phantom(_noise(shape, 10, (0.0, 0.6, 0.6), std=6.0))
    record = guard_spectrum_match([], same, labels, region, [cylindrical_spectrum(source, region)],
                                  histograms={}, noise={}, contrast=80.0, patches=reference)
    assert record["status"] == "dropped"
    assert guard_spectrum_match([], same, labels, region, [cylindrical_spectrum(source, region)], histograms={},
                                noise={}, contrast=80.0, patches=None)["status"] == "not measured"


def test_a_narrow_tube_is_matched_with_the_sources_table_of_half_cubes():
    shape = (64, 64, 64)
    source, _ = _phantom(_noise(shape, 8, (0.0, 0.6, 0.6), std=6.0))
    whole = np.ones(shape, bool)
    tables = [cylindrical_spectrum(source, whole, tile=tile) for tile in (TILE, TILE // 2)]
    # a tube 40 voxels across: no cube of 32 fits in it, cubes of 16 do
    y, x = np.indices(shape[1:]) - 31.5
    tube = np.broadcast_to(np.hypot(y, x) < 20, shape)
    assert len(cube_corners(tube, TILE)) == 0 and len(cube_corners(tube, TILE // 2)) >= MIN_CUBES
    pack, labels = _phantom(_noise(shape, 9, std=6.0))
    reference = PatchReference.measure(source, whole)
    record = guard_spectrum_match([], pack, labels, tube, tables, histograms={}, noise={}, contrast=80.0,
                                  patches=reference)
    assert record["tile"] == TILE // 2 and len(record["gain"]) == (TILE // 4 + 1) * radii(TILE // 2)
    assert record["status"] == "applied", record["logistic"]
    # with the table of 32 alone there is nothing to match it with
    record = guard_spectrum_match([], pack, labels, tube, tables[:1], histograms={}, noise={}, contrast=80.0,
                                  patches=reference)
    assert record["status"] == "not measured" and record["tile"] == TILE and record["cubes"] == 0


def test_the_guard_judges_the_filter_with_the_band_map_refitted_after_it():
    shape = (64, 64, 64)
    region = np.ones(shape, bool)
    source, labels = _phantom(_noise(shape, 8, (0.0, 0.6, 0.6), std=6.0))
    pack, _ = _phantom(_noise(shape, 9, std=6.0))  # the same grains (one geometry), white noise
    distance = signed_distance(labels)
    band_map = fit_band_map(pack, distance, region, band_quantiles(source, distance, region))
    record = guard_spectrum_match([], pack, labels, region, [cylindrical_spectrum(source, region)], histograms={},
                                  noise={}, contrast=80.0, patches=PatchReference.measure(source, region),
                                  band_map=band_map)
    assert record["status"] == "applied", record["logistic"]
    refitted = BandMap.from_dict(record["band_map"])
    assert refitted.bands == band_map.bands and refitted.source == band_map.source and refitted.pack != band_map.pack


def test_the_guard_puts_back_the_noise_level_the_filter_moved_where_the_steps_draw_noise():
    shape = (64, 64, 64)
    region = np.ones(shape, bool)
    source, _ = _phantom(_noise(shape, 8, (0.0, 0.6, 0.6), std=6.0))
    clean, labels = _phantom(np.zeros(shape, np.float32))
    reference, table = PatchReference.measure(source, region), [cylindrical_spectrum(source, region)]
    # the source's noise level read as white noise of 6: the filter to its spectrum takes a third of it away
    judged = {"histograms": {}, "noise": {"grains": 6.0, "pores": 6.0}, "contrast": 80.0, "patches": reference}
    fixed = guard_spectrum_match([GaussianNoise(std=6.0)], clean, labels, region, table, **judged)
    assert fixed["noise_scale"] is None and fixed["figures"]["with"]["noise_grains"] > 0.25
    rescaled = guard_spectrum_match([GaussianNoise(std=6.0)], clean, labels, region, table, **judged,
                                    rescaled=lambda scale: [GaussianNoise(std=6.0 * scale["grains"])])
    assert rescaled["noise_scale"]["grains"] > 1.2  # drawn stronger before the filter
    assert all(t["missed"] == 0 for t in rescaled["tried"]) and rescaled["figures"]["with"]["noise_grains"] < 0.1
