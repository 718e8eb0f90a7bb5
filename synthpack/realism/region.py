"""The volumes a realism comparison measures, and the bulk region of each.

A `Specimen` is a labelled tomogram together with the boolean mask of the part of
it that is measured, its *bulk region*:

* a source scan: the specimen (`synthpack.measure.specimen.specimen_mask`: in each
  slice, the convex hull of the labelled voxels), so the container, the air
  around it and the corners outside the reconstructed field of view are left
  out, as in the source statistics the packs are built from;
* a synthetic pack: the cylinder about the tube axis that the pour's
  packing-fraction check uses (`synthpack.physics.checks`), i.e. one median grain
  diameter away from the tube wall and above the floor, and two diameters below
  the top of the pack (the highest grain point). That excludes the wall, the
  air outside the tube, the ordered layer at the floor and the loose top. It is
  `synthpack.artefacts.recipes.bulk_region`, where ``postprocess: calibrated`` fits too;
* a synthetic pack that is an interior crop (its manifest's ``view`` is ``interior``:
  ``reconstruct.view``): all of it, as the crop lies in its pour's bulk.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import SynthpackInputError
from ..artefacts.recipes import bulk_region
from ..scan.core import Scan
from ..measure.specimen import specimen_mask

__all__ = ["Specimen"]


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
        """A source scan, measured in the specimen (`~synthpack.measure.specimen.specimen_mask`)."""
        labels = np.asarray(scan.labels, dtype=np.int32)
        return cls(name, np.asarray(scan.tomogram, dtype=np.float32), labels, specimen_mask(labels),
                   tuple(scan.voxel_size), scan.unit)

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
        from ..store.pack import open_pack

        pack = open_pack(directory)
        manifest = pack.manifest
        checks = manifest.get("pour_checks", {})
        if "packing_region" not in checks or "grid_origin" not in manifest:
            raise SynthpackInputError(
                f"pack {directory} has no pour region in its manifest: generate it again with this synthpack"
            )
        interior = (manifest.get("view") or {}).get("view") == "interior"
        try:
            region = bulk_region(pack.shape, tuple(manifest["grid_origin"]), pack.voxel_size,
                                 None if interior else checks["packing_region"], manifest.get("n_particles"))
        except SynthpackInputError as error:
            raise SynthpackInputError(f"pack {directory}: {error}") from None
        volume = pack.clean if clean else pack.tomogram
        fraction = checks.get("packing_fraction")
        return cls(name or Path(directory).name, np.asarray(volume[:], dtype=np.float32),
                   np.asarray(pack.labels[:], dtype=np.int32), region, pack.voxel_size, pack.unit,
                   None if fraction is None else float(fraction))
