"""Intensity windows: the range of a material's grey values that figures and exports map to.

A window ``(lo, hi)`` is taken from percentiles of the pooled intensities of one
or more volumes, so that every source shown or exported with it is mapped the
same way (the YOLO export's 8-bit PNGs, the realism report's patches and slices).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from ..errors import SynthpackInputError

__all__ = ["intensity_window"]


def intensity_window(volumes: Sequence[Any], percentiles: tuple[float, float] = (0.5, 99.5),
                     max_samples: int = 1 << 22) -> tuple[float, float]:
    """Percentiles of the pooled intensities of `volumes`, from an even subsample.

    Parameters
    ----------
    volumes : sequence of array-like, shape (Z, Y, X)
        NumPy arrays, memory maps or Zarr arrays (read with a stride).
    percentiles : (low, high)
        In percent.
    max_samples : int
        About this many voxels are read from each volume (every ``s``-th along
        each axis).

    Returns
    -------
    (float, float)
        ``(lo, hi)`` with ``lo < hi``, in the volumes' intensity units.

    Raises
    ------
    SynthpackInputError
        If the window is empty (``lo == hi``, e.g. a constant volume).
    """
    samples = []
    for volume in volumes:
        stride = max(1, math.ceil((math.prod(volume.shape) / max_samples) ** (1 / 3)))
        samples.append(np.asarray(volume[::stride, ::stride, ::stride], dtype=np.float64).ravel())
    lo, hi = np.percentile(np.concatenate(samples), percentiles)
    if not hi > lo:
        raise SynthpackInputError(
            f"the intensity window ({lo:g}, {hi:g}) is empty (constant volume?): give the window explicitly"
        )
    return float(lo), float(hi)
