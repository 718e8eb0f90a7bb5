"""The pore phase's power spectrum over scales from a voxel to the pore bodies: what the pore texture reproduces.

The noise power spectrum (`~synthpack.measure.spectrum`) sees the noise alone, in
``8 x 8`` in-slice patches: nothing of a pore phase's structure, which
in a real scan is most of its spread (a cement paste's spread is ten times its
noise: sand, voids and moisture in it). This module measures the whole 3D
spectrum of the pore interior's intensity fluctuations, on every scale up to
`PORE_SPECTRUM_SIZE` voxels.

**Method: a masked autocovariance (gaps allowed).** The pore interior ``m`` (a
mask: voxels of the specimen at least `~synthpack.measure.edges.INTERIOR` voxels
from a grain) is not a box, so no window of it can be Fourier transformed
directly. Its autocovariance can: with ``x = (I - mean) m`` (the mean over the
interior),

    C(r) = sum_v x(v) x(v + r) / sum_v m(v) m(v + r),

the mean product over every pair of interior voxels at lag ``r``, evaluated for
all lags at once by FFT (the volume zero-padded so lags do not wrap). Large
scans are cut into cubes of `BLOCK` voxels, at most `MAX_BLOCKS` of them
(those with the most interior, evenly spread), whose sums add. Lags with fewer
than `MIN_PAIRS` pairs are left out. The covariance of the lags within
``PORE_SPECTRUM_SIZE / 2`` is tapered by a Hann window in ``|r|`` and Fourier
transformed on a ``PORE_SPECTRUM_SIZE^3`` grid: the power spectral density (Wiener-
Khinchin), which is averaged over shells of ``|f|`` of width ``1 /
PORE_SPECTRUM_SIZE`` cycles per voxel (negative values, from the taper, set to 0).

**Smoothing.** The estimate scatters from shell to shell, most where the density
is lowest (the corners of the grid, beyond 0.5 cycles per voxel, are measured along
the diagonals alone), and its spikes there would draw periodic patterns in a
texture. `smooth_spectrum` makes it fit to draw from: smooth in the logarithm, no
spikes, nothing beyond 0.5 cycles per voxel. The estimate itself is kept as measured.

**Units.** Density in intensity units squared times voxels cubed: on the FFT grid
of any periodic cube, the mean of the density is the variance (white noise of
variance ``s^2`` has the flat density ``s^2``).

**Limits.** The spectrum is isotropic (shells in 3D; a scanner's in-slice and
axial correlations are averaged). Variation on scales beyond about
``PORE_SPECTRUM_SIZE / 2`` voxels is folded into the lowest shells, and the
frequency resolution is about ``2 / PORE_SPECTRUM_SIZE`` cycles per voxel (the
taper); the two lowest shells are biased low (by about a third for white noise
smoothed over 2 voxels), because the taper spreads them and the mean is taken
from the data. Where the pores are thin (a dense sand pack: interior voxels in small,
separate pore bodies), long lags are measured between different pore bodies,
so the large-scale part is that of the pore phase as a whole; with no lag of at
least `MIN_PAIRS` pairs beyond zero, or fewer than `MIN_VOXELS` interior voxels,
nothing is measured (None). It is a second-order description: a pore phase with
sparse inclusions (heavy tails) has their power in its spectrum, but a Gaussian
texture drawn from it has none of their shape.
"""

from __future__ import annotations

import logging

import numpy as np
from scipy import fft, ndimage

from .._shared.chunks import chunk_boxes

__all__ = ["BLOCK", "MAX_BLOCKS", "MIN_PAIRS", "MIN_VOXELS", "PORE_SPECTRUM_SIZE", "SMOOTH_SHELLS", "frequency_radius",
           "measure_pore_spectrum", "shell_frequencies", "smooth_spectrum", "spectrum_on_grid"]

logger = logging.getLogger(__name__)

#: Side (voxels) of the lag window: lags up to half of it, shells of ``1 / PORE_SPECTRUM_SIZE`` cycles per voxel.
PORE_SPECTRUM_SIZE = 64
#: Side (voxels) of the cubes a large scan is cut into.
BLOCK = 128
#: At most this many cubes are measured.
MAX_BLOCKS = 16
#: A lag needs at least this many voxel pairs to be used.
MIN_PAIRS = 2000
#: No spectrum is measured from fewer interior voxels.
MIN_VOXELS = 2000
#: `smooth_spectrum`'s running median spans this many shells.
SMOOTH_SHELLS = 5


