"""The library crops as the render takes them: padded, with their smooth surface, prepared for the partial volume, with their support."""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import numpy as np
from scipy import ndimage

from .._shared.chunks import bounded_map
from .partial_volume import PartialVolume
from .surface import Surface

__all__ = ["RenderCrop", "prepare_crops"]


class RenderCrop(NamedTuple):
    """One library particle as the render takes it (from `prepare_crops`).

    The NumPy render reads these arrays; the torch render keeps copies of `intensity`
    and `distance` on its device (in a `RenderCrop` without `support`).

    Attributes
    ----------
    intensity : ndarray of float32
        The clean crop: as it is (shape (nz, ny, nx)) for whole voxels, or prepared and
        padded by `~synthpack.render.partial_volume.PAD` for the partial volume
        (`~synthpack.render.partial_volume.PartialVolume.prepare`).
    distance : ndarray of float32, shape (nz + 2 PAD, ny + 2 PAD, nx + 2 PAD)
        The signed distance of the grain's smooth surface (voxels, positive inside,
        `~synthpack.render.surface.Surface.distance`): its labels and its occupancy.
    support : ndarray of uint8, same shape as `distance`, or None
        1 on the crop voxels within one voxel (per axis) of a voxel that can give an
        output voxel a label or an occupancy (one whose signed distance exceeds 0 or the
        partial volume's threshold). A voxel whose linear interpolation reads any such
        voxel has its nearest crop voxel in the support, so one cheap
        nearest-neighbour resampling of it finds every output voxel the grain can
        change (see `~synthpack.render.numpy_render.render_chunk`). None in the torch render's copies.
    """

    intensity: np.ndarray
    distance: np.ndarray
    support: np.ndarray | None


def prepare_crops(
    crops: Sequence[tuple[np.ndarray, np.ndarray]],
    partial_volume: PartialVolume | None = None,
    used: Sequence[int] | None = None,
    threads: int = 1,
    thresholds: dict[int, float] | None = None,
    surface: Surface = Surface(),
) -> list[RenderCrop | None]:
    """Crops as the render takes them (see `RenderCrop`).

    Parameters
    ----------
    crops : sequence of (tomogram, mask)
        Clean crop (float32, shape (nz, ny, nx)) and mask (bool, same shape) of every
        library particle.
    partial_volume : PartialVolume, optional
        Prepare the intensities for the partial-volume render (`PartialVolume.prepare`,
        which keeps them for the next render); None: whole voxels.
    used : sequence of int, optional
        Indices of the crops to prepare (e.g. those placed); the others are None. Default: all.
    threads : int
        Threads preparing crops (SciPy's distance transforms and filters release the GIL).
    thresholds : dict of int to float, optional
        Partial volume: per crop, the lowest signed distance (crop voxels) at which any of
        its placements has a non-zero occupancy (`PartialVolume.threshold`); default:
        that of an unscaled placement.
    surface : Surface
        How each grain's smooth surface is made (`Surface.distance`, kept for the next render).
    """
    wanted = sorted(set(range(len(crops)) if used is None else (int(i) for i in used)))
    thresholds = thresholds or {}

    def prepare(index: int) -> RenderCrop:
        tomogram, mask = crops[index]
        distance = surface.distance(mask)
        if partial_volume is None:
            return RenderCrop(tomogram, distance, _support(distance > -_MARGIN))
        threshold = min(0.0, thresholds.get(index, partial_volume.threshold(1.0)))
        # the margin keeps the support a superset whatever the float32 rounding of the occupancy
        return RenderCrop(partial_volume.prepare(tomogram, distance), distance,
                          _support(distance > np.float32(threshold - _MARGIN)))

    prepared: list[RenderCrop | None] = [None] * len(crops)
    for index, crop in bounded_map(prepare, wanted, threads):
        prepared[index] = crop
    return prepared


#: Signed distance (crop voxels) by which the support reaches below the lowest level that labels or fills.
_MARGIN = 0.01


def _support(reached: np.ndarray) -> np.ndarray:
    """`reached` (bool) grown by one voxel along every axis and diagonal (a 3x3x3 cube), as uint8."""
    return ndimage.binary_dilation(reached, np.ones((3, 3, 3), dtype=bool)).view(np.uint8)
