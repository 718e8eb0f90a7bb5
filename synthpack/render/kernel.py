"""The compiled render: each grain in one numba pass over its box (`draw_box`); which render runs (`resolve_kernel`).

The SciPy render (`~synthpack.render.numpy_render.render_chunk` with ``kernel="scipy"``)
reads each voxel a grain can change three times: a nearest-neighbour
``affine_transform`` of the crop's support finds the voxels, then
``map_coordinates`` interpolates the signed distance and, where the grain claims or
fills the voxel, the intensity. `draw_box` visits each voxel of the grain's box once:
it maps the voxel through the pose, reads the support at its nearest crop voxel and,
where that is set, interpolates the distance (linear) and the intensity (order 0, 1
or 3) and draws them on the `~synthpack.render.canvas.Canvas` arrays in place (claims,
then the pasted intensity or the partial-volume sums).

It does SciPy's arithmetic to the bit (``scipy/ndimage/src/ni_interpolation.c`` and
``ni_splines.c``, SciPy >= 1.6): the coordinates are summed in the order SciPy sums
them (``affine_transform`` adds the offset first, `~synthpack.render.poses.mapped`
last), the borders are SciPy's (``mode="constant"``: ``cval`` beyond the outermost
voxel centres, the last one mirrored at the edge; ``mode="nearest"``: the indices
clamped, the weights those of the unclamped coordinate), the weights are computed and
the products summed in SciPy's order in float64, and the result rounded once to
float32. Cubic intensities read the spline coefficients SciPy would prefilter for
them (`spline_coefficients`). So labels, claims and contested voxels equal the SciPy
render's and intensities its float32 values (``tests/test_render_kernel.py``).

The functions are compiled on their first call (``cache=True``: the machine code is
kept next to this module, or in numba's cache folder, for the next process) and
release the GIL, so the chunks render in parallel threads. Without numba they stay
uncompiled and unused: `resolve_kernel` gives ``"scipy"``.
"""

from __future__ import annotations

import functools
import logging
from collections.abc import Callable
from typing import Any

import numpy as np
from scipy import ndimage

from ..errors import SynthpackInputError

try:
    import numba
except ImportError:  # the SciPy render draws instead (resolve_kernel)
    numba = None

__all__ = ["draw_box", "resolve_kernel", "spline_coefficients"]

logger = logging.getLogger(__name__)

#: Voxels by which SciPy pads an array (repeating its edge) before prefiltering it for
#: ``mode="nearest"`` (``scipy.ndimage._interpolation._prepad_for_spline_filter``).
SPLINE_PAD = 12


@functools.cache
def resolve_kernel(kernel: str) -> str:
    """The render that draws the grains for the setting ``reconstruct.kernel``: ``"numba"`` or ``"scipy"``.

    The one place the choice is made (logged once per process at debug). ``auto`` is numba
    where it can be imported, else SciPy.

    Raises
    ------
    SynthpackInputError
        For ``numba`` where numba cannot be imported.
    """
    if kernel == "numba" and numba is None:
        raise SynthpackInputError("reconstruct.kernel: numba needs the numba package, which cannot be imported "
                                  "here; use auto or scipy")
    resolved = "scipy" if kernel == "scipy" or numba is None else "numba"
    logger.debug("render kernel %s: %s", kernel, resolved)
    return resolved


def spline_coefficients(volume: np.ndarray, order: int) -> tuple[np.ndarray, int]:
    """What `draw_box` interpolates a crop's intensities of `order` from, as ``map_coordinates(mode="nearest")`` does.

    Parameters
    ----------
    volume : ndarray of float32, shape (nz, ny, nx)
        A crop's intensities.
    order : int
        0, 1 or 3.

    Returns
    -------
    coefficients : ndarray
        `volume` itself for order 0 and 1; for order 3, SciPy's B-spline coefficients of it
        (float64, shape (nz, ny, nx) + 2 `SPLINE_PAD`): `volume` padded by repeating its
        edge, then prefiltered.
    pad : int
        Voxels of padding: 0, or `SPLINE_PAD` for order 3.
    """
    if order <= 1:
        return volume, 0
    padded = np.pad(volume, SPLINE_PAD, mode="edge")
    return ndimage.spline_filter(padded, order, output=np.float64, mode="nearest"), SPLINE_PAD


def _compiled(function: Callable) -> Callable:
    """`function` compiled by numba (no Python objects, GIL released, cached on disk); as it is without numba."""
    return function if numba is None else numba.njit(cache=True, nogil=True)(function)


