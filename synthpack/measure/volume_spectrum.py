"""The 3D power spectrum of a region of a volume, averaged about the slice normal: what `SpectrumMatch` matches.

A scan's texture is more than its noise's spectrum and its edges' width: how its grains'
outlines, their interiors' speckle and its noise share each frequency, along the slices and
across them, is what a classifier of its patches reads (the realism report's spectrum features
told packs apart where their histograms, noise levels and ring spectra matched). This module
measures the whole of it, structure and noise together, as one figure:

**Welch cubes.** Cubes of `TILE` voxels wholly inside the region, on a lattice of half a cube
from the corner of the region's box (and flush with its far side),
each minus its mean and multiplied by a periodic Hann window along each axis, are Fourier
transformed, and their powers averaged (at most `MAX_CUBES`, spread evenly over the list). A
region too small for `MIN_CUBES` of them (a specimen of a few dozen voxels across) is read in
cubes of half the side, `TILES`, at half the resolution in frequency.

**About the slice normal.** The average power at each ``(|f_z|, f_r)``: ``|f_z| = k / T``
(``k = 0 ... T / 2``, ``T`` the cube side) across the slices, ``f_r = j / T`` (``j = 0 ...
radii(T) - 1``, the in-slice frequency's magnitude, rounded) along them. A scanner's noise and blur are about
symmetric about its rotation axis (the slice normal) but differ along it from across it, and
this table keeps that difference. Powers are normalised by the window's energy, so that white
noise of variance ``s^2`` reads ``s^2`` at every frequency.
"""

from __future__ import annotations

import numpy as np
from scipy import fft

__all__ = ["MAX_CUBES", "MIN_CUBES", "TILE", "TILES", "cube_corners", "cylindrical_spectrum", "frequency_bins",
           "radii", "table_tile"]

