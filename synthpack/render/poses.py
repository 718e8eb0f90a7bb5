"""Where each placed grain goes: the affine maps from output voxels to its crop, and the boxes it reaches.

Every placed particle's crop and mask are resampled ONCE with the affine map of its
pose (rotation ``R = Rz(psi) Ry(phi) Rx(theta)`` or the equivalent quaternion,
translation, scale) into the output grid, instead of the paper code's three
successive rotations. The region each particle can reach is the bounding box of its
rotated crop: the rotated corners of the crop (paper eq. 5) give the box extent
(eqs. 6-8), which is the crop plus the padding of eqs. 9-11, so no voxel of the
particle is cut (`pose_maps` bounds it tighter, by the rotated mask).
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy import ndimage

from ..errors import SynthpackInputError
from .grid import Grid

__all__ = ["PoseMaps", "grain_boxes", "mapped", "pose_maps"]

# (x, y, z) <-> (z, y, x): the permutation matrix is its own inverse.
_XYZ_TO_ZYX = np.array([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0]])


@dataclass(frozen=True)
class PoseMaps:
    """Affine maps from output voxel indices to each particle's crop indices.

    For output index ``o`` (z, y, x), the crop index is ``matrix[i] @ o + offset[i]``.

    Attributes
    ----------
    library_index : ndarray of int, shape (N,)
    matrix : ndarray of float, shape (N, 3, 3)
    offset : ndarray of float, shape (N, 3)
    box_lo, box_hi : ndarray of int, shape (N, 3)
        Half-open output box each particle can reach (clipped to the grid).
    """

    library_index: np.ndarray
    matrix: np.ndarray
    offset: np.ndarray
    box_lo: np.ndarray
    box_hi: np.ndarray


def pose_maps(
    masks: Sequence[np.ndarray],
    library_index: np.ndarray,
    rotations: np.ndarray,
    positions: np.ndarray,
    scales: np.ndarray,
    grid: Grid,
    *,
    reach: float = 1.0,
) -> PoseMaps:
    """Affine maps and reachable boxes of placed particles.

    Parameters
    ----------
    masks : sequence of ndarray of bool, shape (nz, ny, nx)
        Mask crop of every LIBRARY particle (indexed by `library_index`).
    library_index : ndarray of int, shape (N,)
        Library particle of each placement.
    rotations : ndarray, shape (N, 3, 3)
        Rotation matrices acting on ``(x, y, z)``, particle-local -> world.
    positions : ndarray, shape (N, 3)
        World ``(x, y, z)`` of each particle-local origin (crop centre), physical units.
    scales : ndarray, shape (N,)
        Scale factor of each placement.
    grid : Grid
        Output grid (same voxel size as the crops).
    reach : float
        The boxes hold every output voxel within this many crop voxels (per axis) of a
        mask voxel: as far as the grain's smooth surface and its partial volume reach
        (`~synthpack.render.surface.Surface.reach`).

    Returns
    -------
    PoseMaps

    Raises
    ------
    SynthpackInputError
        If a placed library particle has an empty mask (a corrupt library).
    """
    library_index = np.asarray(library_index, dtype=np.int64)
    n = len(library_index)
    rotations = np.asarray(rotations, dtype=float).reshape(n, 3, 3)
    positions = np.asarray(positions, dtype=float).reshape(n, 3)
    scales = np.asarray(scales, dtype=float).reshape(n)
    spacing = np.asarray(grid.voxel_size, dtype=float)
    origin = np.asarray(grid.origin, dtype=float)
    rot_zyx = _XYZ_TO_ZYX @ rotations @ _XYZ_TO_ZYX
    inverse = np.transpose(rot_zyx, (0, 2, 1)) / scales[:, None, None]
    matrix = inverse * spacing[None, None, :] / spacing[None, :, None]
    shapes = np.array([masks[i].shape for i in library_index], dtype=float).reshape(n, 3)
    centre_index = (shapes - 1.0) / 2.0
    t_zyx = positions[:, ::-1]
    offset = np.einsum("nij,nj->ni", inverse, origin - t_zyx) / spacing + centre_index
    # The paper pads each crop to the box of its rotated corners (eqs. 5-11). The box
    # of the rotated MASK voxels is tighter (about 2.4x fewer voxels for sand grains)
    # and still holds every output voxel the grain can label or fill: such a voxel
    # maps to within `reach` crop voxels (per axis) of a mask voxel, which the
    # forward map stretches by at most the row sums of |forward|.
    forward = np.linalg.inv(matrix) if n else np.zeros((0, 3, 3))
    extent = reach * np.abs(forward).sum(axis=2)
    surfaces = {int(i): _surface_voxels(masks[int(i)]) for i in np.unique(library_index)}
    empty = sorted(i for i, surface in surfaces.items() if not len(surface))
    if empty:
        raise SynthpackInputError(
            f"library particle(s) {', '.join(map(str, empty))} have an empty mask: the library is "
            "corrupt; build it again from the scan (synthpack library build)"
        )
    box_lo = np.empty((n, 3), dtype=np.int64)
    box_hi = np.empty((n, 3), dtype=np.int64)
    for k in range(n):
        mapped = (surfaces[int(library_index[k])] - offset[k]) @ forward[k].T
        box_lo[k] = np.floor(mapped.min(axis=0) - extent[k])
        box_hi[k] = np.ceil(mapped.max(axis=0) + extent[k]) + 1
    box_lo = np.clip(box_lo, 0, grid.shape)
    box_hi = np.clip(box_hi, 0, grid.shape)
    return PoseMaps(library_index, matrix, offset, box_lo, box_hi)


def _surface_voxels(mask: np.ndarray) -> np.ndarray:
    """Indices (K, 3), float, of the mask voxels on its surface (their hull bounds the mask)."""
    surface = mask & ~ndimage.binary_erosion(mask)
    return np.argwhere(surface).astype(float)


def grain_boxes(maps: PoseMaps, lo: np.ndarray, hi: np.ndarray) -> Iterator[tuple[int, np.ndarray, np.ndarray, np.ndarray]]:
    """The placements that reach the box ``[lo, hi)``, in placement order.

    Yields
    ------
    i : int
        The placement.
    sub_lo, sub_hi : ndarray of int, shape (3,)
        The part of the box it can reach (output voxel indices).
    offset : ndarray of float, shape (3,)
        Crop index of output voxel `sub_lo` (``maps.offset[i] + maps.matrix[i] @ sub_lo``).
    """
    hit = np.all((maps.box_lo < hi) & (maps.box_hi > lo), axis=1)
    for i in np.flatnonzero(hit):
        sub_lo = np.maximum(maps.box_lo[i], lo)
        sub_hi = np.minimum(maps.box_hi[i], hi)
        yield int(i), sub_lo, sub_hi, maps.offset[i] + maps.matrix[i] @ sub_lo


def mapped(matrix: np.ndarray, where: tuple[Any, Any, Any], xp: Any = np) -> Any:
    """``matrix @ o`` of the box indices ``o = where``, summed as SciPy's ``affine_transform`` sums it.

    Added to a grain's offset, the crop coordinates `scipy.ndimage.affine_transform` computes
    for these voxels, to the last bit: a render that interpolates only some voxels of a box
    reads exactly what a dense resampling of it reads.

    Parameters
    ----------
    matrix : ndarray of float, shape (3, 3)
        A `PoseMaps` matrix.
    where : tuple of 3 arrays, shape (K,)
        The voxels' (z, y, x) indices in the box: NumPy integers or floats, or float64 torch tensors.
    xp : module
        The array module of `where`: numpy or torch.

    Returns
    -------
    array of float64, shape (3, K)
    """
    rows = []
    for row in range(3):
        total = where[0] * float(matrix[row, 0])
        for column in (1, 2):
            total += where[column] * float(matrix[row, column])
        rows.append(total)
    return xp.stack(rows)
