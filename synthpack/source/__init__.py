"""Source measurement: the figures of a real scan that a synthetic pack reproduces, measured once.

Modules, one job each:

==================  =========================================================================================
``statistics``      `SourceStatistics` (typed, frozen) and `measure_source` (scan -> it)
``phases``          pore and grain intensity levels
``noise``           `estimate_noise`: the one noise estimator (source, artefacts, realism)
``edges``           signed distance from grain boundaries, edge profile and 10-90 width
``psf``             `fit_edge_spread`: the scanner's blur and edge shift, fitted to the edge profile
``spectrum``        noise power spectrum of the grain and pore interiors
``pore_spectrum``   the pore interior's 3D power spectrum on every scale up to 32 voxels (the pore texture's)
``pore_histogram``  the pore interior's histogram shape (quantiles) and the map onto it (the pore texture's)
``specimen``        `specimen_mask`: the specimen's voxels, without the container and the air
``scanner``         `measure_scanner`: cupping, rings and the container wall, about the rotation axis
``patches``         in-slice patches wholly inside a mask (the spectrum's and the realism judge's)
==================  =========================================================================================

It comes right after reading the scan and imports nothing of the later stages.
"""

from .edges import EdgeProfile, edge_profile, edge_width, signed_distance, volume_edge_width
from .noise_estimate import NoiseEstimate, estimate_noise
from .phases import PhaseLevels, estimate_phases
from .pore_histogram import QUANTILE_SCORES, map_to_quantiles, measure_pore_quantiles
from .pore_spectrum import PORE_SPECTRUM_SIZE, measure_pore_spectrum, spectrum_on_grid
from .psf import EdgeSpread, fit_edge_spread
from .scanner import ScannerArtefacts, measure_scanner
from .spectrum import NPS_PATCH, NoiseSpectrum, noise_power_spectrum, phase_spectra
from .statistics import SourceStatistics, measure_source

__all__ = [
    "NPS_PATCH",
    "PORE_SPECTRUM_SIZE",
    "EdgeProfile",
    "EdgeSpread",
    "NoiseEstimate",
    "NoiseSpectrum",
    "PhaseLevels",
    "QUANTILE_SCORES",
    "ScannerArtefacts",
    "SourceStatistics",
    "edge_profile",
    "edge_width",
    "estimate_noise",
    "estimate_phases",
    "fit_edge_spread",
    "map_to_quantiles",
    "measure_pore_quantiles",
    "measure_pore_spectrum",
    "measure_scanner",
    "measure_source",
    "noise_power_spectrum",
    "phase_spectra",
    "signed_distance",
    "spectrum_on_grid",
    "volume_edge_width",
]
