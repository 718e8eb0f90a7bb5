"""Square in-slice patches wholly inside a mask, on a regular lattice.

Patches lie in the slices of axis 0 (the slice axis), so a patch is what a 2D
segmentation model would see. Their corners sit on a lattice of `step` voxels in
y and x in every slice; only patches whose every pixel is in the mask are kept,
and an even, deterministic subset is taken when there are more than wanted.
"""

from __future__ import annotations

import numpy as np

__all__ = ["patch_corners", "take_patches"]


def patch_corners(mask: np.ndarray, size: int, step: int, max_patches: int | None = None) -> np.ndarray:
    """Corners of the ``size x size`` in-slice patches that lie wholly in `mask`.

    Parameters
    ----------
    mask : ndarray of bool, shape (Z, Y, X)
        Allowed voxels.
    size : int
        Patch side, voxels.
    step : int
        Lattice spacing of the corners in y and x, voxels.
    max_patches : int, optional
        Keep at most this many, evenly spread over the list (slice by slice).

    Returns
    -------
    ndarray of int64, shape (N, 3)
        ``(z, y0, x0)`` of each patch's first voxel, in slice order.
    """
    counts = np.zeros((mask.shape[0], mask.shape[1] + 1, mask.shape[2] + 1), dtype=np.int32)
    counts[:, 1:, 1:] = mask.astype(np.int32).cumsum(1).cumsum(2)
    inside = (counts[:, size:, size:] - counts[:, :-size, size:] - counts[:, size:, :-size]
              + counts[:, :-size, :-size]) == size * size
    lattice = np.zeros_like(inside)
    lattice[:, ::step, ::step] = inside[:, ::step, ::step]
    corners = np.argwhere(lattice).astype(np.int64)
    if max_patches is not None and len(corners) > max_patches:
        corners = corners[np.linspace(0, len(corners) - 1, max_patches).astype(np.int64)]
    return corners


def take_patches(volume: np.ndarray, corners: np.ndarray, size: int) -> np.ndarray:
    """Cut the patches at `corners` out of `volume`.

    Parameters
    ----------
    volume : ndarray, shape (Z, Y, X)
    corners : ndarray of int, shape (N, 3)
        From `patch_corners`.
    size : int
        Patch side, voxels.

    Returns
    -------
    ndarray of float32, shape (N, size, size)
    """
    offsets = np.arange(size)
    z = corners[:, 0, None, None]
    y = corners[:, 1, None, None] + offsets[None, :, None]
    x = corners[:, 2, None, None] + offsets[None, None, :]
    return np.asarray(volume, dtype=np.float32)[z, y, x]
