"""Structure of a labelled pack: solid fraction, grain size and shape, contacts, fabric, section roughness.

Every per-grain figure is measured on the *complete grains centred in the bulk
region* (`synthpack.measure.contacts.centred_grains`): grains whose voxels do not
touch a face of the volume (so their shape is not cut) and whose centroid lies in
the specimen's region (see `synthpack.realism.region`). In a source scan measured over its whole field of
view those are the grains not cut by the border, as in the particle library.

* **Equivalent diameter**: of the sphere with the grain's voxel volume.
* **Sphericity** (Wadell): ``pi^(1/3) (6 V)^(2/3) / A``, 1 for a sphere, lower for
  elongated or angular grains. ``V`` and ``A`` are the volume and area of the
  grain's smoothed marching-cubes surface (`synthpack.library.meshing.mesh_from_mask`
  without decimation), which keeps the voxel volume and avoids the staircase
  area of the raw voxels.
* **Aspect ratios**: with ``l1 >= l2 >= l3`` the eigenvalues of the covariance of
  the grain's voxel positions (physical units), elongation ``b/a = sqrt(l2/l1)``
  and flatness ``c/b = sqrt(l3/l2)`` of the ellipsoid with the same second
  moments (1 = round in that direction).
* **Orientation fabric**: the long axis ``n`` is the eigenvector of ``l1``;
  ``|n_z|`` is the cosine of its angle with the tube axis (uniform on [0, 1]
  for isotropic orientations, mean 0.5); the fabric tensor ``<n n^T>`` has
  eigenvalues (1/3, 1/3, 1/3) when isotropic.
* **Coordination number**: the number of other grains a grain shares at least
  one voxel face with (`synthpack.measure.contacts`, the count the source
  statistics make too).
* **Section roughness**: per grain section in evenly spaced slices along z (sections of
  at least 30 pixels centred in the region, any grain, complete or not), its outline's
  length over its smoothed outline's (`synthpack.measure.roughness`): about 1.05 for a
  smooth digitised outline, more for teeth and staircases along it.
* **Solid fraction**: the fraction of the region's voxels that belong to a grain
  (porosity = 1 - solid fraction; `synthpack.measure.specimen.solid_fraction`, the
  one the source statistics measure too).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
from scipy import ndimage, stats

from ..library.meshing import mesh_from_mask
from ..library.particles import equivalent_diameter
from ..measure.roughness import volume_roughness
from ..measure.contacts import centred_grains, coordination_numbers
from .region import Specimen

logger = logging.getLogger(__name__)

__all__ = [
    "GrainTable",
    "fabric_eigenvalues",
    "grain_table",
    "ks_distance",
]


def ks_distance(a: np.ndarray, b: np.ndarray) -> float:
    """Two-sample Kolmogorov-Smirnov distance: the largest gap between the two empirical CDFs.

    Parameters
    ----------
    a, b : ndarray, shape (N,) and (M,)
        Samples (any real dtype, N, M >= 1).

    Returns
    -------
    float
        In [0, 1]: 0 for identical samples, 1 for samples that do not overlap.
    """
    return float(stats.ks_2samp(np.asarray(a, dtype=float), np.asarray(b, dtype=float)).statistic)


def fabric_eigenvalues(axes: np.ndarray) -> np.ndarray:
    """Eigenvalues of the fabric tensor ``<n n^T>`` of unit vectors, largest first.

    Parameters
    ----------
    axes : ndarray, shape (N, 3)
        Unit vectors (sign does not matter).

    Returns
    -------
    ndarray of float64, shape (3,)
        Sum 1; ``(1/3, 1/3, 1/3)`` for isotropic directions, ``(1, 0, 0)`` when all align.
    """
    tensor = np.einsum("ni,nj->ij", axes, axes) / len(axes)
    return np.sort(np.linalg.eigvalsh(tensor))[::-1]


@dataclass
class GrainTable:
    """Per-grain figures of the complete grains centred in a region (see the module docstring).

    Attributes
    ----------
    labels : ndarray of int64, shape (N,)
    diameter : ndarray of float64, shape (N,)
        Equivalent diameter, physical units.
    sphericity, elongation, flatness : ndarray of float64, shape (N,)
        Dimensionless, in (0, 1].
    long_axis : ndarray of float64, shape (N, 3)
        Unit long axis in ``(z, y, x)`` components, ``n_z >= 0``.
    coordination : ndarray of int64, shape (N,)
        Grains in face contact.
    roughness : ndarray of float64, shape (M,)
        Boundary roughness of each grain section measured (one per section, not per grain;
        dimensionless, >= about 1).
    """

    labels: np.ndarray
    diameter: np.ndarray
    sphericity: np.ndarray
    elongation: np.ndarray
    flatness: np.ndarray
    long_axis: np.ndarray
    coordination: np.ndarray
    roughness: np.ndarray

    def __len__(self) -> int:
        return len(self.labels)

    @property
    def axis_cosine(self) -> np.ndarray:
        """``|n_z|``: cosine of the angle between each long axis and the tube axis, shape (N,)."""
        return np.abs(self.long_axis[:, 0])


def _moments(mask: np.ndarray, voxel_size: tuple[float, float, float]) -> tuple[np.ndarray, np.ndarray]:
    """Eigenvalues (largest first) and eigenvectors (columns) of the voxel positions' covariance, physical units."""
    coords = np.argwhere(mask).astype(np.float64)
    physical = (coords - coords.mean(axis=0)) * np.asarray(voxel_size)
    values, vectors = np.linalg.eigh(physical.T @ physical / len(coords))
    return values[::-1], vectors[:, ::-1]


