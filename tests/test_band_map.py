"""The band map: a pack's histograms by distance from the boundary mapped onto its source's."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import ndimage

from synthpack.artefacts import ColouredNoise, GaussianNoise, RoundLevels
from synthpack.artefacts.band_map import BandMap, apply_band_map, fit_band_map
from synthpack.artefacts.guard import TARGET, guard_steps
from synthpack.measure.edges import signed_distance
from synthpack.measure.noise_estimate import estimate_noise
from synthpack.measure.spectrum import white_ring_powers
from synthpack.measure.phase_histograms import (
    BAND_KEYS,
    band_of,
    band_quantiles,
    phase_masks,
    phase_quantiles,
    quantile_distance,
)
from synthpack.scan import Scan
from synthpack.source import SourceStatistics, measure_source


def test_bands_are_shells_of_signed_distance_open_at_the_last():
    distance = np.array([-7.3, -4.2, -1.0, -0.5, 0.5, 0.914, 1.23, 4.9, 12.0], dtype=np.float32)
    assert band_of(distance).tolist() == [-5, -5, -1, -1, 1, 1, 2, 5, 5]
    assert BAND_KEYS == (-5, -4, -3, -2, -1, 1, 2, 3, 4, 5)


@pytest.fixture(scope="module")
def halo_source(phantom):
    """The phantom with a bright pore shell (+0.15 within 2 voxels of the grains), noisy: a paste with a transition zone."""
    clean, labels = phantom
    distance = signed_distance(labels)
    shell = ((distance < 0) & (distance >= -2.0)).astype(np.float32)
    source = GaussianNoise(std=0.02)(clean + 0.15 * shell, 1)
    return source, labels, distance


def test_band_quantiles_read_each_shell_of_the_pore_and_grains(halo_source):
    source, labels, distance = halo_source
    bands = band_quantiles(source, distance, np.ones(labels.shape, bool))
    assert set(bands) == set(BAND_KEYS)
    medians = {band: float(np.median(q)) for band, q in bands.items() if q is not None}
    # the shell is 0.15 brighter than the pore beyond it; the grains' interior at the grains' level
    assert medians[-2] - medians[-4] == pytest.approx(0.15, abs=0.03)
    assert medians[5] == pytest.approx(0.8, abs=0.05)


@pytest.fixture(scope="module")
def fitted(phantom, halo_source):
    """A pack of the phantom with the source's noise but no shell, and the band map fitted from it to `halo_source`."""
    clean, labels = phantom
    source, _, distance = halo_source
    region = np.ones(labels.shape, bool)
    pack = GaussianNoise(std=0.02)(clean, 2)
    return pack, fit_band_map(pack, distance, region, band_quantiles(source, distance, region))


def test_a_fitted_band_map_takes_each_band_to_the_source_and_keeps_its_order(halo_source, fitted):
    source, labels, distance = halo_source
    region = np.ones(labels.shape, bool)
    pack, band_map = fitted
    assert band_map is not None and band_map.bands == BAND_KEYS
    assert all(a < b for a, b in zip(band_map.knots[5:], band_map.knots[6:]))  # grain side, nearer first
    mapped = band_map.apply(pack, distance)
    assert mapped.dtype == np.float32 and mapped.shape == pack.shape
    before = band_quantiles(pack, distance, region)
    after = band_quantiles(mapped, distance, region)
    target = band_quantiles(source, distance, region)
    for band in (-5, -2, -1, 1, 5):  # every band comes to the source's (within its blend with the next)
        assert quantile_distance(after[band], target[band]) < 0.3 * quantile_distance(before[band], target[band])
    # monotone within a shell of one distance: neighbours keep their order
    shell = np.isclose(distance, -3.5)
    order = np.argsort(pack[shell], kind="stable")
    assert np.all(np.diff(mapped[shell][order]) >= 0)
    assert BandMap.from_dict(band_map.to_dict()) == band_map


