"""Tests of synthpack.artefacts: noise statistics, blur, radial artefacts, CT simulation,
noise matching, seeding, records and configs."""

from __future__ import annotations

import json
import pickle

import numpy as np
import pytest
import yaml
from scipy import ndimage

from synthpack.artefacts import (
    BeamHardening,
    ColouredNoise,
    Compose,
    CTSimulation,
    GaussianBlur,
    GaussianNoise,
    MotionBlur,
    PoissonNoise,
    RingArtefacts,
    SpeckleNoise,
    available_transforms,
    generic_postprocessing,
    from_config,
    line_kernel,
    noise_to_add,
)
from synthpack.artefacts.blockwise import apply_blockwise
from synthpack.artefacts.coloured_noise import (
    fit_noise_and_texture,
    highpass_variance_of_spectrum,
    ring_powers_of_spectrum,
    semivariogram_of_spectrum,
    spectrum_for_rings,
    texture_spectrum,
)
from synthpack.errors import SynthpackInputError
from synthpack.measure import noise_power_spectrum
from synthpack.measure import estimate_noise

SHAPE = (16, 64, 64)

#: One config per transform, with ranges where the transform has them, cheap enough for a test.
CONFIGS = [
    {"name": "gaussian_noise", "std": [0.02, 0.05]},
    {"name": "speckle_noise", "std": [0.02, 0.05]},
    {"name": "poisson_noise", "photons": [500, 2000]},
    {"name": "gaussian_blur", "sigma": [0.5, 1.5]},
    {"name": "motion_blur", "length": [2, 5], "angle": [0, 180]},
    {"name": "ring_artefacts", "amplitude": [0.01, 0.05], "n_rings": [2, 6]},
    {"name": "beam_hardening", "strength": [0.05, 0.2]},
    {"name": "ct_simulation", "attenuation": 0.02, "photons": [1e4, 1e5], "n_angles": 40, "gain_std": 0.002},
]


def _radius(shape: tuple[int, int]) -> np.ndarray:
    ny, nx = shape
    y, x = np.mgrid[:ny, :nx]
    return np.hypot(y - (ny - 1) / 2, x - (nx - 1) / 2)


@pytest.fixture
def textured() -> np.ndarray:
    """A 16x64x64 float32 volume with structure (so blur and rings change it)."""
    rng = np.random.default_rng(123)
    return ndimage.gaussian_filter(rng.random(SHAPE), 2.0).astype(np.float32)


# --- noise statistics -------------------------------------------------------------------


def test_gaussian_noise_mean_and_std() -> None:
    image = np.full(SHAPE, 0.5, dtype=np.float32)
    out = GaussianNoise(std=0.05)(image, 0)
    n = image.size
    assert out.dtype == np.float32 and out.shape == SHAPE
    assert abs(out.mean() - 0.5) < 5 * 0.05 / np.sqrt(n)
    assert abs(out.std() / 0.05 - 1) < 5 / np.sqrt(2 * n)
    assert np.all(image == 0.5)  # the input is never modified


@pytest.mark.parametrize("level", [0.2, 0.8])
def test_poisson_variance_proportional_to_mean(level: float) -> None:
    photons = 500.0
    out = PoissonNoise(photons=photons)(np.full(SHAPE, level, dtype=np.float32), 1)
    assert abs(out.mean() / level - 1) < 0.01
    # variance = intensity / photons at every level
    assert out.var() * photons / level == pytest.approx(1.0, rel=0.03)


def test_speckle_variance_proportional_to_intensity_squared() -> None:
    image = np.full(SHAPE, 0.25, dtype=np.float32)
    image[:, :, 32:] = 1.0
    out = SpeckleNoise(std=0.1)(image, 2)
    for level in (0.25, 1.0):
        values = out[image == level]
        assert values.mean() == pytest.approx(level, rel=0.005)
        assert values.var() / level**2 == pytest.approx(0.1**2, rel=0.05)


# --- seeding and records ----------------------------------------------------------------


@pytest.mark.parametrize("config", CONFIGS, ids=lambda c: c["name"])
def test_same_seed_same_output_different_seed_different(config: dict, textured: np.ndarray) -> None:
    transform = from_config(config)
    volume = textured[:4] if config["name"] == "ct_simulation" else textured
    a, record_a = transform.apply(volume, 7)
    b, record_b = transform.apply(volume, 7)
    c, record_c = transform.apply(volume, 8)
    assert a.dtype == np.float32 and a.shape == volume.shape
    assert np.array_equal(a, b) and record_a == record_b
    assert not np.array_equal(a, c) and record_a != record_c
    # a Generator is advanced in place: two calls with one generator differ
    rng = np.random.default_rng(7)
    assert not np.array_equal(transform(volume, rng), transform(volume, rng))


