"""Source measurement: the figures of a real scan that a synthetic pack reproduces, measured once.

Modules, one job each:

==============  ====================================================================
``statistics``  `SourceStatistics` (typed, frozen) and `measure_source` (scan -> it)
``phases``      pore and grain intensity levels
``noise``       `estimate_noise`: the one noise estimator (source, artefacts, realism)
``edges``       signed distance from grain boundaries, edge profile and 10-90 width
==============  ====================================================================

It comes right after reading the scan and imports nothing of the later stages.
"""

from .edges import EdgeProfile, edge_profile, edge_width, signed_distance, volume_edge_width
from .noise import NoiseEstimate, estimate_noise
from .phases import PhaseLevels, estimate_phases
from .statistics import SourceStatistics, measure_source

__all__ = [
    "EdgeProfile",
    "NoiseEstimate",
    "PhaseLevels",
    "SourceStatistics",
    "edge_profile",
    "edge_width",
    "estimate_noise",
    "estimate_phases",
    "measure_source",
    "signed_distance",
    "volume_edge_width",
]
