"""Reconstruction artefacts centred on the rotation axis: rings and beam-hardening cupping.

The rotation axis of the scan is axis 0 (z) and passes through the centre of every
slice, ``((Y-1)/2, (X-1)/2)``; both artefacts are functions of the distance ``r``
(voxels) from it only, and are the same in every slice (constant along z), as
they are in a real scan. A 2D input is treated as one slice.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from .._shared.arrays import cupping_factor, radius_grid
from ..errors import SynthpackInputError
from ._base import Transform
from ._param import IntRange, Param, Range

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


class RingArtefacts(Transform):
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

    def _pattern(
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

    def _transform(self, image: np.ndarray, rng: np.random.Generator, **params: Any) -> np.ndarray:
        return image + self._pattern(image.shape, rng, **params)

    def _transform_block(
        self,
        block: np.ndarray,
        rng: np.random.Generator,
        call: np.random.SeedSequence,
        origin: tuple[int, int, int],
        shape: tuple[int, int, int],
        **params: Any,
    ) -> np.ndarray:
        """The block plus its part of the pattern, drawn from `call` (the same rings in every block)."""
        pattern = self._pattern(shape, np.random.default_rng(call), **params)
        return block + pattern[_window(origin, block.shape)]


class BeamHardening(Transform):
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

    def _transform(self, image: np.ndarray, rng: np.random.Generator, *, strength: float, keep: str) -> np.ndarray:
        return image * cupping_factor(image.shape, strength, keep)

    def _transform_block(
        self,
        block: np.ndarray,
        rng: np.random.Generator,
        call: np.random.SeedSequence,
        origin: tuple[int, int, int],
        shape: tuple[int, int, int],
        *,
        strength: float,
        keep: str,
    ) -> np.ndarray:
        """The block times its part of the whole slice's factor."""
        return block * cupping_factor(shape, strength, keep)[_window(origin, block.shape)]


def _window(origin: Sequence[int], shape: Sequence[int]) -> tuple[slice, slice]:
    """The (y, x) slices of a slice pattern covering a block of `shape` at `origin`."""
    return tuple(slice(o, o + n) for o, n in zip(origin[-2:], shape[-2:]))  # type: ignore[return-value]
