"""How close a synthetic pack is to its source scan.

Modules, one job each:

================  ==================================================================
``region``        `Specimen` (a labelled volume and the bulk region measured in it)
``structure``     solid fraction, grain size and shape, coordination, orientation fabric
``appearance``    phase intensities, noise level and power spectrum, edge sharpness
``discriminator`` classifier two-sample tests: cross-validated AUCs of a logistic
                  regression and of the CNN on the same folds; `CnnConfig`
``cnn``           the small CNN discriminator (torch), trained from scratch per fold
``floor``         the floor: the source's even against its odd slabs along z
``ablation``      the patches with phases made flat: where the classifiers see a pack differ
``targets``       the realism targets (thresholds), pass / fail per pack, modes worse than none
``report``        `compare`: measure a source and packs, `RealismReport` (JSON, Markdown)
``markdown``      the report's Markdown
``plots``         the report's PNG pictures
================  ==================================================================

The measurements it shares with the earlier stages come from them: edges, noise,
spectra and patches from `synthpack.source`, the bulk region from
`synthpack.artefacts.recipes`. The fit of the post-processing to the source is
`synthpack.artefacts.calibrate`.
"""

from .discriminator import CnnConfig
from .region import Specimen
from .report import RealismReport, compare

__all__ = ["CnnConfig", "RealismReport", "Specimen", "compare"]