@pytest.mark.parametrize("config", CONFIGS, ids=lambda c: c["name"])
def test_record_holds_drawn_values_and_replays(config: dict) -> None:
    transform = from_config(config)
    image = np.full((2, 32, 32), 0.5, dtype=np.float32)
    out, record = transform.apply(image, 3)
    (entry,) = record
    assert entry["name"] == config["name"]
    for key, value in config.items():
        if isinstance(value, list):  # a range: the record holds the value drawn from it
            assert value[0] <= entry[key] <= value[1]
    # the record is the config of the transform with those values fixed
    replay = from_config(record)
    assert isinstance(replay, Compose) and len(replay) == 1
    assert replay[0].to_dict() == {**entry, "p": 1.0}
    assert json.loads(json.dumps(record)) == record
    assert out.shape == image.shape


def test_compose_applies_in_order_and_records_all(textured: np.ndarray) -> None:
    pipeline = Compose([GaussianBlur(sigma=1.0), GaussianNoise(std=(0.01, 0.02))])
    out, record = pipeline.apply(textured, 11)
    # the pipeline's generator drew the std first, then the noise: reproduce it by hand
    rng = np.random.default_rng(11)
    std = 0.01 + 0.01 * rng.random()
    by_hand = GaussianBlur(sigma=1.0)(textured, None) + std * rng.standard_normal(SHAPE, dtype=np.float32)
    assert [r["name"] for r in record] == ["gaussian_blur", "gaussian_noise"]
    assert record[1]["std"] == pytest.approx(std)
    np.testing.assert_allclose(out, by_hand, atol=1e-6)


def test_probability_zero_skips_and_one_applies() -> None:
    image = np.ones((8, 8), dtype=np.float32)
    out, record = GaussianNoise(std=0.1, p=0.0).apply(image, 0)
    assert record == [] and np.array_equal(out, image)
    applied = [bool(GaussianNoise(std=0.1, p=0.5).apply(image, seed)[1]) for seed in range(200)]
    assert 60 < sum(applied) < 140


# --- blur -------------------------------------------------------------------------------


def test_gaussian_blur_reduces_white_noise_variance_3d() -> None:
    sigma = 1.5
    noise = np.random.default_rng(0).standard_normal((32, 64, 64)).astype(np.float32)
    out = GaussianBlur(sigma=sigma)(noise, None)
    interior = out[6:-6, 6:-6, 6:-6]
    expected = 1.0 / (8 * np.pi**1.5 * sigma**3)
    assert interior.var() == pytest.approx(expected, rel=0.15)


def test_gaussian_blur_reduces_white_noise_variance_2d_slice() -> None:
    sigma = 2.0
    noise = np.random.default_rng(1).standard_normal((256, 256)).astype(np.float32)
    out = GaussianBlur(sigma=sigma)(noise, None)
    assert out.shape == (256, 256)
    expected = 1.0 / (4 * np.pi * sigma**2)
    assert out[8:-8, 8:-8].var() == pytest.approx(expected, rel=0.15)


@pytest.mark.parametrize(("angle", "axis"), [(0.0, 1), (90.0, 0)])
def test_motion_blur_streaks_along_its_direction(angle: float, axis: int) -> None:
    image = np.zeros((3, 33, 33), dtype=np.float32)
    image[:, 16, 16] = 1.0
    out = MotionBlur(length=8.0, angle=angle)(image, None)
    assert out.sum() == pytest.approx(3.0, rel=1e-5)  # blur conserves intensity
    assert np.array_equal(out[0], out[2])  # the same kernel in every slice, none along z
    support = np.argwhere(out[1] > 1e-6)
    extent = support.max(0) - support.min(0) + 1
    assert extent[axis] >= 8 and extent[1 - axis] <= 2


def test_motion_blur_variance_matches_kernel() -> None:
    kernel = line_kernel(6.0, 30.0)
    assert kernel.sum() == pytest.approx(1.0) and np.all(kernel >= 0)
    noise = np.random.default_rng(2).standard_normal((256, 256)).astype(np.float32)
    out = MotionBlur(length=6.0, angle=30.0)(noise, None)
    assert out[8:-8, 8:-8].var() == pytest.approx((kernel**2).sum(), rel=0.1)


# --- radial artefacts -------------------------------------------------------------------


