"""The scan: a tomogram, its instance labels and voxel size; the built-in samples; starting labels; the split.

Modules, one job each:

=============  ================================================================================
``core``       `Scan` and the validation of its volumes and voxel size
``split``      the paper's train / val / test split of a volume's slices (central 20% test)
``samples``    `sample_scan`: the built-in, seeded, labelled stand-in scans
``labelling``  `label_scan`: starting instance labels for a scan that has none
=============  ================================================================================
"""

from __future__ import annotations

from .._shared.exports import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports(__name__, {
    "LabelConfig": ".labelling",
    "SPLITS": ".split",
    "Scan": ".core",
    "TEST_FRACTION": ".split",
    "VAL_FRACTION": ".split",
    "central_block": ".split",
    "label_scan": ".labelling",
    "sample_scan": ".samples",
    "slice_splits": ".split",
    "split_slices": ".split",
    "validate_labels": ".core",
    "validate_tomogram": ".core",
    "validate_voxel_size": ".core",
})