@_compiled
def _linear(volume: np.ndarray, c0: float, c1: float, c2: float, constant: bool, cval: float) -> np.float32:
    """SciPy's linear interpolation of `volume` at ``(c0, c1, c2)``, rounded to float32.

    `constant`: SciPy's ``mode="constant"`` (`cval` beyond the outermost voxel centres, an index
    past the last voxel mirrored, with weight 0); else ``mode="nearest"`` (indices clamped to the
    volume, weights those of the unclamped coordinate). The weights are ``1 - t`` and ``1 - (1 - t)``,
    the 8 products ``((value w0) w1) w2`` summed with the last axis fastest, in float64.
    """
    n0, n1, n2 = volume.shape
    if constant and (c0 < 0.0 or c0 > n0 - 1 or c1 < 0.0 or c1 > n1 - 1 or c2 < 0.0 or c2 > n2 - 1):
        return np.float32(cval)
    f0, f1, f2 = np.floor(c0), np.floor(c1), np.floor(c2)
    a0, b0 = _pair(int(f0), n0, constant)
    a1, b1 = _pair(int(f1), n1, constant)
    a2, b2 = _pair(int(f2), n2, constant)
    u0, u1, u2 = 1.0 - (c0 - f0), 1.0 - (c1 - f1), 1.0 - (c2 - f2)
    v0, v1, v2 = 1.0 - u0, 1.0 - u1, 1.0 - u2
    total = 0.0
    total += (float(volume[a0, a1, a2]) * u0) * u1 * u2
    total += (float(volume[a0, a1, b2]) * u0) * u1 * v2
    total += (float(volume[a0, b1, a2]) * u0) * v1 * u2
    total += (float(volume[a0, b1, b2]) * u0) * v1 * v2
    total += (float(volume[b0, a1, a2]) * v0) * u1 * u2
    total += (float(volume[b0, a1, b2]) * v0) * u1 * v2
    total += (float(volume[b0, b1, a2]) * v0) * v1 * u2
    total += (float(volume[b0, b1, b2]) * v0) * v1 * v2
    return np.float32(total)


@_compiled
def _pair(start: int, n: int, constant: bool) -> tuple[int, int]:
    """The two voxels a linear interpolation reads from `start` on an axis of `n` (see `_linear`)."""
    second = start + 1
    if constant and second >= n:
        second = 0 if n <= 1 else 2 * n - 2 - second
    return min(max(start, 0), n - 1), min(max(second, 0), n - 1)


@_compiled
def _axis(c: float, n: int, order: int, index: np.ndarray, weight: np.ndarray) -> None:
    """One axis of SciPy's ``mode="nearest"`` interpolation of order 0 or 3 at coordinate `c` of an axis of `n` voxels.

    Fills ``index[:order + 1]`` (the voxels read, clamped to the axis) and ``weight[:order + 1]``
    (1 for order 0; else the cubic B-spline's weights of ``ni_splines.c``, the last one 1 less the others).
    """
    if order == 0:
        index[0] = min(max(int(np.floor(c + 0.5)), 0), n - 1)
        weight[0] = 1.0
        return
    start = int(np.floor(c)) - 1
    for k in range(4):
        index[k] = min(max(start + k, 0), n - 1)
    x = c - np.floor(c)
    z = 1.0 - x
    weight[1] = (x * x * (x - 2.0) * 3.0 + 4.0) / 6.0
    weight[2] = (z * z * (z - 2.0) * 3.0 + 4.0) / 6.0
    weight[0] = z * z * z / 6.0
    weight[3] = ((1.0 - weight[0]) - weight[1]) - weight[2]


@_compiled
def _spline(volume: np.ndarray, c0: float, c1: float, c2: float, order: int, index: np.ndarray,
            weight: np.ndarray) -> np.float32:
    """SciPy's ``mode="nearest"`` interpolation of order 0 or 3 of `volume` (the coefficients) at ``(c0, c1, c2)``.

    Summed as `_linear` sums; `index` (int64, (3, 4)) and `weight` (float64, (3, 4)) are scratch space.
    """
    _axis(c0, volume.shape[0], order, index[0], weight[0])
    _axis(c1, volume.shape[1], order, index[1], weight[1])
    _axis(c2, volume.shape[2], order, index[2], weight[2])
    total = 0.0
    for a in range(order + 1):
        for b in range(order + 1):
            for c in range(order + 1):
                total += (float(volume[index[0, a], index[1, b], index[2, c]]) * weight[0, a]) * weight[1, b] \
                    * weight[2, c]
    return np.float32(total)


@_compiled
def _nearest_set(support: np.ndarray, c0: float, c1: float, c2: float) -> bool:
    """Whether `support`'s nearest voxel to ``(c0, c1, c2)`` is set (order 0, ``mode="constant"``, ``cval=0``)."""
    n0, n1, n2 = support.shape
    if c0 < 0.0 or c0 > n0 - 1 or c1 < 0.0 or c1 > n1 - 1 or c2 < 0.0 or c2 > n2 - 1:
        return False
    return support[int(np.floor(c0 + 0.5)), int(np.floor(c1 + 0.5)), int(np.floor(c2 + 0.5))] != 0


