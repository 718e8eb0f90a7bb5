"""Dataset exports of packs and labelled scans for training segmentation models.

`export_yolo` writes an Ultralytics YOLO instance-segmentation dataset (polygons) and
`export_coco` a COCO one (RLE masks); both slice, split and window the volumes the same
way. `export_nnunet` writes an nnU-Net v2 raw dataset of 3D volumes (NIfTI) with a
grain / boundary / background target, split by the same rule. `export` writes any
registered format by name.

Modules, one job each:

=============  ================================================================================
``slices``     the sources, the split of their slices, the intensity window, the PNG slices
``exporter``   `run_export`: check, plan, stage, write, record; the settings; the slice loop
``yolo``       polygon labels, ``data.yaml``
``coco``       RLE masks, ``instances_<split>.json``
``nnunet``     3D NIfTI cases, semantic target, ``dataset.json``
``registry``   `FORMATS`: one record per format; `export` by name
=============  ================================================================================
"""

from __future__ import annotations

from .._shared.exports import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports(__name__, {
    "CocoExportSummary": ".coco",
    "ExportSummary": ".yolo",
    "NnUNetExportSummary": ".nnunet",
    "export": ".registry",
    "export_coco": ".coco",
    "export_nnunet": ".nnunet",
    "export_yolo": ".yolo",
})
