"""Spectral spikes: periodic patterns in a phase, as narrow peaks of its in-slice power spectrum.

A periodic artefact (a checkerboard, stripes, a repeating tile) puts its power
into a few frequencies; noise and texture spread theirs smoothly. This module
finds the few: the 2D in-slice power spectrum of a phase's interior, averaged
over slices, against a smoothed version of itself.

**The spectrum.** In each slice (along `axis`) with at least `MIN_SLICE_VOXELS`
voxels of the mask, the intensities minus their mean over the mask, times the
mask and a 2D Hann window (so the slice's borders do not wrap into an edge), are
Fourier transformed; the squared moduli are summed over slices and divided by
the sum of the squared weights: a masked, tapered periodogram whose mean over
the frequency grid is the variance inside the mask (intensity units squared).

**The baseline and the spikes.** The logarithm of the spectrum is median filtered
over a square of `WINDOW` frequencies (the spectrum wrapped, as it is periodic
in frequency): a peak a few frequencies wide does not move the median. A
frequency's *height* is its power over the baseline's. Its spread over all
frequencies tested (the robust spread of the log heights: 1.4826 times their
median absolute deviation) says how much a smooth spectrum scatters about its
baseline (less for more slices); a *spike* is a frequency whose log height is
more than `SPIKE_SPREADS` spreads above the median and whose height is at least
`MIN_HEIGHT`. The frequencies within the window's half width of 0 are not
tested: there the spectrum of a pore phase rises steeply (its large scales and
the mask's shape), which a median over the window cannot follow. Of the two
frequencies ``f`` and ``-f`` of a real image, which have the same power, only
one is reported.

**Limits.** Averaged over slices, a spike must be there in many slices to stand
out. A period the slice's frequency grid does not hold exactly spreads over
neighbouring frequencies (the mask's and the window's leakage), each of them
lower: a thin, fragmented mask (pores a few voxels wide) spreads it more.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage

__all__ = ["MIN_HEIGHT", "MIN_SLICE_VOXELS", "SPIKE_SPREADS", "SpectralSpikes", "WINDOW", "slice_power_spectrum",
           "spectral_spikes"]

#: Side (frequencies) of the square the baseline's median is taken over.
WINDOW = 9
#: A spike's log height is more than this many robust spreads above the median log height.
SPIKE_SPREADS = 6.0
#: A spike's power is at least this factor above the baseline.
MIN_HEIGHT = 1.5
#: A slice needs at least this many mask voxels to be used.
MIN_SLICE_VOXELS = 64


_CROSS = ndimage.generate_binary_structure(2, 1)


def _hann(n: int) -> np.ndarray:
    """Periodic-free Hann window of `n` samples (0 at both ends only for n > 1), float64."""
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
    """The masked, tapered in-slice power spectrum of `volume` inside `mask`, averaged over slices.

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
        intensity units squared; its mean is the weighted variance inside the mask. All
        zeros when no slice has `MIN_SLICE_VOXELS` mask voxels.
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
        core = ndimage.binary_erosion(inside, _CROSS)
        if np.count_nonzero(core) < MIN_SLICE_VOXELS:
            continue
        whitened = ndimage.laplace(np.asarray(image, dtype=np.float64))
        window = taper * core
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
        The least height a spike needed here (the robust spread rule and `MIN_HEIGHT`).
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
        Side of the median filter's square, frequencies (odd).
    spreads : float
        A spike's log height exceeds the median by this many robust spreads.
    min_height : float
        And its height is at least this.

    Returns
    -------
    SpectralSpikes
        Empty where no slice has `MIN_SLICE_VOXELS` mask voxels.
    """
    power, slices = slice_power_spectrum(volume, mask, axis)
    shape = power.shape
    empty = SpectralSpikes(np.zeros((0, 2)), np.zeros(0), np.inf, slices)
    if slices == 0 or not np.any(power > 0):
        return empty
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
