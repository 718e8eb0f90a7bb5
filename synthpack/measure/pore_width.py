"""How wide the pore space is where each pore voxel lies: its local half-width (local thickness / 2).

A pack can have a real scan's porosity and still not its pores: rigid grains that rest on
each other at points leave a thin wedge of pore around every contact, where a real pack
of the same porosity has fewer, wider pores. The local half-width of a pore voxel is the
radius of the largest ball that holds it and lies wholly in the pore space (Hildebrand and
Rüegsegger's local thickness, halved). Balls of whole-voxel radii ``r = 1, 2, ...`` are
enough to tell a 2-voxel gap from an open pore: a voxel is within a ball of radius ``r``
wholly in the pores where it lies closer than ``r`` to a voxel at least ``r`` from every
grain voxel, so each radius costs one Euclidean distance transform.

The region measured is treated as the pore space's boundary too (outside it, nothing is
pore), as for a scan and a pack alike.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

__all__ = ["MAX_RADIUS", "pore_half_widths"]

#: Largest ball radius tried, voxels: wider pores count as this wide.
MAX_RADIUS = 12


def pore_half_widths(labels: np.ndarray, region: np.ndarray, max_radius: int = MAX_RADIUS) -> np.ndarray:
    """The local half-width of every pore voxel of `region`.

    Parameters
    ----------
    labels : ndarray of int, shape (Z, Y, X)
        0 = pore, > 0 = grain.
    region : ndarray of bool, same shape
        The voxels measured.
    max_radius : int
        Largest ball radius tried, voxels.

    Returns
    -------
    ndarray of int64, shape (N,)
        Per pore voxel of `region` (in C order), the radius in whole voxels of the largest
        ball in the pores that holds it (1 for a voxel of a gap 1 or 2 voxels wide, 2 for
        one of a gap 3 voxels wide).
    """
    pore = (np.asarray(labels) == 0) & region
    depth = ndimage.distance_transform_edt(pore)  # 1 next to a grain voxel
    width = np.where(pore, 1, 0).astype(np.int64)
    for radius in range(2, max_radius + 1):
        centres = depth >= radius
        if not centres.any():
            break
        width[pore & (ndimage.distance_transform_edt(~centres) < radius)] = radius
    return width[pore]
