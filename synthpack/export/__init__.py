"""Dataset exports of packs and labelled scans for training segmentation models.

`export_yolo` writes an Ultralytics YOLO instance-segmentation dataset (polygons) and
`export_coco` a COCO one (RLE masks); both slice, split and window the volumes the same
way (`synthpack.export.slices`). `export_nnunet` writes an nnU-Net v2 raw dataset of 3D
volumes (NIfTI) with a grain / boundary / background target, split by the same rule. See
`synthpack.export.yolo`, `synthpack.export.coco` and `synthpack.export.nnunet` for the
layouts and the format decisions.
"""

from .coco import CocoExportSummary, export_coco
from .nnunet import NnUNetExportSummary, export_nnunet
from .yolo import ExportSummary, export_yolo

__all__ = ["CocoExportSummary", "ExportSummary", "NnUNetExportSummary", "export_coco", "export_nnunet",
           "export_yolo"]
