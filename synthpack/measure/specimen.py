"""Where the specimen is: the part of a scan that the source statistics describe.

Label 0 holds everything that is not a grain: the pore phase between the grains, but in
a real scan also the container wall, the air around it and the dark corners outside the
reconstructed field of view. Measured over all of label 0, the "pore" level, spread and
noise of a cylinder of concrete were those of air and paste mixed (spread 12,090 against
3,328 in the paste alone). :func:`specimen_mask` bounds the specimen by the grains
themselves: in each slice, the convex hull of its labelled pixels. Pore voxels inside it
lie between grains; the wall and what lies outside are left out. :func:`solid_fraction`
is the fraction of a region's voxels that are grain.

A scan is an *interior crop* (:func:`is_interior_crop`) when it shows no container and its
specimen reaches its side faces: it was cut out of the bulk of a larger specimen, so every
slice is full of grains to its edges. :func:`edge_coverage` measures the second part.
"""

from __future__ import annotations

import logging

import numpy as np
from scipy.spatial import ConvexHull, QhullError
from skimage.draw import polygon

__all__ = ["INTERIOR_COVERAGE", "edge_coverage", "is_interior_crop", "solid_fraction", "specimen_mask"]

#: A scan without a container whose specimen covers at least this fraction of its four side
#: faces is an interior crop (the built-in samples and a block of sand cover about 0.9, a
#: cylinder in its field of view none).
INTERIOR_COVERAGE = 0.5

logger = logging.getLogger(__name__)


def _slice_hull(labelled: np.ndarray) -> np.ndarray:
    """Convex hull of the True pixels of a 2D slice, as a mask of the slice's shape."""
    rows = np.flatnonzero(labelled.any(axis=1))
    if rows.size == 0:
        return np.zeros_like(labelled)
    first = labelled[rows].argmax(axis=1)
    last = labelled.shape[1] - 1 - labelled[rows, ::-1].argmax(axis=1)
    points = np.concatenate([np.stack([rows, first], 1), np.stack([rows, last], 1)]).astype(float)
    hull = np.zeros_like(labelled)
    try:
        corners = points[ConvexHull(points).vertices]
    except QhullError:  # the labelled pixels lie on a line: the line itself
        hull[labelled] = True
        return hull
    rr, cc = polygon(corners[:, 0], corners[:, 1], shape=labelled.shape)
    hull[rr, cc] = True
    hull |= labelled
    return hull


def specimen_mask(labels: np.ndarray) -> np.ndarray:
    """The specimen's voxels: per slice (axis 0), the convex hull of the labelled voxels.

    Parameters
    ----------
    labels : (Z, Y, X) ndarray of int
        Instance labels, 0 = not a grain.

    Returns
    -------
    (Z, Y, X) ndarray of bool
        True inside the specimen. Slices without a labelled voxel are empty.

    Notes
    -----
    Each slice costs one pass over its pixels and a convex hull of two points per
    row (the first and last labelled pixel), so a 2000^3 scan takes seconds.
    """
    labelled = np.asarray(labels) != 0
    mask = np.zeros(labelled.shape, dtype=bool)
    for z in range(labelled.shape[0]):
        mask[z] = _slice_hull(labelled[z])
    logger.debug("specimen: %.1f%% of the scan", 100.0 * mask.mean())
    return mask


def solid_fraction(labels: np.ndarray, region: np.ndarray) -> float:
    """Fraction of the `region` voxels that belong to a grain (``labels > 0``).

    The one measure of a bulk's solid fraction: of a source scan in its specimen
    (`SourceStatistics.solid_fraction`, a pour's default target) and of a source
    or a pack in the realism report.

    Parameters
    ----------
    labels : ndarray of int, shape (Z, Y, X)
    region : ndarray of bool, shape (Z, Y, X)

    Returns
    -------
    float
        In [0, 1]; the porosity is one minus it.
    """
    return float(np.count_nonzero(labels[region] > 0) / np.count_nonzero(region))


def edge_coverage(specimen: np.ndarray) -> float:
    """Fraction of the voxels of the four side faces (the first and last rows and columns of every slice) in `specimen`.

    Parameters
    ----------
    specimen : (Z, Y, X) ndarray of bool
        The specimen (`specimen_mask`).

    Returns
    -------
    float
        In [0, 1]: about 1 for a block cut out of the bulk, 0 for a specimen that sits inside
        the field of view (a cylinder, the air around it).
    """
    faces = (specimen[:, 0, :], specimen[:, -1, :], specimen[:, :, 0], specimen[:, :, -1])
    return float(sum(np.count_nonzero(face) for face in faces) / sum(face.size for face in faces))


def is_interior_crop(coverage: float, wall: bool) -> bool:
    """Whether a scan is an interior crop: no container `wall` and an `edge_coverage` of at least `INTERIOR_COVERAGE`."""
    return not wall and coverage >= INTERIOR_COVERAGE
