"""The pore texture: seeded, spatially correlated variation in the space between grains (a step of the render).

A real pore phase is not flat: a cement paste holds sand, voids and moisture, a
brine its own density variations, and every scan adds its noise. The render
draws the pore phase as the source's pore level plus a zero-mean texture, a
Gaussian random field with a given power spectral density ``D(f)``, synthesized
by filtering white noise in Fourier space by ``sqrt(D)`` on a periodic cube
(copies of it tile space seamlessly). The cube's white noise is drawn from the
render's seed, its realised standard deviation is set to the expected one, and
the value of a voxel depends only on its global index: the texture does not
depend on how the volume is cut into chunks.

**Period** (`PoreTextureConfig.period`). The cube covers the volume drawn: its
side is the smallest fast FFT length of at least the volume's largest side (and
at least the 64 voxels of the measured spectrum's largest scale), up to
`PoreTextureConfig.tile` (256). A pack no larger than that never shows the same
texture twice; a larger one repeats it every `tile` voxels (a cube of ``tile^3``
float64 values, and several FFTs of it, is the cost of a longer period). The cube is
drawn once per texture and seed and cached: the render's chunk threads that ask for it
at once wait for the first to draw it, which runs its FFTs on every core (the same
values on any number of threads) and its element-wise steps slab by slab, so that it
holds a few cubes of memory at a time (the default 256^3 cube: 10 s on one core).

Two models (`PoreTextureConfig.model`):

``measured`` (the default)
    ``D`` is the source's pore spectrum
    (`~synthpack.source.SourceStatistics.pore_spectrum`, measured on every scale up
    to 32 voxels) made smooth (`~synthpack.measure.pore_spectrum.smooth_spectrum`:
    in the logarithm of the density, a running median over shells takes out the
    estimate's noise spikes, then a running mean), kept below
    `PoreTextureConfig.cutoff` cycles per voxel and rolled off to 0 by a raised
    cosine over the next `PoreTextureConfig.rolloff` (at least `MIN_ROLLOFF`, the
    measured spectrum's resolution: a sharper cut would ring), the roll-off ending
    at `NYQUIST`, 0.5 cycles per voxel, at most (`PoreTextureConfig.band`), so that
    no power sits in the grid's corners, where a spike of the estimate drew a
    voxel-scale checkerboard. So the texture has no sharp edge in frequency, no
    spike, and nothing beyond the band. The split is the image-formation model's:
    the texture carries the pore phase's structure on scales of 5 voxels and more
    (at 0.1 cycles/voxel a Gaussian PSF of 1 voxel keeps 82 % of the amplitude, so
    the calibrated blur applied later barely changes it), and the calibrated noise step
    (`~synthpack.artefacts.calibrate`) adds what the source's noise power
    spectrum holds beyond it, ring by ring, after the blur. Drawing the whole
    spectrum here instead would put the source's voxel-scale power into the
    clean pack, where the blur would take part of it away and the noise step,
    which only adds, could not give it back in the right shape.
``gaussian``
    White noise smoothed by a Gaussian of `PoreTextureConfig.sigma` voxels (``D`` =
    ``exp(-4 pi^2 sigma^2 |f|^2)``), with the source's pore spread
    (`~synthpack.source.SourceStatistics.pore_std`) as its standard deviation.
    The ``measured`` model falls back to it, with a warning, for a source whose
    pore spectrum could not be measured (too little pore interior).

**Histogram shape** (`PoreTextureConfig.histogram`, on by default; the ``measured`` model
only). A Gaussian field has Gaussian values, and a real pore phase need not: a
cement paste's histogram is heavy-tailed. The measured texture's values are
mapped, voxel by voxel, through the Gaussian CDF and then the source's pore
quantile function (`~synthpack.source.SourceStatistics.pore_quantiles`,
`~synthpack.measure.pore_histogram.map_to_quantiles`). A map of the values alone
spreads part of the power beyond the band and over the roll-off (its harmonics:
1 % of the power for the heavy-tailed concrete paste, as much as the scan's noise
there). So the map is followed by `BAND_ITERATIONS` alternations (iterated
amplitude-adjusted surrogates, after Schreiber and Schmitz): from the roll-off's
start on, the Gaussian field's own Fourier amplitudes with the values' phases (so the roll-off
is the designed one and nothing is beyond it), then the values mapped onto the
histogram again by their ranks; the last step is the amplitudes'. Below the
roll-off the spectrum is the mapped values'. The texture keeps the Gaussian field's
correlations, has no power beyond the band, and has the source's histogram shape
within 1 to 2 % of its spread (Wasserstein distance over standard deviation, with
the concrete and sand scans' quantiles: 0.011 and 0.016, against 0.20 and 0.14
for Gaussian values); its standard deviation is set to the expected one again,
its median is about 0, and `PoreTextureConfig.density` stays the Gaussian field's.
A source without measured quantiles gets Gaussian values.
"""

