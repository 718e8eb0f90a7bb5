"""Tests of synthpack.source: phase levels, the noise estimator, edge width and SourceStatistics."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy import ndimage, special

from synthpack.artefacts import GaussianNoise
from synthpack.errors import SynthpackInputError
from synthpack.scan import Scan
from synthpack.source import SourceStatistics, estimate_noise, estimate_phases, measure_source, volume_edge_width


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
    levels = estimate_phases(Scan(noisy, labels))
    assert (statistics.pore_mean, statistics.pore_std, statistics.grain_mean) == (
        levels.pore_mean, levels.pore_std, levels.grain_mean)
    assert statistics.noise_std == estimate_noise(noisy, labels).std
    assert statistics.edge_width == volume_edge_width(noisy, labels)
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


def test_edge_width_is_none_when_it_cannot_be_measured(phantom, caplog):
    _, labels = phantom
    flat = np.full(labels.shape, 0.5, dtype=np.float32)  # grains and pores of one level: no edge
    statistics = measure_source(Scan(flat, labels))
    assert statistics.edge_width is None
    assert "edge width cannot be measured" in caplog.text


def test_to_dict_is_the_field_order_without_missing_values():
    full = SourceStatistics(pore_mean=0.2, pore_std=0.01, grain_mean=0.8, noise_std=0.03, edge_width=1.5)
    assert list(full.to_dict()) == ["pore_mean", "pore_std", "grain_mean", "noise_std", "edge_width"]
    assert SourceStatistics.from_dict(full.to_dict()) == full
    partial = dataclasses.replace(full, edge_width=None)
    assert "edge_width" not in partial.to_dict()
    assert SourceStatistics.from_dict(partial.to_dict()) == partial
