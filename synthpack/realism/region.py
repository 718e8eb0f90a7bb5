"""The volumes a realism comparison measures, and the bulk region of each.

A `Specimen` is a labelled tomogram together with the boolean mask of the part of
it that is measured, its *bulk region*:

* a source scan: the whole field of view (every voxel of the volume);
* a synthetic pack: the cylinder about the tube axis that the pour's
  packing-fraction check uses (`synthpack.physics.checks`), i.e. one median grain
  diameter away from the tube wall and above the floor, and two diameters below
  the top of the pack (the highest grain point). That excludes the wall, the
  air outside the tube, the ordered layer at the floor and the loose top.
"""

from __future__ import annotations

import logging
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import SynthpackInputError
from ..scan import Scan

logger = logging.getLogger(__name__)

__all__ = ["MIN_REGION_VOXELS", "Specimen", "bulk_region"]

#: A bulk region needs at least this many voxels to be measured.
MIN_REGION_VOXELS = 1000


def bulk_region(
    shape: tuple[int, int, int],
    origin: tuple[float, float, float],
    voxel_size: tuple[float, float, float],
    packing_region: dict[str, float],
) -> np.ndarray:
    """Voxels of a pack grid inside the bulk sub-cylinder of its pour.

    Parameters
    ----------
    shape : tuple of 3 int
        ``(Z, Y, X)`` of the pack volumes.
    origin : tuple of 3 float
        World position ``(z, y, x)`` of the centre of voxel ``(0, 0, 0)``, physical units.
    voxel_size : tuple of 3 float
        ``(dz, dy, dx)``, physical units.
    packing_region : dict
        ``radius``, ``z_min``, ``z_max`` of the sub-cylinder about the world z axis,
        physical units (``PourChecks.packing_region``).

    Returns
    -------
    ndarray of bool, shape (Z, Y, X)
        True for voxels whose centre lies in the sub-cylinder.

    Raises
    ------
    SynthpackInputError
        If fewer than `MIN_REGION_VOXELS` voxels lie in it (a pack too shallow or too
        narrow to have a bulk).
    """
    z = origin[0] + np.arange(shape[0]) * voxel_size[0]
    y = origin[1] + np.arange(shape[1]) * voxel_size[1]
    x = origin[2] + np.arange(shape[2]) * voxel_size[2]
    in_disc = np.hypot(y[:, None], x[None, :]) <= packing_region["radius"]
    in_height = (z >= packing_region["z_min"]) & (z <= packing_region["z_max"])
    region = in_height[:, None, None] & in_disc[None, :, :]
    if np.count_nonzero(region) < MIN_REGION_VOXELS:
        raise SynthpackInputError(
            f"the pack has no bulk to measure ({np.count_nonzero(region)} voxels lie one grain diameter "
            "from the tube wall and floor and two below its top): pour more grains (pour.n_particles) "
            "or use a wider tube (pour.tube_radius)"
        )
    return region


@dataclass
class Specimen:
    """A labelled tomogram and the bulk region that is measured in it.

    Attributes
    ----------
    name : str
        Shown in reports.
    tomogram : ndarray of float32, shape (Z, Y, X)
        Intensities.
    labels : ndarray of int32, shape (Z, Y, X)
        0 = pore (or anything that is not a grain), ``> 0`` = one grain each.
    region : ndarray of bool, shape (Z, Y, X)
        The bulk region (see the module docstring).
    voxel_size : tuple of 3 float
        ``(dz, dy, dx)`` in `unit`.
    unit : str
        Length unit.
    packing_fraction : float or None
        For a pack, the pour's Monte-Carlo packing fraction of the same region
        (from the meshes), to check the voxel measurement against.
    """

    name: str
    tomogram: np.ndarray
    labels: np.ndarray
    region: np.ndarray
    voxel_size: tuple[float, float, float]
    unit: str
    packing_fraction: float | None = None

    @classmethod
    def from_scan(cls, scan: Scan, name: str = "source") -> Specimen:
        """A source scan, measured over its whole field of view."""
        return cls(name, np.asarray(scan.tomogram, dtype=np.float32), np.asarray(scan.labels, dtype=np.int32),
                   np.ones(scan.shape, dtype=bool), tuple(scan.voxel_size), scan.unit)

    @classmethod
    def from_pack(cls, directory: str | os.PathLike, *, clean: bool = False, name: str | None = None) -> Specimen:
        """A synthetic pack on disk, measured in its bulk region.

        Parameters
        ----------
        directory : path-like
            A pack directory written by `synthpack generate`.
        clean : bool
            Use the clean volume (before post-processing) instead of the tomogram.
        name : str, optional
            Default: the directory name.
        """
        from ..pack import open_pack

        pack = open_pack(directory)
        manifest = pack.manifest
        checks = manifest.get("pour_checks", {})
        if "packing_region" not in checks or "grid_origin" not in manifest:
            raise SynthpackInputError(
                f"pack {directory} has no pour region in its manifest: generate it again with this synthpack"
            )
        region = bulk_region(pack.shape, tuple(manifest["grid_origin"]), pack.voxel_size, checks["packing_region"])
        volume = pack.clean if clean else pack.tomogram
        fraction = checks.get("packing_fraction")
        return cls(name or Path(directory).name, np.asarray(volume[:], dtype=np.float32),
                   np.asarray(pack.labels[:], dtype=np.int32), region, pack.voxel_size, pack.unit,
                   None if fraction is None else float(fraction))
