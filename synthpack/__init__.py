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

import importlib
from typing import Any

from .errors import SynthpackInputError
from .scan import Scan

__version__ = "0.6.0"

_LAZY = {
    "read_scan": "synthpack.io",
    "label_scan": "synthpack.labelling",
    "ParticleLibrary": "synthpack.library",
    "Particle": "synthpack.particles",
    "pour": "synthpack.physics",
    "Placements": "synthpack.physics",
    "Tube": "synthpack.physics",
    "SyntheticParticlePackDataset": "synthpack.dataset",
    "ScanSliceDataset": "synthpack.dataset",
    "PatchDataset": "synthpack.dataset",
}

__all__ = ["Scan", "SynthpackInputError", "__version__", *sorted(_LAZY)]


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'synthpack' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_LAZY))