from __future__ import annotations

import functools
import logging
import threading
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass

import numpy as np
from scipy import fft, special

from .._shared.arrays import periodic_window
from .._shared.chunks import thread_count
from .._shared.schema import in_range, non_negative, one_of, positive, setting
from .._shared.seeds import generator
from .._shared.text import sig
from ..measure.pore_histogram import map_to_quantiles
from ..measure.pore_spectrum import PORE_SPECTRUM_SIZE, frequency_radius, smooth_spectrum, spectrum_on_grid

__all__ = ["BAND_ITERATIONS", "MIN_ROLLOFF", "NYQUIST", "PoreTextureConfig"]

logger = logging.getLogger(__name__)

#: The measured texture's band ends here at most, cycles/voxel: the sphere the frequency grid holds in every direction.
NYQUIST = 0.5
#: The narrowest roll-off, cycles/voxel: the measured spectrum's resolution (its taper's, two shells).
MIN_ROLLOFF = 2.0 / PORE_SPECTRUM_SIZE
#: The mapped texture alternates this many times between its band and the source's histogram (ending in the band).
BAND_ITERATIONS = 10
#: The mapped texture's histogram is matched at this many quantiles (between its band steps).
_LEVELS = 1024
#: ... read off at most this many of its values.
_SAMPLE = 1 << 21
#: ... and applied through a table of this many values, evenly spaced from the least to the greatest.
_TABLE = 1 << 14
#: Element-wise steps on the cube run over this many of its slices at a time (their temporaries' size).
_SLAB = 16
#: Held while a periodic cube is drawn: the render's chunk threads that ask for the same cube at once wait for
#: the first to draw it (it is cached) rather than each drawing its own; the one drawing uses every core.
_FIELD_LOCK = threading.Lock()


