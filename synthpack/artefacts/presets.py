"""The default post-processing pipeline."""

from __future__ import annotations

import math

from ..errors import SynthpackInputError
from ._base import Compose
from .blur import GaussianBlur
from .noise import GaussianNoise
from .radial import RingArtefacts

__all__ = ["default_postprocessing"]


def default_postprocessing(contrast: float = 1.0) -> Compose:
    """A modest, realistic post-processing: light blur, weak rings (half the time), Gaussian noise.

    The paper's post-processing was Gaussian noise alone (its section 4.3); this
    default keeps Gaussian noise as the main ingredient and adds the two
    artefacts every real scan shows to some degree, at weak levels, with ranges
    so that every call draws a slightly different scan:

    1. ``GaussianBlur(sigma=(0.5, 1.0))`` voxels: detector / focal-spot blur,
       softening the synthetic volume's resampled edges.
    2. ``RingArtefacts(amplitude=0.02 * contrast, n_rings=(3, 10), width=1.5, p=0.5)``.
    3. ``GaussianNoise(std=(0.03, 0.08) * contrast)``: 3-8 % of the grain-pore contrast.

    Intensities are in the tomogram's own units, so amplitudes are given as
    fractions of `contrast`. To match a particular scan's noise instead, use
    ``postprocess: match_source`` or ``calibrated`` (`synthpack.postprocess`).

    Parameters
    ----------
    contrast : float
        The grain-pore intensity difference of the volumes it will be applied to,
        in intensity units (> 0). Default 1 (intensities scaled to about [0, 1]).

    Returns
    -------
    Compose
        The pipeline; ``.to_config()`` gives its config.
    """
    if isinstance(contrast, bool) or not isinstance(contrast, (int, float)) or not (
        math.isfinite(contrast) and contrast > 0
    ):
        raise SynthpackInputError(
            f"contrast must be a positive number (the grain-pore intensity difference), got {contrast!r}"
        )
    c = float(contrast)
    return Compose(
        [
            GaussianBlur(sigma=(0.5, 1.0)),
            RingArtefacts(amplitude=0.02 * c, n_rings=(3, 10), width=1.5, p=0.5),
            GaussianNoise(std=(0.03 * c, 0.08 * c)),
        ]
    )