def test_a_band_map_refitted_after_a_later_step_takes_that_steps_output_to_the_source(halo_source, fitted):
    source, labels, distance = halo_source
    region = np.ones(labels.shape, bool)
    pack, band_map = fitted
    changed = 1.5 * pack + 0.1  # a later step (the spectrum match) stretches every shell
    refitted = band_map.refitted(changed, distance, region)
    assert refitted.bands == band_map.bands and refitted.source == band_map.source and refitted.pack != band_map.pack
    target = band_quantiles(source, distance, region)
    stale = band_quantiles(band_map.apply(changed, distance), distance, region)
    fresh = band_quantiles(refitted.apply(changed, distance), distance, region)
    for band in (-5, -2, 1, 5):
        assert quantile_distance(fresh[band], target[band]) < 0.2 * quantile_distance(stale[band], target[band])
    # a band of the map with no voxel in the region: nothing to refit it from
    assert band_map.refitted(changed, distance, region & (distance < 0)) is None


def test_a_band_map_to_the_packs_own_histograms_changes_nothing(phantom):
    clean, labels = phantom
    distance = signed_distance(labels)
    region = np.ones(labels.shape, bool)
    pack = GaussianNoise(std=0.02)(clean, 3)
    band_map = fit_band_map(pack, distance, region, band_quantiles(pack, distance, region))
    np.testing.assert_allclose(band_map.apply(pack, distance), pack, atol=2e-3)


def test_the_band_map_applied_chunk_by_chunk_is_the_whole_volumes(halo_source, fitted):
    _, labels, distance = halo_source
    pack, band_map = fitted
    whole = band_map.apply(pack, distance)
    chunked = pack.copy()
    apply_band_map(band_map, chunked, labels, (8, 16, 16), threads=2)
    np.testing.assert_array_equal(chunked, whole)
    # only the voxels inside are mapped; rounding puts them on whole numbers
    outside = pack.copy() * 100
    inside = lambda lo, hi: np.arange(lo[0], hi[0])[:, None, None] < 16 + np.zeros((1, hi[1] - lo[1], hi[2] - lo[2]))
    apply_band_map(band_map, outside, labels, (8, 16, 16), inside=inside, rounding=RoundLevels())
    np.testing.assert_array_equal(outside[16:], np.round(pack[16:] * 100))
    assert not np.array_equal(outside[:16], np.round(pack[:16] * 100))


def _targets(source, labels):
    region = np.ones(labels.shape, bool)
    distance = signed_distance(labels)
    noise = estimate_noise(source, labels)
    return region, {"histograms": phase_quantiles(source, phase_masks(distance, region)),
                    "noise": {"grains": noise.grain_std, "pores": noise.pore_std}, "contrast": 0.6,
                    "bands": band_quantiles(source, distance, region)}


def test_the_guard_fits_a_band_map_where_a_phase_histogram_misses_its_target(phantom, halo_source):
    clean, labels = phantom
    source, _, _ = halo_source
    region, targets = _targets(source, labels)
    steps = {"noise": GaussianNoise(std=0.02)}
    kept, record = guard_steps(lambda kept: [steps[s] for s in kept], ("noise",), clean, labels, region, **targets)
    assert kept == ("noise",)
    figures = record["figures"]
    assert figures["applied"]["w_edges"] > TARGET["w_edges"]  # the bright shell is missing
    assert record["band_map_status"] == "applied"
    assert figures["band_mapped"]["w_edges"] < TARGET["w_edges"] < figures["applied"]["w_edges"]
    assert BandMap.from_dict(record["band_map"]).bands
    noise = estimate_noise(clean, labels)  # the region is the whole phantom: the counts of its interiors
    assert record["noise_voxels"] == {"grains": noise.n_grain, "pores": noise.n_pore}


def test_the_guard_fits_no_band_map_where_the_histograms_meet_their_targets(phantom):
    clean, labels = phantom
    source = GaussianNoise(std=0.02)(clean, 1)
    region, targets = _targets(source, labels)
    steps = {"noise": GaussianNoise(std=0.02)}
    _, record = guard_steps(lambda kept: [steps[s] for s in kept], ("noise",), clean, labels, region, **targets)
    assert record["band_map_status"] == "not needed" and record["band_map"] is None
    assert "band_mapped" not in record["figures"]
    _, record = guard_steps(lambda kept: [steps[s] for s in kept], ("noise",), clean, labels, region,
                            **{**targets, "bands": None})
    assert record["band_map_status"] == "not measured"


def test_the_source_statistics_keep_their_band_histograms(halo_source):
    source, labels, _ = halo_source
    statistics = measure_source(Scan(source, labels))
    assert len(statistics.band_histograms) == len(BAND_KEYS)
    assert all(q is None or len(q) == 200 for q in statistics.band_histograms)
    assert SourceStatistics.from_dict(statistics.to_dict()) == statistics