@dataclass(frozen=True)
class PoreTextureConfig:
    """Settings of the pore texture (config ``reconstruct.pore_texture``), and the texture itself.

    Attributes
    ----------
    model : str
        ``"measured"``: the source's pore spectrum below `cutoff`; ``"gaussian"``:
        Gaussian-smoothed noise of `sigma` (see the module docstring).
    cutoff : float
        Measured model: highest frequency of the source's pore spectrum kept whole, cycles/voxel.
    rolloff : float
        Measured model: width of the raised-cosine roll-off above `cutoff`, cycles/voxel, from `MIN_ROLLOFF`
        (the measured spectrum's resolution) to `NYQUIST`.
    sigma : float
        Gaussian model: correlation length, Gaussian sigma, voxels (0: white noise).
    tile : int
        Largest period of the texture along each axis, voxels (a pack up to this size never repeats it).
    histogram : bool
        Measured model: map the values onto the source's pore histogram shape (see the module docstring).
    """

    model: str = setting("measured", one_of(("measured", "gaussian")),
                         "measured: the source's pore spectrum below cutoff (the calibrated noise adds the rest); "
                         "gaussian: noise smoothed by sigma, with the source's pore spread")
    cutoff: float = setting(0.1, non_negative, "measured model: the source's pore spectrum is kept up to this "
                            "frequency, cycles/voxel")
    rolloff: float = setting(0.1, in_range(MIN_ROLLOFF, NYQUIST), "measured model: width of the raised-cosine "
                             "roll-off above cutoff, cycles/voxel (a sharper cut would ring)")
    sigma: float = setting(0.8, non_negative, "gaussian model: correlation length of the pore texture, Gaussian "
                           "sigma, voxels")
    tile: int = setting(256, positive, "largest period of the pore texture, voxels: it covers a pack up to this "
                        "size, and repeats in larger ones")
    histogram: bool = setting(True, None, "measured model: map the texture's values onto the source's pore "
                              "histogram (its quantiles; false: Gaussian values)")

    def model_for(self, pore_spectrum: tuple[float, ...] | None) -> str:
        """The model drawn for a source with `pore_spectrum`: `model`, or ``"gaussian"`` when none was measured."""
        return "gaussian" if pore_spectrum is None else self.model

    def maps_histogram(self, pore_spectrum: tuple[float, ...] | None,
                       pore_quantiles: tuple[float, ...] | None) -> bool:
        """Whether the texture drawn for a source is mapped onto its pore histogram (measured model, quantiles)."""
        return self.histogram and pore_quantiles is not None and self.model_for(pore_spectrum) == "measured"

    def period(self, extent: Sequence[int] | None = None) -> int:
        """The side of the periodic cube drawn for a volume of shape `extent`, voxels.

        The smallest fast FFT length that covers the volume's largest side, at least
        `~synthpack.measure.pore_spectrum.PORE_SPECTRUM_SIZE` (the measured spectrum's
        largest scale) and at most `tile`; `tile` where `extent` is None.
        """
        if extent is None:
            return self.tile
        return min(self.tile, max(fft.next_fast_len(int(max(extent)), real=True), PORE_SPECTRUM_SIZE))

    def band(self) -> tuple[float, float]:
        """The measured model's roll-off, cycles/voxel: from 1 at the first frequency to 0 at the second.

        ``(cutoff, cutoff + rolloff)``, moved down to end at `NYQUIST` where it would end beyond.
        """
        start = min(self.cutoff, NYQUIST - self.rolloff)
        return start, start + self.rolloff

    def density(self, pore_std: float, pore_spectrum: tuple[float, ...] | None,
                extent: Sequence[int] | None = None) -> np.ndarray:
        """The texture's power spectral density on the FFT grid of its periodic cube.

        Parameters
        ----------
        pore_std : float
            The source's pore spread, intensity units: the Gaussian model's standard deviation.
        pore_spectrum : tuple of float or None
            The source's pore spectrum (`~synthpack.source.SourceStatistics.pore_spectrum`).
        extent : sequence of 3 int, optional
            The shape of the volume the texture is drawn for (see `period`).

        Returns
        -------
        ndarray of float64, shape (P, P, P), P = ``period(extent)``
            Intensity units squared times voxels cubed, 0 at frequency 0; its mean is the texture's variance.
            Read-only (computed once per texture, source and period, then shared).
        """
        return _density(self, float(pore_std), pore_spectrum, self.period(extent))

    def sample(
        self, lo: np.ndarray, hi: np.ndarray, seed: int, pore_std: float, pore_spectrum: tuple[float, ...] | None,
        pore_quantiles: tuple[float, ...] | None = None, extent: Sequence[int] | None = None,
    ) -> np.ndarray:
        """The texture over the global index box ``[lo, hi)``, intensity units.

        Parameters
        ----------
        lo, hi : ndarray of int, shape (3,)
            Half-open box in global voxel indices.
        seed : int
            The render's seed.
        pore_std, pore_spectrum
            The source's pore spread and pore spectrum (see `density`).
        pore_quantiles : tuple of float, optional
            The source's pore histogram shape (`~synthpack.source.SourceStatistics.pore_quantiles`);
            None: Gaussian values.
        extent : sequence of 3 int, optional
            The shape of the whole volume drawn (every box of it with the same `extent`): the period (`period`).

        Returns
        -------
        ndarray of float32, shape hi - lo
            Zero mean (Gaussian values) or median about 0 (mapped onto the histogram) over a period; a new array.
        """
        with _FIELD_LOCK:
            field = _periodic_field(self, float(pore_std), pore_spectrum, pore_quantiles, seed, self.period(extent))
        return periodic_window(field, lo, np.asarray(hi) - np.asarray(lo))

    def record(
        self, pore_std: float, pore_spectrum: tuple[float, ...] | None, seed: int,
        pore_quantiles: tuple[float, ...] | None = None, extent: Sequence[int] | None = None,
    ) -> dict:
        """What was drawn, for the manifest: settings, the model drawn, whether its values were mapped onto the
        source's histogram, amplitude (std, intensity units), period (voxels), seed."""
        amplitude = float(np.sqrt(self.density(pore_std, pore_spectrum, extent).mean()))
        return {**asdict(self), "model": self.model_for(pore_spectrum),
                "histogram": self.maps_histogram(pore_spectrum, pore_quantiles), "amplitude": amplitude,
                "period": self.period(extent), "seed": seed}


