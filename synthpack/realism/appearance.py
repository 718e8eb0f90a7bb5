"""Appearance of a labelled tomogram: phase intensities, noise level and spectrum, edge sharpness.

Measured in the specimen's bulk region (`synthpack.realism.region`), with the
phases defined by the signed distance from the grain-pore boundary
(`synthpack.measure.edges`):

* **grains**: voxels at least `~synthpack.measure.edges.INTERIOR` voxels inside a grain;
* **pores**: voxels at least as far inside the pore space;
* **edges**: the voxels within one voxel of the boundary, on either side
  (`~synthpack.measure.phase_histograms.phase_masks`).

Figures:

* intensity samples of each phase, full band: the raw intensities of every
  voxel of the phase in the region (no high-pass, no per-patch mean removed), so
  shading, drift, blotches and texture at any scale show in their histograms,
  compared by Wasserstein distance;
* noise standard deviation in grains and pores, by
  `synthpack.measure.estimate_noise` (second differences inside each label, away from
  boundaries, robust spread: a high-pass figure, blind to low frequencies);
* noise power spectrum (NPS) of grains and pores (`synthpack.measure.spectrum`): the
  radially averaged power of ``NPS_PATCH x NPS_PATCH`` in-slice patches, each minus
  its mean, of a phase interior's noise (its second differences across slices, so
  that structure is not counted), so that the powers of all frequency rings add up to
  the noise variance within a patch. Its centroid (the power-weighted mean frequency,
  in cycles per voxel) is high for white noise and low for smooth, correlated noise.
  Against the source's, a pack's spectrum is read ring by ring: the ratio pack /
  source of the power in every ring from the lowest (ring 1, ``1 / NPS_PATCH``
  cycles per voxel) to the corner of the spectrum (ring 6 of an 8x8 patch, 0.75)
  (`nps_ratio`; 1 = the same power at that frequency, 2 = twice as much), so noise
  too smooth or too fine shows in its ring; structure (blotches) shows in the
  full-band histograms (W);
* the edge profile, its 10-90 width and its half-height position (where it
  crosses half-way from the pore to the grain level, voxels of signed distance
  from the label boundary; `synthpack.measure.edges`);
* the pore phase's median and interquartile range in bands of one voxel of distance
  from the nearest grain (`synthpack.measure.pore_bands`): a pore phase that is
  brighter or less variable next to the grains than far from them shows there.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np

from ..errors import SynthpackInputError
from ..measure.edges import EdgeProfile, edge_profile, edge_width, half_height, signed_distance
from ..measure.noise_estimate import NoiseEstimate, estimate_noise
from ..measure.phase_histograms import phase_masks
from ..measure.pore_bands import PoreBands, pore_bands
from ..measure.spectrum import NPS_PATCH, NoiseSpectrum, noise_power_spectrum
from .region import Specimen

logger = logging.getLogger(__name__)

__all__ = ["Appearance", "NPS_PATCH", "NoiseSpectrum", "measure_appearance", "noise_levels",
           "noise_power_spectrum", "nps_ratio", "phase_masks"]


def nps_ratio(spectrum: NoiseSpectrum, reference: NoiseSpectrum) -> dict:
    """Ring-by-ring ratio of two noise power spectra of the same patch size, in every ring but ring 0.

    Ring 0 (the patch mean) holds no power by construction; every other ring is
    compared, from ring 1 (``1 / size`` cycles per voxel) to the corner ring.

    Parameters
    ----------
    spectrum, reference : NoiseSpectrum
        E.g. a pack's and the source's, from `noise_power_spectrum` with the same `size`.

    Returns
    -------
    dict
        ``frequency`` (list of the rings' centres, cycles/voxel), ``ratio`` (list of
        ``spectrum / reference`` power per ring), ``max_abs_log2`` (the largest
        ``|log2 ratio|``: at most 1 means within a factor 2 in every ring), and the
        ring where it is reached: ``worst_frequency`` and ``worst_ratio``.

    Raises
    ------
    ValueError
        If the spectra have different rings (patch sizes).
    """
    if not np.array_equal(spectrum.frequency, reference.frequency):
        raise ValueError("the spectra have different frequency rings: measure them with the same patch size")
    ring = reference.frequency > 0
    ratio = spectrum.power[ring] / reference.power[ring]
    worst = int(np.argmax(np.abs(np.log2(ratio))))
    return {"frequency": reference.frequency[ring].tolist(), "ratio": ratio.tolist(),
            "max_abs_log2": float(abs(np.log2(ratio[worst]))),
            "worst_frequency": float(reference.frequency[ring][worst]), "worst_ratio": float(ratio[worst])}


def noise_levels(specimen: Specimen) -> NoiseEstimate:
    """`~synthpack.measure.estimate_noise` of the specimen's region (voxels outside it are ignored).

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
        Raw intensities of ``"grains"``, ``"pores"`` and ``"edges"`` in the region (an
        even subsample; full band: nothing filtered or subtracted).
    noise : NoiseEstimate
        From `noise_levels`.
    spectra : dict of str to NoiseSpectrum or None
        ``"grains"`` and ``"pores"``.
    profile : EdgeProfile
    edge_width : float
        10-90 width of `profile`, voxels.
    half_height : float
        Half-height position of `profile`, voxels of signed distance from the label boundary.
    pore_bands : PoreBands
        The pore phase's level and spread against the distance to the nearest grain.
    """

    samples: dict[str, np.ndarray]
    noise: NoiseEstimate
    spectra: dict[str, NoiseSpectrum | None]
    profile: EdgeProfile
    edge_width: float
    half_height: float
    pore_bands: PoreBands

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
    appearance = Appearance(samples, noise_levels(specimen), spectra, profile, edge_width(profile),
                            half_height(profile), pore_bands(specimen.tomogram, distance, specimen.region))
    logger.info("%s: edge width %.3f voxels, half height at %+.3f voxels, noise %.4g (grain %s, pore %s)",
                specimen.name, appearance.edge_width, appearance.half_height, appearance.noise.std,
                appearance.noise.grain_std, appearance.noise.pore_std)
    return appearance
