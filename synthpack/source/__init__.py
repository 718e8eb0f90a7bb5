"""Source statistics: the figures of a real scan that a synthetic pack reproduces, measured once.

``statistics``: `SourceStatistics` (typed, frozen: phase levels, noise and its spectra, edge
width and spread, the pore texture's spectrum and histogram shape, scanner artefacts, bulk
solid fraction) and `measure_source` (scan -> it), built on the estimators of
`synthpack.measure`. It comes right after reading the scan and imports nothing of the later
stages.
"""

from .statistics import SourceStatistics, measure_source

__all__ = ["SourceStatistics", "measure_source"]