def test_rings_rotationally_symmetric_and_constant_along_z() -> None:
    out = RingArtefacts(amplitude=0.1, radii=[8.0, 20.0], width=1.5)(np.zeros(SHAPE, np.float32), 4)
    for k in range(1, SHAPE[0]):
        assert np.array_equal(out[k], out[0])
    ring = out[0]
    # symmetric under the slice's own rotations and mirrors about its centre
    np.testing.assert_allclose(ring, ring.T, atol=1e-6)
    np.testing.assert_allclose(ring, ring[::-1, :], atol=1e-6)
    np.testing.assert_allclose(ring, np.rot90(ring), atol=1e-6)
    radius = _radius(ring.shape)
    for r in (8.0, 20.0):  # each ring stands out at its radius, with amplitude 0.05-0.1
        on_ring = np.abs(ring[np.abs(radius - r) < 0.3]).mean()
        assert 0.045 < on_ring <= 0.1
    assert np.abs(ring[np.abs(radius - 14.0) < 1.0]).max() < 1e-3


def test_random_rings_lie_in_field_of_view(textured: np.ndarray) -> None:
    pattern = RingArtefacts(amplitude=0.05, n_rings=5)(textured, 9) - textured
    radius = _radius(pattern.shape[1:])
    assert np.abs(pattern[0]).max() > 0.02
    # radii are drawn within the field of view, min(Y, X) / 2 = 32 voxels
    assert np.abs(pattern[0][radius > 32 + 3]).max() < 1e-3


def test_beam_hardening_darkens_the_centre_of_a_disc() -> None:
    radius = _radius((64, 64))
    disc = np.where(radius < 30, 1.0, 0.0).astype(np.float32)
    out = BeamHardening(strength=0.2)(np.repeat(disc[None], 4, 0), None)
    centre = out[:, np.abs(radius) < 2].mean()
    rim = out[:, (radius > 27) & (radius < 30)].mean()
    assert centre == pytest.approx(0.8, abs=0.01)
    assert rim > centre + 0.15
    # the factor is 1 - k (1 - (r/R)^2) with R = 32: check it on the row through the centre
    r = np.hypot(32 - 31.5, np.arange(32, 62) - 31.5)
    np.testing.assert_allclose(out[0, 32, 32:62], 1 - 0.2 * (1 - (r / 32) ** 2), rtol=1e-5)
    assert np.all(np.diff(out[0, 32, 32:61]) > 0)  # brighter towards the edge of the disc


# --- physically based CT ----------------------------------------------------------------


def test_ct_simulation_recovers_attenuation_and_noise_grows_with_fewer_photons() -> None:
    radius = _radius((64, 64))
    disc = np.where(radius < 24, 1.0, 0.0).astype(np.float32)
    volume = np.repeat(disc[None], 3, 0)
    inner = np.broadcast_to(radius < 18, volume.shape)
    stds = []
    for photons in (1e3, 1e4, 1e5):
        out = CTSimulation(attenuation=0.02, photons=photons, gain_std=0.0)(volume, 5)
        assert out.dtype == np.float32 and out.shape == volume.shape
        assert out[inner].mean() == pytest.approx(1.0, rel=0.03)
        assert abs(out[np.broadcast_to(radius > 28, volume.shape)].mean()) < 0.03
        stds.append(out[inner].std())
    # counting noise: std ~ 1/sqrt(photons), so each 10x fewer photons about 3x more noise
    assert stds[0] > 2 * stds[1] > 4 * stds[2]


def test_ct_gain_errors_make_rings_constant_along_z() -> None:
    volume = np.zeros((3, 48, 48), dtype=np.float32)
    volume[:, 8:40, 8:40] = 1.0
    out = CTSimulation(attenuation=0.02, photons=1e9, gain_std=0.01, n_angles=80)(volume, 6)
    clean = CTSimulation(attenuation=0.02, photons=1e9, gain_std=0.0, n_angles=80)(volume, 6)
    rings = out - clean
    assert rings[0].std() > 0.02  # rings of the order of gain_std / attenuation = 0.5
    assert np.abs(rings[1] - rings[0]).max() < 0.1 * np.abs(rings[0]).max()


def test_ct_simulation_on_a_2d_slice() -> None:
    slice_ = np.zeros((40, 56), dtype=np.float32)
    slice_[10:30, 12:44] = 1.0
    out = CTSimulation(attenuation=0.03, photons=1e5, n_angles=60)(slice_, 0)
    assert out.shape == (40, 56) and out.dtype == np.float32
    assert out[14:26, 16:40].mean() == pytest.approx(1.0, rel=0.05)


# --- noise matching ---------------------------------------------------------------------


