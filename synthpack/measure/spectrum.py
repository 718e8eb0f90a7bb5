"""The noise power spectrum (NPS) of a phase: how the noise's power spreads over spatial frequency.

The NPS is measured on ``NPS_PATCH x NPS_PATCH`` in-slice patches wholly inside a
phase's interior (`~synthpack.measure.lattice`), each minus its own mean, and
averaged radially in the slice plane: ring ``k`` holds the frequencies whose
magnitude rounds to ``k / NPS_PATCH`` cycles per voxel. The powers of all rings add
up to the mean variance within a patch (ring 0, the patch mean, is 0), so the
spectrum describes both the noise level and its texture: white noise spreads its
power in proportion to the number of frequencies in each ring, smooth
(correlated) noise puts it into the low rings. Variation on scales larger than a
patch is not in it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .edges import INTERIOR
from .lattice import patch_corners, take_patches

__all__ = ["NPS_PATCH", "NoiseSpectrum", "noise_power_spectrum", "phase_interiors", "phase_spectra", "ring_of",
           "ring_frequencies", "white_ring_powers"]

#: Side (voxels) of the in-slice patches of the noise power spectrum.
NPS_PATCH = 8
#: The NPS uses at most this many patches per phase.
MAX_NPS_PATCHES = 4000


def ring_of(size: int = NPS_PATCH) -> np.ndarray:
    """Ring index of every frequency of a ``size x size`` FFT: ``rint(|f| size)``, int64, shape (size, size)."""
    frequency = np.fft.fftfreq(size)
    return np.rint(np.hypot(frequency[:, None], frequency[None, :]) * size).astype(np.int64)


def ring_frequencies(size: int = NPS_PATCH) -> np.ndarray:
    """Centre frequency (cycles/voxel) of every ring of `ring_of`, ring 0 first, float64."""
    return np.arange(int(ring_of(size).max()) + 1) / size


def white_ring_powers(variance: float, n_rings: int, size: int = NPS_PATCH) -> np.ndarray:
    """Expected ring powers (rings 1 to `n_rings`) of white noise of `variance`: its share of the ring's frequencies.

    Returns float64, shape (n_rings,), intensity units squared (the patch mean, ring 0, is removed).
    """
    counts = np.bincount(ring_of(size).ravel()).astype(np.float64)
    return variance * counts[1 : n_rings + 1] / size**2


@dataclass
class NoiseSpectrum:
    """Radially averaged noise power spectrum.

    Attributes
    ----------
    frequency : ndarray of float64, shape (K,)
        Ring centres, cycles per voxel (0 to about 0.7).
    power : ndarray of float64, shape (K,)
        Power in each ring, intensity units squared; the sum is the mean within-patch variance.
    n_patches : int
        Patches averaged.
    """

    frequency: np.ndarray
    power: np.ndarray
    n_patches: int

    @property
    def centroid(self) -> float:
        """Power-weighted mean frequency, cycles per voxel."""
        return float(np.sum(self.frequency * self.power) / np.sum(self.power))


def noise_power_spectrum(
    tomogram: np.ndarray, mask: np.ndarray, size: int = NPS_PATCH, max_patches: int = MAX_NPS_PATCHES,
) -> NoiseSpectrum | None:
    """Radially averaged power spectrum of the in-slice patches wholly inside `mask`.

    Parameters
    ----------
    tomogram : ndarray, shape (Z, Y, X)
    mask : ndarray of bool, same shape
        Where patches may lie (e.g. a phase interior).
    size : int
        Patch side, voxels.
    max_patches : int
        At most this many patches, evenly spread (`~synthpack.measure.lattice.patch_corners`).

    Returns
    -------
    NoiseSpectrum or None
        None when no patch fits in `mask`.
    """
    corners = patch_corners(mask, size, max(1, size // 2), max_patches)
    if len(corners) == 0:
        return None
    patches = take_patches(tomogram, corners, size).astype(np.float64)
    patches -= patches.mean(axis=(1, 2), keepdims=True)
    power = (np.abs(np.fft.fft2(patches)) ** 2).mean(axis=0) / size**4
    per_ring = np.bincount(ring_of(size).ravel(), weights=power.ravel())
    return NoiseSpectrum(ring_frequencies(size), per_ring, len(corners))


def phase_interiors(distance: np.ndarray, region: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """The grain and pore interiors: voxels at least `~synthpack.measure.edges.INTERIOR` voxels from an edge.

    Parameters
    ----------
    distance : ndarray of float32, shape (Z, Y, X)
        From `~synthpack.measure.edges.signed_distance`.
    region : ndarray of bool, same shape, optional
        Voxels to keep (default all).

    Returns
    -------
    dict
        ``"grains"`` and ``"pores"``: ndarray of bool, same shape.
    """
    grains, pores = distance >= INTERIOR, distance <= -INTERIOR
    if region is not None:
        grains, pores = grains & region, pores & region
    return {"grains": grains, "pores": pores}


def phase_spectra(
    tomogram: np.ndarray, distance: np.ndarray, region: np.ndarray | None = None,
) -> dict[str, NoiseSpectrum | None]:
    """`noise_power_spectrum` of the grain and of the pore interior (`phase_interiors`).

    Returns
    -------
    dict
        ``"grains"`` and ``"pores"``: NoiseSpectrum, or None where no patch fits.
    """
    return {phase: noise_power_spectrum(tomogram, mask) for phase, mask in phase_interiors(distance, region).items()}
