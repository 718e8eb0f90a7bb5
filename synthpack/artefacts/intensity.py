"""The scanner's intensity response: contrast and gamma between the two phase levels, and the grey-level grid.

A scan's grey values are a monotone function of the attenuation that differs from
one scanner, reconstruction and export to the next: the grain-pore contrast
is stretched or squeezed, and the response is bent (a gamma). `ContrastGamma`
applies such a response point by point, between a pore and a grain level.
Most scans are then stored as whole numbers (8 or 16 bit), or as floats on a grid of regular
steps: `RoundLevels` puts a volume on that grid, so that its neighbour differences come in the
same steps.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import numpy as np

from .._shared.arrays import float32_value as _f32
from ._base import BlockContext, Transform
from ._param import Param, Range

if TYPE_CHECKING:
    import torch

    from .torch_blocks import DeviceVolume

__all__ = ["ContrastGamma", "RoundLevels", "rounding_variance"]


class ContrastGamma(Transform):
    """Bend the intensities with a gamma between two levels, then stretch them about their midpoint.

    With ``t = (x - pore_level) / (grain_level - pore_level)`` (0 at the pore level,
    1 at the grain level; either sign of contrast), ``t' = sign(t) |t|^gamma`` and
    ``y = pore_level + (grain_level - pore_level) t'``::

        out = m + contrast * (y - m),   m = (pore_level + grain_level) / 2

    So ``gamma`` moves the intermediate (partial-volume) values towards one level and
    keeps both levels, ``contrast`` scales the grain-pore difference (and the noise
    with it) and keeps the mean of the two levels. A voxel transform.

    Parameters
    ----------
    contrast : float or (float, float)
        Factor on the grain-pore difference (> 0). Default 1.
    gamma : float or (float, float)
        Exponent of the response between the levels (> 0). Default 1.
    pore_level, grain_level : float
        The two phase levels, intensity units (different).
    p : float
        Probability of applying the transform at a call. Default 1.
    """

    name = "contrast_gamma"
    params = (
        Param("contrast", minimum=0.0, exclusive_minimum=True),
        Param("gamma", minimum=0.0, exclusive_minimum=True),
        Param("pore_level", rangeable=False),
        Param("grain_level", rangeable=False),
    )

    def __init__(self, contrast: Range = 1.0, gamma: Range = 1.0, *, pore_level: float, grain_level: float,
                 p: float = 1.0) -> None:
        super().__init__(contrast=contrast, gamma=gamma, pore_level=pore_level, grain_level=grain_level, p=p)

    def _transform(self, image: np.ndarray, rng: np.random.Generator, **params: float) -> np.ndarray:
        return _response(image, np.sign, **params).astype(np.float32, copy=False)

    def _transform_block_torch(
        self, block: torch.Tensor, context: BlockContext, device: DeviceVolume, **params: float
    ) -> torch.Tensor:
        import torch

        return _response(block, torch.sign, **params)


def _response(image: Any, sign: Callable[[Any], Any], *, contrast: float, gamma: float, pore_level: float,
             grain_level: float) -> Any:
    """`ContrastGamma`'s response of float32 intensities: a NumPy array, or a torch tensor on any device.

    Parameters
    ----------
    image : ndarray or torch.Tensor of float32
        Intensities; never modified.
    sign : callable
        The element-wise sign of that array type (`numpy.sign`, `torch.sign`).
    contrast, gamma, pore_level, grain_level : float
        The drawn parameters (see `ContrastGamma`); applied as float32 scalars.

    Returns
    -------
    A new array of the type and dtype of `image`.
    """
    span = _f32(grain_level - pore_level if grain_level != pore_level else 1.0)
    t = (image - _f32(pore_level)) / span
    bent = sign(t) * abs(t) ** _f32(gamma)
    middle = _f32(0.5 * (pore_level + grain_level))
    out = _f32(pore_level) + span * bent
    return middle + _f32(contrast) * (out - middle)


def rounding_variance(step: float = 1.0) -> float:
    """The variance `RoundLevels` adds to intensities that spread over many steps: ``step^2 / 12``.

    The rounding error is then uniform over one step and independent from voxel to voxel:
    white noise of this variance on top of the noise already there (measured on the sand
    micro-CT's pack: noise level 1.035 before rounding, 1.069 after, ``hypot(1.035, 0.289)``
    = 1.075). A pack's noise is fitted less this where it is rounded last
    (`~synthpack.artefacts.calibrate`), as the source's own rounding is part of its noise.

    Parameters
    ----------
    step : float
        Grid spacing, intensity units (> 0).

    Returns
    -------
    float
        Intensity units squared.
    """
    return step * step / 12.0


class RoundLevels(Transform):
    """Round the intensities to the nearest ``offset + k step``: the grey-level grid of a scan stored as integers
    (`~synthpack.measure.grey_levels.grey_level_grid`).

    A voxel transform; float32 in and out.

    Parameters
    ----------
    step : float
        Grid spacing, intensity units (> 0). Default 1: whole numbers.
    offset : float
        Where the grid lies, intensity units. Default 0: whole numbers.
    p : float
        Probability of applying the transform at a call. Default 1.
    """

    name = "round_levels"
    params = (Param("step", minimum=0.0, exclusive_minimum=True, rangeable=False),
              Param("offset", rangeable=False))

    def __init__(self, step: float = 1.0, offset: float = 0.0, *, p: float = 1.0) -> None:
        super().__init__(step=step, offset=offset, p=p)

    def _transform(self, image: np.ndarray, rng: np.random.Generator, **params: float) -> np.ndarray:
        step, offset = _f32(params["step"]), _f32(params["offset"])
        rounded = np.round((image - offset) / step) * step
        return (rounded + offset if offset else rounded).astype(np.float32, copy=False)  # + 0 would turn -0 to +0

    def _transform_block_torch(
        self, block: torch.Tensor, context: BlockContext, device: DeviceVolume, **params: float
    ) -> torch.Tensor:
        step, offset = _f32(params["step"]), _f32(params["offset"])
        rounded = ((block - offset) / step).round_() * step
        return rounded + offset if offset else rounded
