"""How often a pour draws each library grain: the field of view's size bias undone (Miles-Lantuéjoul).

The library keeps only the complete grains of its scan, those not cut by a face of
the field of view (`synthpack.library.particles.extract_particles`). Where the
material runs on past a face, as in an interior crop, a large grain is cut more
often than a small one, so the complete grains under-represent the large ones: in a
100-slice crop of dense sand, the library's grains are on average 16% smaller by
volume than the scan's. A grain whose bounding box spans ``h`` voxels along an axis
of ``L`` voxels lies wholly inside, not touching either face, at ``L - h - 1`` of the
``L - h + 1`` positions it could take, so it is kept with a probability proportional
to the product of these counts over the axes; drawing each grain with the inverse
weight (the Miles-Lantuéjoul minus-sampling correction) gives the pour the size
distribution of all the scan's grains, cut ones included.

An axis counts only where the material reaches its faces, i.e. where some label of
the scan touches one of them (`cut_axes`): a specimen wholly inside the field of
view along an axis (a concrete cylinder, a column whose ends are in view) loses no
grain there. Slices left out of the library (its test block) are a gap in the window
along their axis. A library that keeps the cut grains (``include_border``) is drawn
evenly.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

__all__ = ["cut_axes", "draw", "window_weights"]


def cut_axes(labels: np.ndarray) -> tuple[bool, bool, bool]:
    """Per axis, whether a grain touches one of the field of view's two faces across it.

    Parameters
    ----------
    labels : ndarray of int, shape (Z, Y, X)
        Instance labels, 0 = not a grain.

    Returns
    -------
    tuple of 3 bool
    """
    return tuple(bool(np.take(labels, 0, axis).any() or np.take(labels, -1, axis).any())  # type: ignore[return-value]
                 for axis in range(3))


def _kept_along(extent: np.ndarray, length: int, cut: bool, gap: tuple[int, int] | None) -> np.ndarray:
    """Per grain of `extent` voxels, how likely one axis lets it into the library (up to a common factor).

    On a cut axis, the number of positions at which it lies whole inside, not touching
    a face nor the gap (the material runs on past the faces, so every position is as
    likely); on an axis the specimen lies within, the fraction of its positions in the
    field of view that the gap leaves it (1 without a gap).
    """
    low, high = (1, length - 1) if cut else (0, length)  # a kept grain's voxels lie in [low, high)
    spans = [(low, high)] if gap is None else [(low, gap[0]), (gap[1], high)]
    positions = sum(np.maximum(stop - start - extent + 1, 0) for start, stop in spans)
    return positions if cut else positions / np.maximum(length - extent + 1, 1)


def window_weights(
    bboxes: Sequence[Sequence[int]],
    shape: Sequence[int],
    cut: Sequence[bool],
    gap: tuple[int, int] | None = None,
    gap_axis: int = 0,
) -> np.ndarray:
    """The draw weight of each complete grain: the inverse of how often a grain of its size stays whole.

    Parameters
    ----------
    bboxes : sequence of 6 int
        Per grain ``(z0, y0, x0, z1, y1, x1)``, its bounding box in the scan (stop exclusive).
    shape : 3 int
        ``(Z, Y, X)`` of the scan.
    cut : 3 bool
        `cut_axes` of the scan: the axes whose faces cut grains.
    gap : (start, stop), optional
        Slices ``start <= i < stop`` along `gap_axis` whose grains were left out of the library.
    gap_axis : int
        Axis of `gap`.

    Returns
    -------
    ndarray of float64, shape (N,)
        Weights summing to 1; even where no axis is cut and no slices were left out.
    """
    boxes = np.asarray(bboxes, dtype=np.int64).reshape(-1, 6)
    extent = boxes[:, 3:] - boxes[:, :3]
    kept = np.ones(len(boxes))
    for axis in range(3):
        along = _kept_along(extent[:, axis], int(shape[axis]), bool(cut[axis]), gap if axis == gap_axis else None)
        kept *= np.maximum(along, 1e-9)  # every library grain was kept, so none has a zero chance
    weights = 1.0 / kept
    return weights / weights.sum()


def draw(rng: np.random.Generator, weights: np.ndarray, n: int, members: np.ndarray | None = None) -> np.ndarray:
    """`n` indices drawn with replacement by `weights`, restricted to `members` if given.

    Even weights draw as synthpack 0.8 drew every library (``rng.integers``), so a scan
    whose faces cut no grain gets the packs it got before the weights.

    Parameters
    ----------
    rng : numpy.random.Generator
    weights : ndarray of float, shape (N,)
        Draw weights of all N grains (`window_weights`).
    n : int
    members : ndarray of int, optional
        The indices that may be drawn (a size class); default all.

    Returns
    -------
    ndarray of int64, shape (n,)
    """
    weights = np.asarray(weights, dtype=np.float64)
    chosen = weights if members is None else weights[members]
    p = None if chosen.size and np.all(chosen == chosen[0]) else chosen / chosen.sum()
    if members is None:
        return (rng.integers(0, len(weights), n) if p is None else rng.choice(len(weights), n, p=p)).astype(np.int64)
    return rng.choice(np.asarray(members), size=n, replace=True, p=p).astype(np.int64)
