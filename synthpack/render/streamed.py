"""The render of a pack's chunks while its pour goes on: each row of chunks once the grains locked so far bury it.

A batch of grains, once locked, never moves again (`synthpack.physics.driver`), so the
chunks below the grains still to come can be rendered before the pour ends, on the cores
the pour leaves idle. `LockedRender` takes the grains of each batch as it is locked and
renders, on a pool of threads, every row of chunks (``chunks[0]`` slices of the grid) that
ends one grain height below the batch's lowest grain: later grains fall from above onto
the grains already there. That rule is a guess; what makes the result exact is
`LockedRender.finish`: once the pour is done, a chunk rendered early is kept only where the
final placements reach it with exactly the grains, maps and boxes it was drawn with. The
caller (`synthpack.pipeline.generate`) then renders the other chunks with
`~synthpack.render.chunked.reconstruct` (its ``done``), so the volumes are byte for byte
those of a render after the pour: a chunk's voxels depend only on the grains that reach it,
the background at its position and crops whose support holds every voxel a grain can change
(a larger support changes nothing, `~synthpack.render.crops.RenderCrop`).
"""

from __future__ import annotations

import functools
import logging
import threading
import time
from collections.abc import Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from types import TracebackType

import numpy as np

from .background import Background
from .chunked import crop_thresholds
from .crops import RenderCrop, prepare_crops
from .grid import Grid
from .kernel import resolve_kernel
from .numpy_render import render_chunk
from .partial_volume import PartialVolume
from .poses import PoseMaps, pose_maps
from .surface import Surface

logger = logging.getLogger(__name__)

__all__ = ["LockedRender"]


@dataclass(frozen=True)
class _Drawn:
    """What one chunk rendered early was drawn with: the placements reaching it and their rows of the maps."""

    hi: tuple[int, int, int]
    placements: np.ndarray
    library_index: np.ndarray
    matrix: np.ndarray
    offset: np.ndarray
    box_lo: np.ndarray
    box_hi: np.ndarray
    contested: int

    @classmethod
    def of(cls, maps: PoseMaps, lo: np.ndarray, hi: np.ndarray, contested: int) -> _Drawn:
        hit = np.flatnonzero(np.all((maps.box_lo < hi) & (maps.box_hi > lo), axis=1))
        return cls(tuple(int(v) for v in hi), hit, maps.library_index[hit], maps.matrix[hit], maps.offset[hit],
                   maps.box_lo[hit], maps.box_hi[hit], contested)

    def same(self, other: _Drawn) -> bool:
        """Whether `other` reaches the same box with the same placements, maps and boxes (bit for bit)."""
        return self.hi == other.hi and all(
            np.array_equal(getattr(self, name), getattr(other, name))
            for name in ("placements", "library_index", "matrix", "offset", "box_lo", "box_hi"))