def test_the_guard_scales_the_noise_down_where_the_band_map_stretches_it(phantom):
    """The source's pores hold more structure than the pack's: the map stretches the pack's pores, their noise
    with them; the guard then draws the noise weaker, so that after the map it is the source's again."""
    clean, labels = phantom

    def field(seed: int) -> np.ndarray:  # smooth structure, unit spread: no noise to second differences
        smooth = ndimage.gaussian_filter(np.random.default_rng(seed).standard_normal(clean.shape), 2.0)
        return (smooth / smooth.std()).astype(np.float32)

    pores = labels == 0
    source = GaussianNoise(std=0.02)(clean + 0.2 * field(1) * pores, 1)
    pack = clean + 0.12 * field(2) * pores
    region, targets = _targets(source, labels)

    def noise(scale):  # white noise of 0.02 in each phase, each phase's amplitude scaled apart
        power = {phase: white_ring_powers((0.02 * scale[phase]) ** 2, 6) for phase in scale}
        return [ColouredNoise(pore_power=power["pores"], grain_power=power["grains"], pore_level=0.2, grain_level=0.8)]

    kept, plain = guard_steps(lambda kept: noise({"grains": 1.0, "pores": 1.0}) if kept else [], ("noise",), pack, labels, region,
                              **targets)
    _, rescaled = guard_steps(lambda kept: noise({"grains": 1.0, "pores": 1.0}) if kept else [], ("noise",), pack, labels, region,
                              **targets, rescaled=lambda kept, scale: noise(scale) if kept else None)
    # the map alone fixes the pore histogram and puts the pore noise beyond its target: no fewer targets missed
    assert plain["band_map_status"] == "dropped" and plain["noise_scale"] is None
    assert plain["figures"]["applied"]["w_pores"] > TARGET["w_pores"]
    assert rescaled["band_map_status"] == "applied" and rescaled["noise_scale"]["pores"] < 0.9
    assert all(value <= TARGET[name] for name, value in rescaled["figures"]["band_mapped"].items())


def test_a_map_of_one_side_keeps_the_other_sides_values():
    both = BandMap(bands=(-2, -1, 1, 2), knots=(2.0, 1.0, 1.0, 2.0), pack=((0.0, 1.0),) * 4,
                   source=((0.0, 2.0),) * 4)  # every shell stretched twice
    values, distance = np.full(4, 0.5), np.array([-2.0, -1.0, 1.0, 2.0])
    assert both.apply(values, distance).tolist() == [1.0, 1.0, 1.0, 1.0]
    assert both.side(-1).bands == (-2, -1) and both.side(-1).apply(values, distance).tolist() == [1.0, 1.0, 0.5, 0.5]
    assert both.side(1).apply(values, distance).tolist() == [0.5, 0.5, 1.0, 1.0]
    assert BandMap(bands=(1,), knots=(1.0,), pack=((0.0, 1.0),), source=((0.0, 2.0),)).side(-1) is None


def test_the_guard_maps_the_pores_alone_where_a_map_of_both_sides_stretches_the_grains_noise(phantom, halo_source):
    """The source's grains differ from grain to grain, its pores hold a bright shell: a map of both sides spreads
    each of the pack's grains over all the source's grain levels (their noise with them, beyond no
    post-processing's), so the pores' map alone is taken, and the grains keep their values."""
    clean, labels = phantom
    source, _, distance = halo_source
    offsets = np.array([0.0, -0.12, 0.0, 0.12], dtype=np.float32)  # grain 1 at the level, 2 darker, 3 brighter
    source = source + offsets[labels] * (distance > 0)
    region, targets = _targets(source, labels)
    steps = {"noise": GaussianNoise(std=0.02)}
    kept, record = guard_steps(lambda kept: [steps[s] for s in kept], ("noise",), clean, labels, region, **targets)
    assert kept == ("noise",) and record["band_map_status"] == "applied"
    assert all(band < 0 for band in record["band_map"]["bands"])  # the pores' shells only
    figures = record["figures"]
    assert figures["band_mapped"]["w_edges"] < figures["applied"]["w_edges"]  # the shell is there
    assert figures["band_mapped"]["noise_grains"] == figures["applied"]["noise_grains"]  # the grains untouched
    both = fit_band_map(steps["noise"](clean, 0), distance, region, targets["bands"])
    assert any(band > 0 for band in both.bands)  # a map of both sides was there to take