@functools.lru_cache(maxsize=2)
def _density(texture: PoreTextureConfig, pore_std: float, pore_spectrum: tuple[float, ...] | None,
             period: int) -> np.ndarray:
    """`PoreTextureConfig.density` on a cube of `period`, computed once per argument and read-only.

    Computed `_SLAB` slices at a time (every step is a function of the frequency alone).
    """
    shape = (period,) * 3
    density = np.empty(shape)
    measured = texture.model_for(pore_spectrum) == "measured"
    smooth = smooth_spectrum(np.asarray(pore_spectrum)) if measured else None
    start, end = texture.band()
    for first in range(0, period, _SLAB):
        rows = slice(first, first + _SLAB)
        radius = frequency_radius(shape, rows)
        if measured:
            slab = spectrum_on_grid(smooth, period, rows=rows)
            slab *= 0.5 * (1.0 + np.cos(np.pi * np.clip((radius - start) / (end - start), 0.0, 1.0)))
        else:
            slab = np.exp(-4.0 * np.pi**2 * texture.sigma**2 * radius**2)
        density[rows] = slab
    density[0, 0, 0] = 0.0
    if not measured:
        density *= pore_std**2 / max(density.mean(), np.finfo(float).tiny)
    density.flags.writeable = False
    return density


def _onto_histogram(values: np.ndarray, sigma: float, quantiles: np.ndarray) -> np.ndarray:
    """`values` mapped monotonically onto the histogram of `quantiles`: the quantile of each one's rank.

    The ranks are read off `_LEVELS` quantiles of at most `_SAMPLE` of the values (every
    k-th) and the least and greatest value, with linear interpolation between them; a
    rank's quantile is `~synthpack.measure.pore_histogram.map_to_quantiles` of its
    normal score (standard deviation `sigma`). Applied slab by slab (`_by_slabs`).
    """
    flat = values.ravel()
    sample = np.sort(flat[:: max(1, flat.size // _SAMPLE)])
    levels = (np.arange(_LEVELS) + 0.5) / _LEVELS
    observed = np.concatenate([[flat.min()], sample[(levels * len(sample)).astype(np.int64)], [flat.max()]])
    ends = 0.5 / flat.size
    scores = sigma * special.ndtri(np.concatenate([[ends], levels, [1.0 - ends]]))
    low, high = float(observed[0]), float(observed[-1])
    if high <= low:
        return np.zeros_like(values)
    table = np.interp(np.linspace(low, high, _TABLE), observed, map_to_quantiles(scores, sigma, quantiles))
    table, slope = table.astype(values.dtype), np.diff(table).astype(values.dtype)
    origin, scale = values.dtype.type(low), values.dtype.type((_TABLE - 1) / (high - low))

    def look_up(slab: np.ndarray) -> np.ndarray:
        position = (slab - origin) * scale
        index = np.minimum(position.astype(np.int32), _TABLE - 2)  # a table lookup: np.interp's search is slow
        position -= index
        return table[index] + position * slope[index]

    return _by_slabs(look_up, values, values.dtype)


def _by_slabs(function: Callable[[np.ndarray], np.ndarray], values: np.ndarray, dtype: type) -> np.ndarray:
    """``function(values)`` for an element-wise `function`, computed `_SLAB` slices of `values` at a time.

    The same values as one call, with the temporaries of a slab rather than of the whole cube.
    """
    out = np.empty(values.shape, dtype=dtype)
    for start in range(0, values.shape[0], _SLAB):
        out[start:start + _SLAB] = function(values[start:start + _SLAB])
    return out


def _mapped_in_band(field: np.ndarray, sigma: float, quantiles: np.ndarray, rolled: np.ndarray) -> np.ndarray:
    """The Gaussian `field` (standard deviation `sigma`) with the histogram of `quantiles`, no power beyond its band
    and its own roll-off: the map onto the histogram, then `BAND_ITERATIONS` times the field's own Fourier
    amplitudes (0 beyond the band) where `rolled` (bool, on the rfftn grid: the roll-off and beyond) with the
    values' phases, and, but for the last time, the histogram again (by the values' ranks)."""
    workers = thread_count(None)
    amplitudes = np.abs(fft.rfftn(field, workers=workers)[rolled]).astype(np.float32)
    values = _by_slabs(lambda slab: map_to_quantiles(slab, sigma, quantiles), field, np.float32)
    for step in range(BAND_ITERATIONS):
        spectrum = fft.rfftn(values, workers=workers)
        del values
        outer = spectrum[rolled]
        spectrum[rolled] = outer * (amplitudes / np.maximum(np.abs(outer), np.finfo(np.float32).tiny))
        del outer
        values = fft.irfftn(spectrum, s=field.shape, workers=workers)
        del spectrum
        if step < BAND_ITERATIONS - 1:
            values = _onto_histogram(values, sigma, quantiles)
    return values.astype(np.float64)


@functools.lru_cache(maxsize=2)
def _periodic_field(
    texture: PoreTextureConfig, pore_std: float, pore_spectrum: tuple[float, ...] | None,
    pore_quantiles: tuple[float, ...] | None, seed: int, period: int,
) -> np.ndarray:
    """A periodic cube of `period` voxels of the texture (`PoreTextureConfig.density`) from the white noise of
    `seed`, its values mapped onto `pore_quantiles` in its band where `PoreTextureConfig.maps_histogram`.

    Read-only float32, shape ``(period,) * 3``; its standard deviation is exactly the expected one.
    """
    if texture.model == "measured" and pore_spectrum is None:
        logger.warning("the source has no measured pore spectrum: Gaussian pore texture of sigma %s voxels",
                       sig(texture.sigma))
    shape = (period,) * 3
    density = _density(texture, pore_std, pore_spectrum, period)
    workers = thread_count(None)
    spectrum = fft.rfftn(generator(seed, "pore_texture").standard_normal(shape), workers=workers)
    spectrum *= np.sqrt(density[..., : period // 2 + 1])
    field = fft.irfftn(spectrum, s=shape, workers=workers)
    del spectrum
    expected = np.sqrt(density.mean())
    realised = field.std()
    if realised > 0:
        field *= expected / realised
        if texture.maps_histogram(pore_spectrum, pore_quantiles):
            rolled = np.concatenate([frequency_radius(shape, slice(first, first + _SLAB))[..., : period // 2 + 1]
                                     > texture.band()[0] for first in range(0, period, _SLAB)])
            field = _mapped_in_band(field, expected, np.asarray(pore_quantiles), rolled)
            field *= expected / field.std()
    field = field.astype(np.float32)
    field.flags.writeable = False
    return field
