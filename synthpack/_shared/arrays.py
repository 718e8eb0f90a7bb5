"""Array helpers of the image stages (source measurement, artefacts): input checks, slabs, slice radius."""

from __future__ import annotations

import math
from collections.abc import Iterator, Sequence
from typing import Any

import numpy as np

from ..errors import SynthpackInputError

__all__ = ["SLAB_VOXELS", "as_image", "cupping_factor", "without_cupping", "float32_value", "periodic_indices", "periodic_window",
           "radius_grid", "slabs"]

#: Noise is drawn (and measured) in slabs of at most this many voxels along axis 0, so
#: the extra memory it needs is bounded whatever the volume's size.
SLAB_VOXELS = 1 << 22


def as_image(image: Any) -> np.ndarray:
    """Return `image` as a float32 array (no copy when it already is one).

    Parameters
    ----------
    image : array_like, shape (Z, Y, X) or (H, W)
        A volume (axis 0 = slice axis = rotation axis) or a single slice.

    Raises
    ------
    SynthpackInputError
        If it is not 2D or 3D or does not hold real numbers.
    """
    array = np.asarray(image)
    if array.ndim not in (2, 3):
        raise SynthpackInputError(
            f"expected a volume (z, y, x) or a slice (y, x) of intensities, got an array of shape "
            f"{array.shape}: pass one volume or one 2D slice at a time"
        )
    if not np.issubdtype(array.dtype, np.number) or np.iscomplexobj(array):
        raise SynthpackInputError(
            f"intensities must be real-valued, got dtype {array.dtype}"
        )
    return array.astype(np.float32, copy=False)


def float32_value(value: float) -> float:
    """`value` rounded to float32, as a Python float: NumPy and torch apply it to float32 arrays as that float32."""
    return float(np.float32(value))


def periodic_window(tile: np.ndarray, origin: Sequence[int], shape: Sequence[int]) -> np.ndarray:
    """The box of `shape` at global index `origin` of the space that copies of `tile` fill periodically.

    Voxel ``g`` of the box is ``tile[g % tile.shape]``. One gather along each axis in
    turn (the first two on the small tile), about 4x faster than a single
    ``tile[np.ix_(...)]`` on a chunk, with the same values.

    Parameters
    ----------
    tile : ndarray, shape (Tz, Ty, Tx) (any number of axes)
    origin, shape : sequence of int, one per axis of `tile`

    Returns
    -------
    ndarray, dtype of `tile`, shape `shape`
        A new array.
    """
    out = tile
    for axis, index in enumerate(periodic_indices(origin, shape, tile.shape)):
        out = out.take(index, axis=axis)
    return out


def periodic_indices(origin: Sequence[int], shape: Sequence[int], period: Sequence[int]) -> list[np.ndarray]:
    """Per axis, the tile indices ``g % period`` of the global indices ``g`` of a box of `shape` at `origin`.

    Returns
    -------
    list of ndarray of int64, one per axis, of lengths `shape`
        What `periodic_window` gathers along each axis (a device gather uses the same).
    """
    return [np.arange(int(start), int(start) + int(length)) % int(p) for start, length, p in zip(origin, shape, period)]


def slabs(shape: tuple[int, ...], max_voxels: int = SLAB_VOXELS) -> Iterator[slice]:
    """Yield slices of axis 0 covering `shape`, each at most about `max_voxels` voxels."""
    per_row = max(1, math.prod(shape[1:]))
    step = max(1, max_voxels // per_row)
    for start in range(0, shape[0], step):
        yield slice(start, min(start + step, shape[0]))


def radius_grid(shape: tuple[int, ...], centre: tuple[float, float] | None = None) -> np.ndarray:
    """Distance (voxels) of each pixel of a slice from the slice centre (or `centre`).

    Parameters
    ----------
    shape : tuple of int
        The image shape; its last two axes (Y, X) are the slice.
    centre : (float, float), optional
        ``(y, x)`` of the rotation axis; default the slice centre ``((Y-1)/2, (X-1)/2)``.

    Returns
    -------
    ndarray of float32, shape (Y, X)
        ``hypot(y - cy, x - cx)``: the distance from the rotation axis, which passes
        through the same point of every slice along axis 0.
    """
    ny, nx = shape[-2:]
    cy, cx = ((ny - 1) / 2, (nx - 1) / 2) if centre is None else centre
    y = np.arange(ny, dtype=np.float32) - np.float32(cy)
    x = np.arange(nx, dtype=np.float32) - np.float32(cx)
    return np.hypot(y[:, None], x[None, :])


def cupping_factor(
    shape: tuple[int, ...], strength: float, keep: str = "rim", centre: tuple[float, float] | None = None
) -> np.ndarray:
    """The radial intensity factor of beam-hardening cupping on one slice.

    ``1 - strength * max(1 - (r / R)^2, 0)`` with ``R = min(Y, X) / 2`` (the field
    of view) and ``r`` the distance from the rotation axis (`radius_grid`); with
    ``keep="mean"`` divided by its mean over the field of view, ``1 - strength / 2``.

    Parameters
    ----------
    shape : tuple of int
        The image shape; its last two axes (Y, X) are the slice.
    strength : float
        Relative darkening of the axis against the rim, in [-1, 1].
    keep : {"rim", "mean"}
        What the factor leaves unchanged: the rim of the field of view or the mean inside it.
    centre : (float, float), optional
        ``(y, x)`` of the rotation axis; default the slice centre.

    Returns
    -------
    ndarray of float32, shape (Y, X)
    """
    r = radius_grid(shape, centre)
    radius = np.float32(min(shape[-2:]) / 2.0)
    factor = 1.0 - np.float32(strength) * np.clip(1.0 - (r / radius) ** 2, 0.0, 1.0)
    if keep == "mean":
        factor /= np.float32(1.0 - strength / 2.0)
    return factor.astype(np.float32)


def without_cupping(
    tomogram: np.ndarray, strength: float | None, centre: tuple[float, float] | None = None
) -> np.ndarray:
    """`tomogram` with a measured cupping divided out, its mean level over the field of view kept.

    Parameters
    ----------
    tomogram : ndarray, shape (Z, Y, X)
        Intensities; slices along axis 0 are perpendicular to the rotation axis.
    strength : float or None
        The cupping's strength (`cupping_factor`); None (none measured) returns `tomogram` itself.
    centre : (float, float), optional
        ``(y, x)`` of the rotation axis; default the slice centre.

    Returns
    -------
    ndarray of float32, shape (Z, Y, X), or `tomogram` itself when `strength` is None
    """
    if strength is None:
        return tomogram
    return np.asarray(tomogram, dtype=np.float32) / cupping_factor(np.shape(tomogram), strength, "mean", centre)
