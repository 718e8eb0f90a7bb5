"""Dataset exports of packs and labelled scans for training segmentation models.

`export_yolo` writes an Ultralytics YOLO instance-segmentation dataset (see
`synthpack.export.yolo` for the layout and the format decisions).
"""

from .yolo import ExportSummary, export_yolo

__all__ = ["ExportSummary", "export_yolo"]
