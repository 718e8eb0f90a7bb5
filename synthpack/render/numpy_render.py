"""The render of one chunk with NumPy and SciPy: `render_chunk`.

Each grain whose box reaches the chunk is drawn on the chunk's `~synthpack.render.canvas.Canvas`
at only the voxels it can change: one cheap nearest-neighbour resampling of its crop's
support (`~synthpack.render.crops.RenderCrop`) finds them, and its smooth surface's signed
distance and its intensities are interpolated there with `scipy.ndimage.map_coordinates`, at the very
coordinates a dense ``affine_transform`` of its box would read. With the compiled kernel
(``kernel="numba"``, `synthpack.render.kernel`) each grain is drawn instead in one pass
over its box that does the same arithmetic: the same labels, claims and float32 values.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from scipy import ndimage

from .background import Background, background_values
from .canvas import Canvas
from .crops import RenderCrop
from .grid import Grid
from .kernel import resolve_kernel, spline_coefficients
from .partial_volume import PAD, PartialVolume
from .poses import PoseMaps, grain_boxes, mapped

__all__ = ["render_chunk"]


def render_chunk(
    crops: Sequence[RenderCrop | None],
    maps: PoseMaps,
    grid: Grid,
    lo: np.ndarray,
    hi: np.ndarray,
    background: Background,
    *,
    tube: tuple[float, float, float] | None = None,
    order: int = 1,
    seed: int = 0,
    partial_volume: PartialVolume | None = None,
    kernel: str = "auto",
) -> tuple[np.ndarray, np.ndarray, int]:
    """Render the output box ``[lo, hi)``.

    Parameters
    ----------
    crops : sequence of RenderCrop
        Every library particle's crop, from `~synthpack.render.crops.prepare_crops` (with the
        same `partial_volume`; those `maps` places are not None).
    maps : PoseMaps
        From `~synthpack.render.poses.pose_maps`.
    grid : Grid
        Output grid.
    lo, hi : ndarray of int, shape (3,)
        Half-open box in output voxel indices.
    background : Background
        Pore level, pore texture and wall intensity.
    tube : (inner_radius, outer_radius, base_z) or None
        Tube wall geometry in physical units (None: no wall).
    order : int
        Spline order for intensities (1 linear, 3 cubic). Signed distances are
        always resampled linearly.
    seed : int
        Seed of the pore texture.
    partial_volume : PartialVolume, optional
        Composite grains by their occupancy of each voxel (`synthpack.render.partial_volume`);
        None: each grain's label voxels take its intensity (a hard step).
    kernel : str
        ``"numba"``: draw each grain in one compiled pass (`~synthpack.render.canvas.Canvas.draw_box`);
        ``"scipy"``: with SciPy; ``"auto"``: numba where it can be imported
        (`~synthpack.render.kernel.resolve_kernel`). Either gives the same result.

    Returns
    -------
    tomogram : ndarray of float32, shape hi - lo
    labels : ndarray of int32, shape hi - lo
        Placement ``i`` gets label ``i + 1`` inside its smooth surface (where its
        resampled signed distance is positive). A voxel claimed by two particles goes
        to the one it is deeper in (the larger signed distance; the earlier placement
        on a tie), a deterministic rule independent of the chunking
        (`~synthpack.render.canvas.Canvas`).
    contested : int
        Number of voxels claimed by more than one particle.
    """
    shape = tuple(int(n) for n in hi - lo)
    canvas = Canvas(background_values(grid, lo, hi, background, tube, seed), _sample, np, order, partial_volume)
    compiled = resolve_kernel(kernel) == "numba"
    intensities: dict[int, tuple[np.ndarray, int]] = {}  # spline coefficients, per library crop
    for i, sub_lo, sub_hi, offset in grain_boxes(maps, lo, hi):
        crop = crops[maps.library_index[i]]
        matrix = maps.matrix[i]
        if compiled:
            k = int(maps.library_index[i])
            if k not in intensities:
                intensities[k] = spline_coefficients(crop.intensity, order)
            canvas.draw_box(i + 1, sub_lo - lo, sub_hi - sub_lo, offset, crop, matrix, intensities[k])
            continue
        # the box's voxels the grain can change: a nearest-neighbour resampling of its support
        near = ndimage.affine_transform(
            crop.support, matrix, offset=offset + PAD, output_shape=tuple(int(n) for n in sub_hi - sub_lo),
            order=0, mode="constant", cval=0,
        )
        where = np.nonzero(near)
        if not len(where[0]):
            continue
        index = np.ravel_multi_index(tuple(w + int(a - b) for w, a, b in zip(where, sub_lo, lo)), shape)
        canvas.draw(i + 1, index, mapped(matrix, where), offset, crop, matrix)
    canvas.finish()
    return canvas.tomogram, canvas.labels, canvas.contested


def _sample(volume: np.ndarray, mapped: np.ndarray, shift: np.ndarray, order: int, cval: float | None) -> np.ndarray:
    """`~synthpack.render.canvas.Sampler` with `scipy.ndimage.map_coordinates` (float32)."""
    coordinates = mapped + np.asarray(shift, dtype=np.float64)[:, None]
    if cval is None:
        return ndimage.map_coordinates(volume, coordinates, order=order, mode="nearest", prefilter=order > 1,
                                       output=np.float32)
    return ndimage.map_coordinates(volume, coordinates, order=order, mode="constant", cval=cval, output=np.float32)
