"""Tests of synthpack.artefacts.recipes: what every ``postprocess`` value resolves to, and the bulk region."""

from __future__ import annotations

import dataclasses
import logging

import numpy as np
import pytest
from scipy import ndimage

from synthpack.artefacts import recipes as postprocess_module
from synthpack.artefacts import (ColouredNoise, GaussianBlur, GaussianNoise, RoundLevels, calibrate,
                                 generic_postprocessing)
from synthpack.artefacts.calibrate import Calibration, _clean_ring_powers
from synthpack.artefacts.calibration_region import MIN_CALIBRATION_SLICES, central_slices, measured_slices
from synthpack.artefacts.guard import TOLERANCE, guard_steps
from synthpack.errors import SynthpackInputError
from synthpack.artefacts.recipes import (POSTPROCESS_MODES, _calibration_targets, bulk_region, check_postprocess,
                                        resolve_postprocessing)
from synthpack.render import Grid
from synthpack.measure import estimate_noise, fit_edge_spread, phase_masks, phase_quantiles, phase_spectra
from synthpack.scan.core import Scan
from synthpack.source import SourceStatistics, measure_source
from synthpack.measure.edges import edge_profile, interior_depth, signed_distance
from synthpack.measure.specimen import specimen_mask
from synthpack.measure.steepness import edge_steepness
from synthpack.measure.semivariogram import phase_semivariograms
from synthpack.artefacts.coloured_noise import TEXTURE_SIGMAS
from synthpack.measure.spectrum import white_ring_powers
from synthpack.measure.volume_spectrum import cylindrical_spectrum

STATISTICS = SourceStatistics(pore_mean=0.2, pore_std=0.01, grain_mean=0.8, noise_std=0.05, edge_width=3.0,
                              edge_shift=0.0, edge_sigma=1.2, nps_grains=(1e-4,) * 6, nps_pores=(1e-4,) * 6)
#: A bulk sub-cylinder holding the whole phantom.
EVERYWHERE = {"radius": 1e3, "z_min": -1e3, "z_max": 1e3}


@pytest.fixture(scope="module")
def rendered(phantom):
    """The phantom as a clean pack with a little noise of its own (std 0.01), on a grid centred on the axis."""
    clean, labels = phantom
    grid = Grid(clean.shape, (0.0, -32.0, -32.0), (1.0, 1.0, 1.0))
    return GaussianNoise(std=0.01)(clean, 0), labels, grid


def _resolve(postprocess, rendered, statistics=STATISTICS):
    clean, labels, grid = rendered
    return resolve_postprocessing(postprocess, statistics, clean=clean, labels=labels, grid=grid,
                                  packing_region=EVERYWHERE)


@pytest.fixture
def fresh_warnings():
    """Forget which warnings were logged (each is logged once per process)."""
    postprocess_module._warn_once.cache_clear()
    yield
    postprocess_module._warn_once.cache_clear()


@pytest.mark.parametrize("contrast", [0.6, -0.6])
def test_generic_is_the_generic_pipeline_scaled_to_the_source_contrast_of_either_sign(rendered, contrast):
    statistics = dataclasses.replace(STATISTICS, grain_mean=STATISTICS.pore_mean + contrast)
    resolved = _resolve("generic", rendered, statistics)
    assert resolved.pipeline.to_config() == generic_postprocessing(contrast=abs(statistics.contrast)).to_config()
    assert resolved.record == {"postprocess_mode": "generic"}


@pytest.mark.parametrize("postprocess", ["none", []])
def test_none_and_an_empty_list_do_nothing(rendered, postprocess):
    resolved = _resolve(postprocess, rendered)
    assert len(resolved.pipeline) == 0
    assert resolved.record == {"postprocess_mode": "none" if postprocess == "none" else "custom"}
    np.testing.assert_array_equal(resolved.pipeline(rendered[0], 0), rendered[0])


def test_a_list_is_built_as_given(rendered):
    steps = [{"name": "gaussian_blur", "sigma": [0.5, 1.0]}, {"name": "gaussian_noise", "std": 0.02}]
    resolved = _resolve(steps, rendered)
    assert [step["name"] for step in resolved.pipeline.to_config()] == ["gaussian_blur", "gaussian_noise"]
    assert resolved.pipeline[0].sigma == pytest.approx((0.5, 1.0)) and resolved.pipeline[1].std == 0.02
    assert resolved.record == {"postprocess_mode": "custom"}


def test_match_source_reaches_the_source_noise_level_and_records_it(rendered):
    clean, labels, _ = rendered
    resolved = _resolve("match_source", rendered)
    (noise,) = resolved.pipeline
    assert isinstance(noise, GaussianNoise)
    assert noise.std == pytest.approx(np.sqrt(0.05**2 - 0.01**2), rel=0.05)  # variances add
    assert estimate_noise(resolved.pipeline(clean, 1), labels).std == pytest.approx(0.05, rel=0.05)
    assert resolved.record["postprocess_mode"] == "match_source"
    match = resolved.record["noise_match"]
    assert match["target_noise"] == 0.05 and match["noise_std"] == noise.std
    assert match["clean_noise"] == pytest.approx(0.01, rel=0.1)
    assert "postprocess_fallback" not in resolved.record


