"""Voxel mask to surface mesh (paper section 3.2): marching cubes, then decimation."""

from __future__ import annotations

import logging

import numpy as np
import trimesh
from scipy import ndimage
from skimage.measure import marching_cubes

from ..errors import SynthpackInputError

logger = logging.getLogger(__name__)

__all__ = ["mesh_from_mask"]

_PAD = 2  # empty voxels around the mask, so the smoothed surface closes
_SMOOTHING_SIGMA = 0.5  # voxels


def mesh_from_mask(
    mask: np.ndarray,
    voxel_size: tuple[float, float, float] = (1.0, 1.0, 1.0),
    *,
    target_faces: int | None = None,
) -> trimesh.Trimesh:
    """Watertight surface of a binary particle mask.

    The mask's holes are filled (the simulator needs the outer surface only), it
    is padded by two empty voxels so the surface closes, and smoothed with a
    Gaussian of half a voxel: the raw voxel staircase makes quadric decimation
    leave non-manifold edges (about one grain in ten; one in hundreds after
    smoothing). Marching cubes (Lewiner) then extracts the iso-surface at the
    level above which the smoothed volume holds exactly as many voxels as the
    mask, which keeps the particle's volume (median error 0.2% on the sample
    grains; sharp corners are rounded, a box gains about 3%). The mesh is then
    decimated with quadric error metrics (``fast-simplification`` through trimesh)
    to about `target_faces` faces (within 25%; a count that would break
    watertightness is nudged, then the mesh is halved (`DECIMATION_STEP`) and tried again,
    and the fewest faces that kept it whole are kept if no count works).

    Parameters
    ----------
    mask : ndarray of bool, shape (nz, ny, nx)
        The particle's voxels.
    voxel_size : tuple of 3 float
        ``(dz, dy, dx)`` in physical units.
    target_faces : int or None
        Face budget after decimation; None (default) keeps the marching-cubes
        mesh. The library's budget is `synthpack.library.core.LibraryConfig.target_faces`.

    Returns
    -------
    trimesh.Trimesh
        Watertight mesh in the particle-local frame: vertices ``(x, y, z)`` in
        physical units, origin at the centre of the mask's box, with ``x, y, z``
        along array axes ``2, 1, 0``. Faces wind outwards (positive volume).
    """
    mask = np.asarray(mask, dtype=bool)
    if mask.ndim != 3 or not mask.any():
        raise SynthpackInputError(
            f"cannot mesh a mask of shape {mask.shape} with {int(mask.sum())} voxels: "
            "a non-empty 3D mask is needed"
        )
    if target_faces is not None and target_faces < 8:
        raise SynthpackInputError(f"target_faces must be at least 8, got {target_faces}")
    spacing = np.asarray(voxel_size, dtype=float)
    filled = ndimage.binary_fill_holes(mask)
    smooth = ndimage.gaussian_filter(np.pad(filled, _PAD).astype(np.float32), _SMOOTHING_SIGMA)
    verts_zyx, faces, _, _ = marching_cubes(
        smooth, level=_volume_preserving_level(smooth, int(filled.sum())),
        spacing=tuple(spacing), allow_degenerate=False,
    )
    centre_zyx = ((np.asarray(mask.shape, dtype=float) - 1.0) / 2.0 + _PAD) * spacing
    # (z, y, x) -> (x, y, z) mirrors the frame, so the winding flips too.
    vertices = (verts_zyx - centre_zyx)[:, ::-1]
    mesh = trimesh.Trimesh(vertices, faces[:, ::-1], process=True)
    if mesh.volume < 0:
        mesh.invert()
    if not mesh.is_watertight:
        raise SynthpackInputError(
            "marching cubes gave an open surface; the mask may be degenerate "
            f"(shape {mask.shape}, {int(mask.sum())} voxels)"
        )
    if target_faces is not None and len(mesh.faces) > target_faces:
        mesh = _decimate(mesh, target_faces)
    return mesh


def _volume_preserving_level(smooth: np.ndarray, n_voxels: int) -> float:
    ranked = np.partition(smooth.ravel(), [smooth.size - n_voxels - 1, smooth.size - n_voxels])
    return 0.5 * float(ranked[smooth.size - n_voxels - 1] + ranked[smooth.size - n_voxels])


#: Face counts tried, as fractions of the target: quadric decimation occasionally leaves a
#: non-manifold edge at one exact face count; a slightly different count almost always avoids it.
DECIMATION_FACTORS = (1.0, 0.96, 1.04, 0.9, 1.1, 0.8, 1.25)
#: Where no count of `DECIMATION_FACTORS` keeps the surface, the mesh is cut by this factor and tried again: straight
#: from a large grain's marching-cubes mesh (10,000-38,000 faces) to ~500, quadric decimation left non-manifold
#: edges in 173 of 502 grains of a sand micro-CT at 2x finer voxels; halving at a time brings all but a few to it.
DECIMATION_STEP = 2.0


def _decimate(mesh: trimesh.Trimesh, target_faces: int) -> trimesh.Trimesh:
    while True:
        for factor in DECIMATION_FACTORS:
            simplified = mesh.simplify_quadric_decimation(face_count=int(target_faces * factor))
            if _intact(simplified):
                return simplified
        if len(mesh.faces) <= max(DECIMATION_FACTORS) * target_faces:
            return mesh
        halved = mesh.simplify_quadric_decimation(face_count=max(int(len(mesh.faces) / DECIMATION_STEP),
                                                                 target_faces))
        if not _intact(halved):
            logger.debug("decimation to ~%d faces kept breaking the surface; mesh left at %d faces",
                         target_faces, len(mesh.faces))
            return mesh
        mesh = halved


def _intact(mesh: trimesh.Trimesh) -> bool:
    """Whether a decimated mesh is still a closed surface with outward faces."""
    return bool(mesh.is_watertight and mesh.volume > 0)
