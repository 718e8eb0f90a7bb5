"""The whole render: `reconstruct` draws the grid chunk by chunk with a chunk renderer (paper 3.4).

The output is rendered chunk by chunk: each chunk renders the particles whose boxes
intersect it, so memory stays bounded by the output arrays plus one chunk's work, no
two workers write the same voxel, and nothing copies the whole volume per particle.
The background is a function of the global voxel position
(`~synthpack.render.background`), so the result does not depend on the chunking. A
chunk is rendered by `~synthpack.render.numpy_render.render_chunk` (NumPy, each grain
drawn by the compiled kernel or with SciPy: `~synthpack.render.kernel.resolve_kernel`) or by
`~synthpack.render.torch_render.TorchRenderer` (a GPU); all draw with the same
`~synthpack.render.canvas.Canvas`.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Collection, Sequence

import numpy as np

from .._shared.chunks import bounded_map, chunk_boxes, thread_count
from ..errors import SynthpackInputError
from .background import Background
from .crops import prepare_crops
from .grid import Grid
from .kernel import resolve_kernel
from .numpy_render import render_chunk
from .partial_volume import PartialVolume
from .poses import PoseMaps
from .surface import Surface

__all__ = ["crop_thresholds", "reconstruct"]


def reconstruct(
    crops: Sequence[tuple[np.ndarray, np.ndarray]],
    maps: PoseMaps,
    grid: Grid,
    background: Background,
    *,
    tube: tuple[float, float, float] | None = None,
    order: int = 1,
    seed: int = 0,
    chunks: tuple[int, int, int] = (64, 256, 256),
    workers: int | None = None,
    out: tuple[np.ndarray, np.ndarray] | None = None,
    partial_volume: PartialVolume | None = None,
    renderer: Callable[..., tuple[np.ndarray, np.ndarray, int]] | None = None,
    surface: Surface = Surface(),
    kernel: str = "auto",
    done: Collection[tuple[int, int, int]] = (),
) -> tuple[np.ndarray, np.ndarray, int]:
    """Render the whole grid chunk by chunk (see `~synthpack.render.numpy_render.render_chunk`).

    Chunks are rendered by a pool of threads (SciPy's interpolation and the compiled kernel
    release the GIL), at most ``2 * workers`` chunks in flight, so memory stays bounded by the
    output plus a few chunks' work. Each chunk is written by one thread only.

    Parameters
    ----------
    crops : sequence of (tomogram, mask)
        Clean crop (float32) and mask (bool) of every library particle.
    maps, grid, background, tube, order, seed, partial_volume
        As in `render_chunk` (`maps` with ``reach=surface.reach(partial_volume)``).
    chunks : tuple of 3 int
        Chunk shape in voxels.
    workers : int, optional
        Threads; default: the number of CPU cores. The result does not depend on it.
    out : (tomogram, labels), optional
        Arrays (or array-likes supporting slice assignment, e.g. Zarr arrays) of
        ``grid.shape`` to write into; new arrays by default.
    renderer : callable, optional
        Renders one chunk, with `render_chunk`'s arguments and results; default
        `render_chunk` (NumPy), e.g. `synthpack.render.torch_render.TorchRenderer` on a GPU.
    surface : Surface
        How the grains' smooth surfaces are made (`synthpack.render.surface`).
    kernel : str
        How the default renderer draws each grain: ``"numba"``, ``"scipy"`` or ``"auto"``
        (`~synthpack.render.kernel.resolve_kernel`); the result does not depend on it.
    done : collection of (int, int, int)
        The first corners of chunks already rendered into `out` (`synthpack.render.streamed`): skipped.

    Returns
    -------
    tomogram : float32 array, shape grid.shape
    labels : int32 array, shape grid.shape
    contested : int
        Voxels claimed by more than one particle, in the chunks rendered here.
    """
    if order not in (0, 1, 3):
        raise SynthpackInputError(f"interpolation order must be 0, 1 or 3, got {order}")
    if any(c < 1 for c in chunks):
        raise SynthpackInputError(f"chunk shape must be positive, got {chunks}")
    workers = thread_count(workers)
    if out is None:
        out = (np.empty(grid.shape, dtype=np.float32), np.empty(grid.shape, dtype=np.int32))
    tomogram, labels = out
    contested = 0

    thresholds = crop_thresholds(maps, partial_volume)
    prepared = prepare_crops(crops, partial_volume, np.unique(maps.library_index), workers, thresholds, surface)

    renderer = renderer or functools.partial(render_chunk, kernel=resolve_kernel(kernel))

    def render(box: tuple[np.ndarray, np.ndarray]) -> tuple[np.ndarray, np.ndarray, int]:
        lo, hi = box
        return renderer(prepared, maps, grid, lo, hi, background, tube=tube, order=order, seed=seed,
                        partial_volume=partial_volume)

    done = set(done)
    boxes = (box for box in chunk_boxes(grid.shape, chunks) if tuple(int(v) for v in box[0]) not in done)
    for (lo, hi), (chunk_tomogram, chunk_labels, chunk_contested) in bounded_map(render, boxes, workers):
        window = tuple(slice(a, b) for a, b in zip(lo, hi))
        tomogram[window] = chunk_tomogram
        labels[window] = chunk_labels
        contested += chunk_contested
    return tomogram, labels, contested


def crop_thresholds(maps: PoseMaps, partial_volume: PartialVolume | None,
                    placements: np.ndarray | None = None) -> dict[int, float] | None:
    """Per library crop placed, the lowest signed distance (crop voxels) at which one of its placements fills a voxel.

    ``prepare_crops``'s `thresholds` for the `placements` of `maps` (default: all of them):
    `~synthpack.render.partial_volume.PartialVolume.threshold` of each placement's scale (output
    voxels per crop voxel), the lowest per crop. None without a partial volume or placements.
    """
    chosen = np.arange(len(maps.library_index)) if placements is None else np.asarray(placements, dtype=np.int64)
    if partial_volume is None or not len(chosen):
        return None
    scales = np.abs(np.linalg.det(maps.matrix[chosen])) ** (-1.0 / 3.0)  # output voxels per crop voxel
    lowest = partial_volume.threshold(scales)
    index = maps.library_index[chosen]
    return {int(k): float(lowest[index == k].min()) for k in np.unique(index)}
