"""A linear filter that gives a volume a source scan's 3D power spectrum, about the slice normal.

The calibration's blur and noise are fitted to figures that each see part of a scan's spectrum:
the edges' width, the noise's in-slice rings (on second differences across slices), its level.
Matched on all of them, a pack's patches were still told from the source's by their spectra
(sand micro-CT: a Gaussian PSF left the pack short of the scan's power at 3-5 voxels, and its
isotropic noise too strong near the slices' Nyquist frequency). `SpectrumMatch` corrects the
rest at once: a zero-phase 3D filter whose gain at each ``(|f_z|, f_r)``
(`~synthpack.measure.volume_spectrum.cylindrical_spectrum`'s table) is
``sqrt(source power / pack power)``, fitted by `fit_gain` on the calibrated pack.

**The gain** (`fit_gain`): the log of the power ratio, smoothed by a Gaussian of `SMOOTHING`
table bins (the ratio of two Welch estimates is noisy, and a filter with sharp steps in
frequency would ring), clipped to a power factor of `MAX_POWER_GAIN` either way, halved
(power to amplitude) and exponentiated. At frequency 0, which the spectra do not see (each cube's
mean is removed), the ratio is its neighbours'.

**The kernel** (`spectrum_kernel`): the gain, interpolated linearly from the table to each
frequency of a cube of `~synthpack.measure.volume_spectrum.TILE` voxels (whatever cube side
the table was measured with), inverse Fourier transformed and cut to `KERNEL_RADIUS` voxels
about its centre; it is symmetric about every axis, so convolution and correlation are the
same. It sums to the gain at frequency 0, ``g``,
about 1: the filter adds ``(1 - g) level`` to keep a volume of the mean intensity `level` (the
fitted pack's) at that level, so the phases' levels move by ``(g - 1)`` of their distance from it.

**Applied** by FFT convolution of the volume mirrored beyond its borders (SciPy's
``"reflect"``, NumPy's ``"symmetric"``), in float32 (its rounding, about 1e-6 of the intensities,
is far below a scan's grey-level step), with the kernel's transform kept for each block shape: a
``"neighbourhood"`` transform of halo `KERNEL_RADIUS`, so block by block
(`synthpack.artefacts.blockwise`) it gives the whole volume's values within float32 rounding.
A slice (H, W) gets the kernel summed along z (a volume constant across slices). No torch
step: a pipeline holding it runs on the CPU.
"""

from __future__ import annotations

import functools
from collections.abc import Sequence

import numpy as np
from scipy import fft, ndimage

from ..errors import SynthpackInputError
from ..measure.volume_spectrum import TILE, TILES, frequency_bins, radii
from ._base import Transform
from ._param import Param

__all__ = ["KERNEL_RADIUS", "MAX_POWER_GAIN", "SMOOTHING", "SpectrumMatch", "fit_gain", "spectrum_kernel"]

