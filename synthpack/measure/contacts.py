"""Grain contacts: how many other grains each grain touches, in a scan's labels or a pack's.

The one count of contacts, for the source statistics (`SourceStatistics.coordination`,
the default target of a pour's ``pour.target_coordination``) and the realism report
(`synthpack.realism.structure`) alike, so a figure means the same on a scan and a pack:

* **Coordination number** of a grain: the number of distinct other grains it shares at
  least one voxel face with (6-connectivity, no dilation: two grains touch when the
  labelling, watershed or render, leaves no pore voxel between them).
* **Centred grains**: the complete grains centred in a region, the ones whose figures are
  kept. A grain is complete when none of its voxels lies on a face of the volume (nor
  outside the voxels that may be read), so neither its shape nor its contacts are cut;
  it is centred in the region when the voxel of its centroid is in it.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

__all__ = ["centred_grains", "coordination_numbers", "mean_coordination"]


def coordination_numbers(labels: np.ndarray) -> np.ndarray:
    """Number of distinct grains each label shares at least one voxel face with.

    Parameters
    ----------
    labels : ndarray of int, shape (Z, Y, X)
        0 = pore.

    Returns
    -------
    ndarray of int64, shape (labels.max() + 1,)
        Entry ``k`` is the coordination number of label ``k`` (entry 0 is unused, 0).
    """
    labels = np.asarray(labels, dtype=np.int64)
    n = int(labels.max()) + 1 if labels.size else 1
    codes = [np.zeros(0, dtype=np.int64)]
    for axis in range(labels.ndim):
        a = np.moveaxis(labels, axis, 0)[:-1].ravel()
        b = np.moveaxis(labels, axis, 0)[1:].ravel()
        touching = (a != b) & (a > 0) & (b > 0)
        low, high = np.minimum(a[touching], b[touching]), np.maximum(a[touching], b[touching])
        codes.append(low * n + high)
    pairs = np.unique(np.concatenate(codes))
    return np.bincount(np.concatenate([pairs // n, pairs % n]), minlength=n).astype(np.int64)


def centred_grains(labels: np.ndarray, region: np.ndarray, readable: np.ndarray | None = None) -> np.ndarray:
    """The labels of the complete grains centred in `region` (see the module docstring).

    Parameters
    ----------
    labels : ndarray of int, shape (Z, Y, X)
        0 = pore.
    region : ndarray of bool, shape (Z, Y, X)
        Where a grain's centroid must lie.
    readable : ndarray of bool, shape (Z, Y, X), optional
        The voxels that may be read (default: all); a grain with a voxel outside them
        is not complete (a held-out block of a source scan).

    Returns
    -------
    ndarray of int64, shape (N,)
        Increasing labels.
    """
    labels = np.asarray(labels)
    region = np.asarray(region, dtype=bool)
    kept = []
    for index, box in enumerate(ndimage.find_objects(labels)):
        if box is None or any(s.start == 0 or s.stop == n for s, n in zip(box, labels.shape)):
            continue
        mask = labels[box] == index + 1
        if readable is not None and not np.asarray(readable[box])[mask].all():
            continue
        centre = tuple(int(round(c)) + s.start for c, s in zip(np.argwhere(mask).mean(axis=0), box))
        if region[centre]:
            kept.append(index + 1)
    return np.array(kept, dtype=np.int64)


def mean_coordination(labels: np.ndarray, region: np.ndarray, readable: np.ndarray | None = None) -> float | None:
    """Mean coordination number of the complete grains centred in `region`.

    Parameters
    ----------
    labels : ndarray of int, shape (Z, Y, X)
        0 = pore.
    region : ndarray of bool, shape (Z, Y, X)
        The bulk region (a scan's specimen, a pack's bulk).
    readable : ndarray of bool, shape (Z, Y, X), optional
        The voxels that may be read (:func:`centred_grains`); grains outside them count as pore.

    Returns
    -------
    float or None
        Contacts per grain; None when no complete grain is centred in the region.
    """
    labels = np.asarray(labels)
    grains = centred_grains(labels, region, readable)
    if grains.size == 0:
        return None
    seen = labels if readable is None else np.where(readable, labels, 0)
    return float(coordination_numbers(seen)[grains].mean())
