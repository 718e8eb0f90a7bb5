"""Particle extraction (paper section 3.1): one clean crop and mask per label.

The bounding boxes of all labels come from a single pass over the label volume
(:func:`scipy.ndimage.find_objects`); each particle's mask is then computed inside
its own box only, so the cost grows with the total box volume, not with
``n_labels x volume``.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
import trimesh
from scipy import ndimage

from ..errors import SynthpackInputError
from ..scan.core import Scan
from ..measure.phases import estimate_phases

logger = logging.getLogger(__name__)

__all__ = ["Particle", "ParticleCrop", "equivalent_diameter", "extract_particles"]


def equivalent_diameter(volume: float | np.ndarray) -> float | np.ndarray:
    """Diameter of the sphere of `volume` (cubic physical units), in physical units."""
    return (6.0 * np.asarray(volume, dtype=float) / np.pi) ** (1.0 / 3.0)


@dataclass
class ParticleCrop:
    """A particle cut out of a scan (paper Fig. 2), before meshing.

    Attributes
    ----------
    label : int
        The particle's label in the source scan, as given (sparse labels are
        renumbered inside a `Scan`, see `synthpack.scan.core.compact_labels`; this is
        the original value).
    bbox : tuple of 6 int
        ``(z0, y0, x0, z1, y1, x1)``: half-open bounding box in source voxels.
    tomogram : ndarray of float32, shape (nz, ny, nx)
        Clean intensity crop: voxels outside the particle's mask (other particles
        and pores) are set to the scan's background value.
    mask : ndarray of bool, shape (nz, ny, nx)
        The particle's voxels (largest connected component of its label).
    voxel_size : tuple of 3 float
        ``(dz, dy, dx)`` in the scan's unit.
    touches_border : bool
        True when the box touches a face of the scan: the grain was cut by the
        field of view and its shape is partial.
    """

    label: int
    bbox: tuple[int, int, int, int, int, int]
    tomogram: np.ndarray
    mask: np.ndarray
    voxel_size: tuple[float, float, float]
    touches_border: bool

    @property
    def voxel_count(self) -> int:
        """Number of voxels in the mask."""
        return int(np.count_nonzero(self.mask))

    @property
    def equivalent_diameter(self) -> float:
        """Diameter of the sphere with the mask's volume, in physical units."""
        return float(equivalent_diameter(self.voxel_count * float(np.prod(self.voxel_size))))


@dataclass
class Particle(ParticleCrop):
    """A meshed particle, ready to pour (paper sections 3.1-3.3).

    Adds to :class:`ParticleCrop` the surface mesh and its mass properties. The
    mesh lives in the particle-local frame: origin at the centre of the crop box,
    axes ``(x, y, z)`` along the crop's array axes ``(2, 1, 0)``, physical units.

    Attributes
    ----------
    mesh : trimesh.Trimesh
        Watertight, decimated surface of the mask.
    density : float
        Material density used for `mass` (mass unit per cubic length unit).
    """

    mesh: trimesh.Trimesh
    density: float

    @property
    def volume(self) -> float:
        """Mesh volume in cubic physical units."""
        return float(self.mesh.volume)

    @property
    def mass(self) -> float:
        """Mass = density x volume (paper eq. 1)."""
        return self.density * self.volume

    @property
    def center_mass(self) -> np.ndarray:
        """Centre of mass, shape (3,), in the particle-local frame (uniform density)."""
        return np.asarray(self.mesh.center_mass, dtype=float)

    @property
    def inertia(self) -> np.ndarray:
        """Inertia tensor about the centre of mass, shape (3, 3), scaled by `density`."""
        return np.asarray(self.mesh.moment_inertia, dtype=float) * self.density

    def __repr__(self) -> str:
        return (
            f"Particle(label={self.label}, shape={self.mask.shape}, voxels={self.voxel_count}, "
            f"d_eq={self.equivalent_diameter:.4g}, faces={len(self.mesh.faces)}, "
            f"touches_border={self.touches_border})"
        )


def _largest_component(mask: np.ndarray) -> tuple[np.ndarray, bool]:
    components, n = ndimage.label(mask)
    if n <= 1:
        return mask, False
    sizes = np.bincount(components.ravel())
    sizes[0] = 0
    return components == int(np.argmax(sizes)), True


def extract_particles(
    scan: Scan,
    *,
    min_voxels: int,
    include_border: bool = False,
    background: float | None = None,
) -> list[ParticleCrop]:
    """Cut every labelled particle out of `scan` (paper section 3.1).

    Parameters
    ----------
    scan : Scan
        Tomogram and labels.
    min_voxels : int
        Particles with fewer voxels are dropped (the library's default is
        `synthpack.library.core.LibraryConfig.min_voxels`).
    include_border : bool
        Keep particles whose bounding box touches the scan border (their shape is
        cut by the field of view; excluded by default).
    background : float, optional
        Value written outside each particle's mask in its clean crop. Default: the
        pore level of :func:`~synthpack.measure.phases.estimate_phases`.

    Returns
    -------
    list of ParticleCrop
        In increasing label order. A label made of several disconnected pieces
        keeps its largest piece (logged).
    """
    if min_voxels < 1:
        raise SynthpackInputError(f"min_voxels must be at least 1, got {min_voxels}")
    if background is None:
        background = estimate_phases(scan).pore_mean
    labels, tomogram, shape = scan.labels, scan.tomogram, scan.shape
    boxes = ndimage.find_objects(labels)
    crops: list[ParticleCrop] = []
    n_small = n_border = n_split = 0
    for index, box in enumerate(boxes):
        if box is None:
            continue
        label = index + 1
        mask = labels[box] == label
        mask, was_split = _largest_component(mask)
        n_split += was_split
        if np.count_nonzero(mask) < min_voxels:
            n_small += 1
            continue
        touches = any(s.start == 0 or s.stop == n for s, n in zip(box, shape))
        if touches and not include_border:
            n_border += 1
            continue
        clean = np.where(mask, tomogram[box], background).astype(np.float32)
        bbox = tuple(s.start for s in box) + tuple(s.stop for s in box)
        crops.append(ParticleCrop(scan.original_label(label), bbox, clean, mask, scan.voxel_size, touches))
    logger.info("extracted %d particles (dropped %d < %d voxels, %d on the border%s)", len(crops), n_small,
                min_voxels, n_border, f"; {n_split} split label(s) cut to one piece" if n_split else "")
    if not crops:
        raise SynthpackInputError(
            f"no particle left after filtering: {n_small} below min_voxels={min_voxels}, "
            f"{n_border} touching the border. Lower --min-voxels or pass "
            "--include-border to keep cut particles"
        )
    return crops
