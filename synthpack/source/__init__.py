"""Source measurement: the figures of a real scan that a synthetic pack reproduces, measured once.

Modules, one job each:

==============  ====================================================================
``statistics``  `SourceStatistics` (typed, frozen) and `measure_source` (scan -> it)
``phases``      pore and grain intensity levels
``noise``       `estimate_noise`: the one noise estimator (source, artefacts, realism)
``edges``       signed distance from grain boundaries, edge profile and 10-90 width
``psf``         `fit_edge_spread`: the scanner's blur and edge shift, fitted to the edge profile
``spectrum``    noise power spectrum of the grain and pore interiors
``patches``     in-slice patches wholly inside a mask (the spectrum's and the realism judge's)
==============  ====================================================================

It comes right after reading the scan and imports nothing of the later stages.
"""

from .edges import EdgeProfile, edge_profile, edge_width, signed_distance, volume_edge_width
from .noise import NoiseEstimate, estimate_noise
from .phases import PhaseLevels, estimate_phases
from .psf import EdgeSpread, fit_edge_spread
from .spectrum import NPS_PATCH, NoiseSpectrum, noise_power_spectrum, phase_spectra
from .statistics import SourceStatistics, measure_source

__all__ = [
    "NPS_PATCH",
    "EdgeProfile",
    "EdgeSpread",
    "NoiseEstimate",
    "NoiseSpectrum",
    "PhaseLevels",
    "SourceStatistics",
    "edge_profile",
    "edge_width",
    "estimate_noise",
    "estimate_phases",
    "fit_edge_spread",
    "measure_source",
    "noise_power_spectrum",
    "phase_spectra",
    "signed_distance",
    "volume_edge_width",
]
