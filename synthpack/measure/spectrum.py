"""The noise power spectrum (NPS) of a phase, measured on its noise only: what the calibrated noise matches.

**Rings.** The NPS describes ``NPS_PATCH x NPS_PATCH`` in-slice patches, each minus
its own mean, radially averaged in the slice plane: ring ``k`` holds the frequencies
whose magnitude rounds to ``k / NPS_PATCH`` cycles per voxel, and the powers of all
rings add up to the mean variance within a patch (ring 0, the patch mean, is 0).
White noise spreads its power in proportion to the number of frequencies in each
ring, smooth (correlated) noise puts it into the low rings.

**Noise only.** A phase interior holds structure as well as noise (a cement paste's
sand and voids, a pore's texture, the grains' own texture), and a patch of its
intensities counts the structure's power as noise, most of it in the low rings. The
NPS is therefore measured on the *second difference across slices*,
``d(z) = (I(z - 1) - 2 I(z) + I(z + 1)) / sqrt(6)``, at the voxels whose three voxels
``z - 1, z, z + 1`` all lie in the phase's interior: whatever varies linearly (or
less) over three slices cancels, so structure on scales of a few voxels and more
drops out (a smooth field of Gaussian correlation length ``L`` voxels keeps about
``1 / (2 L^4)`` of its power: 3 % for ``L = 2``, 0.2 % for ``L = 4``), while white noise
keeps its variance (the gain ``(2 - 2 cos 2 pi f_z)^2 / 6`` averages 1). The
in-slice autocovariance of ``d`` at the lags of a patch is estimated from every pair
of such voxels in the same slice (sums by FFT, masked; enough pairs that every ring is
known to `MAX_NPS_ERROR`, `ring_errors`), and the ring powers are those of a patch of a field with that
autocovariance (`patch_ring_powers`), exactly as a patch periodogram would average
them, without needing a whole patch inside the phase: thin phases (narrow pores,
small grains) are measured too.

**Slice-to-slice correlation.** Noise that is independent from slice to slice (a
scanner that reconstructs each slice alone) is measured exactly. Noise correlated
between slices (a cone-beam reconstruction, a blur, an interpolation along z) with
correlations ``rho_1``, ``rho_2`` at one and two slices (at each in-slice
frequency) is measured at ``1 - 4 rho_1 / 3 + rho_2 / 3`` of its in-slice power:
less, the smoother it is along z. That is no bias for the calibration: it measures
the source and the pack alike, and the noise it adds
(`~synthpack.artefacts.ColouredNoise`, an isotropic 3D spectrum) is fitted to this
very figure, computed from its spectrum with the same gain
(`~synthpack.artefacts.coloured_noise.ring_powers_of_spectrum`,
`slice_difference_gain`). The assumption is the synthesis's: the source's noise is
about isotropic in 3D (its slice-to-slice correlation that of its in-slice
correlation). Noise smooth over many voxels is, like structure, little seen, and
the calibration adds little of it: the pack's low frequencies are the render's
(grain crops of the source, the pore texture).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import fft

from .edges import INTERIOR

__all__ = ["MAX_NPS_ERROR", "MAX_NPS_VOXELS", "NPS_DEPTH_STEP", "NPS_PATCH", "NPS_RING_FACTOR", "NoiseSpectrum",
           "measurable_phase_spectra", "noise_power_spectrum", "patch_lags",
           "patch_ring_powers", "phase_interiors", "phase_spectra", "ring_errors", "ring_frequencies", "ring_of",
           "slice_difference_gain", "white_ring_powers"]

#: Side (voxels) of the in-slice patches whose rings the noise power spectrum describes.
NPS_PATCH = 8
#: The realism target of a pack's NPS: within this factor of the source's in every ring
#: (`synthpack.realism.targets`; the calibration's guard keeps to it too).
NPS_RING_FACTOR = 2.0
#: The NPS uses at most about this many voxels of second differences per phase (evenly spaced slices).
MAX_NPS_VOXELS = 1 << 22
#: A phase's NPS is measured only where its voxel pairs give the power of every ring up to 0.5 cycles/voxel
#: to this relative standard error or better (`ring_errors`, for white noise): a phase too thin or too small
#: is not measured (the corner rings beyond hold a few frequencies each and little power).
MAX_NPS_ERROR = 0.1
#: Where both phases are too thin for a spectrum at the edges' reach, `measurable_phase_spectra` tries again this
#: many voxels closer to the edges at a time, down to `~synthpack.measure.edges.INTERIOR`.
NPS_DEPTH_STEP = 0.25


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


def slice_difference_gain(frequency: np.ndarray) -> np.ndarray:
    """Power gain ``(2 - 2 cos 2 pi f_z)^2 / 6`` of the second difference across slices at `frequency` (cycles/voxel).

    Averaged over all frequencies it is 1: white noise keeps its variance. Same shape as `frequency`, float64.
    """
    return (2.0 - 2.0 * np.cos(2.0 * np.pi * np.asarray(frequency, dtype=np.float64))) ** 2 / 6.0


def patch_lags(size: int = NPS_PATCH) -> np.ndarray:
    """The in-slice lags of a ``size x size`` patch along one axis: ``-(size - 1) .. size - 1``, int64."""
    return np.arange(-(size - 1), size)


def patch_ring_powers(covariance: np.ndarray, size: int = NPS_PATCH) -> np.ndarray:
    """Expected ring powers of ``size x size`` patches, each minus its mean, of a field of in-slice `covariance`.

    Parameters
    ----------
    covariance : ndarray of float64, shape (2 size - 1, 2 size - 1)
        The field's autocovariance at the in-slice lags `patch_lags` (y, x), intensity units squared.
    size : int
        Patch side, voxels.

    Returns
    -------
    ndarray of float64, shape (K,)
        Rings 0 (always 0: the patch mean is removed) to ``K - 1`` of `ring_of`, intensity
        units squared: ``E |FFT(patch)(k)|^2 / size^4``, summed over each ring.
    """
    lags = patch_lags(size)
    weight = (size - np.abs(lags))[:, None] * (size - np.abs(lags))[None, :]
    phase = np.exp(-2j * np.pi * np.outer(np.arange(size), lags) / size)  # (k, lag)
    periodogram = (phase @ (covariance * weight) @ phase.T).real / size**4
    periodogram[0, 0] = 0.0  # the patch mean is removed
    return np.bincount(ring_of(size).ravel(), weights=periodogram.ravel())


def ring_errors(pairs: np.ndarray, size: int = NPS_PATCH) -> np.ndarray:
    """Relative standard error of each ring's power measured from `pairs` voxel pairs per lag, for white noise.

    The covariance at a lag estimated from ``n`` pairs of white noise of variance ``v`` has a
    standard error of about ``v / sqrt(n)``; `patch_ring_powers` weighs each lag's into each
    ring, so a ring's error is the root of the weighted sum of their variances, twice that of
    a lag other than 0 (a lag and its opposite are one estimate; a lag without pairs counts as
    one pair). On white noise in a mask of 1,600 voxels the errors found by repeated draws are
    about 1.3 times these.

    Parameters
    ----------
    pairs : ndarray, shape (2 size - 1, 2 size - 1)
        Voxel pairs at each in-slice lag of `patch_lags`.

    Returns
    -------
    ndarray of float64, shape (K,)
        Per ring of `ring_of` (ring 0 too), the standard error over white noise's expected power.
    """
    lags = patch_lags(size)
    weight = (size - np.abs(lags))[:, None] * (size - np.abs(lags))[None, :]
    phase = np.exp(-2j * np.pi * np.outer(np.arange(size), lags) / size)  # (k, lag)
    gain = np.einsum("al,bm->ablm", phase, phase).real  # (ky, kx, ly, lx)
    rings = ring_of(size)
    counts = np.bincount(rings.ravel())
    per_ring = np.stack([gain[rings == ring].sum(axis=0) for ring in range(len(counts))])
    twice = np.where((lags[:, None] == 0) & (lags[None, :] == 0), 1.0, 2.0)
    variance = (twice * (weight * per_ring) ** 2 / np.maximum(pairs, 1)).sum(axis=(1, 2))
    return np.sqrt(variance) / (size**2 * counts)


@dataclass
class NoiseSpectrum:
    """Radially averaged noise power spectrum.

    Attributes
    ----------
    frequency : ndarray of float64, shape (K,)
        Ring centres, cycles per voxel (0 to about 0.7).
    power : ndarray of float64, shape (K,)
        Power in each ring, intensity units squared; the sum is the mean within-patch noise variance.
    n_voxels : int
        Voxels of second differences measured.
    """

    frequency: np.ndarray
    power: np.ndarray
    n_voxels: int

    @property
    def centroid(self) -> float:
        """Power-weighted mean frequency, cycles per voxel."""
        return float(np.sum(self.frequency * self.power) / np.sum(self.power))


def _centres(mask: np.ndarray) -> np.ndarray:
    """True at the voxels of `mask` whose neighbours across slices (z - 1 and z + 1) are in it too."""
    centres = np.zeros_like(mask)
    centres[1:-1] = mask[:-2] & mask[1:-1] & mask[2:]
    return centres


def noise_power_spectrum(
    tomogram: np.ndarray, mask: np.ndarray, size: int = NPS_PATCH, max_voxels: int = MAX_NPS_VOXELS,
) -> NoiseSpectrum | None:
    """Radially averaged noise power spectrum of the voxels in `mask`, from second differences across slices.

    See the module docstring.

    Parameters
    ----------
    tomogram : ndarray, shape (Z, Y, X)
        Intensities (any real dtype).
    mask : ndarray of bool, same shape
        Where to measure (e.g. a phase interior, `phase_interiors`).
    size : int
        Patch side of the rings, voxels.
    max_voxels : int
        At most about this many second-difference voxels: every ``k``-th slice that has any.

    Returns
    -------
    NoiseSpectrum or None
        None when `mask` holds too few voxel pairs at the lags of a patch to know every ring
        to `MAX_NPS_ERROR` (`ring_errors`; a phase too thin or too small).
    """
    centres = _centres(np.asarray(mask, dtype=bool))
    counts = np.count_nonzero(centres, axis=(1, 2))
    slices = np.flatnonzero(counts)
    if len(slices) == 0:
        return None
    slices = slices[:: max(1, math.ceil(counts.sum() / max_voxels))]
    rows, columns = np.flatnonzero(centres.any(axis=(0, 2))), np.flatnonzero(centres.any(axis=(0, 1)))
    window = (slice(int(rows[0]), int(rows[-1]) + 1), slice(int(columns[0]), int(columns[-1]) + 1))
    shape = tuple(fft.next_fast_len(n.stop - n.start + size - 1, real=True) for n in window)
    products = np.zeros((shape[0], shape[1] // 2 + 1))
    pairs = np.zeros_like(products)
    for z in slices:
        inside = centres[(z, *window)]
        near = np.asarray(tomogram[z - 1 : z + 2][(slice(None), *window)], dtype=np.float64)
        difference = np.where(inside, (near[0] - 2.0 * near[1] + near[2]) / math.sqrt(6.0), 0.0)
        products += np.abs(fft.rfft2(difference, s=shape)) ** 2
        pairs += np.abs(fft.rfft2(inside.astype(np.float64), s=shape)) ** 2
    lags = patch_lags(size)
    index = np.ix_(lags % shape[0], lags % shape[1])
    products, pairs = fft.irfft2(products, s=shape)[index], np.rint(fft.irfft2(pairs, s=shape)[index])
    if ring_errors(pairs, size)[1 : size // 2 + 1].max() > MAX_NPS_ERROR:
        return None
    # a mean of the differences adds a constant to every lag: it goes wholly into ring 0, which is removed
    power = patch_ring_powers(products / pairs, size)
    return NoiseSpectrum(ring_frequencies(size), power, int(counts[slices].sum()))


def phase_interiors(
    distance: np.ndarray, region: np.ndarray | None = None, depth: float = INTERIOR,
) -> dict[str, np.ndarray]:
    """The grain and pore interiors: voxels at least `depth` voxels from an edge.

    Parameters
    ----------
    distance : ndarray of float32, shape (Z, Y, X)
        From `~synthpack.measure.edges.signed_distance`.
    region : ndarray of bool, same shape, optional
        Voxels to keep (default all).
    depth : float
        Voxels from the boundary (default `~synthpack.measure.edges.INTERIOR`; the noise
        spectrum's, `~synthpack.measure.edges.interior_depth`).

    Returns
    -------
    dict
        ``"grains"`` and ``"pores"``: ndarray of bool, same shape.
    """
    grains, pores = distance >= depth, distance <= -depth
    if region is not None:
        grains, pores = grains & region, pores & region
    return {"grains": grains, "pores": pores}


def phase_spectra(
    tomogram: np.ndarray, distance: np.ndarray, region: np.ndarray | None = None, depth: float = INTERIOR,
) -> dict[str, NoiseSpectrum | None]:
    """`noise_power_spectrum` of the grain and of the pore interior (`phase_interiors` at `depth`).

    Returns
    -------
    dict
        ``"grains"`` and ``"pores"``: NoiseSpectrum, or None where the phase is too thin to measure.
    """
    return {phase: noise_power_spectrum(tomogram, mask)
            for phase, mask in phase_interiors(distance, region, depth).items()}


def measurable_phase_spectra(
    tomogram: np.ndarray, distance: np.ndarray, region: np.ndarray | None, depth: float,
) -> tuple[dict[str, NoiseSpectrum | None], float]:
    """`phase_spectra` at `depth`, or nearer the edges where both phases are too thin there.

    Small grains and narrow pores (a fine sand at a coarse voxel) may leave no interior
    `depth` voxels from the edges wide enough for the pairs of a patch. The depth then
    steps down by `NPS_DEPTH_STEP` voxels, to `~synthpack.measure.edges.INTERIOR` at the
    least, until one phase is measured: the deepest interior that is, where the edges
    leak least into the second differences.

    Returns
    -------
    spectra : dict
        As `phase_spectra`'s.
    depth : float
        The depth measured at, voxels: `depth` itself, unless both phases are too thin there.
    """
    spectra = phase_spectra(tomogram, distance, region, depth)
    while all(spectrum is None for spectrum in spectra.values()) and depth > INTERIOR:
        depth = max(INTERIOR, depth - NPS_DEPTH_STEP)
        spectra = phase_spectra(tomogram, distance, region, depth)
    return spectra, depth
