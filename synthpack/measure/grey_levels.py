"""The grey-level grid a scan's values lie on: whole numbers, or a float file's regular steps.

Most scans are stored as integers (8 or 16 bit). Some are stored as floats that are integers
scaled and shifted on the way out of the reconstruction (attenuation units, a normalised
HDF5): their values still lie on a grid, ``offset + k step``. A pack rounded to the same grid
(`~synthpack.artefacts.RoundLevels`) has the source's steps between neighbours; a float scan
whose values are continuous has no grid.
"""

from __future__ import annotations

import numpy as np

__all__ = ["GRID_TOLERANCE", "MIN_LEVELS", "grey_level_grid"]

#: The fewest distinct values a float scan's grid must hold (a CT scan holds many more; fewer is a phantom's).
MIN_LEVELS = 32
#: How far from the grid a float scan's values may lie, in steps (float32 rounding of the scaled integers).
GRID_TOLERANCE = 0.05
#: The most values read to find a float scan's grid (an even subset of the voxels).
_MAX_VALUES = 1 << 20


def grey_level_grid(tomogram: np.ndarray) -> tuple[float, float] | None:
    """The grid ``(step, offset)`` every value of `tomogram` lies on, or None where there is none.

    An integer file, or floats that are all whole, lie on ``(1.0, 0.0)``. Otherwise the distinct
    values of an even subset of the voxels (at most 2^20) are read: where there are at least
    `MIN_LEVELS` of them and at most one for every 8 values read, the step is the slope of the
    runs of neighbouring values (those about the smallest gap apart), fitted within each run and
    pooled, which is exact enough to count the steps of the widest gaps; then every value's whole
    number of steps from the lowest gives the step and offset by least squares, and the grid holds
    where every value lies within `GRID_TOLERANCE` of a step of it.

    Parameters
    ----------
    tomogram : ndarray, shape (Z, Y, X)
        The scan, any real dtype (read one slice at a time for the whole-number check).

    Returns
    -------
    (float, float) or None
        The step (> 0) and the offset, in ``[-step / 2, step / 2)``, intensity units.
    """
    if np.issubdtype(tomogram.dtype, np.integer):
        return 1.0, 0.0
    if all(np.array_equal(block, np.round(block)) for block in tomogram):
        return 1.0, 0.0
    flat = np.asarray(tomogram).reshape(-1)
    sample = flat[:: max(1, flat.size // _MAX_VALUES)].astype(np.float64)
    levels = np.unique(sample[np.isfinite(sample)])
    if not MIN_LEVELS <= len(levels) <= sample.size // 8:
        return None
    gaps = np.diff(levels)
    run = np.concatenate([[0], np.cumsum(gaps >= 1.5 * gaps.min())])  # runs of neighbouring levels, one step apart
    place = np.arange(len(levels)) - np.searchsorted(run, run)  # each level's place in its run
    step = _pooled_slope(place.astype(np.float64), levels, run)
    steps = np.concatenate([[0.0], np.cumsum(np.rint(gaps / step))])  # whole steps from the lowest value
    step, start = (float(v) for v in np.polyfit(steps, levels, 1))
    if step <= 0 or np.abs(levels - (start + steps * step)).max() > GRID_TOLERANCE * step:
        return None
    return step, start - step * float(np.floor(start / step + 0.5))


def _pooled_slope(x: np.ndarray, y: np.ndarray, group: np.ndarray) -> float:
    """The slope of `y` against `x` fitted within each group (each its own intercept), pooled: least squares."""
    count = np.bincount(group).astype(np.float64)
    x_mean, y_mean = (np.bincount(group, weights=v) / count for v in (x, y))
    dx, dy = x - x_mean[group], y - y_mean[group]
    return float(np.sum(dx * dy) / np.sum(dx * dx))