def test_calibrated_fits_the_psf_and_the_noise_spectrum_to_the_source_and_records_the_fit(rendered):
    clean, labels, _ = rendered
    distance = signed_distance(labels)
    spread = fit_edge_spread(edge_profile(clean, distance))
    spectra = phase_spectra(clean, distance)
    # softer edges, 4x the noise power of the clean pack in every ring, twice its noise level
    level = 2 * estimate_noise(clean, labels).std
    target = dataclasses.replace(STATISTICS, edge_sigma=spread.sigma + 0.4, edge_shift=spread.shift,
                                 nps_grains=tuple(4 * spectra["grains"].power[1:]),
                                 nps_pores=tuple(4 * spectra["pores"].power[1:]),
                                 noise_grain_std=level, noise_pore_std=level)
    resolved = _resolve("calibrated", rendered, target)
    assert resolved.record["postprocess_mode"] == "calibrated"
    fit = resolved.record["calibration"]
    assert fit["target_sigma"] == target.edge_sigma and fit["target_shift"] == target.edge_shift
    assert fit["blur_sigma"] > 0 and fit["edge_sigma"] == pytest.approx(target.edge_sigma, abs=0.05)
    blur, noise = resolved.pipeline
    assert isinstance(noise, ColouredNoise) and blur.sigma == fit["blur_sigma"]
    assert list(noise.pore_power) == fit["added_power"]["pores"]
    out = resolved.pipeline(clean, 1)
    for phase, spectrum in phase_spectra(out, distance).items():  # rings 0.125 to 0.5 cycles/voxel
        ratio = spectrum.power[1:5] / np.asarray(fit["target_power"][phase])[:4]
        assert np.all((ratio > 0.7) & (ratio < 1.4)), (phase, ratio)
    assert fit_edge_spread(edge_profile(out, distance)).sigma == pytest.approx(target.edge_sigma, abs=0.1)
    noise = estimate_noise(out, labels)
    assert (noise.grain_std, noise.pore_std) == (pytest.approx(level, rel=0.1), pytest.approx(level, rel=0.1))


def test_central_slices_keep_at_most_the_asked_voxels_of_a_region_centred_in_its_slices():
    region = np.zeros((70, 8, 8), dtype=bool)
    region[5:65, 2:6, 2:6] = True  # 60 slices of 16 voxels
    assert central_slices(region, 10_000) is region
    kept = central_slices(region, 640)  # 40 slices, at least MIN_CALIBRATION_SLICES
    assert np.count_nonzero(kept) == 640 and not np.any(kept & ~region)
    assert np.flatnonzero(kept.any(axis=(1, 2))).tolist() == list(range(15, 55))
    assert np.count_nonzero(central_slices(region, 1)) == 1  # at least one slice of a central square
    wide = np.zeros((40, 300, 300), dtype=bool)
    wide[5:35, 10:290, 10:290] = True  # 30 slices of 78,400 voxels: one slice would be 78% of the bound
    kept = central_slices(wide, 100_000)
    slices = np.flatnonzero(kept.any(axis=(1, 2)))
    assert len(slices) >= min(30, MIN_CALIBRATION_SLICES) and np.count_nonzero(kept) <= 100_000
    assert not np.any(kept & ~wide)
    rows = np.flatnonzero(kept.any(axis=(0, 2)))
    assert abs((rows[0] + rows[-1]) / 2 - 149.5) <= 1  # about the lateral centre


@pytest.mark.parametrize("shape, max_voxels", [((60, 20, 20), 10_000), ((60, 20, 20), 1_000),
                                               ((50, 301, 301), 100_000), ((9, 40, 40), 50)])
def test_measured_slices_are_those_central_slices_keeps_of_the_whole_region(shape, max_voxels):
    """A big pack's calibration reads only these slices of the bulk (never the (Z, Y, X) mask)."""
    y, x = np.mgrid[:shape[1], :shape[2]]
    in_slice = np.hypot(y - shape[1] / 2, x - shape[2] / 2) < shape[1] / 2 - 2
    in_slices = np.zeros(shape[0], dtype=bool)
    in_slices[3:shape[0] - 1] = True
    kept = central_slices(in_slices[:, None, None] & in_slice[None], max_voxels)
    slices = np.flatnonzero(kept.any(axis=(1, 2)))
    assert measured_slices(in_slices, in_slice, max_voxels) == (slices[0], slices[-1] + 1)


