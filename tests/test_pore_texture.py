"""The pore phase's measured spectrum (synthpack.measure.pore_spectrum) and the texture drawn from it."""

import logging

import numpy as np
import pytest
from scipy import ndimage

from synthpack.render import Background, Grid, PoreTextureConfig, pose_maps, reconstruct
from synthpack.render.pore_texture import MIN_ROLLOFF, NYQUIST
from synthpack.measure.pore_histogram import MIN_QUANTILE_VOXELS, QUANTILE_SCORES, measure_pore_quantiles
from synthpack.measure.pore_spectrum import (
    PORE_SPECTRUM_SIZE,
    frequency_radius,
    measure_pore_spectrum,
    shell_frequencies,
    smooth_spectrum,
    spectrum_on_grid,
)

SIGMA = 2.0  # voxels
VARIANCE = 4.0  # intensity units squared


def _gaussian_density(frequency: np.ndarray) -> np.ndarray:
    """The density of white noise smoothed by a Gaussian of SIGMA, scaled to VARIANCE (intensity^2 voxel^3)."""
    return VARIANCE * (8 * np.pi**1.5 * SIGMA**3) * np.exp(-4 * np.pi**2 * SIGMA**2 * frequency**2)


def _smoothed_noise(shape=(96, 96, 96), seed=0) -> np.ndarray:
    white = np.random.default_rng(seed).standard_normal(shape)
    field = ndimage.gaussian_filter(white, SIGMA, mode="wrap")
    return 10.0 + field * np.sqrt(VARIANCE) / field.std()


def _holes(shape, seed=1) -> np.ndarray:
    """A pore-interior-like mask: the volume less 120 random balls of radius 9 (about two thirds left)."""
    rng = np.random.default_rng(seed)
    centres = rng.uniform(0, shape[0], size=(120, 3))
    index = np.indices(shape).reshape(3, -1).T
    mask = np.ones(shape, bool).ravel()
    for centre in centres:
        mask &= np.sum((index - centre) ** 2, axis=1) > 81
    return mask.reshape(shape)


def test_measured_spectrum_recovers_smoothed_noise_through_holes():
    field = _smoothed_noise()
    mask = _holes(field.shape)
    assert 0.4 < mask.mean() < 0.8
    measured = measure_pore_spectrum(field, mask)
    f = shell_frequencies(len(measured))
    assert len(measured) == int(np.rint(np.sqrt(3) * PORE_SPECTRUM_SIZE / 2)) + 1
    # the variance (the mean of the density on the grid) within 10 %
    assert spectrum_on_grid(measured, PORE_SPECTRUM_SIZE).mean() == pytest.approx(VARIANCE, rel=0.1)
    # the shape within 25 % where it holds 99 % of the power (beyond: the taper's leakage floor), but
    # for the two lowest shells: the taper's width and the mean taken from the data bias them low
    expected = _gaussian_density(f)
    band = (f >= 2 / PORE_SPECTRUM_SIZE) & (f <= 0.15)
    np.testing.assert_allclose(measured[band], expected[band], rtol=0.25)
    np.testing.assert_allclose(measured[:2], expected[:2], rtol=0.5)


def test_too_little_pore_interior_measures_nothing():
    field = _smoothed_noise((32, 32, 32))
    mask = np.zeros(field.shape, bool)
    mask[:10, :10, :10] = True
    assert measure_pore_spectrum(field, mask) is None


