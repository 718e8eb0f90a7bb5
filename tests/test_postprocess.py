"""Tests of synthpack.postprocess: what every ``postprocess`` value resolves to, and the bulk region."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from synthpack.artefacts import ColouredNoise, GaussianNoise, default_postprocessing
from synthpack.errors import SynthpackInputError
from synthpack.postprocess import POSTPROCESS_MODES, bulk_region, check_postprocess, resolve_postprocessing
from synthpack.reconstruct import Grid
from synthpack.source import SourceStatistics, estimate_noise, fit_edge_spread, phase_spectra
from synthpack.source.edges import edge_profile, signed_distance

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


def test_default_is_the_default_pipeline_scaled_to_the_source_contrast(rendered):
    resolved = _resolve("default", rendered)
    assert resolved.pipeline.to_config() == default_postprocessing(contrast=STATISTICS.contrast).to_config()
    assert resolved.record == {}


@pytest.mark.parametrize("postprocess", ["none", []])
def test_none_and_an_empty_list_do_nothing(rendered, postprocess):
    resolved = _resolve(postprocess, rendered)
    assert len(resolved.pipeline) == 0 and resolved.record == {}
    np.testing.assert_array_equal(resolved.pipeline(rendered[0], 0), rendered[0])


def test_a_list_is_built_as_given(rendered):
    steps = [{"name": "gaussian_blur", "sigma": [0.5, 1.0]}, {"name": "gaussian_noise", "std": 0.02}]
    resolved = _resolve(steps, rendered)
    assert [step["name"] for step in resolved.pipeline.to_config()] == ["gaussian_blur", "gaussian_noise"]
    assert resolved.pipeline[0].sigma == pytest.approx((0.5, 1.0)) and resolved.pipeline[1].std == 0.02
    assert resolved.record == {}


def test_match_source_reaches_the_source_noise_level(rendered):
    clean, labels, _ = rendered
    resolved = _resolve("match_source", rendered)
    (noise,) = resolved.pipeline
    assert isinstance(noise, GaussianNoise)
    assert noise.std == pytest.approx(np.sqrt(0.05**2 - 0.01**2), rel=0.05)  # variances add
    assert estimate_noise(resolved.pipeline(clean, 1), labels).std == pytest.approx(0.05, rel=0.05)
    assert resolved.record == {}


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


def test_calibrated_needs_the_source_edge_width(rendered):
    unmeasured = dataclasses.replace(STATISTICS, edge_width=None)
    for postprocess in [*POSTPROCESS_MODES, []]:
        if postprocess != "calibrated":
            check_postprocess(postprocess, unmeasured)
    with pytest.raises(SynthpackInputError, match="edge width"):
        check_postprocess("calibrated", unmeasured)
    with pytest.raises(SynthpackInputError, match="edge width"):
        _resolve("calibrated", rendered, unmeasured)


def test_an_unknown_mode_is_refused(rendered):
    with pytest.raises(SynthpackInputError, match="postprocess must be one of default, none"):
        _resolve("fancy", rendered)


def test_bulk_region_is_the_pour_sub_cylinder():
    # a cylinder of radius 8 from z = 2 to 7 on a grid centred on the axis, 1-unit voxels
    shape = (10, 21, 21)
    cylinder = bulk_region(shape, (0.0, -10.0, -10.0), (1.0, 1.0, 1.0), {"radius": 8.0, "z_min": 2.0, "z_max": 7.0})
    assert cylinder.sum() == pytest.approx(6 * np.pi * 64, rel=0.05)
    assert not cylinder[:2].any() and not cylinder[8:].any()
    with pytest.raises(SynthpackInputError, match="no bulk"):
        bulk_region(shape, (0.0, -10.0, -10.0), (1.0, 1.0, 1.0), {"radius": 1.0, "z_min": 2.0, "z_max": 3.0})