def grain_table(specimen: Specimen) -> GrainTable:
    """Measure every complete grain centred in the specimen's region.

    Parameters
    ----------
    specimen : Specimen
        Labels, region and voxel size.

    Returns
    -------
    GrainTable
        Possibly empty (a warning is logged).
    """
    labels, region, voxel_size = specimen.labels, specimen.region, specimen.voxel_size
    coordination = coordination_numbers(labels)
    roughness = volume_roughness(labels, region)
    voxel_volume = float(np.prod(voxel_size))
    boxes = ndimage.find_objects(labels)
    rows: list[tuple] = []
    for label in centred_grains(labels, region):
        mask = labels[boxes[label - 1]] == label
        values, vectors = _moments(mask, voxel_size)
        mesh = mesh_from_mask(mask, voxel_size, target_faces=None)
        sphericity = np.pi ** (1 / 3) * (6 * mesh.volume) ** (2 / 3) / mesh.area
        l1, l2, l3 = np.maximum(values, 1e-12)
        axis = vectors[:, 0] * (1 if vectors[0, 0] >= 0 else -1)
        rows.append((label, equivalent_diameter(np.count_nonzero(mask) * voxel_volume), sphericity,
                     np.sqrt(l2 / l1), np.sqrt(l3 / l2), axis, coordination[label]))
    if not rows:
        logger.warning("%s: no complete grain is centred in the region", specimen.name)
        empty = np.zeros(0)
        return GrainTable(empty.astype(np.int64), empty, empty, empty, empty, np.zeros((0, 3)),
                          empty.astype(np.int64), roughness)
    columns = list(zip(*rows))
    return GrainTable(
        labels=np.array(columns[0], dtype=np.int64),
        diameter=np.array(columns[1], dtype=np.float64),
        sphericity=np.array(columns[2], dtype=np.float64),
        elongation=np.array(columns[3], dtype=np.float64),
        flatness=np.array(columns[4], dtype=np.float64),
        long_axis=np.array(columns[5], dtype=np.float64),
        coordination=np.array(columns[6], dtype=np.int64),
        roughness=roughness,
    )
