"""Tests of synthpack.source: phase levels, the noise estimator, edge width and spread, NPS, SourceStatistics."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy import ndimage, special

from synthpack.artefacts import BeamHardening, GaussianNoise
from synthpack.artefacts.coloured_noise import ring_powers_of_spectrum
from synthpack.errors import SynthpackInputError
from synthpack.scan.core import Scan
from synthpack.measure import estimate_noise, estimate_phases, fit_edge_spread, noise_power_spectrum, volume_edge_width
from synthpack.source import SourceStatistics, measure_source
from synthpack.measure.edges import INTERIOR, edge_profile, signed_distance
from synthpack.measure.specimen import specimen_mask
from synthpack.measure.lattice import patch_corners, take_patches
from synthpack.measure.noise_estimate import estimate_spread
from synthpack.measure.pore_spectrum import measure_pore_spectrum
from synthpack.measure.spectrum import (NPS_DEPTH_STEP, measurable_phase_spectra, phase_interiors, phase_spectra,
                                       ring_of, white_ring_powers)


def test_pore_statistics_leave_out_the_blurred_rim_along_grains():
    # slabs of 6 grain and 6 pore voxels along x, blurred as a scanner does
    labels = np.zeros((20, 20, 72), dtype=np.int32)
    for k, x0 in enumerate(range(0, 72, 12)):
        labels[:, :, x0:x0 + 6] = k + 1
    sharp = np.where(labels > 0, 0.8, 0.2)
    tomogram = ndimage.gaussian_filter(sharp, 1.0, mode="nearest").astype(np.float32)
    levels = estimate_phases(Scan(tomogram, labels))
    rim_included = np.median(tomogram[labels == 0])
    assert rim_included > 0.21
    assert levels.pore_mean == pytest.approx(0.2, abs=0.006)


@pytest.mark.parametrize("std", [0.01, 0.05])
def test_estimate_noise_recovers_added_noise(phantom, std):
    clean, labels = phantom
    estimate = estimate_noise(GaussianNoise(std=std)(clean, 0), labels)
    assert estimate.std == pytest.approx(std, rel=0.1)
    assert estimate.grain_std == pytest.approx(std, rel=0.1)
    assert estimate.pore_std == pytest.approx(std, rel=0.1)
    assert estimate.n_grain > 1000 and estimate.n_pore > 1000
    assert estimate_noise(clean, labels).std < 0.1 * 0.01  # the smooth structure is ignored


def test_the_noise_estimate_varies_between_realisations_as_estimate_spread_says():
    for grain in ((slice(None), slice(0, 12), slice(24, 30)), (slice(None), slice(None), slice(24, None))):
        labels = np.zeros((24, 48, 48), dtype=np.int32)
        labels[grain] = 1  # a thin grain (a few hundred interior voxels), then a thick one (thousands)
        estimates = [estimate_noise(GaussianNoise(std=1.0)(np.zeros(labels.shape, np.float32), seed), labels)
                     for seed in range(40)]
        levels = np.array([e.grain_std for e in estimates])
        measured = levels.std() / levels.mean()
        assert measured == pytest.approx(estimate_spread(estimates[0].n_grain), rel=0.35), estimates[0].n_grain


def test_the_noise_estimate_of_whole_numbers_reads_between_grey_levels():
    # a scan stored as whole numbers with noise of a grey level or so: its second differences lie on a grid,
    # and the level must follow the noise continuously (rounding adds a variance of 1/12), not in ~10 % steps
    labels = np.zeros((40, 64, 64), dtype=np.int32)
    labels[:, :, 32:] = 1
    levels = []
    for std in (0.9, 0.95, 1.0, 1.05, 1.1):
        noisy = np.rint(50.0 + GaussianNoise(std=std)(np.zeros(labels.shape, np.float32), 0))
        estimate = estimate_noise(noisy, labels)
        assert estimate.std == pytest.approx(np.hypot(std, np.sqrt(1 / 12)), rel=0.02), std
        levels.append(estimate.std)
    assert np.all(np.diff(levels) > 0.02)


def test_estimate_noise_leaves_out_negative_labels(phantom):
    clean, labels = phantom
    noisy = GaussianNoise(std=0.05)(clean, 0)
    noisy[:, :, 32:] += np.random.default_rng(1).normal(0.0, 0.5, (32, 64, 32)).astype(np.float32)  # right half
    left = np.where(np.arange(64) < 32, labels, -1)
    assert estimate_noise(noisy, left).std == pytest.approx(0.05, rel=0.1)


def test_estimate_noise_input_errors(phantom):
    clean, labels = phantom
    with pytest.raises(SynthpackInputError, match="shape"):
        estimate_noise(clean, labels[:-1])
    with pytest.raises(SynthpackInputError, match="integers"):
        estimate_noise(clean, labels.astype(float))
    with pytest.raises(SynthpackInputError, match="lower margin"):
        estimate_noise(clean[:4, :8, :8], labels[:4, :8, :8])


@pytest.mark.parametrize("sigma", [1.0, 2.0])
@pytest.mark.parametrize("step", [1.0, -1.0])
def test_edge_width_of_a_gaussian_blurred_step(sigma, step):
    z = np.arange(64, dtype=float)[:, None, None] * np.ones((1, 16, 16))
    labels = (z < 32).astype(np.int32)  # boundary at z = 31.5
    tomogram = 0.5 * step * (1 + special.erf((31.5 - z) / (sigma * np.sqrt(2))))  # grains brighter or darker
    assert volume_edge_width(tomogram.astype(np.float32), labels) == pytest.approx(2.5631 * sigma, rel=0.08)


def test_measure_source_measures_every_field_once(phantom):
    clean, labels = phantom
    noisy = GaussianNoise(std=0.02)(clean, 0)
    statistics = measure_source(Scan(noisy, labels))
    specimen = specimen_mask(labels)  # what the statistics describe: no container, no air around it
    levels = estimate_phases(Scan(noisy, labels), region=specimen)
    assert (statistics.pore_mean, statistics.pore_std, statistics.grain_mean) == (
        levels.pore_mean, levels.pore_std, levels.grain_mean)
    assert statistics.noise_std == estimate_noise(noisy, labels, region=specimen).std
    assert statistics.edge_width == volume_edge_width(noisy, labels, region=specimen)
    assert statistics.contrast == levels.grain_mean - levels.pore_mean > 0.5
    with pytest.raises(dataclasses.FrozenInstanceError):
        statistics.noise_std = 0.0  # type: ignore[misc]


def test_darker_grains_have_a_negative_contrast_and_the_same_edge_width(phantom):
    clean, labels = phantom
    noisy = GaussianNoise(std=0.02)(clean, 0)
    brighter = measure_source(Scan(noisy, labels))
    darker = measure_source(Scan((1.0 - noisy).astype(np.float32), labels))  # grains 0.2, pores 0.8
    assert darker.contrast == pytest.approx(-brighter.contrast, abs=1e-6) and darker.contrast < -0.5
    assert darker.edge_width == pytest.approx(brighter.edge_width, rel=1e-4)
    assert darker.noise_std == pytest.approx(brighter.noise_std, rel=1e-4)
    assert darker.pore_std == pytest.approx(brighter.pore_std, rel=1e-4)


def test_edge_width_is_none_when_it_cannot_be_measured(caplog):
    labels = np.zeros((32, 64, 64), np.int32)
    for k, x in enumerate(range(4, 60, 8)):
        labels[4:28, 4:60, x:x + 2] = k + 1  # plates 2 voxels thin: no grain voxel 2.5 voxels from an edge
    noise = np.random.default_rng(0).normal(0.0, 0.01, labels.shape)
    statistics = measure_source(Scan((0.2 + 0.6 * (labels > 0) + noise).astype(np.float32), labels))
    assert statistics.edge_width is None and statistics.grain_mean == pytest.approx(0.8, abs=0.01)
    assert "edge width cannot be measured" in caplog.text


def test_a_scan_without_contrast_is_refused(phantom):
    _, labels = phantom
    flat = np.full(labels.shape, 0.5, dtype=np.float32)  # grains and pores of one level
    with pytest.raises(SynthpackInputError, match="the scan has no contrast"):
        measure_source(Scan(flat, labels))


def test_to_dict_is_the_field_order_without_missing_values():
    full = SourceStatistics(pore_mean=0.2, pore_std=0.01, grain_mean=0.8, noise_std=0.03, edge_width=1.5)
    assert list(full.to_dict()) == ["pore_mean", "pore_std", "grain_mean", "noise_std", "edge_width"]
    assert SourceStatistics.from_dict(full.to_dict()) == full
    partial = dataclasses.replace(full, edge_width=None)
    assert "edge_width" not in partial.to_dict()
    assert SourceStatistics.from_dict(partial.to_dict()) == partial


def test_edge_spread_fit_recovers_the_shift_and_blur_of_a_step():
    z = np.arange(64, dtype=float)[:, None, None] * np.ones((1, 16, 16))
    labels = (z < 32).astype(np.int32)  # grain below z = 31.5
    # the intensity edge 0.3 voxel inside the grain, blurred by sigma 0.9
    tomogram = 0.2 + 0.5 * special.ndtr((31.5 - 0.3 - z) / 0.9)
    spread = fit_edge_spread(edge_profile(tomogram.astype(np.float32), signed_distance(labels)))
    assert spread.shift == pytest.approx(0.3, abs=0.01) and spread.sigma == pytest.approx(0.9, rel=0.01)
    assert (spread.pore, spread.grain) == (pytest.approx(0.2, abs=1e-3), pytest.approx(0.7, abs=1e-3))


@pytest.mark.parametrize(("shift", "sigma"), [(0.0, 0.8), (0.4, 1.2), (-0.3, 1.0)])
def test_edge_spread_fit_recovers_a_blurred_shifted_ball(shift, sigma):
    # a ball of radius 14 (label: voxel centres inside), its intensity edge `shift` voxels
    # inside, made by a Gaussian blur of `sigma` of the 4x supersampled ball, with noise
    fine = (np.indices((160, 160, 160)).astype(float) + 0.5) / 4.0
    radius = np.sqrt(((fine - 20.0) ** 2).sum(axis=0))
    sharp = (radius <= 14.0 - shift).astype(float).reshape(40, 4, 40, 4, 40, 4).mean(axis=(1, 3, 5))
    box_sigma = np.sqrt(1.0 / 12.0 - 1.0 / (12.0 * 16.0))  # what averaging the supersamples adds
    tomogram = 0.2 + 0.5 * ndimage.gaussian_filter(sharp, np.sqrt(sigma**2 - box_sigma**2))
    tomogram = GaussianNoise(std=0.01)(tomogram, 0)
    centre = np.sqrt(((np.indices((40, 40, 40)) + 0.5 - 20.0) ** 2).sum(axis=0))
    labels = (centre <= 14.0).astype(np.int32)
    spread = fit_edge_spread(edge_profile(tomogram, signed_distance(labels)))
    # blurring a ball also moves its half-height inwards by its curvature, about sigma^2 / radius
    assert spread.shift == pytest.approx(shift + sigma**2 / 14.0, abs=0.1)
    assert spread.sigma == pytest.approx(sigma, rel=0.1)


def test_measure_source_fits_the_edge_and_the_noise_spectra(phantom):
    clean, labels = phantom
    noisy = GaussianNoise(std=0.02)(clean, 0)
    statistics = measure_source(Scan(noisy, labels))
    spread = fit_edge_spread(edge_profile(noisy, signed_distance(labels), region=specimen_mask(labels)))
    assert (statistics.edge_shift, statistics.edge_sigma) == (spread.shift, spread.sigma)
    assert abs(statistics.edge_shift) < 0.2 and statistics.edge_sigma == pytest.approx(1.0, rel=0.15)  # balls: curved
    # white noise: each ring's power is the variance x its share of the frequencies (the
    # phantom's smooth ripple adds to the lowest rings only; few patches fit between the
    # three balls inside the specimen, hence the tolerance)
    share = np.bincount(ring_of().ravel())[1:] / 64
    for power in (statistics.nps_grains, statistics.nps_pores):
        assert len(power) == 6  # one ring per frequency (k + 1) / NPS_PATCH, k < 6
        np.testing.assert_allclose(np.array(power)[2:5], 0.02**2 * share[2:5], rtol=0.5)
    assert SourceStatistics.from_dict(statistics.to_dict()) == statistics


def _patch_spectrum(volume: np.ndarray, size: int = 8) -> np.ndarray:
    """Ring powers of the mean-removed 8x8 in-slice patches of the intensities: structure and noise alike."""
    patches = take_patches(volume, patch_corners(np.ones(volume.shape, dtype=bool), size, size // 2), size)
    patches = patches.astype(np.float64) - patches.mean(axis=(1, 2), keepdims=True)
    power = (np.abs(np.fft.fft2(patches)) ** 2).mean(axis=0) / size**4
    return np.bincount(ring_of(size).ravel(), weights=power.ravel())


def test_noise_power_spectrum_sees_the_noise_and_not_the_structure():
    # a smooth texture (correlation length 5 voxels) four times as strong as white noise of std 0.05
    rng = np.random.default_rng(3)
    texture = ndimage.gaussian_filter(rng.standard_normal((48, 96, 96)), 5.0, mode="wrap")
    texture *= 0.2 / texture.std()
    volume = (texture + rng.normal(0.0, 0.05, texture.shape)).astype(np.float32)
    mask = np.ones(volume.shape, dtype=bool)
    mask[:, 40:48] = False  # gaps are fine: every voxel pair in the mask counts
    measured = noise_power_spectrum(volume, mask)
    white = white_ring_powers(0.05**2, 6)
    np.testing.assert_allclose(measured.power[1:], white, rtol=0.1)
    assert measured.power.sum() == pytest.approx(0.05**2 * 63 / 64, rel=0.05)  # the noise's variance in a patch
    # the intensities' own patch spectrum counts the texture as noise: several times the noise's power
    # in the lowest ring
    assert _patch_spectrum(volume)[1] > 3 * white[0]
    # the noise alone has the same spectrum, with or without the texture
    np.testing.assert_allclose(noise_power_spectrum(volume - texture.astype(np.float32), mask).power[1:],
                               measured.power[1:], rtol=0.05)


def test_noise_power_spectrum_of_a_phase_too_thin_is_none():
    volume = np.random.default_rng(0).normal(size=(16, 32, 32)).astype(np.float32)
    mask = np.zeros(volume.shape, dtype=bool)
    mask[:, 10:14, :] = True  # 4 voxels wide: no pair 7 voxels apart along y
    assert noise_power_spectrum(volume, mask) is None
    mask[:, 4:28, :] = True
    assert noise_power_spectrum(volume, mask) is not None


def test_phases_too_thin_at_the_edges_reach_are_measured_at_the_deepest_interior_that_holds_a_spectrum():
    # grain slabs 11 voxels wide, pores 1 wide: small grains and narrow pores at a coarse voxel
    labels = np.zeros((24, 96, 64), dtype=np.int32)
    for k, y in enumerate(range(0, 96, 12)):
        labels[:, y:y + 11] = k + 1
    volume = np.random.default_rng(0).normal(0.0, 0.1, labels.shape).astype(np.float32)
    distance = signed_distance(labels)
    assert all(s is None for s in phase_spectra(volume, distance, None, 4.0).values())
    spectra, depth = measurable_phase_spectra(volume, distance, None, 4.0)
    steps = (4.0 - depth) / NPS_DEPTH_STEP
    assert INTERIOR <= depth < 4.0 and steps == pytest.approx(round(steps))
    assert all(s is None for s in phase_spectra(volume, distance, None, depth + NPS_DEPTH_STEP).values())  # the deepest
    np.testing.assert_allclose(spectra["grains"].power[1:], white_ring_powers(0.1**2, 6), rtol=0.1)
    assert spectra["pores"] is None
    assert measurable_phase_spectra(volume, distance, None, depth)[1] == depth  # measurable: measured where asked


def test_noise_power_spectrum_of_known_coloured_noise():
    # white noise smoothed by a Gaussian of 1 voxel: its spectrum is exp(-(2 pi f)^2), known exactly
    white = np.random.default_rng(0).standard_normal((64, 64, 64))
    coloured = ndimage.gaussian_filter(white, 1.0, mode="wrap")
    f = np.fft.fftfreq(64)
    radius = np.sqrt(f[:, None, None] ** 2 + f[None, :, None] ** 2 + f[None, None, :] ** 2)
    expected = ring_powers_of_spectrum(np.exp(-((2 * np.pi * radius) ** 2)), 4)
    measured = noise_power_spectrum(coloured.astype(np.float32), np.ones(coloured.shape, dtype=bool)).power[1:5]
    np.testing.assert_allclose(measured, expected, rtol=0.1)
    assert np.all(np.diff(measured) < 0)  # smooth noise: power falls with frequency


def test_the_pore_texture_figures_are_read_with_the_cupping_divided_out(large_scan):
    """The texture is rendered before the cupping is applied, so its figures must not hold the cupping's trend."""
    tomogram = np.asarray(large_scan.tomogram, dtype=np.float32)
    flat = measure_source(Scan(tomogram, large_scan.labels))
    cupped_tomogram = BeamHardening(strength=0.15, keep="mean")(tomogram, 0)
    cupped = measure_source(Scan(cupped_tomogram, large_scan.labels))
    assert flat.cupping_strength is None and cupped.cupping_strength == pytest.approx(0.15, abs=0.02)
    # read on the cupped intensities as they are, the radial trend nearly doubles the pore texture's power
    interior = phase_interiors(signed_distance(large_scan.labels), specimen_mask(large_scan.labels))["pores"]
    assert np.sum(measure_pore_spectrum(cupped_tomogram, interior)) > 1.5 * np.sum(flat.pore_spectrum)
    assert np.sum(cupped.pore_spectrum) == pytest.approx(np.sum(flat.pore_spectrum), rel=0.05)
    np.testing.assert_allclose(cupped.pore_quantiles, flat.pore_quantiles, atol=0.03)
    np.testing.assert_allclose(cupped.semivariogram_pores, flat.semivariogram_pores, rtol=0.02)
