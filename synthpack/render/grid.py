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

    @classmethod
    def box(cls, lo: np.ndarray, hi: np.ndarray, voxel_size: tuple[float, float, float]) -> Grid:
        """The voxels whose centres lie in the box ``[lo, hi]``, centred in it (an interior crop).

        Parameters
        ----------
        lo, hi : (3,) array of float
            World corners ``(z, y, x)`` of the box, physical units.
        voxel_size : tuple of 3 float
            ``(dz, dy, dx)``.
        """
        lo, hi, size = (np.asarray(v, dtype=float) for v in (lo, hi, voxel_size))
        shape = np.maximum(np.floor((hi - lo) / size + 1e-9).astype(int) + 1, 1)
        origin = (lo + hi) / 2 - (shape - 1) / 2 * size
        return cls(tuple(int(n) for n in shape), tuple(float(o) for o in origin), tuple(voxel_size))
