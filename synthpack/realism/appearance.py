"""Appearance of a labelled tomogram: phase intensities, noise level and spectrum, edge sharpness.

Measured in the specimen's bulk region (`synthpack.realism.region`), with the
phases defined by the signed distance from the grain-pore boundary
(`synthpack.source.edges`):

* **grains**: voxels at least `~synthpack.source.edges.INTERIOR` voxels inside a grain;
* **pores**: voxels at least as far inside the pore space;
* **edges**: the voxels within one voxel of the boundary, on either side.

Figures:

* intensity samples of each phase (their histograms, compared by Wasserstein distance);
* noise standard deviation in grains and pores, by
  `synthpack.source.estimate_noise` (second differences inside each label, away from
  boundaries, robust spread);
* noise power spectrum (NPS) of grains and pores: the radially averaged power of
  ``NPS_PATCH x NPS_PATCH`` in-slice patches wholly inside a phase's interior,
  each minus its mean, so that the powers of all frequency rings add up to the
  variance within a patch. Its centroid (the power-weighted mean frequency, in
  cycles per voxel) is high for white noise and low for smooth, correlated noise
  and texture;
* the edge profile and its 10-90 width (`synthpack.source.edges`).
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np

from ..errors import SynthpackInputError
from ..source.edges import INTERIOR, EdgeProfile, edge_profile, edge_width, signed_distance
from ..source.noise import NoiseEstimate, estimate_noise
from .patches import patch_corners, take_patches
from .region import Specimen

logger = logging.getLogger(__name__)

__all__ = ["Appearance", "NPS_PATCH", "NoiseSpectrum", "measure_appearance", "noise_levels",
           "noise_power_spectrum", "phase_masks"]

#: Side (voxels) of the in-slice patches of the noise power spectrum.
NPS_PATCH = 8
#: The NPS uses at most this many patches per phase.
_MAX_NPS_PATCHES = 4000


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


def noise_power_spectrum(tomogram: np.ndarray, mask: np.ndarray, size: int = NPS_PATCH) -> NoiseSpectrum | None:
    """Radially averaged power spectrum of the in-slice patches wholly inside `mask`.

    Parameters
    ----------
    tomogram : ndarray, shape (Z, Y, X)
    mask : ndarray of bool, same shape
        Where patches may lie (e.g. a phase interior).
    size : int
        Patch side, voxels.

    Returns
    -------
    NoiseSpectrum or None
        None when no patch fits in `mask`.
    """
    corners = patch_corners(mask, size, max(1, size // 2), _MAX_NPS_PATCHES)
    if len(corners) == 0:
        return None
    patches = take_patches(tomogram, corners, size).astype(np.float64)
    patches -= patches.mean(axis=(1, 2), keepdims=True)
    power = (np.abs(np.fft.fft2(patches)) ** 2).mean(axis=0) / size**4
    frequency = np.fft.fftfreq(size)
    ring = np.rint(np.hypot(frequency[:, None], frequency[None, :]) * size).astype(np.int64)
    per_ring = np.bincount(ring.ravel(), weights=power.ravel())
    return NoiseSpectrum(np.arange(len(per_ring)) / size, per_ring, len(corners))


def phase_masks(distance: np.ndarray, region: np.ndarray) -> dict[str, np.ndarray]:
    """Boolean masks of the grain interior, pore interior and edge voxels in `region`.

    Parameters
    ----------
    distance : ndarray of float32, shape (Z, Y, X)
        From `~synthpack.source.edges.signed_distance`.
    region : ndarray of bool, same shape

    Returns
    -------
    dict
        ``"grains"``, ``"pores"``, ``"edges"``: ndarray of bool, same shape.
    """
    return {
        "grains": region & (distance >= INTERIOR),
        "pores": region & (distance <= -INTERIOR),
        "edges": region & (np.abs(distance) <= 1.0),
    }


def noise_levels(specimen: Specimen) -> NoiseEstimate:
    """`~synthpack.source.estimate_noise` of the specimen's region (voxels outside it are ignored).

    Returns
    -------
    NoiseEstimate
        Where neither phase has enough interior voxels to measure (e.g. grains a
        few voxels across in a shallow pack), ``std`` is NaN and both phases None
        (the report shows n/a), with a warning.
    """
    labels = np.where(specimen.region, specimen.labels, -1)
    try:
        return estimate_noise(specimen.tomogram, labels)
    except SynthpackInputError as error:
        logger.warning("%s: the noise cannot be measured (%s)", specimen.name, error)
        return NoiseEstimate(math.nan, None, None, 0, 0)


@dataclass
class Appearance:
    """What a specimen looks like (see the module docstring).

    Attributes
    ----------
    samples : dict of str to ndarray of float32, shape (N_phase,)
        Intensities of ``"grains"``, ``"pores"`` and ``"edges"`` (an even subsample).
    noise : NoiseEstimate
        From `noise_levels`.
    spectra : dict of str to NoiseSpectrum or None
        ``"grains"`` and ``"pores"``.
    profile : EdgeProfile
    edge_width : float
        10-90 width of `profile`, voxels.
    """

    samples: dict[str, np.ndarray]
    noise: NoiseEstimate
    spectra: dict[str, NoiseSpectrum | None]
    profile: EdgeProfile
    edge_width: float

    @property
    def contrast(self) -> float:
        """Grain minus pore interior level, intensity units; negative for grains darker than pores."""
        return self.profile.contrast


def measure_appearance(specimen: Specimen, *, max_samples: int = 200_000) -> Appearance:
    """Measure the appearance of a specimen's bulk region.

    Parameters
    ----------
    specimen : Specimen
    max_samples : int
        At most about this many intensity samples are kept per phase (every k-th voxel).

    Returns
    -------
    Appearance
    """
    distance = signed_distance(specimen.labels)
    masks = phase_masks(distance, specimen.region)
    samples = {}
    for phase, mask in masks.items():
        values = specimen.tomogram[mask]
        samples[phase] = values[:: max(1, values.size // max_samples)]
    profile = edge_profile(specimen.tomogram, distance, specimen.region)
    spectra = {phase: noise_power_spectrum(specimen.tomogram, masks[phase]) for phase in ("grains", "pores")}
    appearance = Appearance(samples, noise_levels(specimen), spectra, profile, edge_width(profile))
    logger.info("%s: edge width %.3f voxels, noise %.4g (grain %s, pore %s)", specimen.name,
                appearance.edge_width, appearance.noise.std, appearance.noise.grain_std,
                appearance.noise.pore_std)
    return appearance
