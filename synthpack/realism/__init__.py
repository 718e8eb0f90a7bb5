"""How close a synthetic pack is to its source scan, and post-processing calibrated to it.

Modules, one job each:

================  ==================================================================
``region``        `Specimen` (a labelled volume and the bulk region measured in it)
``structure``     solid fraction, grain size and shape, coordination, orientation fabric
``edges``         signed distance from grain boundaries, edge profile and 10-90 width
``appearance``    phase intensities, noise level and power spectrum, edge sharpness
``patches``       in-slice patches on a lattice inside a mask
``discriminator`` classifier two-sample test: cross-validated AUC real vs synthetic
``calibrate``     fit blur sigma and noise std to the source's edge width and noise
``report``        `compare`: measure a source and packs, `RealismReport` (JSON, Markdown)
``markdown``      the report's Markdown
``plots``         the report's PNG pictures
================  ==================================================================
"""

from typing import Any

from .calibrate import Calibration, calibrate
from .region import Specimen, bulk_region

__all__ = ["Calibration", "RealismReport", "Specimen", "bulk_region", "calibrate", "compare"]


def __getattr__(name: str) -> Any:
    """`compare` and `RealismReport` are imported on first use: the particle library imports this
    package for the edge width, and should not pay for the report's imports."""
    if name in ("compare", "RealismReport"):
        from . import report

        return getattr(report, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