#: Half the kernel's side, voxels (its halo on every axis).
KERNEL_RADIUS = 12
#: Standard deviation of the Gaussian that smooths the log power ratio, table bins.
SMOOTHING = 1.0
#: The gain changes the power at any frequency by at most this factor, up or down.
MAX_POWER_GAIN = 9.0
#: The number of gains of a table, by the cube side it was measured with.
_SIZES = {(tile // 2 + 1) * radii(tile): tile for tile in TILES}


def fit_gain(source: np.ndarray, pack: np.ndarray) -> np.ndarray:
    """The amplitude gain that takes the `pack`'s spectrum to the `source`'s (see the module docstring).

    Parameters
    ----------
    source, pack : ndarray of float64, shape (T // 2 + 1, radii(T))
        `~synthpack.measure.volume_spectrum.cylindrical_spectrum` tables of the same cube side ``T``,
        intensity units squared.

    Returns
    -------
    ndarray of float64, the tables' shape
        Gain per frequency bin (dimensionless, > 0); about 1 where either table has no power.
    """
    source, pack = np.asarray(source, dtype=np.float64), np.asarray(pack, dtype=np.float64)
    known = (source > 0) & (pack > 0)
    ratio = np.zeros_like(source)
    ratio[known] = np.log(source[known]) - np.log(pack[known])
    ratio[0, 0] = np.mean([ratio[0, 1], ratio[1, 0]])  # frequency 0 (each cube's mean, removed): its neighbours'
    ratio = ndimage.gaussian_filter(ratio, SMOOTHING, mode="nearest")
    limit = np.log(MAX_POWER_GAIN)
    return np.exp(np.clip(ratio, -limit, limit) / 2.0)


@functools.lru_cache(maxsize=4)
def _kernel(gain: tuple[float, ...]) -> np.ndarray:
    tile = _SIZES[len(gain)]
    table = np.asarray(gain, dtype=np.float64).reshape(tile // 2 + 1, radii(tile))
    fz, fr = frequency_bins((TILE,) * 3, tile)
    response = ndimage.map_coordinates(table, [fz, fr], order=1, mode="nearest")
    centre = TILE // 2
    kernel = fft.fftshift(fft.ifftn(response).real)
    kernel = kernel[tuple(slice(centre - KERNEL_RADIUS, centre + KERNEL_RADIUS + 1) for _ in range(3))]
    return (kernel + kernel[::-1] + kernel[:, ::-1] + kernel[:, :, ::-1]
            + kernel[::-1, ::-1] + kernel[::-1, :, ::-1] + kernel[:, ::-1, ::-1] + kernel[::-1, ::-1, ::-1]) / 8


@functools.lru_cache(maxsize=8)
def _kernel_spectrum(gain: tuple[float, ...], shape: tuple[int, ...]) -> np.ndarray:
    """The real FFT of the kernel (summed along z for a slice) on a grid of `shape`, complex64."""
    kernel = _kernel(gain)
    if len(shape) == 2:
        kernel = kernel.sum(axis=0)
    return fft.rfftn(kernel.astype(np.float32), shape)


def spectrum_kernel(gain: Sequence[float]) -> np.ndarray:
    """The convolution kernel of a gain table (see the module docstring).

    Parameters
    ----------
    gain : sequence of float
        The table of `fit_gain`, flattened row by row.

    Returns
    -------
    ndarray of float64, shape (2 KERNEL_RADIUS + 1,) * 3
        Symmetric about every axis; sums to about the gain at frequency 0. Read-only (cached).
    """
    kernel = _kernel(tuple(float(g) for g in gain))
    kernel.flags.writeable = False
    return kernel


class SpectrumMatch(Transform):
    """Filter a volume so that its power spectrum about the slice normal becomes a source's.

    Parameters
    ----------
    gain : sequence of float
        Amplitude gains (`fit_gain`'s table, row by row: ``|f_z|`` rows, in-slice frequency
        columns; see `synthpack.measure.volume_spectrum`): 408 of cubes of 32 voxels, 117 of 16.
    level : float
        Intensity that the filter keeps (the mean of the volume it was fitted on), intensity units.
    p : float
        Probability of applying the transform at a call. Default 1.
    """

    name = "spectrum_match"
    params = (Param("gain", kind="floats", minimum=0.0, exclusive_minimum=True, rangeable=False),
              Param("level", rangeable=False))
    locality = "neighbourhood"

    def __init__(self, gain: Sequence[float], level: float = 0.0, *, p: float = 1.0) -> None:
        if len(gain) not in _SIZES:
            raise SynthpackInputError(
                f"spectrum_match takes {' or '.join(map(str, _SIZES))} gains (a table of fit_gain, row by row), "
                f"got {len(gain)}"
            )
        super().__init__(gain=gain, level=level, p=p)

    def halo(self, *, gain: Sequence[float], level: float) -> tuple[int, int, int]:
        """`KERNEL_RADIUS` on every axis."""
        return (KERNEL_RADIUS,) * 3

    def _transform(self, image: np.ndarray, rng: np.random.Generator, *, gain: Sequence[float],
                   level: float) -> np.ndarray:
        padded = np.pad(np.asarray(image, dtype=np.float32), KERNEL_RADIUS, mode="symmetric")
        shape = tuple(fft.next_fast_len(n, real=True) for n in padded.shape)
        # circular convolution on a grid at least as long as the padded image: its values from index
        # 2 KERNEL_RADIUS on are the linear convolution's, the image's own voxels
        out = fft.irfftn(fft.rfftn(padded, shape) * _kernel_spectrum(tuple(float(g) for g in gain), shape), shape)
        out = out[tuple(slice(2 * KERNEL_RADIUS, n) for n in padded.shape)]
        kept = np.float32((1.0 - float(spectrum_kernel(gain).sum())) * level)
        return (out + kept).astype(np.float32, copy=False)
