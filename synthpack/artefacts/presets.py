"""The generic post-processing recipe: not fitted to any scan, for when no source scan should shape the packs."""

from __future__ import annotations

import math

from ..errors import SynthpackInputError
from ._base import Compose
from .blur import GaussianBlur
from .noise import GaussianNoise
from .radial import RingArtefacts

__all__ = ["generic_postprocessing"]


def generic_postprocessing(contrast: float = 1.0) -> Compose:
    """A generic recipe, scaled to the contrast only: light blur, weak rings (half the time), Gaussian noise.

    The paper's post-processing was Gaussian noise alone (its section 4.3); this
    recipe keeps Gaussian noise as the main ingredient and adds the two
    artefacts every real scan shows to some degree, at weak levels, with ranges
    so that every call draws a slightly different scan:

    1. ``GaussianBlur(sigma=(0.5, 1.0))`` voxels: detector / focal-spot blur,
       softening the synthetic volume's resampled edges.
    2. ``RingArtefacts(amplitude=0.02 * |contrast|, n_rings=(3, 10), width=1.5, p=0.5)``.
    3. ``GaussianNoise(std=(0.03, 0.08) * |contrast|)``: 3-8 % of the grain-pore contrast.

    It is not fitted to anything: its noise is whatever fraction of the contrast
    it draws, 3.4 times the source's on the ``large`` sample and several times
    a real scan's. It was the default before synthpack 0.3.0 (``postprocess:
    default``); packs made from a source scan now get ``calibrated``
    (`synthpack.artefacts.recipes`).

    Parameters
    ----------
    contrast : float
        The grain-pore intensity difference of the volumes it will be applied to,
        in intensity units: non-zero, negative for grains darker than pores;
        amplitudes scale with its magnitude. Default 1 (intensities scaled to
        about [0, 1]).

    Returns
    -------
    Compose
        The pipeline; ``.to_config()`` gives its config.

    Raises
    ------
    SynthpackInputError
        If `contrast` is not a finite, non-zero number.
    """
    if isinstance(contrast, bool) or not isinstance(contrast, (int, float)) or not (
        math.isfinite(contrast) and contrast != 0
    ):
        raise SynthpackInputError(
            f"contrast must be a finite, non-zero number (the grain-pore intensity difference), got {contrast!r}"
        )
    c = abs(float(contrast))
    return Compose(
        [
            GaussianBlur(sigma=(0.5, 1.0)),
            RingArtefacts(amplitude=0.02 * c, n_rings=(3, 10), width=1.5, p=0.5),
            GaussianNoise(std=(0.03 * c, 0.08 * c)),
        ]
    )
