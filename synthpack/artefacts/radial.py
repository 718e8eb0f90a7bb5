"""Reconstruction artefacts centred on the rotation axis: rings and beam-hardening cupping.

The rotation axis of the scan is axis 0 (z) and passes through the centre of every
slice, ``((Y-1)/2, (X-1)/2)``; both artefacts are functions of the distance ``r``
(voxels) from it only, and are the same in every slice (constant along z), as
they are in a real scan. A 2D input is treated as one slice.

Each is a map over one slice, made once per call by the NumPy code below (on a
torch device too: the map is moved there once per volume), which every voxel is
combined with: the rings are added, the cupping factor multiplies.
"""

from __future__ import annotations

from abc import abstractmethod
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from .._shared.arrays import cupping_factor, radius_grid
from ..errors import SynthpackInputError
from ._base import BlockContext, Transform
from ._param import IntRange, Param, Range

if TYPE_CHECKING:
    import torch

    from .torch_blocks import DeviceVolume

__all__ = ["BeamHardening", "RingArtefacts"]

_FWHM_TO_SIGMA = 1.0 / (2.0 * np.sqrt(2.0 * np.log(2.0)))


def _ring_pattern(
    shape: tuple[int, ...], radii: np.ndarray, amplitudes: np.ndarray, width: float
) -> np.ndarray:
    """Sum of Gaussian ring profiles ``a_k exp(-(r - r_k)^2 / 2 s^2)`` on one slice.

    The radial profile is tabulated every 1/8 voxel and interpolated at each
    pixel's radius, so the cost is one pass over the slice whatever the number of
    rings. Returns float32, shape (Y, X).
    """
    r = radius_grid(shape)
    table_r = np.arange(0.0, float(r.max()) + 1.0, 0.125)
    sigma = width * _FWHM_TO_SIGMA
    profile = (amplitudes[:, None] * np.exp(-0.5 * ((table_r[None, :] - radii[:, None]) / sigma) ** 2)).sum(0)
    return np.interp(r, table_r, profile).astype(np.float32)


def _window(origin: Sequence[int], shape: Sequence[int]) -> tuple[slice, slice]:
    """The (y, x) slices of a slice map covering a block of `shape` at `origin`."""
    return tuple(slice(o, o + n) for o, n in zip(origin[-2:], shape[-2:]))  # type: ignore[return-value]


class _SliceMap(Transform):
    """A map over one slice (Y, X), the same in every slice, combined with every voxel by `_combine`.

    A block is combined with its window of the whole slice's map, drawn from the
    call's generator (``BlockContext.call``), so every block gets the same map.
    """

    @abstractmethod
    def _slice_map(self, shape: tuple[int, ...], rng: np.random.Generator, **params: Any) -> np.ndarray:
        """The map of one slice of an image of `shape`, its draws from `rng`: float32, (Y, X)."""

    @staticmethod
    @abstractmethod
    def _combine(image: Any, map_: Any) -> Any:
        """`image` (float32) combined with `map_` (its (y, x) window): both NumPy arrays or both torch tensors.

        Returns a new array or tensor of the shape of `image`.
        """

    def _transform(self, image: np.ndarray, rng: np.random.Generator, **params: Any) -> np.ndarray:
        return self._combine(image, self._slice_map(image.shape, rng, **params))

    def _volume_map(self, context: BlockContext, **params: Any) -> np.ndarray:
        """The map of the whole volume's slice, drawn from ``context.call``."""
        return self._slice_map(context.shape, np.random.default_rng(context.call), **params)

    def _transform_block(self, block: np.ndarray, context: BlockContext, **params: Any) -> np.ndarray:
        return self._combine(block, self._volume_map(context, **params)[_window(context.origin, block.shape)])

    def _transform_block_torch(
        self, block: torch.Tensor, context: BlockContext, device: DeviceVolume, **params: Any
    ) -> torch.Tensor:
        map_ = device.once("slice map", lambda: device.put(self._volume_map(context, **params)))
        return self._combine(block, map_[_window(context.origin, block.shape)])


