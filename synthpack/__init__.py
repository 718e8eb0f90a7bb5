"""synthpack: synthetic CT tomograms of particle packs with exact instance labels.

The pipeline follows "Particle Pack Generation: Synthesise Tomograms with
Physics-Based Simulation": extract the particles of a labelled scan, mesh them,
pour them into a virtual tube with a rigid-body simulator, rebuild a tomogram and
label volume from the particles' voxels at their simulated poses, and add CT noise
and artefacts.

Heavy submodules (torch, pybullet) are imported on first use, so ``import
synthpack`` stays fast.
"""

from __future__ import annotations

from ._shared.exports import lazy_exports
from .errors import SynthpackInputError
from .scan.core import Scan

__version__ = "0.23.0"

_getattr, __dir__, _lazy = lazy_exports(__name__, {
    "read_scan": ".io",
    "label_scan": ".scan",
    "ParticleLibrary": ".library",
    "Particle": ".library",
    "pour": ".physics",
    "Placements": ".physics",
    "Tube": ".physics",
    "SyntheticParticlePackDataset": ".dataset",
    "ScanSliceDataset": ".dataset",
    "PatchDataset": ".dataset",
})
__getattr__ = _getattr
__all__ = ["Scan", "SynthpackInputError", "__version__", *_lazy]
