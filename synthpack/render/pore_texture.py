"""The pore texture: seeded, spatially correlated variation in the space between grains (a step of the render).

A real pore phase is not flat: a cement paste holds sand, voids and moisture, a
brine its own density variations, and every scan adds its noise. The render
draws the pore phase as the source's pore level plus a zero-mean texture, a
Gaussian random field with a given power spectral density ``D(f)``, synthesized
by filtering white noise in Fourier space by ``sqrt(D)`` on a periodic cube of
`PoreTextureConfig.tile` voxels (copies of it tile space seamlessly). The cube's white
noise is drawn from the render's seed, its realised standard deviation is set
to the expected one, and the value of a voxel depends only on its global index:
the texture does not depend on how the volume is cut into chunks.

Two models (`PoreTextureConfig.model`):

``measured`` (the default)
    ``D`` is the source's pore spectrum
    (`~synthpack.source.SourceStatistics.pore_spectrum`, measured on every scale up
    to 32 voxels), kept below `PoreTextureConfig.cutoff` cycles per voxel and rolled off
    to 0 by a raised cosine over the next `PoreTextureConfig.rolloff`. The split is the
    image-formation model's: the texture carries the pore phase's structure on
    scales of 5 voxels and more (at 0.1 cycles/voxel a Gaussian PSF of 1 voxel
    keeps 82 % of the amplitude, so the calibrated blur applied later barely
    changes it), and the calibrated noise step
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
`~synthpack.measure.pore_histogram.map_to_quantiles`), and its realised standard
deviation set to the expected one again: the texture gets the source's histogram
shape with the same variance and median 0. The map is monotonic and smooth, so the
spectrum moves little (for the heavy-tailed concrete paste, 1 % of the power moves
from below the cutoff to above the roll-off; docs/realism-concrete.md), and
`PoreTextureConfig.density` stays the Gaussian field's. A source without measured
quantiles gets Gaussian values.
"""

from __future__ import annotations

import functools
import logging
from dataclasses import asdict, dataclass

import numpy as np
from scipy import fft

from .._shared.arrays import periodic_window
from .._shared.schema import non_negative, one_of, positive, setting
from .._shared.seeds import generator
from .._shared.text import sig
from ..measure.pore_histogram import map_to_quantiles
from ..measure.pore_spectrum import frequency_radius, spectrum_on_grid

__all__ = ["PoreTextureConfig"]

logger = logging.getLogger(__name__)

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
        Measured model: width of the raised-cosine roll-off above `cutoff`, cycles/voxel (0: a sharp cut).
    sigma : float
        Gaussian model: correlation length, Gaussian sigma, voxels (0: white noise).
    tile : int
        Period of the texture along each axis, voxels.
    histogram : bool
        Measured model: map the values onto the source's pore histogram shape (see the module docstring).
    """

    model: str = setting("measured", one_of(("measured", "gaussian")),
                         "measured: the source's pore spectrum below cutoff (the calibrated noise adds the rest); "
                         "gaussian: noise smoothed by sigma, with the source's pore spread")
    cutoff: float = setting(0.1, non_negative, "measured model: the source's pore spectrum is kept up to this "
                            "frequency, cycles/voxel")
    rolloff: float = setting(0.1, non_negative, "measured model: width of the raised-cosine roll-off above cutoff, "
                             "cycles/voxel")
    sigma: float = setting(0.8, non_negative, "gaussian model: correlation length of the pore texture, Gaussian "
                           "sigma, voxels")
    tile: int = setting(128, positive, "period of the pore texture, voxels (beyond the largest scale it holds)")
    histogram: bool = setting(True, None, "measured model: map the texture's values onto the source's pore "
                              "histogram (its quantiles; false: Gaussian values)")

    def model_for(self, pore_spectrum: tuple[float, ...] | None) -> str:
        """The model drawn for a source with `pore_spectrum`: `model`, or ``"gaussian"`` when none was measured."""
        return "gaussian" if pore_spectrum is None else self.model

    def maps_histogram(self, pore_spectrum: tuple[float, ...] | None,
                       pore_quantiles: tuple[float, ...] | None) -> bool:
        """Whether the texture drawn for a source is mapped onto its pore histogram (measured model, quantiles)."""
        return self.histogram and pore_quantiles is not None and self.model_for(pore_spectrum) == "measured"

    def density(self, pore_std: float, pore_spectrum: tuple[float, ...] | None) -> np.ndarray:
        """The texture's power spectral density on the FFT grid of its tile.

        Parameters
        ----------
        pore_std : float
            The source's pore spread, intensity units: the Gaussian model's standard deviation.
        pore_spectrum : tuple of float or None
            The source's pore spectrum (`~synthpack.source.SourceStatistics.pore_spectrum`).

        Returns
        -------
        ndarray of float64, shape (tile, tile, tile)
            Intensity units squared times voxels cubed, 0 at frequency 0; its mean is the texture's variance.
            Read-only (computed once per texture and source, then shared).
        """
        return _density(self, float(pore_std), pore_spectrum)

    def sample(
        self, lo: np.ndarray, hi: np.ndarray, seed: int, pore_std: float, pore_spectrum: tuple[float, ...] | None,
        pore_quantiles: tuple[float, ...] | None = None,
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

        Returns
        -------
        ndarray of float32, shape hi - lo
            Zero mean (Gaussian values) or median 0 (mapped onto the histogram) over a period; a new array.
        """
        field = _periodic_field(self, float(pore_std), pore_spectrum, pore_quantiles, seed)
        return periodic_window(field, lo, np.asarray(hi) - np.asarray(lo))

    def record(
        self, pore_std: float, pore_spectrum: tuple[float, ...] | None, seed: int,
        pore_quantiles: tuple[float, ...] | None = None,
    ) -> dict:
        """What was drawn, for the manifest: settings, the model drawn, whether its values were mapped onto the
        source's histogram, amplitude (std, intensity units), seed."""
        amplitude = float(np.sqrt(self.density(pore_std, pore_spectrum).mean()))
        return {**asdict(self), "model": self.model_for(pore_spectrum),
                "histogram": self.maps_histogram(pore_spectrum, pore_quantiles), "amplitude": amplitude, "seed": seed}


