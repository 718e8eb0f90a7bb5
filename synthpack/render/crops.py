"""The library crops as the render takes them: padded, prepared for the partial volume, with their support."""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import numpy as np
from scipy import ndimage

from .._shared.chunks import bounded_map
from .partial_volume import PAD, PartialVolume

__all__ = ["RenderCrop", "prepare_crops"]


class RenderCrop(NamedTuple):
    """One library particle as the render takes it (from `prepare_crops`).

    The NumPy render reads these arrays; the torch render keeps copies of `mask`, `intensity`
    and `distance` on its device (in a `RenderCrop` without `support`).

    Attributes
    ----------
    mask : ndarray of float32, shape (nz + 2, ny + 2, nx + 2)
        The mask, padded by one empty voxel: with the pad, SciPy's fast
        ``"constant"`` boundary mode interpolates it towards 0 beyond its edge
        exactly as the slower ``"grid-constant"`` would.
    intensity : ndarray of float32
        The clean crop: as it is for whole voxels, or prepared and padded by
        `~synthpack.render.partial_volume.PAD` for the partial volume
        (`~synthpack.render.partial_volume.PreparedCrop`).
    distance : ndarray of float32 or None
        Signed distance from the mask's boundary (voxels, padded like `intensity`)
        for the partial volume; None for whole voxels.
    support : ndarray of uint8, shape (nz + 2 PAD, ny + 2 PAD, nx + 2 PAD), or None
        1 on the crop voxels within one voxel (per axis) of a voxel that can give an
        output voxel a label or an occupancy (a mask voxel, or one whose signed
        distance exceeds the partial volume's threshold), padded by
        `~synthpack.render.partial_volume.PAD`. A voxel whose linear interpolation reads any
        such voxel has its nearest crop voxel in the support, so one cheap
        nearest-neighbour resampling of it finds every output voxel the grain can
        change (see `~synthpack.render.numpy_render.render_chunk`). None in the torch render's copies.
    """

    mask: np.ndarray
    intensity: np.ndarray
    distance: np.ndarray | None
    support: np.ndarray | None


def prepare_crops(
    crops: Sequence[tuple[np.ndarray, np.ndarray]],
    partial_volume: PartialVolume | None = None,
    used: Sequence[int] | None = None,
    threads: int = 1,
    thresholds: dict[int, float] | None = None,
) -> list[RenderCrop | None]:
    """Crops as the render takes them (see `RenderCrop`).

    Parameters
    ----------
    crops : sequence of (tomogram, mask)
        Clean crop (float32, shape (nz, ny, nx)) and mask (bool, same shape) of every
        library particle.
    partial_volume : PartialVolume, optional
        Prepare the crops for the partial-volume render (`PartialVolume.prepare`, which
        keeps them for the next render); None: whole voxels.
    used : sequence of int, optional
        Indices of the crops to prepare (e.g. those placed); the others are None. Default: all.
    threads : int
        Threads preparing crops (SciPy's distance transforms release the GIL).
    thresholds : dict of int to float, optional
        Partial volume: per crop, the lowest signed distance (crop voxels) at which any of
        its placements has a non-zero occupancy (`PartialVolume.threshold`); default:
        that of an unscaled placement.
    """
    wanted = sorted(set(range(len(crops)) if used is None else (int(i) for i in used)))
    thresholds = thresholds or {}

    def prepare(index: int) -> RenderCrop:
        tomogram, mask = crops[index]
        padded_mask = np.pad(mask.astype(np.float32), 1)
        if partial_volume is None:
            return RenderCrop(padded_mask, tomogram, None, _support(np.pad(mask, PAD)))
        intensity, distance = partial_volume.prepare(tomogram, mask)
        threshold = thresholds.get(index, partial_volume.threshold(1.0))
        # the margin keeps the support a superset whatever the float32 rounding of the occupancy
        reached = (distance > np.float32(threshold - _MARGIN)) | np.pad(mask, PAD)
        return RenderCrop(padded_mask, intensity, distance, _support(reached))

    prepared: list[RenderCrop | None] = [None] * len(crops)
    for index, crop in bounded_map(prepare, wanted, threads):
        prepared[index] = crop
    return prepared


#: Signed distance (crop voxels) by which the support reaches beyond the occupancy's threshold.
_MARGIN = 0.01


def _support(reached: np.ndarray) -> np.ndarray:
    """`reached` (bool) grown by one voxel along every axis and diagonal (a 3x3x3 cube), as uint8."""
    return ndimage.binary_dilation(reached, np.ones((3, 3, 3), dtype=bool)).view(np.uint8)