def test_noise_to_add_brings_clean_volume_to_source_level(phantom: tuple[np.ndarray, np.ndarray]) -> None:
    clean, labels = phantom
    source = estimate_noise(GaussianNoise(std=0.05)(clean, 1), labels).std
    synthetic = GaussianNoise(std=0.03)(clean, 2)
    transform = noise_to_add(source, estimate_noise(synthetic, labels).std)
    assert isinstance(transform, GaussianNoise)
    assert transform.std == pytest.approx(0.04, rel=0.1)  # sqrt(0.05^2 - 0.03^2)
    matched = estimate_noise(transform(synthetic, 3), labels).std
    assert matched == pytest.approx(0.05, rel=0.1)
    assert noise_to_add(0.03, 0.05).std == 0.0  # already noisier: nothing added


# --- configs ----------------------------------------------------------------------------


def test_config_round_trip_through_json_and_yaml() -> None:
    pipeline = Compose(
        [from_config(c) for c in CONFIGS] + [Compose([BeamHardening(0.1)]), CTSimulation(filter_name="hann")]
    )
    config = pipeline.to_config()
    assert from_config(json.loads(json.dumps(config))) == pipeline
    assert from_config(yaml.safe_load(yaml.safe_dump(config))) == pipeline
    assert from_config(pipeline.to_dict()) == pipeline
    assert pickle.loads(pickle.dumps(pipeline)) == pipeline  # for DataLoader workers
    assert from_config({"name": "gaussian_blur", "sigma": [0.5, 1.0]}) == GaussianBlur(sigma=(0.5, 1.0))


def test_generic_postprocessing_runs_on_volumes_and_slices(textured: np.ndarray) -> None:
    pipeline = generic_postprocessing()
    assert [t.name for t in pipeline] == ["gaussian_blur", "ring_artefacts", "gaussian_noise"]
    out, record = pipeline.apply(textured, 0)
    assert out.dtype == np.float32 and out.shape == SHAPE
    assert 0.03 <= record[-1]["std"] <= 0.08
    assert pipeline(textured[0], 0).shape == (64, 64)
    assert from_config(pipeline.to_config()) == pipeline
    assert generic_postprocessing(contrast=0.5)[2].std == pytest.approx((0.015, 0.04))
    assert generic_postprocessing(contrast=-0.5) == generic_postprocessing(contrast=0.5)  # darker grains
    for contrast in (0, float("nan"), True):
        with pytest.raises(SynthpackInputError, match="contrast"):
            generic_postprocessing(contrast=contrast)


@pytest.mark.parametrize(
    ("config", "message"),
    [
        ({"name": "gausian_noise", "std": 0.1}, "unknown artefact transform 'gausian_noise'.*gaussian_noise"),
        ({"std": 0.1}, "no 'name'"),
        ({"name": "gaussian_noise", "sigma": 0.1}, "unknown parameter.*'sigma'.*valid parameters are std, p"),
        ({"name": "gaussian_noise", "std": "0.1"}, "must be a number"),
        ({"name": "poisson_noise", "photons": "1e4"}, "write 1.0e4"),
        ({"name": "gaussian_noise", "std": True}, "must be a number"),
        ({"name": "gaussian_noise", "std": [0.1, 0.2, 0.3]}, "3 values"),
        ({"name": "gaussian_noise", "std": -0.1}, "must be >= 0"),
        ({"name": "gaussian_noise", "std": [0.2, 0.1]}, "minimum exceeds its maximum"),
        ({"name": "gaussian_noise", "std": float("nan")}, "finite"),
        ({"name": "gaussian_noise", "std": 0.1, "p": 1.5}, "'p'.*<= 1"),
        ({"name": "gaussian_noise", "std": 0.1, "p": [0.1, 0.5]}, "not a range"),
        ({"name": "poisson_noise", "photons": 0}, "> 0"),
        ({"name": "beam_hardening", "strength": 1.2}, "<= 1"),
        ({"name": "ring_artefacts", "n_rings": 2.5}, "whole number"),
        ({"name": "ring_artefacts", "radii": [3, -1]}, ">= 0"),
        ({"name": "ring_artefacts", "radii": 3}, "list of numbers"),
        ({"name": "ct_simulation", "filter_name": "butterworth"}, "'ramp'"),
        ({"name": "ct_simulation", "n_angles": 1}, ">= 2"),
        ({"name": "compose", "steps": []}, "'transforms'"),
        ("gaussian_noise", "must be a mapping"),
    ],
)
def test_config_errors(config: object, message: str) -> None:
    with pytest.raises(SynthpackInputError, match=message):
        from_config(config)  # type: ignore[arg-type]


