"""The output voxel grid: its shape and where its voxels lie in the world."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Grid"]


@dataclass(frozen=True)
class Grid:
    """The output voxel grid in world coordinates.

    Attributes
    ----------
    shape : tuple of 3 int
        ``(Z, Y, X)`` in voxels.
    origin : tuple of 3 float
        World position ``(z, y, x)`` of the CENTRE of voxel ``(0, 0, 0)``, physical units.
    voxel_size : tuple of 3 float
        ``(dz, dy, dx)``, physical units.
    """

    shape: tuple[int, int, int]
    origin: tuple[float, float, float]
    voxel_size: tuple[float, float, float]

    @classmethod
    def covering(
        cls,
        radius: float,
        z_min: float,
        z_max: float,
        voxel_size: tuple[float, float, float],
        margin: int = 4,
    ) -> Grid:
        """A grid that covers a cylinder of `radius` about the z axis from `z_min` to `z_max`.

        Parameters
        ----------
        radius : float
            Radius to cover (e.g. the tube's outer radius), physical units.
        z_min, z_max : float
            World z range to cover, physical units.
        voxel_size : tuple of 3 float
            ``(dz, dy, dx)``.
        margin : int
            Extra voxels on every side.
        """
        dz, dy, dx = voxel_size
        ny = 2 * (int(np.ceil(radius / dy)) + margin) + 1
        nx = 2 * (int(np.ceil(radius / dx)) + margin) + 1
        nz = int(np.ceil((z_max - z_min) / dz)) + 2 * margin + 1
        origin = (z_min - margin * dz, -(ny // 2) * dy, -(nx // 2) * dx)
        return cls((nz, ny, nx), origin, tuple(voxel_size))
