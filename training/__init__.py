"""The paper's augmentation experiment with Ultralytics YOLOv8-seg, run from a synthpack checkout.

A package of the checkout, not of the installed ``synthpack``: run its modules
from the checkout root (needs the ``train`` extra)::

    python -m training.experiment --config smoke --out runs/smoke
    python -m training.train --data yolo_ds/data.yaml --out runs/mine
    python -m training.evaluate --weights runs/mine/weights/best.pt --data yolo_ds --out eval_mine

Modules
-------
offline
    Ultralytics set up to run offline inside a run folder.
train
    One YOLO segmentation training from a ``.yaml`` model.
evaluate
    Predictions of the test slices as label images; Dice and mAP50.
experiment
    The paper's experiment matrix, report and chart.

Importing the package imports nothing else: `training.offline.offline_ultralytics`
must run before anything imports ``ultralytics``.
"""
