"""Lazy access: `memmap_volume` memory-maps a volume file; `read_slice` and `read_box` read one slice or box
of a memory map, a Zarr array or an array.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
import tifffile

from ..errors import SynthpackInputError
from ._base import ArrayLike, PathLike, _reading
from .tiff import _TIFF_SUFFIXES


def memmap_volume(path: PathLike) -> np.ndarray:
    """Memory-map a volume file read-only, so that slicing it reads only the slices asked for.

    Parameters
    ----------
    path : str or Path
        A NumPy ``.npy`` file or an uncompressed, contiguous TIFF stack
        (``.tif``/``.tiff``, as `write_tiff` writes).

    Returns
    -------
    numpy.memmap, usually shape (Z, Y, X)
        The data as stored (any dtype), read-only. A memory map belongs to the
        process that made it: open it again in each process (e.g. in each
        DataLoader worker) instead of pickling it.

    Raises
    ------
    SynthpackInputError
        If the file is missing, of another type, compressed, tiled or truncated
        (read it with `read_volume` instead).
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in (".npy", *_TIFF_SUFFIXES):
        raise SynthpackInputError(
            f"{path} cannot be memory-mapped: only .npy files and uncompressed TIFF stacks can; "
            "read it with read_volume instead"
        )
    with _reading(path, "a memory-mappable NPY or uncompressed TIFF file"):
        return np.load(path, mmap_mode="r") if suffix == ".npy" else tifffile.memmap(path, mode="r")


def read_slice(volume: ArrayLike, axis: int, index: int) -> np.ndarray:
    """One 2D slice of a 3D volume, read alone.

    Parameters
    ----------
    volume : array-like, shape (Z, Y, X)
        A NumPy array, a memory map (`memmap_volume`) or a Zarr array: only the
        slice is read (from a Zarr array, only the chunks it crosses).
    axis : {0, 1, 2}
        Slicing axis.
    index : int
        Slice index along `axis`.

    Returns
    -------
    ndarray, dtype of `volume`
        Shape (Y, X) for axis 0, (Z, X) for axis 1, (Z, Y) for axis 2; a view
        when `volume` is a NumPy array or memory map.
    """
    return np.asarray(volume[(slice(None),) * axis + (index,)])


def read_box(volume: ArrayLike, origin: Sequence[int], size: Sequence[int]) -> np.ndarray:
    """One box of a 3D volume, read alone.

    Parameters
    ----------
    volume : array-like, shape (Z, Y, X)
        A NumPy array, a memory map (`memmap_volume`) or a Zarr array: only the
        box is read (from a memory map, only the pages it crosses; from a Zarr
        array, only the chunks it crosses).
    origin : sequence of 3 int
        First voxel ``(z, y, x)`` of the box, inside the volume.
    size : sequence of 3 int
        Extent ``(d, h, w)`` of the box in voxels; the box must lie inside the volume.

    Returns
    -------
    ndarray, dtype of `volume`, shape `size`
        A view when `volume` is a NumPy array or memory map.
    """
    box = tuple(slice(int(start), int(start) + int(extent)) for start, extent in zip(origin, size))
    out = np.asarray(volume[box])
    if out.shape != tuple(int(n) for n in size):
        raise ValueError(f"box at {tuple(origin)} of size {tuple(size)} is not inside a volume of shape {volume.shape}")
    return out

