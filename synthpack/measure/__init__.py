"""Measurement: the estimators used on real scans and synthetic packs alike.

The source statistics (`synthpack.source`) measure a scan with them once; the realism report
(`synthpack.realism`) measures the source and the packs with the same ones, so a figure
means the same on both. Modules, one job each:

``phases``            pore and grain intensity levels
``noise_estimate``    `estimate_noise`: the one noise estimator (source, artefacts, realism)
``edges``             signed distance from grain boundaries, edge profile and 10-90 width
``psf``               `fit_edge_spread`: the scanner's blur and edge shift, fitted to the edge profile
``steepness``         `edge_steepness`: how steep the edges are, read without labels (the neighbour steps' upper tail)
``spectrum``          noise power spectrum of the grain and pore interiors, on their noise only (differences across slices)
``semivariogram``     the fine texture of grain and pore interiors: their in-slice semivariogram at lags 1-4 voxels
``phase_histograms``  full-band intensity histograms (quantiles) of grains, pores and edges, and their distance
``pore_spectrum``     the pore interior's 3D power spectrum on every scale up to 32 voxels (the pore texture's)
``pore_width``        the local half-width of the pore space at each pore voxel (thin gaps against open pores)
``pore_bands``        the pore phase's level and spread in bands of distance from the nearest grain
``pore_histogram``    the pore interior's histogram shape (quantiles) and the map onto it (the pore texture's)
``spectral_spikes``   `spectral_spikes`: periodic patterns in a phase, as narrow peaks of its in-slice spectrum
``specimen``          `specimen_mask`: the specimen's voxels, without the container and the air
``scanner``           `measure_scanner`: cupping, rings and the container wall, about the rotation axis
``lattice``           in-slice patches wholly inside a mask (the realism judge's)
``roughness``         boundary roughness of grain sections: outline length over the smoothed outline's
``contacts``          grain contacts: coordination numbers of the complete grains centred in a region
====================  ======================================================================================="""

from .contacts import centred_grains, coordination_numbers, mean_coordination
from .edges import EdgeProfile, edge_profile, edge_width, signed_distance, volume_edge_width
from .noise_estimate import NoiseEstimate, estimate_noise
from .phase_histograms import phase_masks, phase_quantiles, quantile_distance
from .phases import PhaseLevels, estimate_phases
from .pore_histogram import QUANTILE_SCORES, map_to_quantiles, measure_pore_quantiles
from .pore_spectrum import PORE_SPECTRUM_SIZE, measure_pore_spectrum, spectrum_on_grid
from .pore_bands import PoreBands, pore_bands
from .pore_width import pore_half_widths
from .psf import EdgeSpread, fit_edge_spread
from .roughness import section_roughness, volume_roughness
from .scanner import ScannerArtefacts, measure_scanner
from .semivariogram import phase_semivariograms, semivariogram
from .spectral_spikes import SpectralSpikes, spectral_spikes
from .spectrum import NPS_PATCH, NoiseSpectrum, noise_power_spectrum, phase_spectra
from .steepness import edge_steepness, steepness_distance

__all__ = [
    "centred_grains",
    "coordination_numbers",
    "edge_profile",
    "edge_steepness",
    "edge_width",
    "EdgeProfile",
    "EdgeSpread",
    "estimate_noise",
    "estimate_phases",
    "fit_edge_spread",
    "map_to_quantiles",
    "measure_pore_quantiles",
    "pore_bands",
    "PoreBands",
    "measure_pore_spectrum",
    "mean_coordination",
    "measure_scanner",
    "noise_power_spectrum",
    "NoiseEstimate",
    "NoiseSpectrum",
    "NPS_PATCH",
    "phase_masks",
    "phase_quantiles",
    "phase_semivariograms",
    "phase_spectra",
    "PhaseLevels",
    "PORE_SPECTRUM_SIZE",
    "pore_half_widths",
    "quantile_distance",
    "QUANTILE_SCORES",
    "ScannerArtefacts",
    "steepness_distance",
    "section_roughness",
    "semivariogram",
    "signed_distance",
    "SpectralSpikes",
    "spectral_spikes",
    "spectrum_on_grid",
    "volume_edge_width",
    "volume_roughness",
]