@_compiled
def _draw(label: int, corner: np.ndarray, shape: np.ndarray, matrix: np.ndarray, shift: np.ndarray,
          intensity_shift: np.ndarray, support: np.ndarray, distance: np.ndarray, far: float, scale: np.float32,
          coefficients: np.ndarray, pad: float, order: int, level: np.float32, labels: np.ndarray,
          claim: np.ndarray, tomogram: np.ndarray, occupancy: np.ndarray, value: np.ndarray) -> int:
    """`draw_box`'s pass over the box (arguments as there; `pad`: of the coefficients, added last as SciPy adds it)."""
    index = np.empty((3, 4), dtype=np.int64)
    weight = np.empty((3, 4), dtype=np.float64)
    composite = occupancy.size > 0
    zero, one = np.float32(0.0), np.float32(1.0)
    contested = 0
    m = matrix
    for z in range(shape[0]):
        for y in range(shape[1]):
            for x in range(shape[2]):
                fz, fy, fx = float(z), float(y), float(x)
                # the support, at the coordinates affine_transform computes (its offset added first)
                if not _nearest_set(support, ((shift[0] + fz * m[0, 0]) + fy * m[0, 1]) + fx * m[0, 2],
                                    ((shift[1] + fz * m[1, 0]) + fy * m[1, 1]) + fx * m[1, 2],
                                    ((shift[2] + fz * m[2, 0]) + fy * m[2, 1]) + fx * m[2, 2]):
                    continue
                # the distance and intensity, at those map_coordinates reads (poses.mapped, then the shift)
                p0 = (fz * m[0, 0] + fy * m[0, 1]) + fx * m[0, 2]
                p1 = (fz * m[1, 0] + fy * m[1, 1]) + fx * m[1, 2]
                p2 = (fz * m[2, 0] + fy * m[2, 1]) + fx * m[2, 2]
                s = _linear(distance, p0 + shift[0], p1 + shift[1], p2 + shift[2], True, far) * scale
                o0, o1, o2 = corner[0] + z, corner[1] + y, corner[2] + x
                held = claim[o0, o1, o2]  # 0 where unclaimed
                wins, filled = False, zero
                if s > zero:
                    if held > zero:
                        contested += 1
                    if s > held:
                        labels[o0, o1, o2] = label
                        claim[o0, o1, o2] = s
                        wins = True
                if composite:
                    filled = min(max(s - level, zero), one)
                    drawn = filled > zero
                else:
                    drawn = wins
                if drawn:
                    c0 = (p0 + intensity_shift[0]) + pad
                    c1 = (p1 + intensity_shift[1]) + pad
                    c2 = (p2 + intensity_shift[2]) + pad
                    if order == 1:
                        grain = _linear(coefficients, c0, c1, c2, False, 0.0)
                    else:
                        grain = _spline(coefficients, c0, c1, c2, order, index, weight)
                    if composite:
                        occupancy[o0, o1, o2] += filled
                        value[o0, o1, o2] += filled * grain
                    else:
                        tomogram[o0, o1, o2] = grain
    return contested


def draw_box(
    label: int, corner: np.ndarray, shape: np.ndarray, matrix: np.ndarray, shift: np.ndarray,
    intensity_shift: np.ndarray, support: np.ndarray, distance: np.ndarray, far: float, scale: np.float32,
    intensities: tuple[np.ndarray, int], order: int, level: np.float32 | None, arrays: tuple[Any, ...],
) -> int:
    """Draw one grain over a box of a chunk in one pass: claims, and the pasted or composited intensities.

    Parameters
    ----------
    label : int
        The grain's label.
    corner, shape : ndarray of int, shape (3,)
        The box's first voxel in the chunk, and its shape (voxels).
    matrix : ndarray of float64, shape (3, 3)
        The grain's pose matrix (`~synthpack.render.poses.PoseMaps`).
    shift : ndarray of float64, shape (3,)
        Crop coordinates of the box's first voxel in `support` and `distance` (its offset plus their padding).
    intensity_shift : ndarray of float64, shape (3,)
        Crop coordinates of the box's first voxel in the intensities.
    support : ndarray of uint8, shape (nz, ny, nx)
        The crop's support (`~synthpack.render.crops.RenderCrop`): only its voxels are drawn.
    distance : ndarray of float32, same shape
        The crop's smooth signed distance (crop voxels), read linearly, `far` beyond it.
    far : float
        Distance beyond the crop.
    scale : numpy.float32
        Output voxels per crop voxel: the drawn distance is the read one times `scale` (float32).
    intensities : (ndarray, int)
        `spline_coefficients` of the crop's intensities for `order`.
    order : int
        Interpolation of the intensities: 0, 1 or 3 (``mode="nearest"``).
    level : numpy.float32 or None
        The partial volume's occupancy is ``clip(distance - level, 0, 1)``
        (`~synthpack.render.partial_volume.PartialVolume.level`); None: whole voxels.
    arrays : tuple of ndarray, shape (z, y, x)
        The chunk's labels (int32), claims, tomogram and, for the partial volume, occupancy
        and value sums (float32), C-contiguous, updated in place.

    Returns
    -------
    int
        Voxels the grain claims that an earlier grain claimed.
    """
    labels, claim, tomogram, *sums = arrays
    occupancy, value = sums if level is not None else (np.empty((0, 0, 0), dtype=np.float32),) * 2
    coefficients, pad = intensities
    return int(_draw(label, corner, shape, matrix, shift, intensity_shift, support, distance, far, scale,
                     coefficients, float(pad), order, np.float32(0.0 if level is None else level), labels, claim,
                     tomogram, occupancy, value))