def shell_frequencies(n_shells: int, size: int = PORE_SPECTRUM_SIZE) -> np.ndarray:
    """Centre frequency (cycles/voxel) of shells ``0 .. n_shells - 1``: ``k / size``, float64."""
    return np.arange(n_shells) / size


def frequency_radius(shape: tuple[int, ...], rows: slice = slice(None)) -> np.ndarray:
    """``|f|`` (cycles/voxel) at every frequency of the full FFT grid of `shape`, float64, shape `shape`;
    only its `rows` along the first axis where given (the same values, a slab's memory)."""
    squares = [np.square(np.fft.fftfreq(n)).reshape([-1 if i == j else 1 for j in range(len(shape))])
               for i, n in enumerate(shape)]
    squares[0] = squares[0][rows]
    return np.sqrt(sum(squares))


def _lag_radius(size: int) -> np.ndarray:
    """``|r|`` (voxels) at every lag of a ``size^3`` grid of wrapped lags, float64."""
    return frequency_radius((size,) * 3) * size


def _blocks(mask: np.ndarray, block: int, max_blocks: int) -> list[tuple[slice, ...]]:
    """The cubes of `block` voxels with the most mask voxels (at most `max_blocks`), in volume order."""
    boxes = [tuple(slice(int(a), int(b)) for a, b in zip(lo, hi)) for lo, hi in chunk_boxes(mask.shape, (block,) * 3)]
    counts = np.array([np.count_nonzero(mask[box]) for box in boxes])
    order = np.argsort(-counts, kind="stable")[:max_blocks]
    return [boxes[i] for i in sorted(order) if counts[i] > 0]


def _lag_sums(values: np.ndarray, weights: np.ndarray, half: int) -> np.ndarray:
    """``sum_v values(v) values(v + r)`` for lags ``|r_i| <= half``, on a ``(2 half)^3`` wrapped grid, float64."""
    shape = [n + half for n in values.shape]
    spectrum = fft.rfftn(values * weights, s=shape)
    product = fft.irfftn(np.abs(spectrum) ** 2, s=shape)
    lags = np.fft.fftfreq(2 * half) * 2 * half
    index = [lags.astype(np.int64) % n for n in shape]
    return product[np.ix_(*index)]


def measure_pore_spectrum(
    tomogram: np.ndarray, mask: np.ndarray, *, size: int = PORE_SPECTRUM_SIZE, block: int = BLOCK,
    max_blocks: int = MAX_BLOCKS,
) -> np.ndarray | None:
    """The radially averaged 3D power spectral density of `tomogram` inside `mask` (see the module docstring).

    Parameters
    ----------
    tomogram : ndarray, shape (Z, Y, X)
        Intensities.
    mask : ndarray of bool, same shape
        The voxels to measure (the pore interior of the specimen).
    size : int
        Side of the lag window, voxels (even): lags up to ``size / 2``.
    block : int
        Side of the cubes a large volume is cut into, voxels.
    max_blocks : int
        At most this many cubes.

    Returns
    -------
    ndarray of float64, shape (K,) or None
        Density in shells ``k = 0 .. K - 1`` at ``k / size`` cycles per voxel
        (`shell_frequencies`; ``K - 1 = rint(sqrt(3) size / 2)``, the grid's
        corners), intensity units squared times voxels cubed, >= 0. None when
        `mask` holds fewer than `MIN_VOXELS` voxels or no lag but 0 has
        `MIN_PAIRS` pairs.
    """
    mask = np.asarray(mask, dtype=bool)
    if np.count_nonzero(mask) < MIN_VOXELS:
        logger.debug("pore spectrum: %d interior voxels (%d needed): not measured", np.count_nonzero(mask), MIN_VOXELS)
        return None
    boxes = _blocks(mask, block, max_blocks)
    total = sum(np.asarray(tomogram[box], dtype=np.float64)[mask[box]].sum() for box in boxes)
    mean = total / sum(np.count_nonzero(mask[box]) for box in boxes)
    half = size // 2
    products = np.zeros((size,) * 3)
    pairs = np.zeros((size,) * 3)
    for box in boxes:
        weights = mask[box].astype(np.float64)
        products += _lag_sums(np.asarray(tomogram[box], dtype=np.float64) - mean, weights, half)
        pairs += _lag_sums(np.ones_like(weights), weights, half)
    lag = _lag_radius(size)
    used = (pairs >= MIN_PAIRS) & (lag < half)
    if not used[lag > 0].any():
        logger.debug("pore spectrum: no lag beyond 0 has %d voxel pairs: not measured", MIN_PAIRS)
        return None
    taper = 0.5 * (1.0 + np.cos(np.pi * lag / half))
    covariance = np.where(used, products / np.maximum(pairs, 1.0) * taper, 0.0)
    density = fft.fftn(covariance).real
    frequency = frequency_radius((size,) * 3)
    shells = np.rint(frequency * size).astype(np.int64).ravel()
    radial = np.bincount(shells, weights=density.ravel()) / np.bincount(shells)
    logger.debug("pore spectrum: variance %.4g over %d blocks, %.0f%% of it below 0.1 cycles/voxel",
                 covariance[0, 0, 0], len(boxes),
                 100.0 * density[frequency < 0.1].sum() / max(density.sum(), np.finfo(float).tiny))
    return np.maximum(radial, 0.0)


