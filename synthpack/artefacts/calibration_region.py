"""Which voxels of a pack the calibration measures: its central slices, and the window of them the guard reads.

`~synthpack.artefacts.calibrate` fits on a representative sample of a pack's bulk region, so
that its cost is fixed whatever the pack's size: the central slices holding at most
`CALIBRATION_VOXELS` voxels (`central_slices`; `measured_slices` gives the same slices without
making the region, for a volume larger than memory), with `calibration_halo` voxels read
around them for the blur; in a region too wide for `MIN_CALIBRATION_SLICES` slices, a central
square of them first. The guard (`~synthpack.artefacts.guard`) reads those slices in the
window `lateral_window` keeps.
"""

from __future__ import annotations

import math

import numpy as np

from .coloured_noise import TILE
from .guard import MEASURED_MARGIN

__all__ = ["CALIBRATION_VOXELS", "MIN_CALIBRATION_SLICES", "bounding_box", "calibration_halo", "central_slices",
           "lateral_window", "measured_slices"]

#: The fit measures at most about this many voxels of the region (its central slices, `central_slices`):
#: more than a 150-grain pack's whole bulk. On a 600-grain pack of the "large" sample (bulk 3.2 M voxels)
#: the PSF sigma fitted on it is within 0.003 voxel, the noise levels within 0.1 % and the ring powers
#: within 2 % of the whole-bulk fit, at a quarter of its cost.
CALIBRATION_VOXELS = 1 << 20
#: The fewest slices the fit measures: a wider region is cut to a central square first (`central_slices`); as
#: deep as the spectrum match's cubes (`~synthpack.measure.volume_spectrum.TILE`).
MIN_CALIBRATION_SLICES = 32


def bounding_box(region: np.ndarray, halo: int) -> tuple[slice, ...]:
    """Bounding box of `region` grown by `halo` voxels (clipped to the volume)."""
    where = np.argwhere(region)
    low, high = where.min(axis=0) - halo, where.max(axis=0) + 1 + halo
    return tuple(slice(max(0, int(lo)), min(n, int(hi))) for lo, hi, n in zip(low, high, region.shape))


def central_slices(region: np.ndarray, max_voxels: int = CALIBRATION_VOXELS) -> np.ndarray:
    """The part of `region` in its central slices (along axis 0), holding at most about `max_voxels` voxels.

    Where fewer than `MIN_CALIBRATION_SLICES` of the region's widest slices would fit in
    `max_voxels` (a pack much wider than tall, e.g. a tube 1,000 voxels wide), the region
    is first cut to the central square of its slices (about its lateral centre) in which
    that many slices fit: the noise and spectra need voxels a few slices deep.

    Parameters
    ----------
    region : ndarray of bool, shape (Z, Y, X)
        Not empty.
    max_voxels : int
        Bound on the voxels kept; at least the central slice (of the central square) is kept.

    Returns
    -------
    ndarray of bool, same shape
        `region` itself when it holds at most `max_voxels` voxels; else `region` on
        ``n`` consecutive slices of those it occupies, centred in their range, with
        ``n = max_voxels // (the most voxels on one of its slices)`` (at least 1).
    """
    per_slice = np.count_nonzero(region, axis=(1, 2))
    if per_slice.sum() <= max_voxels:
        return region
    square = _central_square(region.any(axis=0), int(per_slice.max()), max_voxels)
    if square is not None:
        cut = np.zeros_like(region)
        cut[(slice(None), *square)] = region[(slice(None), *square)]
        region = cut
        per_slice = np.count_nonzero(region, axis=(1, 2))
    start, stop = _central_range(per_slice, max_voxels)
    kept = np.zeros_like(region)
    kept[start:stop] = region[start:stop]
    return kept


def measured_slices(in_slices: np.ndarray, in_slice: np.ndarray, max_voxels: int = CALIBRATION_VOXELS) -> tuple[int, int]:
    """The slices `central_slices` keeps of a region that is a stack of one shape, without making the region.

    For a region ``in_slices[:, None, None] & in_slice[None]`` (a pack's bulk
    cylinder): a caller can read only these slices (and `calibration_halo` more on
    each side) of a volume larger than memory, and get the same calibration as
    from the whole region.

    Parameters
    ----------
    in_slices : ndarray of bool, shape (Z,)
        The slices the region occupies.
    in_slice : ndarray of bool, shape (Y, X)
        The region on each of them.
    max_voxels : int
        As for `central_slices`.

    Returns
    -------
    (start, stop) : tuple of int
    """
    per_slice = in_slices.astype(np.int64) * int(np.count_nonzero(in_slice))
    if per_slice.sum() <= max_voxels:
        occupied = np.flatnonzero(per_slice)
        return int(occupied[0]), int(occupied[-1]) + 1
    square = _central_square(in_slice, int(per_slice.max()), max_voxels)
    if square is not None:
        per_slice = in_slices.astype(np.int64) * int(np.count_nonzero(in_slice[square]))
    return _central_range(per_slice, max_voxels)


def _central_square(lateral: np.ndarray, widest: int, max_voxels: int) -> tuple[slice, slice] | None:
    """The central square of `lateral` ((Y, X) bool) in which `MIN_CALIBRATION_SLICES` slices fit, or None."""
    if max_voxels // widest >= MIN_CALIBRATION_SLICES:
        return None
    side = max(1, math.isqrt(max_voxels // MIN_CALIBRATION_SLICES))
    rows, columns = np.flatnonzero(lateral.any(axis=1)), np.flatnonzero(lateral.any(axis=0))
    y0 = max(0, (int(rows[0]) + int(rows[-1]) + 1 - side) // 2)
    x0 = max(0, (int(columns[0]) + int(columns[-1]) + 1 - side) // 2)
    return slice(y0, y0 + side), slice(x0, x0 + side)


def _central_range(per_slice: np.ndarray, max_voxels: int) -> tuple[int, int]:
    """``(start, stop)`` of the central occupied slices holding at most `max_voxels` (at least one slice)."""
    occupied = np.flatnonzero(per_slice)
    n = min(len(occupied), max(1, max_voxels // int(per_slice.max())))
    start = occupied[(len(occupied) - n) // 2]
    stop = occupied[(len(occupied) - n) // 2 + n - 1] + 1
    return int(start), int(stop)


def calibration_halo(target_sigma: float) -> int:
    """Voxels read around the measured region for a source edge width `target_sigma` (voxels)."""
    return int(math.ceil(4 * target_sigma)) + 2


def lateral_window(region: np.ndarray, halo: int, cupping: bool) -> tuple[slice, slice]:
    """The (y, x) window of the slices the guard needs around `region`: centred, cut by multiples of the noise tile.

    A region much narrower than its slices (the central square of a wide tube's) needs no more
    than itself, the measured margin and `halo`. Cut by the same multiple of `TILE` on either
    side, the window keeps the slice centre (the rings' axis) and every voxel's noise (the
    coloured noise repeats every `TILE` voxels from the array's first), and the blur beyond
    the halo does not reach what is measured: the guard's figures are those of whole slices,
    at a fraction of their cost and memory. Whole slices where `cupping` is applied: its
    factor is scaled by the slice's size.
    """
    if cupping:
        return slice(None), slice(None)
    window = []
    for axis in (1, 2):
        occupied = np.flatnonzero(region.any(axis=tuple(a for a in range(3) if a != axis)))
        spare = min(int(occupied[0]), region.shape[axis] - 1 - int(occupied[-1])) - halo - MEASURED_MARGIN
        cut = max(spare, 0) // TILE * TILE
        window.append(slice(cut, region.shape[axis] - cut))
    return window[0], window[1]