#: Cube side, voxels.
TILE = 32
#: The cube sides tried, the first that gives `MIN_CUBES` first.
TILES = (TILE, TILE // 2)
#: Fewer cubes than this in the region give no spectrum.
MIN_CUBES = 8
#: At most this many cubes are read (spread evenly over those that fit).
MAX_CUBES = 512


def cube_corners(region: np.ndarray, tile: int = TILE, max_cubes: int = MAX_CUBES) -> np.ndarray:
    """Corners of the cubes of side `tile` wholly inside `region`, on a lattice of half a cube from its box's corner.

    Parameters
    ----------
    region : ndarray of bool, shape (Z, Y, X)
    tile : int
        Cube side, voxels.
    max_cubes : int
        Keep at most this many, evenly spread over the list (in z, y, x order).

    Returns
    -------
    ndarray of int64, shape (N, 3)
        ``(z, y, x)`` of each cube's first voxel; N may be 0.
    """
    region = np.asarray(region, dtype=bool)
    if any(n < tile for n in region.shape):
        return np.zeros((0, 3), dtype=np.int64)
    # a summed-volume table: the voxels of the region in every cube, in O(1) each
    table = np.zeros(tuple(n + 1 for n in region.shape), dtype=np.int64)
    table[1:, 1:, 1:] = region.cumsum(0).cumsum(1).cumsum(2)
    step = max(1, tile // 2)
    occupied = [np.flatnonzero(region.any(axis=tuple(a for a in range(3) if a != axis))) for axis in range(3)]
    if any(len(o) == 0 or o[-1] - o[0] + 1 < tile for o in occupied):
        return np.zeros((0, 3), dtype=np.int64)
    # a lattice from the region's first voxel on each axis, and a last cube flush with its end
    starts = [np.unique(np.append(np.arange(o[0], o[-1] - tile + 2, step), o[-1] - tile + 1)) for o in occupied]
    z, y, x = np.meshgrid(*starts, indexing="ij")
    z, y, x = z.ravel(), y.ravel(), x.ravel()
    count = (table[z + tile, y + tile, x + tile] - table[z, y + tile, x + tile] - table[z + tile, y, x + tile]
             - table[z + tile, y + tile, x] + table[z, y, x + tile] + table[z, y + tile, x]
             + table[z + tile, y, x] - table[z, y, x])
    corners = np.stack([z, y, x], axis=1)[count == tile**3]
    if len(corners) > max_cubes:
        corners = corners[np.linspace(0, len(corners) - 1, max_cubes).round().astype(np.int64)]
    return corners.astype(np.int64)


def radii(tile: int) -> int:
    """In-slice frequency bins of a table of cubes of side `tile`: ``j / tile`` cycles per voxel, up to the corner."""
    return int(np.ceil(tile / 2 * np.sqrt(2))) + 1


def table_tile(table: np.ndarray) -> int:
    """The cube side a `cylindrical_spectrum` table was measured with (its rows are ``tile / 2 + 1``)."""
    return 2 * (np.shape(table)[0] - 1)


def frequency_bins(shape: tuple[int, int, int], tile: int) -> tuple[np.ndarray, np.ndarray]:
    """The continuous table coordinates of every frequency of an FFT grid of `shape`.

    Returns
    -------
    fz, fr : ndarray of float64, shape `shape`
        ``|f_z| * tile`` and ``hypot(f_y, f_x) * tile``: the row and column of a
        `cylindrical_spectrum` table of cubes of side `tile` (fractional) where each frequency falls.
    """
    fz, fy, fx = (np.abs(fft.fftfreq(n)) * tile for n in shape)
    return (np.broadcast_to(fz[:, None, None], shape).astype(np.float64),
            np.broadcast_to(np.hypot(fy[:, None], fx[None, :])[None], shape).astype(np.float64))


def cylindrical_spectrum(volume: np.ndarray, region: np.ndarray, *, tile: int | None = None,
                         max_cubes: int = MAX_CUBES) -> np.ndarray | None:
    """The power spectrum of `volume` in `region`, averaged about the slice normal (see the module docstring).

    Parameters
    ----------
    volume : array-like, shape (Z, Y, X)
        Intensities (any real dtype; read as float64).
    region : ndarray of bool, same shape
        Where cubes may lie.
    tile : int, optional
        Cube side, voxels; None: the first of `TILES` of which `MIN_CUBES` fit.
    max_cubes : int
        At most this many cubes.

    Returns
    -------
    ndarray of float64, shape (tile // 2 + 1, radii(tile)), or None
        Power per frequency, intensity units squared: row ``k`` is ``|f_z| = k / tile``,
        column ``j`` is ``f_r = j / tile`` cycles per voxel; entry (0, 0) is 0 (each cube's
        mean is removed). None where fewer than `MIN_CUBES` cubes fit in `region`.
    """
    for tile in (TILES if tile is None else (tile,)):
        corners = cube_corners(region, tile, max_cubes)
        if len(corners) >= MIN_CUBES:
            break
    else:
        return None
    from scipy.signal import windows  # here, not at import: scipy.signal takes a third of the command line's start

    hann = windows.hann(tile, sym=False)
    window = hann[:, None, None] * hann[None, :, None] * hann[None, None, :]
    power = np.zeros((tile,) * 3, dtype=np.float64)
    for z, y, x in corners:
        cube = np.asarray(volume[z:z + tile, y:y + tile, x:x + tile], dtype=np.float64)
        power += np.abs(fft.fftn((cube - cube.mean()) * window)) ** 2
    power /= len(corners) * float(np.sum(window**2))
    fz, fr = frequency_bins((tile,) * 3, tile)
    columns, size = radii(tile), (tile // 2 + 1) * radii(tile)
    index = fz.astype(np.int64).ravel() * columns + np.rint(fr).astype(np.int64).ravel()
    sums = np.bincount(index, weights=power.ravel(), minlength=size)
    counts = np.bincount(index, minlength=size)
    table = np.where(counts > 0, sums / np.maximum(counts, 1), 0.0).reshape(tile // 2 + 1, columns)
    table[0, 0] = 0.0
    return table
