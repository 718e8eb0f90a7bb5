"""A pack's labels drawn as a threshold segmentation of its scan would draw them (a render step).

The render's labels are exact: every voxel whose centre lies in a grain's smooth surface.
A real scan's labels are not: they are drawn on the image (a threshold of the scan, then a
watershed, or a hand correction of one), and the image is blurred by the scanner. Where two
grains are closer than the blur, the gap between them is brighter than the threshold and
the labels join them by a shared face; a sharp tip is darker than it and is cut. So the
pores of an exact pack hold many more thin gaps than those of its labelled source (on the
sand micro-CT of docs/realism-sand.md, 0.41 of the pore space in gaps at most 4 voxels
wide against the scan's 0.26), and a model trained on exact labels learns gaps that the
scan's labels do not draw. ``reconstruct.labels: segmented`` redraws the labels so:

1. ``m``: the grain mask (label > 0), blurred by a Gaussian of the source's edge-spread
   sigma (`~synthpack.source.SourceStatistics.edge_sigma`, voxels), as the scanner blurs it;
2. ``t``: the level at which ``m > t`` holds as many voxels as the mask, so the solid volume
   is kept: a flat face stays where it is, gaps narrower than about the blur close, tips are
   rounded (found from a histogram of ``m`` in `LEVEL_BINS` bins, one pass before the
   labels are written);
3. every voxel of ``m > t`` takes the label of the nearest grain voxel
   (`skimage.segmentation.expand_labels`, at most `reach` voxels away); every other voxel is 0.

It goes slab by slab along z, each slab read with a halo of `halo` slices on either side,
and each slab in lateral tiles of `TILE` voxels with the same halo, so a Zarr pack is never
held whole and the memory does not grow with its width; the result does not depend on the
slabs or the tiles.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy import ndimage
from skimage.segmentation import expand_labels

__all__ = ["LABEL_STYLES", "LEVEL_BINS", "TILE", "SegmentedLabels"]

logger = logging.getLogger(__name__)

#: What ``reconstruct.labels`` may be: ``exact`` (the render's labels) or ``segmented`` (this module).
LABEL_STYLES = ("exact", "segmented")
#: Bins of the histogram of the blurred mask (values in [0, 1]) from which the level is found.
LEVEL_BINS = 4096
#: Lateral side (voxels) of the tiles a slab is redrawn in, each with its halo: the memory stays flat
#: however wide the pack.
TILE = 256
#: The Gaussian is cut at this many sigmas (SciPy's default), so a slab's halo holds all it reads.
_TRUNCATE = 4.0


@dataclass(frozen=True)
class SegmentedLabels:
    """Labels as a segmentation of the scan draws them (see the module docstring).

    Attributes
    ----------
    sigma : float
        Standard deviation of the blur, voxels (> 0): the source's edge-spread sigma.
    """

    sigma: float

    def __post_init__(self) -> None:
        if not (math.isfinite(self.sigma) and self.sigma > 0):
            raise ValueError(f"the blur of segmented labels must be a positive number of voxels, got {self.sigma}")

    @property
    def reach(self) -> int:
        """How far (voxels) a voxel the segmentation adds may lie from the grain whose label it takes."""
        return math.ceil(2 * self.sigma) + 1

    @property
    def halo(self) -> int:
        """Slices read above and below each slab: the blur's radius and the reach."""
        return int(_TRUNCATE * self.sigma + 0.5) + self.reach

    def redraw(self, labels: Any, slab: int, n_labels: int) -> dict:
        """Redraw `labels` in place, slab by slab.

        Parameters
        ----------
        labels : array-like of int32, shape (Z, Y, X)
            The render's labels (0 = not a grain), a NumPy or Zarr array; overwritten.
        slab : int
            Slices per slab (>= 1), e.g. the chunks' depth.
        n_labels : int
            The largest label there may be (the grains placed).

        Returns
        -------
        dict
            For the manifest: ``sigma``, ``level`` (the threshold of the blurred mask) and
            ``changed``, the share of the voxels whose label changed; and ``present``, a bool
            array of length ``n_labels + 1``, which labels the result holds (label 0 always).
        """
        counts = np.zeros(LEVEL_BINS, dtype=np.int64)
        solid = 0
        for window, lo, (z0, z1) in self._slabs(labels, slab):
            for _, core, _, blurred in self._tiles(window, lo, z1 - z0):
                counts += np.bincount(self._bins(blurred), minlength=LEVEL_BINS)
                solid += int(np.count_nonzero(window[core]))
        level = self._level(counts, solid)
        present = np.zeros(n_labels + 1, dtype=bool)
        present[0] = True
        changed = 0
        for window, lo, (z0, z1) in self._slabs(labels, slab):
            redrawn = np.zeros((z1 - z0,) + window.shape[1:], dtype=np.int32)
            for tile, core, inner, blurred in self._tiles(window, lo, z1 - z0):
                expanded = expand_labels(window[tile], self.reach)[inner]
                redrawn[(slice(None),) + core[1:]] = np.where(blurred > level, expanded, 0)
            changed += int(np.count_nonzero(redrawn != window[lo:lo + z1 - z0]))
            present[np.unique(redrawn)] = True
            labels[z0:z1] = redrawn
        share = changed / max(1, math.prod(labels.shape))
        logger.info("Labels drawn as a segmentation at the source's blur (sigma %.3g voxels, level %.3f): "
                    "%.2f %% of the voxels changed", self.sigma, level, 100 * share)
        return {"sigma": self.sigma, "level": level, "changed": share, "present": present}

    def _slabs(self, labels: Any, slab: int) -> Iterator[tuple[np.ndarray, int, tuple[int, int]]]:
        """Per slab: its labels with the halo above and below, the index of its first slice in them, ``(z0, z1)``.

        The halo is read before the slab above it is overwritten: the slices below a slab are
        read from the array, those above it from a copy kept before they were written.
        """
        depth, halo = labels.shape[0], self.halo
        above = np.zeros((0,) + tuple(labels.shape[1:]), dtype=np.int32)  # original slices over the slab
        for z0 in range(0, depth, slab):
            z1 = min(depth, z0 + slab)
            window = np.concatenate([above, np.asarray(labels[z0:min(depth, z1 + halo)], dtype=np.int32)])
            yield window, len(above), (z0, z1)
            above = window[max(0, len(above) + z1 - z0 - halo):len(above) + z1 - z0]

    def _tiles(self, window: np.ndarray, lo: int, depth: int) -> Iterator[tuple[tuple[slice, ...], ...]]:
        """Per lateral tile of a slab's `window` (`TILE` voxels a side, with the halo around it): the tile read
        and its core (indices into `window`; the core without the halo, the slab's `depth` slices from `lo`), the
        core's indices into the tile, and the core's blurred mask."""
        halo = self.halo
        for y0 in range(0, window.shape[1], TILE):
            for x0 in range(0, window.shape[2], TILE):
                y1, x1 = min(window.shape[1], y0 + TILE), min(window.shape[2], x0 + TILE)
                tile = (slice(None), slice(max(0, y0 - halo), min(window.shape[1], y1 + halo)),
                        slice(max(0, x0 - halo), min(window.shape[2], x1 + halo)))
                core = (slice(lo, lo + depth), slice(y0, y1), slice(x0, x1))
                inner = tuple(slice(c.start - (t.start or 0), c.stop - (t.start or 0)) for c, t in zip(core, tile))
                blurred = ndimage.gaussian_filter((window[tile] > 0).astype(np.float32), self.sigma, mode="nearest",
                                                  truncate=_TRUNCATE)[inner]
                yield tile, core, inner, blurred

    @staticmethod
    def _bins(blurred: np.ndarray) -> np.ndarray:
        """The histogram bin of each blurred value."""
        return np.clip((blurred.ravel() * LEVEL_BINS).astype(np.int64), 0, LEVEL_BINS - 1)

    @staticmethod
    def _level(counts: np.ndarray, solid: int) -> float:
        """The lowest bin edge above which at most `solid` voxels lie (0.5 where there is no grain)."""
        if solid == 0:
            return 0.5
        above = np.cumsum(counts[::-1])[::-1]  # above[k]: voxels in bins k and up
        k = int(np.argmax(above <= solid)) if (above <= solid).any() else LEVEL_BINS
        return k / LEVEL_BINS