class LockedRender:
    """Renders the rows of chunks that the batches locked so far bury, while the pour goes on.

    Use as a context manager; `add` each batch as it is locked, then `finish` with the final
    maps. The chunks are written into `out` by the pool's threads (each chunk by one thread).

    Parameters
    ----------
    crops : sequence of (tomogram, mask)
        Clean crop (float32) and mask (bool) of every library particle (as `reconstruct`'s).
    grid : Grid
        A grid with the final grid's origin and voxel size that covers every voxel the pack can
        reach (the tube up to its rim): its chunks below the final grid's top are the final ones.
    background, tube, order, seed, partial_volume, surface, kernel
        As in `~synthpack.render.chunked.reconstruct`; `background`'s pore texture must have the
        final grid's period.
    out : (tomogram, labels)
        Array-likes supporting slice assignment, at least as deep as the chunks rendered.
    n_placed : int
        Placements in the whole pour (labels ``1..n_placed``).
    chunks : tuple of 3 int
        Chunk shape, voxels (the final render's).
    reach : float
        `~synthpack.render.poses.pose_maps`'s `reach`.
    workers : int
        Threads rendering chunks.
    """

    def __init__(
        self, crops: Sequence[tuple[np.ndarray, np.ndarray]], grid: Grid, background: Background,
        out: tuple[object, object], *, n_placed: int, tube: tuple[float, float, float] | None, order: int,
        seed: int, chunks: tuple[int, int, int], partial_volume: PartialVolume | None, surface: Surface,
        kernel: str, reach: float, workers: int,
    ) -> None:
        self._crops, self._grid, self._out, self._chunks = crops, grid, out, tuple(int(c) for c in chunks)
        self._partial_volume, self._surface, self._reach = partial_volume, surface, reach
        self._render = functools.partial(render_chunk, grid=grid, background=background, tube=tube, order=order,
                                         seed=seed, partial_volume=partial_volume, kernel=resolve_kernel(kernel))
        self._maps = PoseMaps(np.zeros(n_placed, dtype=np.int64), np.zeros((n_placed, 3, 3)),
                              np.zeros((n_placed, 3)), np.zeros((n_placed, 3), dtype=np.int64),
                              np.zeros((n_placed, 3), dtype=np.int64))
        self._prepared: list[RenderCrop | None] = [None] * len(crops)
        self._thresholds: dict[int, float] = {}
        self._rows: set[int] = set()  # z starts of the rows handed to the pool
        self._drawn: dict[tuple[int, int, int], _Drawn] = {}
        self._lock = threading.Lock()
        self._pool = ThreadPoolExecutor(max_workers=max(1, workers), thread_name_prefix="synthpack-render")
        self._futures: list[Future] = []
        self.seconds = 0.0  # summed over the chunks rendered (thread seconds)

    def __enter__(self) -> LockedRender:
        return self

    def __exit__(self, kind: type[BaseException] | None, error: BaseException | None,
                 trace: TracebackType | None) -> None:
        self._pool.shutdown(wait=True, cancel_futures=True)

    def add(self, batch: int, members: np.ndarray, library_index: np.ndarray, rotations: np.ndarray,
            positions: np.ndarray, scales: np.ndarray) -> None:
        """Take one locked batch and hand the pool the rows of chunks it buries.

        Parameters
        ----------
        batch : int
            The batch's number: 0 starts a pour (again, for containment), forgetting the grains added before.
        members : ndarray of int, shape (B,)
            The placements.
        library_index : ndarray of int, shape (B,)
            The crop each is drawn from (an index into `crops`).
        rotations : ndarray of float, shape (B, 3, 3)
            Rotation matrices, particle-local -> world, acting on ``(x, y, z)``.
        positions : ndarray of float, shape (B, 3)
            World ``(x, y, z)`` of their local origins, physical units.
        scales : ndarray of float, shape (B,)
            Their scale factors.
        """
        if batch == 0 and self._rows:
            self._drain()  # a pour run again: the chunks drawn so far are checked by `finish` like any other
            self._rows.clear()
            self._maps.box_lo[:] = self._maps.box_hi[:] = 0
        members = np.asarray(members, dtype=np.int64)
        if not len(members):
            return
        maps = pose_maps([crop[1] for crop in self._crops], library_index, rotations, positions, scales, self._grid,
                         reach=self._reach)
        for name in ("library_index", "matrix", "offset", "box_lo", "box_hi"):
            getattr(self._maps, name)[members] = getattr(maps, name)
        self._prepare(maps)
        lowest = int(maps.box_lo[:, 0].min()) - int((maps.box_hi[:, 0] - maps.box_lo[:, 0]).max())
        rows = [z for z in range(0, lowest - self._chunks[0] + 1, self._chunks[0]) if z not in self._rows]
        if not rows:
            return
        snapshot = PoseMaps(*(getattr(self._maps, name).copy()
                              for name in ("library_index", "matrix", "offset", "box_lo", "box_hi")))
        crops = list(self._prepared)
        for z in rows:
            self._rows.add(z)
            for y in range(0, self._grid.shape[1], self._chunks[1]):
                for x in range(0, self._grid.shape[2], self._chunks[2]):
                    lo = np.array([z, y, x])
                    hi = np.minimum(lo + np.asarray(self._chunks), self._grid.shape)
                    self._futures.append(self._pool.submit(self._draw, crops, snapshot, lo, hi))

    def _prepare(self, maps: PoseMaps) -> None:
        """Prepare the crops of `maps`' placements not yet prepared, or prepared for a higher threshold."""
        thresholds = crop_thresholds(maps, self._partial_volume) or {}
        wanted = [int(k) for k in np.unique(maps.library_index)
                  if self._prepared[int(k)] is None or thresholds.get(int(k), 0.0) < self._thresholds.get(int(k), 0.0)]
        if not wanted:
            return
        self._thresholds.update({k: min(thresholds[k], self._thresholds.get(k, thresholds[k]))
                                 for k in wanted if k in thresholds})
        prepared = prepare_crops(self._crops, self._partial_volume, wanted, 1, self._thresholds, self._surface)
        for k in wanted:
            self._prepared[k] = prepared[k]

    def _draw(self, crops: list[RenderCrop | None], maps: PoseMaps, lo: np.ndarray, hi: np.ndarray) -> None:
        start = time.perf_counter()
        tomogram, labels, contested = self._render(crops, maps, lo=lo, hi=hi)
        window = tuple(slice(a, b) for a, b in zip(lo, hi))
        self._out[0][window] = tomogram
        self._out[1][window] = labels
        drawn = _Drawn.of(maps, lo, hi, contested)
        with self._lock:
            self._drawn[tuple(int(v) for v in lo)] = drawn
            self.seconds += time.perf_counter() - start

    def _drain(self) -> None:
        """Wait for every chunk handed to the pool; raise the first error of one."""
        futures, self._futures = self._futures, []
        for future in futures:
            future.result()

    def finish(self, maps: PoseMaps, shape: tuple[int, int, int]) -> tuple[set[tuple[int, int, int]], int, int]:
        """Wait for the chunks in flight and keep those the final placements reach as they were drawn.

        Parameters
        ----------
        maps : PoseMaps
            The final maps of every placement, on the final grid.
        shape : tuple of 3 int
            The final grid's shape.

        Returns
        -------
        done : set of (int, int, int)
            First corners of the chunks rendered here that the final render need not draw again.
        contested : int
            Voxels claimed by more than one particle in those chunks.
        redrawn : int
            Chunks rendered here that the final placements reach otherwise (to draw again).
        """
        self._drain()
        done, contested = set(), 0
        for lo, drawn in self._drawn.items():
            corner = np.array(lo)
            hi = np.minimum(corner + np.asarray(self._chunks), shape)
            if np.all(corner < shape) and drawn.same(_Drawn.of(maps, corner, hi, 0)):
                done.add(lo)
                contested += drawn.contested
        redrawn = len(self._drawn) - len(done)
        logger.debug("rendered %d chunks while pouring (%.1f thread seconds); %d to draw again",
                     len(self._drawn), self.seconds, redrawn)
        return done, contested, redrawn