@functools.lru_cache(maxsize=4)
def _density(texture: PoreTextureConfig, pore_std: float, pore_spectrum: tuple[float, ...] | None) -> np.ndarray:
    """`PoreTextureConfig.density`, computed once per argument and read-only."""
    radius = frequency_radius((texture.tile,) * 3)
    if texture.model_for(pore_spectrum) == "measured":
        ramp = np.clip((radius - texture.cutoff) / max(texture.rolloff, np.finfo(float).tiny), 0.0, 1.0)
        density = spectrum_on_grid(np.asarray(pore_spectrum), texture.tile) * 0.5 * (1.0 + np.cos(np.pi * ramp))
        density[0, 0, 0] = 0.0
    else:
        density = np.exp(-4.0 * np.pi**2 * texture.sigma**2 * radius**2)
        density[0, 0, 0] = 0.0
        density *= pore_std**2 / max(density.mean(), np.finfo(float).tiny)
    density.flags.writeable = False
    return density


@functools.lru_cache(maxsize=8)
def _periodic_field(
    texture: PoreTextureConfig, pore_std: float, pore_spectrum: tuple[float, ...] | None,
    pore_quantiles: tuple[float, ...] | None, seed: int,
) -> np.ndarray:
    """A periodic cube of the texture (`PoreTextureConfig.density`) from the white noise of `seed`, its values
    mapped onto `pore_quantiles` where `PoreTextureConfig.maps_histogram`.

    Read-only float32, shape ``(tile,) * 3``; its standard deviation is exactly the expected one.
    """
    if texture.model == "measured" and pore_spectrum is None:
        logger.warning("the source has no measured pore spectrum: Gaussian pore texture of sigma %s voxels",
                       sig(texture.sigma))
    shape = (texture.tile,) * 3
    density = texture.density(pore_std, pore_spectrum)
    white = generator(seed, "pore_texture").standard_normal(shape)
    field = fft.irfftn(fft.rfftn(white) * np.sqrt(density[..., : texture.tile // 2 + 1]), s=shape)
    expected = np.sqrt(density.mean())
    realised = field.std()
    if realised > 0:
        field *= expected / realised
        if texture.maps_histogram(pore_spectrum, pore_quantiles):
            field = map_to_quantiles(field, expected, np.asarray(pore_quantiles))
            field *= expected / field.std()
    field = field.astype(np.float32)
    field.flags.writeable = False
    return field
