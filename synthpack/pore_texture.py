"""The pore texture: seeded, spatially correlated noise in the space between grains (a step of the render).

A CT scan's pores are not flat: reconstruction and detector blur leave noise that
is correlated over about a voxel. The render draws the pore phase as the source's
pore level plus ``amplitude x texture``, with the amplitude the source's pore
spread (`~synthpack.source.SourceStatistics.pore_std`) and the texture a
unit-variance field of white noise smoothed by a Gaussian of `PoreTexture.sigma`
voxels. The field is a periodic cube of `PoreTexture.tile` voxels (its period far
beyond the correlation length, so the repetition is invisible) drawn from the
render's seed, and the value of a voxel depends only on its global index: the
texture does not depend on how the volume is cut into chunks.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from ._schema import non_negative, positive, setting

__all__ = ["PoreTexture"]

#: Stream of the render's seed that the texture's white noise is drawn from.
_STREAM = 0x7E47


@dataclass(frozen=True)
class PoreTexture:
    """Settings of the pore texture (config ``reconstruct.pore_texture``), and the texture itself.

    Attributes
    ----------
    sigma : float
        Correlation length: Gaussian sigma of the smoothing, voxels (0: white noise).
    tile : int
        Period of the texture along each axis, voxels.
    """

    sigma: float = setting(0.8, non_negative, "correlation length of the pore texture: Gaussian sigma, voxels")
    tile: int = setting(64, positive, "period of the pore texture, voxels (far beyond its correlation length)")

    def sample(self, lo: np.ndarray, hi: np.ndarray, seed: int) -> np.ndarray:
        """The texture over the global index box ``[lo, hi)``.

        Parameters
        ----------
        lo, hi : ndarray of int, shape (3,)
            Half-open box in global voxel indices.
        seed : int
            The render's seed.

        Returns
        -------
        ndarray of float32, shape hi - lo
            Unit variance and zero mean over a period; a new array.
        """
        wrapped = (np.arange(a, b) % self.tile for a, b in zip(lo, hi))
        return _periodic_field(self.sigma, self.tile, seed)[np.ix_(*wrapped)]

    def record(self, amplitude: float, seed: int) -> dict:
        """What was drawn, for the pack manifest: settings, amplitude (intensity units) and seed."""
        return {"sigma": self.sigma, "tile": self.tile, "amplitude": amplitude, "seed": seed}


@functools.lru_cache(maxsize=8)
def _periodic_field(sigma: float, tile: int, seed: int) -> np.ndarray:
    """A periodic cube of unit-variance noise with a Gaussian correlation of `sigma` voxels.

    White noise from ``seed``, smoothed with wrap-around boundaries, so copies of
    the cube tile space seamlessly. Read-only float32, shape ``(tile,) * 3``.
    """
    white = np.random.default_rng([seed, _STREAM]).standard_normal((tile,) * 3)
    smooth = ndimage.gaussian_filter(white, sigma, mode="wrap")
    field = ((smooth - smooth.mean()) / smooth.std()).astype(np.float32)
    field.flags.writeable = False
    return field