def test_unknown_name_lists_every_valid_name() -> None:
    with pytest.raises(SynthpackInputError) as info:
        from_config([{"name": "gaussian_noise"}, {"name": "salt_and_pepper"}])
    for name in available_transforms():
        assert name in str(info.value)


def test_constructor_and_image_errors() -> None:
    with pytest.raises(SynthpackInputError, match="must be >= 0"):
        GaussianBlur(sigma=-1)
    with pytest.raises(SynthpackInputError, match="list of transforms"):
        Compose(GaussianNoise())  # type: ignore[arg-type]
    with pytest.raises(SynthpackInputError, match="volume"):
        GaussianNoise()(np.zeros(10), 0)
    with pytest.raises(SynthpackInputError, match="real-valued"):
        GaussianNoise()(np.zeros((4, 4), dtype=complex), 0)
    out = GaussianNoise()(np.zeros((4, 4), dtype=np.uint16), 0)
    assert out.dtype == np.float32


#: Ring powers falling over three decades, and a noise level: those the concrete neutron CT's pore
#: noise asked of its pack (intensity units squared), rounded.
STEEP_RINGS = (742_000.0, 427_000.0, 215_000.0, 114_000.0, 6_300.0, 830.0)
STEEP_HIGHPASS = 101_600.0


def test_the_noise_fit_matches_every_ring_of_a_steep_spectrum_as_a_factor() -> None:
    """The weak outer rings count as much, as a fraction of their power, as the strong inner ones:
    weighed relative to each target plus the largest, the fit gave the fifth and sixth rings half
    of their power (x0.53, x0.48), the pack then x0.33."""
    spectrum = spectrum_for_rings(STEEP_RINGS, STEEP_HIGHPASS)
    ratios = ring_powers_of_spectrum(spectrum, len(STEEP_RINGS)) / np.asarray(STEEP_RINGS)
    assert np.all((ratios > 0.75) & (ratios < 4 / 3)), ratios
    assert 0.75 < highpass_variance_of_spectrum(spectrum) / STEEP_HIGHPASS < 4 / 3


def test_the_texture_fit_converges_where_scipys_default_iterations_stop_short() -> None:
    """What a 60-grain pack of the concrete scan lacked (rounded): with SciPy's default of 3 iterations
    per unknown, its non-negative least squares raised "Maximum number of iterations reached" and the
    pack was not made."""
    semivariogram = (3_156_000.0, 7_553_000.0, 9_664_000.0, 10_074_000.0)
    powers, highpass, texture = fit_noise_and_texture(
        (745_800.0, 427_100.0, 215_300.0, 114_800.0, 6_258.0, 874.6), 101_600.0, semivariogram,
        (3_727_000.0, 9_692_000.0, 13_952_000.0, 16_517_000.0))
    assert min(powers) >= 0 and highpass >= 0
    added = semivariogram_of_spectrum(texture_spectrum(*texture)) if texture else np.zeros(4)
    assert added[-1] > 0.5 * semivariogram[-1]  # the texture carries the structure the noise cannot


def test_coloured_noise_has_the_asked_spectrum_per_phase_whatever_the_blocks() -> None:
    pore_power = [4e-4, 3e-4, 2e-4, 1e-4, 1e-5, 2e-6]  # smooth: falls with frequency
    grain_power = [1e-4] * 4 + [2e-5, 5e-6]
    image = np.zeros((64, 64, 96), dtype=np.float32)
    image[..., 48:] = 1.0  # pores at 0, grains at 1
    noise = ColouredNoise(pore_power=pore_power, grain_power=grain_power, pore_level=0.0, grain_level=1.0)
    whole = np.empty_like(image)
    apply_blockwise(noise, image, whole, seed=3, chunks=image.shape)
    for chunks in ((16, 32, 40), (64, 13, 7)):
        blocks = np.empty_like(image)
        apply_blockwise(noise, image, blocks, seed=3, chunks=chunks)
        np.testing.assert_array_equal(blocks, whole)
    for power, phase in ((pore_power, whole[..., 4:44] - 0.0), (grain_power, whole[..., 52:92] - 1.0)):
        measured = noise_power_spectrum(phase, np.ones(phase.shape, dtype=bool)).power[1:]
        np.testing.assert_allclose(measured[:4], power[:4], rtol=0.15)
    again = np.empty_like(image)
    apply_blockwise(noise, image, again, seed=4, chunks=image.shape)
    assert not np.array_equal(again, whole)
