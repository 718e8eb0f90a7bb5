"""The scanner's intensity response: contrast and gamma between the two phase levels.

A scan's grey values are a monotone function of the attenuation that differs from
one scanner, reconstruction and export to the next: the grain-pore contrast
is stretched or squeezed, and the response is bent (a gamma). `ContrastGamma`
applies such a response point by point, between a pore and a grain level.
"""

from __future__ import annotations

import numpy as np

from ._base import Transform
from ._param import Param, Range

__all__ = ["ContrastGamma"]


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

    def _transform(self, image: np.ndarray, rng: np.random.Generator, *, contrast: float, gamma: float,
                   pore_level: float, grain_level: float) -> np.ndarray:
        span = np.float32(grain_level - pore_level if grain_level != pore_level else 1.0)
        t = (image - np.float32(pore_level)) / span
        bent = np.sign(t) * np.abs(t) ** np.float32(gamma)
        middle = np.float32(0.5 * (pore_level + grain_level))
        out = np.float32(pore_level) + span * bent
        return (middle + np.float32(contrast) * (out - middle)).astype(np.float32, copy=False)
