"""Pixel noise: additive Gaussian, multiplicative speckle and photon-counting (Poisson).

Every transform works on a volume (Z, Y, X) or a slice (H, W) of float32
intensities in the tomogram's own units and draws its noise in slabs along axis 0
(at most `SLAB_VOXELS` voxels at a time), so the memory it needs beyond the output
is bounded. The noise of different voxels is independent ("white").
"""

from __future__ import annotations

from abc import abstractmethod
from collections.abc import Iterator
from typing import TYPE_CHECKING, Any

import numpy as np

from .._shared.arrays import float32_value as _f32
from .._shared.arrays import slabs
from ._base import BlockContext, Transform
from ._param import Param, Range

if TYPE_CHECKING:
    import torch

    from .torch_blocks import DeviceVolume

__all__ = ["GaussianNoise", "PoissonNoise", "SpeckleNoise"]


def _standard_noise(shape: tuple[int, ...], rng: np.random.Generator) -> Iterator[tuple[slice, np.ndarray]]:
    """White ``N(0, 1)`` noise over an image of `shape`, drawn slab by slab in the order every noise transform draws.

    Yields
    ------
    slab : slice
        Rows of axis 0 (`~synthpack._shared.arrays.slabs`).
    noise : ndarray of float32, shape ``(rows, *shape[1:])``
        A new array.
    """
    for s in slabs(shape):
        yield s, rng.standard_normal((s.stop - s.start, *shape[1:]), dtype=np.float32)


def _poisson_noise(image: np.ndarray, photons: float, rng: np.random.Generator) -> np.ndarray:
    """``Poisson(photons * max(image, 0)) / photons`` per voxel; float32, a new array."""
    out = np.empty(image.shape, dtype=np.float32)
    for s in slabs(image.shape):
        expected = np.maximum(image[s], 0.0, dtype=np.float64) * photons
        out[s] = rng.poisson(expected) / photons
    return out


class _WhiteNoise(Transform):
    """White Gaussian noise ``n ~ N(0, std^2)`` per voxel, combined with the image by `_combine`.

    The noise is drawn slab by slab (`_standard_noise`); the torch step draws the
    same slabs on the CPU from the block's generator and combines them on the device.
    """

    params = (Param("std", minimum=0.0),)

    def __init__(self, std: Range = 0.05, *, p: float = 1.0) -> None:
        super().__init__(std=std, p=p)

    @staticmethod
    @abstractmethod
    def _combine(noise: Any, image: Any) -> Any:
        """`noise` (float32, ``std * N(0, 1)``) combined with `image` (float32, its shape), in place of `noise`.

        Both NumPy arrays or both torch tensors on one device; returns `noise`.
        """

    def _transform(self, image: np.ndarray, rng: np.random.Generator, *, std: float) -> np.ndarray:
        out = np.empty(image.shape, dtype=np.float32)
        for rows, noise in _standard_noise(image.shape, rng):
            noise *= np.float32(std)
            out[rows] = self._combine(noise, image[rows])
        return out

    def _transform_block_torch(
        self, block: torch.Tensor, context: BlockContext, device: DeviceVolume, *, std: float
    ) -> torch.Tensor:
        import torch

        out = torch.empty_like(block)
        for rows, noise in _standard_noise(tuple(block.shape), context.rng):
            out[rows] = self._combine(device.put(noise).mul_(_f32(std)), block[rows])
        return out


class GaussianNoise(_WhiteNoise):
    """Add white Gaussian noise of standard deviation `std` (the paper's post-processing).

    ``out = image + n``, ``n ~ N(0, std^2)`` independently per voxel.

    Parameters
    ----------
    std : float or (float, float)
        Standard deviation in intensity units (>= 0); a ``(min, max)`` pair is
        drawn uniformly per call. Default 0.05.
    p : float
        Probability of applying the transform at a call. Default 1.
    """

    name = "gaussian_noise"

    @staticmethod
    def _combine(noise: Any, image: Any) -> Any:
        noise += image
        return noise


class SpeckleNoise(_WhiteNoise):
    """Multiplicative (speckle) noise: ``out = image * (1 + n)``, ``n ~ N(0, std^2)``.

    The noise standard deviation is ``std * |image|``, i.e. proportional to the
    intensity (its variance to the intensity squared).

    Parameters
    ----------
    std : float or (float, float)
        Relative standard deviation (dimensionless, >= 0); a ``(min, max)`` pair is
        drawn uniformly per call. Default 0.05.
    p : float
        Probability of applying the transform at a call. Default 1.
    """

    name = "speckle_noise"

    @staticmethod
    def _combine(noise: Any, image: Any) -> Any:
        noise += 1.0
        noise *= image
        return noise


class PoissonNoise(Transform):
    """Photon-counting noise: the variance is proportional to the intensity.

    Each voxel's intensity ``x`` is read as ``photons * x`` expected counts:
    ``out = Poisson(photons * max(x, 0)) / photons``. The mean stays ``x`` (for
    ``x >= 0``) and the variance is ``x / photons``, so fewer photons mean more
    noise. Negative intensities are counted as 0 (no photons).

    Parameters
    ----------
    photons : float or (float, float)
        Expected counts per unit of intensity (> 0); a ``(min, max)`` pair is drawn
        uniformly per call. Default 1000 (relative noise 3 % at intensity 1).
    p : float
        Probability of applying the transform at a call. Default 1.
    """

    name = "poisson_noise"
    params = (Param("photons", minimum=0.0, exclusive_minimum=True),)

    def __init__(self, photons: Range = 1000.0, *, p: float = 1.0) -> None:
        super().__init__(photons=photons, p=p)

    def _transform(self, image: np.ndarray, rng: np.random.Generator, *, photons: float) -> np.ndarray:
        return _poisson_noise(image, photons, rng)