def _shells(field: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The periodogram of a periodic cube averaged over shells of 1/T: (density per shell, frequencies per shell)."""
    tile = field.shape[0]
    periodogram = np.abs(np.fft.fftn(field)) ** 2 / tile**3
    shells = np.rint(frequency_radius(field.shape) * tile).astype(int).ravel()
    counts = np.bincount(shells)
    return np.bincount(shells, periodogram.ravel()) / counts, counts


def test_texture_has_the_spectrum_it_is_drawn_from():
    f = shell_frequencies(29)
    spectrum = tuple(_gaussian_density(f) + 1.0)  # a smooth texture on a white floor
    texture = PoreTextureConfig(cutoff=0.15, rolloff=0.1, tile=128)
    field = texture.sample(np.zeros(3, int), np.full(3, 128), 7, pore_std=1.0, pore_spectrum=spectrum)
    expected = texture.density(1.0, spectrum)
    assert field.std() == pytest.approx(np.sqrt(expected.mean()), rel=1e-5)  # the expected variance, exactly
    measured, counts = _shells(field.astype(np.float64))
    shells = np.rint(frequency_radius(expected.shape) * 128).astype(int).ravel()
    wanted = np.bincount(shells, expected.ravel()) / counts
    # every shell of at least 100 frequencies within 25 % (sampling: about 1 / sqrt(n) per shell)
    kept = (counts >= 100) & (wanted > 0.01 * wanted.max())
    assert kept.sum() >= 15
    np.testing.assert_allclose(measured[kept], wanted[kept], rtol=0.25)
    # above cutoff + rolloff nothing: the noise step's band
    beyond = shell_frequencies(len(measured), 128) > 0.25 + 1.5 / 128
    assert measured[beyond].max() < 1e-6 * measured.max()


def _empty_render(texture: PoreTextureConfig, spectrum, seed: int, chunks, quantiles=None) -> np.ndarray:
    grid = Grid((40, 48, 56), (0.0, 0.0, 0.0), (1.0, 1.0, 1.0))
    maps = pose_maps([], np.zeros(0, int), np.zeros((0, 3, 3)), np.zeros((0, 3)), np.zeros(0), grid)
    background = Background(5.0, 1.0, texture=texture, pore_spectrum=spectrum, pore_quantiles=quantiles)
    return reconstruct([], maps, grid, background, seed=seed, chunks=chunks)[0]


def test_measured_texture_is_chunking_independent_and_seeded():
    spectrum = tuple(_gaussian_density(shell_frequencies(29)))
    texture = PoreTextureConfig(tile=32)
    whole = _empty_render(texture, spectrum, 3, (40, 48, 56))
    np.testing.assert_array_equal(whole, _empty_render(texture, spectrum, 3, (7, 11, 13)))
    assert whole.tobytes() == _empty_render(texture, spectrum, 3, (40, 48, 56)).tobytes()
    assert not np.array_equal(whole, _empty_render(texture, spectrum, 4, (40, 48, 56)))
    np.testing.assert_array_equal(whole[:8], whole[32:40])  # period: the tile
    assert not np.array_equal(whole[:8], whole[8:16])


def test_without_a_measured_spectrum_the_texture_is_gaussian(caplog):
    texture = PoreTextureConfig(tile=32)
    with caplog.at_level(logging.WARNING, logger="synthpack.render.pore_texture"):
        drawn = _empty_render(texture, None, 3, (40, 48, 56))
    assert "no measured pore spectrum" in caplog.text
    gaussian = _empty_render(PoreTextureConfig(model="gaussian", tile=32), None, 3, (40, 48, 56))
    np.testing.assert_array_equal(drawn, gaussian)
    assert texture.record(1.0, None, 3)["model"] == "gaussian"
    assert texture.record(1.0, (1.0, 0.5), 3)["model"] == "measured"


def _lognormal_quantiles() -> tuple[float, ...]:
    """Pore quantiles measured on a skewed, heavy-tailed (log-normal) pore interior seen through holes."""
    values = np.exp(0.6 * np.random.default_rng(5).standard_normal((64, 64, 64)))
    return tuple(measure_pore_quantiles(values, _holes((64, 64, 64))))


def _standardized_quantiles(values: np.ndarray) -> np.ndarray:
    return measure_pore_quantiles(values, np.ones(values.shape, bool))


def test_quantile_mapping_recovers_a_non_gaussian_marginal():
    quantiles = _lognormal_quantiles()
    assert quantiles[len(quantiles) // 2] == 0.0 and np.all(np.diff(quantiles) >= 0)
    spectrum = tuple(_gaussian_density(shell_frequencies(29)))
    texture = PoreTextureConfig(tile=96)
    box = (np.zeros(3, int), np.full(3, 96))
    mapped = texture.sample(*box, 7, 1.0, spectrum, quantiles).astype(np.float64)
    gaussian = texture.sample(*box, 7, 1.0, spectrum).astype(np.float64)
    expected = np.sqrt(texture.density(1.0, spectrum).mean())
    assert mapped.std() == pytest.approx(expected, rel=1e-5)  # the variance is kept
    assert np.median(mapped) == pytest.approx(0.0, abs=0.01 * expected)
    middle = np.abs(QUANTILE_SCORES) <= 2.5
    np.testing.assert_allclose(_standardized_quantiles(mapped)[middle], np.asarray(quantiles)[middle], atol=0.04)
    # the Gaussian texture has the wrong shape: the log-normal's lower tail is much shorter
    assert np.abs(_standardized_quantiles(gaussian) - quantiles)[middle].max() > 0.3
    # mapped in the band: from the roll-off on, the Gaussian field's own amplitudes (a map of the values alone
    # would spread power over the roll-off and beyond), nothing beyond it; and still the same field
    radius = frequency_radius(mapped.shape)
    rolled = radius > texture.band()[0]
    mapped_amplitude, gaussian_amplitude = np.abs(np.fft.fftn(mapped)), np.abs(np.fft.fftn(gaussian))
    held = rolled & (gaussian_amplitude > 1e-3 * gaussian_amplitude[rolled].max())
    ratio = mapped_amplitude[held] / gaussian_amplitude[held]  # one factor: the final standard deviation's
    assert held.sum() > 1000 and ratio.max() / ratio.min() < 1.001 and ratio.mean() == pytest.approx(1.0, abs=0.05)
    assert mapped_amplitude[radius > texture.band()[1] + 1e-9].max() < 1e-5 * gaussian_amplitude.max()
    assert np.corrcoef(mapped.ravel(), gaussian.ravel())[0, 1] > 0.8
    assert texture.record(1.0, spectrum, 7, quantiles)["histogram"] is True
    assert PoreTextureConfig(histogram=False).record(1.0, spectrum, 7, quantiles)["histogram"] is False
    assert PoreTextureConfig(model="gaussian").record(1.0, spectrum, 7, quantiles)["histogram"] is False


def test_mapped_texture_is_chunking_independent_and_seeded():
    spectrum = tuple(_gaussian_density(shell_frequencies(29)))
    quantiles = _lognormal_quantiles()
    texture = PoreTextureConfig(tile=32)
    whole = _empty_render(texture, spectrum, 3, (40, 48, 56), quantiles)
    np.testing.assert_array_equal(whole, _empty_render(texture, spectrum, 3, (7, 11, 13), quantiles))
    assert whole.tobytes() == _empty_render(texture, spectrum, 3, (40, 48, 56), quantiles).tobytes()
    assert not np.array_equal(whole, _empty_render(texture, spectrum, 4, (40, 48, 56), quantiles))
    assert not np.array_equal(whole, _empty_render(texture, spectrum, 3, (40, 48, 56)))
    # histogram: false draws the Gaussian values
    np.testing.assert_array_equal(_empty_render(PoreTextureConfig(tile=32, histogram=False), spectrum, 3, (40, 48, 56),
                                                quantiles), _empty_render(texture, spectrum, 3, (40, 48, 56)))


def test_too_little_pore_interior_measures_no_quantiles():
    values = np.random.default_rng(0).standard_normal((20, 20, 20))
    mask = np.zeros(values.shape, bool)
    mask.ravel()[: MIN_QUANTILE_VOXELS - 1] = True
    assert measure_pore_quantiles(values, mask) is None
    mask.ravel()[MIN_QUANTILE_VOXELS - 1] = True
    assert len(measure_pore_quantiles(values, mask)) == len(QUANTILE_SCORES)


def test_smoothing_takes_out_the_estimates_spikes_and_the_grids_corners():
    f = shell_frequencies(56)
    clean = 100.0 * np.exp(-30.0 * f)  # log-linear: the smoothing keeps it
    noisy = clean.copy()
    noisy[20] *= 100.0  # a spike of the estimate's noise
    noisy[25:27] = 0.0  # shells where the estimate fell below 0
    noisy[40:] = np.abs(np.random.default_rng(0).standard_normal(16))  # the corners: noise above the spectrum
    smooth = smooth_spectrum(noisy)
    assert np.all(smooth[: PORE_SPECTRUM_SIZE // 2 + 1] > 0) and not smooth[PORE_SPECTRUM_SIZE // 2 + 1 :].any()
    np.testing.assert_allclose(smooth[2:17], clean[2:17], rtol=1e-9)
    assert np.abs(np.log(smooth[17:31] / clean[17:31])).max() < np.log(2)  # spike and gap gone (100x, 0)
    assert not smooth_spectrum(np.zeros(56)).any()


def test_the_band_ends_at_nyquist_and_the_rolloff_is_never_sharp():
    assert PoreTextureConfig().band() == (0.1, pytest.approx(0.2))
    assert PoreTextureConfig(cutoff=0.5).band() == (pytest.approx(0.4), 0.5)
    spectrum = tuple(np.ones(56))
    density = PoreTextureConfig(cutoff=1.0, tile=32).density(1.0, spectrum)
    radius = frequency_radius(density.shape)
    assert density[radius > NYQUIST].max() == 0.0 and density[(radius > 0) & (radius < 0.4)].min() > 0
    assert MIN_ROLLOFF == 2 / PORE_SPECTRUM_SIZE


def test_the_period_covers_the_volume_up_to_the_tile():
    texture = PoreTextureConfig()
    assert texture.period(None) == texture.tile == 256
    assert texture.period((85, 109, 109)) >= 109 and texture.period((114, 205, 205)) >= 205
    assert texture.period((20, 30, 30)) == PORE_SPECTRUM_SIZE  # the measured spectrum's largest scale
    assert texture.period((10, 1000, 1000)) == 256 and PoreTextureConfig(tile=32).period((85, 109, 109)) == 32
    spectrum = tuple(_gaussian_density(shell_frequencies(29)))
    extent = (8, 150, 24)
    field = texture.sample(np.zeros(3, int), np.array(extent), 3, 1.0, spectrum, extent=extent)
    assert field.shape == extent and not np.allclose(field[:, :22], field[:, 128:150])  # 128, the old tile
    assert texture.record(1.0, spectrum, 3, extent=extent)["period"] == texture.period(extent)


def test_drawing_the_mapped_texture_holds_a_few_cubes_of_memory():
    """The periodic cube is the render's largest fixed cost (256^3 by default): its temporaries stay a few cubes.

    Measured with tracemalloc, which sees NumPy's allocations: drawing a 96^3 mapped texture peaks at
    4.2 float64 cubes (the cached density, the field, its half spectrum); with whole-cube temporaries
    (the white noise kept, the histogram map over the whole cube at once) it peaked at 7.6.
    """
    import tracemalloc

    spectrum = tuple(_gaussian_density(shell_frequencies(29)))
    texture = PoreTextureConfig(tile=96)
    box = (np.zeros(3, int), np.full(3, 96))
    tracemalloc.start()
    try:
        texture.sample(*box, 11, 1.0, spectrum, _lognormal_quantiles())
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 6 * 96**3 * 8


def test_chunk_threads_asking_for_the_texture_at_once_draw_its_cube_once():
    """The render's chunk threads share the cached cube: the second waits for the first rather than drawing its own."""
    from concurrent.futures import ThreadPoolExecutor

    from synthpack.render import pore_texture

    spectrum = tuple(_gaussian_density(shell_frequencies(29)))
    texture = PoreTextureConfig(tile=96)
    before = pore_texture._periodic_field.cache_info().misses
    boxes = [(np.array([0, 0, 0]), np.array([8, 8, 8])), (np.array([40, 0, 0]), np.array([48, 8, 8]))]
    with ThreadPoolExecutor(2) as pool:
        values = list(pool.map(lambda box: texture.sample(*box, 12345, 1.0, spectrum, _lognormal_quantiles()), boxes))
    assert pore_texture._periodic_field.cache_info().misses == before + 1
    assert not np.array_equal(values[0], values[1])