class RingArtefacts(_SliceMap):
    """Concentric rings about the rotation axis, constant along z.

    A detector pixel whose response is slightly off shifts every projection ray
    it records by the same amount; filtered back-projection turns that into a
    ring at the pixel's distance from the axis. Here each ring is an additive
    Gaussian profile in ``r`` of full width at half maximum `width`, its
    amplitude ``sign * amplitude * U(0.5, 1)`` with a random sign (brighter or
    darker ring) unless `amplitudes` fixes them, at a radius drawn uniformly in
    ``[0, min(Y, X) / 2]`` (the field of view) unless `radii` fixes them (a scan's
    measured rings: `~synthpack.source.SourceStatistics.ring_radii`).

    Parameters
    ----------
    amplitude : float or (float, float)
        Largest ring amplitude, in intensity units (>= 0). Default 0.02.
    n_rings : int or (int, int)
        Number of rings (>= 0), used when `radii` is None. Default (3, 10).
    width : float or (float, float)
        Ring FWHM in voxels (> 0). Default 1.5.
    radii : list of float or None
        Fixed ring radii in voxels; overrides `n_rings`. Default None.
    amplitudes : list of float or None
        Fixed signed ring amplitudes in intensity units, one per radius of `radii`;
        overrides the random amplitudes and signs (`amplitude` is then unused). Default None.
    p : float
        Probability of applying the transform at a call. Default 1.
    """

    name = "ring_artefacts"
    params = (
        Param("amplitude", minimum=0.0),
        Param("n_rings", kind="int", minimum=0),
        Param("width", minimum=0.0, exclusive_minimum=True),
        Param("radii", kind="floats", minimum=0.0, optional=True, rangeable=False),
        Param("amplitudes", kind="floats", optional=True, rangeable=False),
    )

    def __init__(
        self,
        amplitude: Range = 0.02,
        n_rings: IntRange = (3, 10),
        width: Range = 1.5,
        radii: Sequence[float] | None = None,
        amplitudes: Sequence[float] | None = None,
        *,
        p: float = 1.0,
    ) -> None:
        super().__init__(amplitude=amplitude, n_rings=n_rings, width=width, radii=radii, amplitudes=amplitudes, p=p)
        if self.amplitudes is not None and (self.radii is None or len(self.radii) != len(self.amplitudes)):
            raise SynthpackInputError(
                f"parameter 'amplitudes' of {self.name!r} needs one value per ring of 'radii', got "
                f"{len(self.amplitudes)} amplitudes and radii {self.radii!r}: give both lists, of the same length"
            )

    def _slice_map(
        self,
        shape: tuple[int, ...],
        rng: np.random.Generator,
        *,
        amplitude: float,
        n_rings: int,
        width: float,
        radii: tuple[float, ...] | None,
        amplitudes: tuple[float, ...] | None,
    ) -> np.ndarray:
        """The additive ring pattern of one slice of an image of `shape`: float32, (Y, X)."""
        if radii is None:
            ring_radii = rng.uniform(0.0, min(shape[-2:]) / 2.0, size=n_rings)
        else:
            ring_radii = np.asarray(radii, dtype=np.float64)
        if amplitudes is None:
            signs = rng.choice([-1.0, 1.0], size=ring_radii.size)
            peaks = amplitude * signs * rng.uniform(0.5, 1.0, size=ring_radii.size)
        else:
            peaks = np.asarray(amplitudes, dtype=np.float64)
        return _ring_pattern(shape, ring_radii, peaks, width)

    @staticmethod
    def _combine(image: Any, map_: Any) -> Any:
        return image + map_


class BeamHardening(_SliceMap):
    """Cupping: intensities fall off (or, with a negative strength, rise) towards the centre of each slice.

    A polychromatic beam hardens (loses its soft photons) along long paths, so
    rays through the middle of the sample look less attenuating and the
    reconstruction is darker in the centre. Modelled as the radial factor
    ``out = image * (1 - strength * max(1 - (r / R)^2, 0))`` with ``R = min(Y, X) / 2``
    (the field of view): the centre is scaled by ``1 - strength``, the rim of the
    field of view and everything outside it is unchanged. A scan's measured
    strength (`~synthpack.source.SourceStatistics.cupping_strength`) is fitted to this form.

    With ``keep="mean"`` the factor is divided by its mean over the field of view,
    ``1 - strength / 2``, so the mean level inside it is kept: for a synthetic volume
    whose phase levels are already the source's averages over its field (cupping
    included), so that the cupping is not counted twice.

    Parameters
    ----------
    strength : float or (float, float)
        Relative darkening of the centre, in [-1, 1]: negative for a brighter centre
        (as a scatter correction or a neutron scan may show). Default 0.05.
    keep : {"rim", "mean"}
        What the factor leaves unchanged: the rim of the field of view (default) or
        the mean level inside it.
    p : float
        Probability of applying the transform at a call. Default 1.
    """

    name = "beam_hardening"
    params = (Param("strength", minimum=-1.0, maximum=1.0),
              Param("keep", kind="choice", choices=("rim", "mean"), rangeable=False))

    def __init__(self, strength: Range = 0.05, *, keep: str = "rim", p: float = 1.0) -> None:
        super().__init__(strength=strength, keep=keep, p=p)

    def _slice_map(self, shape: tuple[int, ...], rng: np.random.Generator, *, strength: float,
                   keep: str) -> np.ndarray:
        """The cupping factor of one slice (`~synthpack._shared.arrays.cupping_factor`); nothing is drawn."""
        return cupping_factor(shape, strength, keep)

    @staticmethod
    def _combine(image: Any, map_: Any) -> Any:
        return image * map_