def test_calibrated_on_central_slices_fits_what_the_whole_region_fits(rendered):
    clean, labels, _ = rendered
    spread = fit_edge_spread(edge_profile(clean, signed_distance(labels)))
    region = np.ones(clean.shape, dtype=bool)
    targets = dict(target_sigma=spread.sigma + 0.4, target_shift=spread.shift, target_power={
        "grains": (1e-4,) * 6, "pores": (1e-4,) * 6}, target_phase_noise={"grains": 0.05, "pores": 0.05},
        target_edge_width=3.0, target_noise=0.05, pore_level=0.2, grain_level=0.8)
    whole = calibrate(clean, labels, region, max_voxels=region.size, **targets)
    half = calibrate(clean, labels, region, max_voxels=region.size // 2, **targets)
    assert half.blur_sigma == pytest.approx(whole.blur_sigma, abs=0.05)
    assert half.noise_std == pytest.approx(whole.noise_std, rel=0.05)


def test_calibrated_fits_darker_grains_as_it_fits_brighter_ones(rendered):
    clean, labels, _ = rendered
    spread = fit_edge_spread(edge_profile(clean, signed_distance(labels)))
    inverted = (1.0 - clean).astype(np.float32)  # grains 0.2, pores 0.8
    statistics = dataclasses.replace(STATISTICS, edge_sigma=spread.sigma + 0.4, edge_shift=spread.shift)
    brighter = _resolve("calibrated", rendered, statistics).record["calibration"]
    darker_statistics = dataclasses.replace(statistics, pore_mean=0.8, grain_mean=0.2)
    darker = _resolve("calibrated", (inverted, *rendered[1:]), darker_statistics).record["calibration"]
    assert darker["blur_sigma"] == pytest.approx(brighter["blur_sigma"], abs=1e-3)
    assert darker["edge_sigma"] == pytest.approx(brighter["edge_sigma"], abs=1e-3)


def test_a_phase_without_a_measured_spectrum_gets_white_noise_at_its_own_level(rendered):
    # e.g. a cement paste's spectrum holds its sand and voids: not the noise of the aggregates
    statistics = dataclasses.replace(STATISTICS, nps_grains=None, noise_grain_std=0.02, noise_pore_std=0.03)
    fit = _resolve("calibrated", rendered, statistics).record["calibration"]
    np.testing.assert_allclose(fit["target_power"]["grains"], white_ring_powers(0.02**2, 6))
    assert fit["target_power"]["pores"] == list(STATISTICS.nps_pores)


def test_a_scan_with_no_phase_wide_enough_for_a_spectrum_is_still_calibrated_with_white_noise(rendered):
    # small grains and narrow pores (a finer sand at a coarser voxel): the blur is fitted all the same
    statistics = dataclasses.replace(STATISTICS, nps_grains=None, nps_pores=None, noise_grain_std=0.02,
                                     noise_pore_std=None)
    resolved = _resolve("calibrated", rendered, statistics)
    fit = resolved.record["calibration"]
    assert resolved.record["postprocess_mode"] == "calibrated" and "postprocess_fallback" not in resolved.record
    assert fit["blur_sigma"] > 0 and "gaussian_blur" in [t.name for t in resolved.pipeline]
    for phase in ("grains", "pores"):  # the pores take the grains' level
        np.testing.assert_allclose(fit["target_power"][phase], white_ring_powers(0.02**2, 6))


def test_the_clean_spectrum_of_a_phase_too_thin_for_a_patch_is_white_noise_plus_the_pore_texture():
    texture = np.full((16, 16, 16), 2.0)  # a white texture of variance 2
    np.testing.assert_allclose(_clean_ring_powers(None, 6, 1.0, texture), white_ring_powers(3.0, 6))
    np.testing.assert_allclose(_clean_ring_powers(None, 6, None, None), np.zeros(6))


def test_calibrated_falls_back_to_match_source_with_a_warning_when_it_cannot_be_fitted(
        rendered, fresh_warnings, caplog):
    unmeasured = dataclasses.replace(STATISTICS, edge_width=None)
    with caplog.at_level(logging.WARNING, logger="synthpack.artefacts.recipes"):
        for postprocess in [*POSTPROCESS_MODES, []]:
            check_postprocess(postprocess, unmeasured)  # nothing refused
        resolved = _resolve("calibrated", rendered, unmeasured)
        randomised = _resolve("randomised", rendered, unmeasured)
    warning, randomised_warning = [r.getMessage() for r in caplog.records]  # once each, though checked and resolved
    assert "calibrated cannot be fitted" in warning and "edge width" in warning and "match_source" in warning
    assert "randomised cannot be fitted" in randomised_warning
    assert randomised.record["postprocess_mode"] == "randomised" and "edge width" in randomised.record[
        "postprocess_fallback"]
    assert randomised.record["randomised"]["centre"]["noise_std"] == resolved.record["noise_match"]["noise_std"]
    assert "gaussian_noise" in [t.name for t in randomised.pipeline]
    assert resolved.record["postprocess_mode"] == "match_source"
    assert "edge width" in resolved.record["postprocess_fallback"]
    assert [t.name for t in resolved.pipeline] == ["gaussian_noise"]
    assert resolved.pipeline.to_config() == _resolve("match_source", rendered, unmeasured).pipeline.to_config()



def test_calibrated_on_a_pack_without_a_bulk_says_so_and_how_many_grains_would_give_one(
        rendered, fresh_warnings, caplog):
    # the pour's region of a pack of 20 grains 2.5 grain diameters (of 10) deep: its top at 25,
    # its bulk from 10 (one diameter above the floor) to 5 (two below the top), empty
    clean, labels, grid = rendered
    region = {"radius": 30.0, "z_min": 10.0, "z_max": 5.0}
    with caplog.at_level(logging.WARNING, logger="synthpack.artefacts.recipes"):
        shallow = resolve_postprocessing("calibrated", STATISTICS, clean=clean, labels=labels, grid=grid,
                                         packing_region=region, n_grains=20)
    (warning,) = [r.getMessage() for r in caplog.records]
    assert shallow.record["postprocess_mode"] == "match_source"
    assert shallow.record["postprocess_fallback"] in warning and "\n" not in warning
    assert "calibrated cannot be fitted (no bulk region: 2.5 diameters deep, a bulk needs > 3" in warning
    # a pack 4 diameters deep has a bulk 1 deep: 20 * 4 / 2.5 grains
    assert "pour ~32: --n-particles 32 (pour.n_particles)" in warning
    unknown = resolve_postprocessing("calibrated", STATISTICS, clean=clean, labels=labels, grid=grid,
                                     packing_region=region)  # no count given: "more grains"
    assert "pour more grains: --n-particles" in unknown.record["postprocess_fallback"]
    narrow = resolve_postprocessing("calibrated", STATISTICS, clean=clean, labels=labels, grid=grid,
                                    packing_region={"radius": -1.0, "z_min": 10.0, "z_max": 50.0}, n_grains=20)
    assert "too narrow" in narrow.record["postprocess_fallback"] and "--tube-radius" in narrow.record[
        "postprocess_fallback"]


def test_an_unknown_mode_is_refused(rendered):
    for check in (lambda: _resolve("fancy", rendered), lambda: check_postprocess("fancy", STATISTICS)):
        with pytest.raises(SynthpackInputError, match="postprocess must be one of calibrated, match_source, generic"):
            check()
    with pytest.raises(SynthpackInputError, match="must be one of"):
        _resolve("default", rendered)  # the deprecated name is the config's to read, not a mode


def test_bulk_region_is_the_pour_sub_cylinder():
    # a cylinder of radius 8 from z = 2 to 7 on a grid centred on the axis, 1-unit voxels
    shape = (10, 21, 21)
    cylinder = bulk_region(shape, (0.0, -10.0, -10.0), (1.0, 1.0, 1.0), {"radius": 8.0, "z_min": 2.0, "z_max": 7.0})
    assert cylinder.sum() == pytest.approx(6 * np.pi * 64, rel=0.05)
    assert not cylinder[:2].any() and not cylinder[8:].any()
    with pytest.raises(SynthpackInputError, match="no bulk"):
        bulk_region(shape, (0.0, -10.0, -10.0), (1.0, 1.0, 1.0), {"radius": 1.0, "z_min": 2.0, "z_max": 3.0})


def test_calibrated_adds_the_source_cupping_and_rings_about_the_tube_axis_and_records_them(rendered):
    scanner = dataclasses.replace(STATISTICS, cupping_strength=0.05, cupping_error=0.01, ring_radii=(10.0, 20.0),
                                  ring_amplitudes=(0.03, -0.02), ring_width=1.5)
    plain, resolved = _resolve("calibrated", rendered), _resolve("calibrated", rendered, scanner)
    assert len(plain.pipeline) == 2  # a source without artefacts: blur and noise only
    fit = resolved.record["calibration"]
    assert fit["cupping_strength"] == 0.05 and fit["ring_radii"] == [10.0, 20.0]
    assert fit["ring_amplitudes"] == [0.03, -0.02] and fit["ring_width"] == 1.5
    *_, cupping, rings = resolved.pipeline
    assert cupping.strength == 0.05 and rings.radii == (10.0, 20.0) and rings.amplitudes == (0.03, -0.02)
    clean = rendered[0]
    difference = rings(clean, 0) - clean  # about the slice centre, (31.5, 31.5): the pack's tube axis
    sigma = 1.5 / (2 * np.sqrt(2 * np.log(2)))
    for (y, x), ring, peak in (((31, 21), 10.0, 0.03), ((52, 31), 20.0, -0.02)):
        r = np.hypot(y - 31.5, x - 31.5)
        assert difference[16, y, x] == pytest.approx(peak * np.exp(-0.5 * ((r - ring) / sigma) ** 2), abs=1e-3)
    factor = cupping(np.ones_like(clean), 0)[16]
    # the pack's levels are the source's averages already: the factor keeps the mean in the field of view
    assert factor[31, 31] == pytest.approx(0.95 / 0.975, abs=0.002)
    assert factor[np.hypot(*np.indices(factor.shape) - 31.5) < 32].mean() == pytest.approx(1.0, abs=0.003)


@pytest.fixture(scope="module")
def source_statistics(phantom):
    """A source of the phantom's structure: blurred once more, white noise of std 0.02 (its ripple is no cupping)."""
    clean, labels = phantom
    source = GaussianNoise(std=0.02)(GaussianBlur(sigma=0.8)(clean, 0), 1)
    statistics = measure_source(Scan(source, labels))
    # the edges' steepness over the whole volume, where the pack is calibrated (EVERYWHERE), not in the specimen
    return dataclasses.replace(statistics, cupping_strength=None, ring_radii=None, ring_amplitudes=None,
                               ring_width=None, edge_steepness=tuple(edge_steepness(source, np.ones_like(labels, bool))))


def test_the_guard_keeps_steps_that_make_the_pack_like_its_source(rendered, source_statistics):
    resolved = _resolve("calibrated", rendered, source_statistics)
    guard = resolved.record["calibration"]["guard"]
    assert [t.name for t in resolved.pipeline] == ["gaussian_blur", "coloured_noise"]  # the blur, both phases' noise
    # the phantom's ripple reads as a cupping, and the grain texture read with it divided out is not the pack's
    assert guard["dropped"] == ["grain_texture"]
    figures = guard["figures"]
    assert set(figures["none"]) == {"w_grains", "w_pores", "w_edges", "noise_grains", "noise_pores"}
    for name, value in figures["applied"].items():  # no less like the source than no post-processing
        assert value <= figures["none"][name] + TOLERANCE[name], name
    for phase in ("grains", "pores"):  # and the noise within 10 % of the source's, where the clean pack has half
        assert figures["applied"][f"noise_{phase}"] < 0.1 < 0.4 < figures["none"][f"noise_{phase}"]
    assert figures["applied"]["w_grains"] < figures["none"]["w_grains"] - TOLERANCE["w_grains"]
    assert guard["logistic"]["applied"] < guard["logistic"]["none"] - 0.05  # the patches look more alike too


def test_a_noise_scale_scales_each_phases_noise_amplitude_alone(rendered, source_statistics):
    fit = _resolve("calibrated", rendered, source_statistics).record["calibration"]
    calibration = Calibration(**fit)
    steps = ("grain_noise", "pore_noise")
    (plain,) = calibration.transforms(steps)
    (scaled,) = calibration.transforms(steps, {"grains": 1.0, "pores": 0.5})
    np.testing.assert_allclose(scaled.pore_power, 0.25 * np.asarray(plain.pore_power))
    assert list(scaled.grain_power) == list(plain.grain_power)
    if plain.pore_std is not None:
        assert scaled.pore_std == pytest.approx(0.5 * plain.pore_std)
    calibration.noise_scale = {"grains": 1.0, "pores": 0.5}  # what the pack's pipeline applies
    noise = next(t for t in calibration.pipeline() if t.name == "coloured_noise")
    unscaled = next(t for t in calibration.transforms(calibration.applied_steps()) if t.name == "coloured_noise")
    np.testing.assert_allclose(noise.pore_power, 0.25 * np.asarray(unscaled.pore_power))


def test_the_spectrum_match_is_judged_recorded_and_applied_after_the_steps(phantom, rendered, source_statistics):
    clean, labels = phantom  # the source's spectrum, read in cubes of 16 over its whole volume (its specimen is small)
    source = GaussianNoise(std=0.02)(GaussianBlur(sigma=0.8)(clean, 0), 1)
    spectrum = cylindrical_spectrum(source, np.ones(source.shape, bool), tile=16)
    statistics = dataclasses.replace(source_statistics, volume_spectra=(tuple(map(tuple, spectrum)),))
    fit = _resolve("calibrated", rendered, statistics).record["calibration"]
    match = fit["spectrum_match"]  # fitted on the pack's slices and judged there
    assert match["status"] in ("applied", "dropped") and len(match["gain"]) == 117 and match["tile"] == 16
    assert set(match["logistic"]) == {"without", "with"} and set(match["figures"]) == {"without", "with"}
    calibration = Calibration(**{**fit, "spectrum_match": {**match, "status": "applied"}, "grey_levels": [1.0, 0.0]})
    names = [t.name for t in calibration.pipeline()]
    assert names[-2:] == ["spectrum_match", "round_levels"] and names.index("coloured_noise") < len(names) - 2
    without = Calibration(**{**fit, "spectrum_match": None})
    assert "spectrum_match" not in [t.name for t in without.pipeline()]


def test_the_guard_drops_a_noise_step_fitted_to_structure_and_records_it(rendered, source_statistics, caplog):
    # the source's pore noise 30 times too strong in the two lowest rings, as a patch estimate that
    # counts the pores' structure as noise makes it (the noise fitted alone: no texture measured)
    wrong = dataclasses.replace(source_statistics, nps_pores=tuple(
        p * (30 if k < 2 else 1) for k, p in enumerate(source_statistics.nps_pores)),
        semivariogram_grains=None, semivariogram_pores=None)
    with caplog.at_level(logging.WARNING, logger="synthpack.artefacts.guard"):
        resolved = _resolve("calibrated", rendered, wrong)
    fit = resolved.record["calibration"]
    # without the pore noise, the blur alone would make the pores' noise level less like the source's
    assert fit["guard"]["dropped"] == ["blur", "pore_noise"]
    assert "the pore_noise step is dropped" in caplog.text
    (noise,) = resolved.pipeline
    assert not any(noise.pore_power) and list(noise.grain_power) == fit["added_power"]["grains"]
    assert any(fit["added_power"]["pores"])  # the fitted values are kept in the record
    figures = fit["guard"]["figures"]
    assert figures["fitted"]["w_pores"] > figures["none"]["w_pores"] + TOLERANCE["w_pores"]
    assert all(figures["applied"][name] <= figures["none"][name] + TOLERANCE[name] for name in figures["none"])


@pytest.fixture
def guarded(phantom):
    """The phantom (clean), its labels, a whole-volume region, and the figures of a source with white noise of 0.02."""
    clean, labels = phantom
    source = GaussianNoise(std=0.02)(clean, 1)
    region = np.ones(labels.shape, dtype=bool)
    noise = estimate_noise(source, labels)
    targets = {"histograms": phase_quantiles(source, phase_masks(signed_distance(labels), region)),
               "noise": {"grains": noise.grain_std, "pores": noise.pore_std}, "contrast": 0.6}
    return clean, labels, region, targets


def test_the_guard_applies_the_admissible_steps_most_like_the_source(guarded):
    clean, labels, region, targets = guarded
    steps = {"blur": GaussianBlur(sigma=2.0), "noise": GaussianNoise(std=0.02), "loud": GaussianNoise(std=0.1),
             "idle": GaussianNoise(std=0.0)}

    def build(kept):
        return [steps[name] for name in kept]

    kept, record = guard_steps(build, ("blur", "noise", "loud", "idle"), clean, labels, region, **targets)
    assert kept == ("noise", "idle")  # a step that changes nothing is no worse
    assert record["dropped"] == ["blur", "loud"]  # the wide blur and the loud noise make the pack less alike
    kept, record = guard_steps(build, ("blur",), clean, labels, region, **targets)
    assert kept == () and record["figures"]["applied"] == record["figures"]["none"]


def test_the_guard_drops_a_texture_and_keeps_the_noise_it_refines(guarded):
    """A step that needs another (a phase's texture needs its noise) is tried only with it, and dropped alone."""
    clean, labels, region, targets = guarded
    # the "texture" replaces the noise by a far louder one: worse than the noise alone
    steps = {"noise": [GaussianNoise(std=0.02)], "noise+texture": [GaussianNoise(std=0.1)]}
    built = []

    def build(kept):
        built.append(kept)
        return steps["noise+texture" if "texture" in kept else "noise"] if "noise" in kept else []

    kept, record = guard_steps(build, ("noise", "texture"), clean, labels, region, **targets,
                               requires={"texture": "noise"})
    assert kept == ("noise",) and record["dropped"] == ["texture"]
    assert ("texture",) not in built and ("noise", "texture") in built


def _randomised(rendered, seed):
    clean, labels, grid = rendered
    resolved = resolve_postprocessing("randomised", STATISTICS, clean=clean, labels=labels, grid=grid,
                                      packing_region=EVERYWHERE, seed=seed)
    return resolved, resolved.pipeline(clean, seed)


def test_randomised_is_seeded_and_differs_between_packs(rendered):
    first, image = _randomised(rendered, 1)
    again, image_again = _randomised(rendered, 1)
    other, other_image = _randomised(rendered, 2)
    assert first.record == again.record and image.tobytes() == image_again.tobytes()
    assert first.record["postprocess_mode"] == "randomised"
    assert first.record["randomised"]["drawn"] != other.record["randomised"]["drawn"]
    assert image.tobytes() != other_image.tobytes()


def test_randomised_draws_within_its_ranges_about_the_calibrated_values(rendered):
    calibrated = _resolve("calibrated", rendered).record["calibration"]
    ranges = postprocess_module.RANDOMISED_RANGES
    for seed in range(6):
        record = _randomised(rendered, seed)[0].record["randomised"]
        drawn, centre = record["drawn"], record["centre"]
        assert centre["blur_sigma"] == pytest.approx(calibrated["blur_sigma"])
        assert centre["noise_std"] == pytest.approx(calibrated["noise_std"])
        steps = {step["name"]: step for step in record["pipeline"]}
        assert set(steps) == {"gaussian_blur", "coloured_noise" if not drawn["white_noise"] else "gaussian_noise",
                              "beam_hardening", "ring_artefacts", "contrast_gamma"}
        low, high = ranges["blur_factor"]
        base = max(centre["blur_sigma"], ranges["min_blur"])
        assert low * base <= steps["gaussian_blur"]["sigma"] <= high * base
        assert ranges["contrast"][0] <= steps["contrast_gamma"]["contrast"] <= ranges["contrast"][1]
        assert ranges["gamma"][0] <= steps["contrast_gamma"]["gamma"] <= ranges["gamma"][1]
        if drawn["white_noise"]:
            assert steps["gaussian_noise"]["std"] == pytest.approx(drawn["noise_factor"] * centre["noise_std"])


def test_contrast_gamma_keeps_the_levels_with_gamma_and_stretches_about_their_midpoint():
    from synthpack.artefacts import ContrastGamma

    image = np.array([[0.2, 0.5, 0.8]], np.float32)
    bent = ContrastGamma(gamma=2.0, pore_level=0.2, grain_level=0.8)(image, 0)
    assert bent == pytest.approx(np.array([[0.2, 0.2 + 0.6 * 0.25, 0.8]]), abs=1e-6)
    stretched = ContrastGamma(contrast=1.5, pore_level=0.8, grain_level=0.2)(image, 0)  # darker grains
    assert stretched == pytest.approx(np.array([[0.05, 0.5, 0.95]]), abs=1e-6)


def test_calibrated_fills_the_source_texture_that_the_noise_spectra_do_not_see(rendered):
    """A source whose interiors hold a Gaussian-correlated texture (variance 4e-4, 1.2 voxels): the
    noise estimates, on second differences, see little of it; calibration fits it from the
    semivariogram and the pack gets the source's texture at every lag."""
    clean, labels, _ = rendered
    distance = signed_distance(labels)
    texture = ColouredNoise([0.0] * 6, [0.0] * 6, 0.2, 0.8, pore_texture=[4e-4, 1.2], grain_texture=[4e-4, 1.2])
    source = texture(GaussianNoise(std=0.01)(clean, 1), 2)
    depth = interior_depth(STATISTICS.edge_sigma)
    gamma = phase_semivariograms(source, distance, None, depth)
    spectra = phase_spectra(source, distance, None, depth)
    noise = estimate_noise(source, labels)
    target = dataclasses.replace(STATISTICS, edge_sigma=fit_edge_spread(edge_profile(source, distance)).sigma,
                                 nps_grains=tuple(spectra["grains"].power[1:]), nps_pores=tuple(spectra["pores"].power[1:]),
                                 noise_grain_std=noise.grain_std, noise_pore_std=noise.pore_std,
                                 semivariogram_grains=tuple(gamma["grains"]), semivariogram_pores=tuple(gamma["pores"]))
    without = _resolve("calibrated", rendered, dataclasses.replace(target, semivariogram_grains=None,
                                                                   semivariogram_pores=None))
    resolved = _resolve("calibrated", rendered, target)
    fit = resolved.record["calibration"]
    assert without.record["calibration"]["textured"] == {"grains": None, "pores": None}
    assert fit["guard"]["dropped"] == []
    for phase in ("grains", "pores"):  # the noise's lowest knot may carry a share of the texture's power
        variance, sigma = fit["textured"][phase]["texture"]
        assert 0 < variance < 1.5 * 4e-4 and sigma in TEXTURE_SIGMAS
    ratios = {}
    for name, result in (("with", resolved), ("without", without)):
        out = phase_semivariograms(result.pipeline(clean, 3), distance, None, depth)
        ratios[name] = np.concatenate([out[phase] / gamma[phase] for phase in gamma])
    assert np.all(np.abs(ratios["with"] - 1) < 0.1), ratios  # every lag of both phases within 10 %
    assert np.max(np.abs(ratios["without"] - 1)) > 0.25, ratios  # the noise alone misses the texture
    out = resolved.pipeline(clean, 3)
    for phase, spectrum in phase_spectra(out, distance, None, depth).items():  # and the noise still matches
        ratio = spectrum.power[1:5] / np.asarray(fit["target_power"][phase])[:4]
        assert np.all((ratio > 0.7) & (ratio < 1.4)), (phase, ratio)
    noise_out = estimate_noise(resolved.pipeline(clean, 3), labels)
    assert noise_out.grain_std == pytest.approx(noise.grain_std, rel=0.1)


def test_calibrated_puts_a_whole_number_source_pack_on_its_grey_level_grid(rendered):
    clean, labels, grid = rendered
    scaled = (clean * 200).astype(np.float32), labels, grid  # intensities of an 8-bit scan
    statistics = dataclasses.replace(STATISTICS, pore_mean=40.0, grain_mean=160.0, noise_std=2.0,
                                     nps_grains=(0.5,) * 6, nps_pores=(0.5,) * 6)
    for whole in (True, False):
        resolved = _resolve("calibrated", scaled, dataclasses.replace(statistics, grey_levels=(1.0, 0.0) if whole else None))
        out = resolved.pipeline(scaled[0], 1)
        assert resolved.record["calibration"]["grey_levels"] == ([1.0, 0.0] if whole else None)
        assert np.array_equal(out, np.round(out)) is whole
        assert isinstance(resolved.pipeline.transforms[-1], RoundLevels) is whole


def test_calibrated_puts_a_float_source_pack_on_its_grid_of_scaled_integers(rendered):
    clean, labels, grid = rendered
    step, offset = 2e-4, -0.005  # an 8-bit scan written as attenuation: 2e-4 per grey level, less 0.005
    scaled = (clean * 200 * step + offset).astype(np.float32), labels, grid
    statistics = dataclasses.replace(STATISTICS, pore_mean=40 * step + offset, grain_mean=160 * step + offset,
                                     noise_std=2.0 * step, nps_grains=(0.5 * step**2,) * 6,
                                     nps_pores=(0.5 * step**2,) * 6, grey_levels=(step, 0.0))
    resolved = _resolve("calibrated", scaled, statistics)
    assert resolved.record["calibration"]["grey_levels"] == [step, 0.0]
    levels = (resolved.pipeline(scaled[0], 1).astype(np.float64) - offset) / step
    assert np.abs(levels - np.round(levels)).max() < 0.01  # on the source's grid (to float32 rounding)
    assert np.unique(np.round(levels)).size > 50  # of many levels, as the source's


def test_the_source_statistics_hold_the_interior_texture_and_whether_the_scan_holds_whole_numbers(phantom):
    clean, labels = phantom
    noisy = GaussianNoise(std=0.02)(clean, 0)
    floats = measure_source(Scan(noisy, labels, voxel_size=(1.0, 1.0, 1.0), unit="px"))
    whole = measure_source(Scan(np.round(noisy * 200).astype(np.uint8), labels, voxel_size=(1.0, 1.0, 1.0), unit="px"))
    assert floats.grey_levels is None and whole.grey_levels == (1.0, 0.0)
    for statistics, scale in ((floats, 1.0), (whole, 200.0)):
        gamma = np.asarray(statistics.semivariogram_grains)
        assert gamma.shape == (4,) and np.all(np.diff(gamma) >= -0.05 * gamma.max())  # white noise: flat, 2 * std^2 / 2
        assert gamma[0] == pytest.approx((0.02 * scale) ** 2, rel=0.3)
    assert SourceStatistics.from_dict(whole.to_dict()) == whole


def test_calibrated_fits_the_psf_to_the_edges_steepness_where_the_labels_scatter(phantom):
    """A watershed's labels scatter about the true boundaries; the label-aligned profile then asks for too wide a PSF."""
    clean, labels = phantom
    pack = GaussianNoise(std=0.01)(clean, 0)
    source = GaussianNoise(std=0.02)(GaussianBlur(sigma=0.8)(clean, 0), 1)  # the pack's structure, 0.8 voxel softer
    scattered = labels.copy()  # one grain's labels a voxel too wide, one a voxel too narrow
    for label, move in ((1, ndimage.binary_dilation), (2, ndimage.binary_erosion)):
        grown = move(labels == label)
        scattered[labels == label] = 0
        scattered[grown & (scattered == 0)] = label
    region = specimen_mask(labels)
    for source_labels in (labels, scattered):
        statistics = dataclasses.replace(measure_source(Scan(source, source_labels)), cupping_strength=None)
        fit = calibrate(pack, labels, region, **_calibration_targets(statistics))
        profile_only = calibrate(pack, labels, region,
                                 **_calibration_targets(dataclasses.replace(statistics, edge_steepness=None)))
        assert fit.blur_sigma == pytest.approx(0.8, abs=0.1)
        assert fit.steepness_sigmas[int(np.argmin(fit.steepness_distances))] == fit.blur_sigma
        assert profile_only.steepness_sigmas is None
    wide = profile_only.sigmas[-1]
    assert wide > 1.05  # the scattered labels' profile alone: a PSF 0.3 voxel too wide
    # which the guard drops (its patches look less like the source's), and half of it is kept (NARROWER_PSF)
    assert [tried["sigma"] for tried in profile_only.guard["psf_tried"]] == pytest.approx([wide, wide / 2])
    assert profile_only.blur_sigma == pytest.approx(wide / 2)


def test_a_calibration_region_too_small_for_the_steepness_keeps_the_profile_width(phantom, caplog):
    clean, labels = phantom
    source = GaussianNoise(std=0.02)(GaussianBlur(sigma=0.8)(clean, 0), 1)
    statistics = dataclasses.replace(measure_source(Scan(source, labels)), cupping_strength=None)
    region = np.zeros(labels.shape, bool)
    region[11:21, 5:35, 5:35] = True  # 17,400 in-slice neighbour pairs: fewer than a steepness needs
    with caplog.at_level(logging.WARNING):
        fit = calibrate(clean, labels, region, **_calibration_targets(statistics))
    assert fit.steepness_sigmas is None and fit.blur_sigma == fit.sigmas[-1]
    assert "too few voxel pairs to read its edges' steepness" in caplog.text


def test_the_guard_measures_a_narrow_region_of_wide_slices_in_a_window_with_the_same_figures(phantom):
    """A wide tube's calibration region is its slices' central square: the guard reads a centred window cut by
    multiples of the noise tile around it, and measures there what it measures on whole slices."""
    from synthpack.artefacts import ColouredNoise, RingArtefacts
    from synthpack.artefacts.calibration_region import lateral_window
    from synthpack.artefacts.coloured_noise import TILE

    clean, labels = (np.tile(a, (1, 4, 4)) for a in phantom)  # 32 x 256 x 256
    region = np.zeros(labels.shape, dtype=bool)
    region[8:24, 96:160, 96:160] = True
    steps = {"blur": GaussianBlur(sigma=0.8),
             "noise": ColouredNoise(pore_power=[2e-4, 1e-4, 4e-5], grain_power=[3e-4, 2e-4, 1e-4], pore_level=0.2,
                                    grain_level=0.8),
             "rings": RingArtefacts(amplitude=0.05, radii=[10.0, 40.0], width=1.5)}
    source = GaussianNoise(std=0.02)(clean, 1)
    noise = estimate_noise(source, labels)
    targets = {"histograms": phase_quantiles(source, phase_masks(signed_distance(labels), region)),
               "noise": {"grains": noise.grain_std, "pores": noise.pore_std}, "contrast": 0.6}

    def build(kept):
        return [steps[name] for name in kept]

    window = lateral_window(region, 5, cupping=False)
    assert window == (slice(64, 192), slice(64, 192)) and window[0].start % TILE == 0
    assert lateral_window(region, 5, cupping=True) == (slice(None), slice(None))  # cupping scales with the slice
    whole = guard_steps(build, tuple(steps), clean, labels, region, **targets)
    cut = (slice(None), *window)
    windowed = guard_steps(build, tuple(steps), clean[cut], labels[cut], region[cut], **targets)
    assert windowed == whole and whole[1]["figures"]["fitted"] != whole[1]["figures"]["none"]


def test_a_rounded_pack_has_the_source_noise_after_its_rounding(rendered):
    # noise of a grey level: the rounding's own variance (1/12) is a tenth of it, and part of the source's noise
    clean, labels, grid = rendered
    scaled = (clean * 200).astype(np.float32), labels, grid
    statistics = dataclasses.replace(STATISTICS, pore_mean=40.0, grain_mean=160.0, noise_std=1.0, noise_grain_std=1.0,
                                     noise_pore_std=1.0, nps_grains=tuple(white_ring_powers(1.0, 6)),
                                     nps_pores=tuple(white_ring_powers(1.0, 6)), grey_levels=(1.0, 0.0))
    resolved = _resolve("calibrated", scaled, statistics)
    assert estimate_noise(resolved.pipeline(scaled[0], 1), labels).std == pytest.approx(1.0, rel=0.02)
