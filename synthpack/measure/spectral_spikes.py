"""Spectral spikes: periodic patterns in a phase, as narrow peaks of its in-slice power spectrum.

A periodic artefact (a checkerboard, stripes) puts its power into a few
frequencies; noise and texture spread theirs smoothly. This module finds the
few: the 2D in-slice power spectrum of a phase's interior, averaged over slices,
against a smoothed version of itself.

**The spectrum** (`slice_power_spectrum`). In each slice (normal to `axis`) with at
least `MIN_SLICE_VOXELS` voxels of the mask, the Laplacian of the intensities (the
five-point stencil) at the mask's voxels, minus its mean there, times the mask and
a 2D Hann window (so the slice's borders do not wrap into an edge), is Fourier
transformed; the squared moduli are summed over slices and divided by the sum of
the squared weights. The stencil reaches the four neighbours of a mask voxel: the
mask should be a phase's interior (`~synthpack.measure.spectrum.phase_interiors`:
at least 2.5 voxels from an edge), so that they are of the same phase. The
Laplacian whitens the spectrum: it takes the steep large-scale power of a pore
phase down by ``|H(f)|^2 = (4 sin^2 pi f_row + 4 sin^2 pi f_column)^2`` (0 at
frequency 0, 64 at the corner), which would otherwise leak, through the mask's
edges, over the whole spectrum and bury a spike at high frequencies under it.

**The baseline** (`spectral_spikes`). In the logarithm of the spectrum: its
isotropic part, the median over rings `WINDOW` frequencies wide (up to 0.5 cycles
per voxel, the rings the grid holds whole; held beyond, in the corners),
interpolated linearly in ``|f|``, is taken off; the rest is median filtered over
a square of `WINDOW` by `WINDOW` frequencies (wrapped: the spectrum is periodic in
frequency). A frequency's *height* is its power over that baseline: a peak a few
frequencies wide does not move the medians, a smooth slope, even a steep one,
is followed. How far heights scatter about 1 depends on the frequency (on how
many independent slices the average holds there, fewer where the phase's
variation is smooth): the *spread* is 1.4826 times the median absolute log
height, over the same rings, interpolated likewise.

**The spikes.** A frequency whose log height is more than `SPIKE_SPREADS` spreads,
and its height more than `MIN_HEIGHT`; the frequencies within ``(WINDOW // 2 +
1)`` steps of 0 are not tested (the mask's own shape). Of the two frequencies
``f`` and ``-f`` of a real image, which have the same power, one is reported.
On smooth and white Gaussian random fields, through holes or not, none is found;
a checkerboard of 1 % of the field's standard deviation is (the tests).

**Limits.** Averaged over slices, a pattern must be there in many slices to stand
out. A period that the slice's frequency grid does not hold exactly spreads over
the neighbouring frequencies (the window's and the mask's leakage), each lower:
a thin, fragmented mask (pores a few voxels wide) spreads it more, and a strong
spike is reported at several neighbouring frequencies. A texture that repeats
itself every few tens of voxels or more (a tile) puts its power on a comb finer
than the window resolves: look at its autocorrelation instead.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage

__all__ = ["MIN_HEIGHT", "MIN_SLICE_VOXELS", "SPIKE_SPREADS", "SpectralSpikes", "WINDOW", "slice_power_spectrum",
           "spectral_spikes"]

#: Width of the baseline's rings and side of its median filter's square, frequencies.
WINDOW = 9
#: A spike's log height is more than this many spreads (its ring's robust spread of the log heights).
SPIKE_SPREADS = 6.0
#: A spike's power is at least this factor above the baseline.
MIN_HEIGHT = 1.5
#: A slice needs at least this many mask voxels to be used.
MIN_SLICE_VOXELS = 64


def _hann(n: int) -> np.ndarray:
    """A Hann window of `n` samples without its two zeros at the ends, float64."""
    return np.hanning(n + 2)[1:-1]


def _ring_profile(values: np.ndarray, position: np.ndarray, width: int, end: float) -> np.ndarray:
    """The median of `values` over rings `width` frequencies wide up to `end`, interpolated linearly in `position`
    (held at the last ring's beyond it)."""
    rings = np.rint(position / width).astype(np.int64)
    index = np.arange(int(np.rint(end / width)) + 1)
    inside = position <= end
    centres = np.asarray(ndimage.mean(position[inside], rings[inside], index))
    return np.interp(position, centres, np.asarray(ndimage.median(values[inside], rings[inside], index)))


def slice_power_spectrum(volume: np.ndarray, mask: np.ndarray, axis: int = 0) -> tuple[np.ndarray, int]:
    """The whitened, masked, tapered in-slice power spectrum of `volume` inside `mask`, averaged over slices.

    See the module docstring: the spectrum of the slices' Laplacian.

    Parameters
    ----------
    volume : ndarray, shape (Z, Y, X)
        Intensities.
    mask : ndarray of bool, same shape
        The voxels to measure (e.g. the pore interior).
    axis : int
        The axis the slices are normal to.

    Returns
    -------
    power : ndarray of float64, shape (the slice's shape)
        Power on the slice's FFT grid (`numpy.fft.fftfreq` order, frequency 0 first),
        intensity units squared: the power spectrum times ``|H(f)|^2``; its mean is the
        Laplacian's weighted variance inside the mask (20 for white noise of variance 1).
        All zeros when no slice has `MIN_SLICE_VOXELS` voxels to measure.
    slices : int
        How many slices were used.
    """
    volume = np.moveaxis(np.asarray(volume), axis, 0)
    mask = np.moveaxis(np.asarray(mask, dtype=bool), axis, 0)
    shape = volume.shape[1:]
    taper = _hann(shape[0])[:, None] * _hann(shape[1])[None, :]
    power = np.zeros(shape)
    weight = 0.0
    slices = 0
    for image, inside in zip(volume, mask):
        if np.count_nonzero(inside) < MIN_SLICE_VOXELS:
            continue
        whitened = ndimage.laplace(np.asarray(image, dtype=np.float64))
        window = taper * inside
        centred = (whitened - np.average(whitened, weights=window)) * window
        power += np.abs(np.fft.fft2(centred)) ** 2
        weight += float(np.sum(window**2))
        slices += 1
    return (power / weight if weight > 0 else power), slices


@dataclass(frozen=True)
class SpectralSpikes:
    """The spikes of a phase's in-slice power spectrum (`spectral_spikes`).

    Attributes
    ----------
    frequency : ndarray of float64, shape (N, 2)
        The spikes' in-slice frequencies ``(f_row, f_column)``, cycles per voxel, in
        ``[-0.5, 0.5)``; one of each pair ``f, -f``; highest first.
    height : ndarray of float64, shape (N,)
        Power over the baseline at each spike (> 1).
    threshold : float
        The height a spike needed, the median over the frequencies tested (each has its own, from its spread).
    slices : int
        How many slices the spectrum averages.
    """

    frequency: np.ndarray
    height: np.ndarray
    threshold: float
    slices: int

    def __len__(self) -> int:
        return len(self.height)

    def not_in(self, reference: SpectralSpikes, tolerance: float = 0.02) -> SpectralSpikes:
        """The spikes farther than `tolerance` (cycles/voxel) from every spike of `reference`, either sign.

        Parameters
        ----------
        reference : SpectralSpikes
            E.g. the source's, against a pack's.
        tolerance : float
            Largest in-slice distance (cycles/voxel, frequency wrapped) for a spike to be the same.
        """
        if not len(self) or not len(reference):
            return self
        keep = np.ones(len(self), bool)
        for sign in (1.0, -1.0):
            step = self.frequency[:, None, :] - sign * reference.frequency[None, :, :]
            step -= np.rint(step)
            keep &= np.hypot(step[..., 0], step[..., 1]).min(axis=1) > tolerance
        return SpectralSpikes(self.frequency[keep], self.height[keep], self.threshold, self.slices)


def spectral_spikes(
    volume: np.ndarray, mask: np.ndarray, *, axis: int = 0, window: int = WINDOW, spreads: float = SPIKE_SPREADS,
    min_height: float = MIN_HEIGHT,
) -> SpectralSpikes:
    """The frequencies where a phase's in-slice power spectrum peaks above its smoothed self (module docstring).

    Parameters
    ----------
    volume : ndarray, shape (Z, Y, X)
        Intensities.
    mask : ndarray of bool, same shape
        The phase's interior (e.g. the pore interior of the specimen).
    axis : int
        The axis the slices are normal to.
    window : int
        Width of the rings and side of the median filter's square, frequencies (odd).
    spreads : float
        A spike's log height is more than this many spreads.
    min_height : float
        And its height more than this (> 0).

    Returns
    -------
    SpectralSpikes
        Empty (`~SpectralSpikes.threshold` infinite) where no slice has `MIN_SLICE_VOXELS` voxels to measure.
    """
    power, slices = slice_power_spectrum(volume, mask, axis)
    shape = power.shape
    if slices == 0 or not np.any(power > 0):
        return SpectralSpikes(np.zeros((0, 2)), np.zeros(0), np.inf, slices)
    logarithm = np.log(np.maximum(power, np.finfo(float).tiny))
    frequencies = np.meshgrid(np.fft.fftfreq(shape[0]), np.fft.fftfreq(shape[1]), indexing="ij")
    radius = np.hypot(*frequencies)
    position = radius * min(shape)
    residual = logarithm - _ring_profile(logarithm, position, window, min(shape) / 2)
    excess = residual - ndimage.median_filter(residual, size=window, mode="wrap")
    spread = 1.4826 * _ring_profile(np.abs(excess), position, window, min(shape) / 2)
    tested = radius >= (window // 2 + 1) / min(shape)
    rows, columns = np.indices(shape)
    mirror = (-rows % shape[0]) * shape[1] + (-columns % shape[1])
    canonical = rows * shape[1] + columns <= mirror  # one of each pair f, -f
    needed = np.maximum(spreads * spread, np.log(min_height))
    spiky = tested & canonical & (excess > needed)
    order = np.argsort(-excess[spiky], kind="stable")
    frequency = np.stack([frequencies[0][spiky], frequencies[1][spiky]], axis=1)[order]
    return SpectralSpikes(frequency, np.exp(excess[spiky][order]), float(np.exp(np.median(needed[tested]))), slices)
