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
compute
    Training compute per arm: the same images seen and steps for every arm (epochs scaled
    from its training-set size), or the paper's fixed epochs.
train
    One YOLO segmentation training from a ``.yaml`` model, for an arm's planned epochs,
    validated at the plan's steps.
curves
    Learning curves: validation Dice against steps, recorded during training; the plateau check.
evaluate
    Predictions of the test slices as label images; Dice (pooled and per slice) and mAP50.
arms
    The training arms (real, + packs, packs alone, randomised packs, label budgets, packs first
    then real) and the training lists of those that take part of an export.
stats
    Paired bootstrap intervals of a difference in Dice over test slices and seeds.
report
    The report's tables (the paper's layout, with intervals), comparisons and charts.
experiment
    The experiment: config, data, training and scoring of every arm, resumable.

Importing the package imports nothing else: `training.offline.offline_ultralytics`
must run before anything imports ``ultralytics``.
"""
