"""Dataset exports of packs and labelled scans for training segmentation models.

`export_yolo` writes an Ultralytics YOLO instance-segmentation dataset (polygons) and
`export_coco` a COCO one (RLE masks); both slice, split and window the volumes the same
way (`synthpack.export.slices`). See `synthpack.export.yolo` and `synthpack.export.coco`
for the layouts and the format decisions.
"""

from .coco import CocoExportSummary, export_coco
from .yolo import ExportSummary, export_yolo

__all__ = ["CocoExportSummary", "ExportSummary", "export_coco", "export_yolo"]