def spectrum_on_grid(density: np.ndarray, tile: int, size: int = PORE_SPECTRUM_SIZE,
                     rows: slice = slice(None)) -> np.ndarray:
    """A shell spectrum (`measure_pore_spectrum`) on the full FFT grid of a periodic cube of `tile` voxels
    (only its `rows` along the first axis where given).

    Interpolated linearly in ``|f|`` on the logarithm of the density (geometrically:
    a spectrum that falls by decades between two shells is not lifted by the one
    above it), 0 beyond the last shell.

    Returns
    -------
    ndarray of float64, shape (tile, tile, tile), or (rows, tile, tile)
        Density at every frequency of the grid; its mean is the variance of noise with it.
    """
    density = np.asarray(density, dtype=np.float64)
    radius = frequency_radius((tile,) * 3, rows)
    logarithm = np.log(np.maximum(density, np.finfo(float).tiny))
    grid = np.exp(np.interp(radius, shell_frequencies(len(density), size), logarithm))
    grid[radius > shell_frequencies(len(density), size)[-1]] = 0.0
    return grid


def smooth_spectrum(density: np.ndarray, size: int = PORE_SPECTRUM_SIZE) -> np.ndarray:
    """A measured shell spectrum made fit to draw a texture from: smooth, without the estimate's spikes.

    The estimate (`measure_pore_spectrum`) scatters from shell to shell, most where
    the density is lowest: its negative values (the taper's leakage and the noise of
    the long lags) are set to 0, and the shells beyond ``size / 2`` (more than 0.5
    cycles per voxel: only the corners of the frequency grid, the diagonals) hold
    spikes of such noise. A texture drawn from such shells gets their spikes as
    periodic patterns. Here, in the logarithm of the density and on the shells up to
    0.5 cycles per voxel: shells of 0 are filled by linear interpolation from their
    positive neighbours (held at the first and last positive one beyond them), a
    running median over `SMOOTH_SHELLS` shells takes out spikes up to two shells
    wide (a monotonic stretch is kept as it is), and a running mean with weights
    ``1/4, 1/2, 1/4`` smooths what is left. The shells beyond 0.5 cycles per voxel are 0.

    Parameters
    ----------
    density : array of float, shape (K,)
        From `measure_pore_spectrum` (intensity units squared times voxels cubed, >= 0).
    size : int
        The lag window it was measured with (shells of ``1 / size`` cycles per voxel).

    Returns
    -------
    ndarray of float64, shape (K,)
        > 0 up to shell ``size / 2``, 0 beyond; all 0 where no shell is positive.
    """
    density = np.asarray(density, dtype=np.float64)
    kept = density[: size // 2 + 1]
    smooth = np.zeros_like(density)
    positive = np.flatnonzero(kept > 0)
    if not len(positive):
        return smooth
    logarithm = np.interp(np.arange(len(kept)), positive, np.log(kept[positive]))
    logarithm = ndimage.median_filter(logarithm, size=SMOOTH_SHELLS, mode="nearest")
    logarithm = ndimage.convolve1d(logarithm, [0.25, 0.5, 0.25], mode="nearest")
    smooth[: len(kept)] = np.exp(logarithm)
    return smooth
