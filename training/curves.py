"""Learning curves: validation Dice against training steps, recorded while an arm trains; the plateau check.

`CurveRecorder` is a set of Ultralytics callbacks: after every validation of a training
(`training.train`'s schedule) it predicts the real val slices with the weights just saved
(``last.pt``: the EMA weights Ultralytics validates) and scores their foreground Dice against
the export's ``truth/val`` images (`training.evaluate`), the same figure as the report's
tables on the test slices; Ultralytics' own mask mAP50 on those slices comes with it. The
points go to ``<run>/curve.json``.

`tail_rise` is the plateau check: the rise of a curve over its last `TAIL` of steps, from a
least-squares line; a real-only arm whose mean curve rises by more than `RISE_LIMIT` there
has not converged, and the report says so.
"""

from __future__ import annotations

import json
import logging
from pathlib import Path

import numpy as np
import yaml

from synthpack.io import atomic_file

from .evaluate import predict_label_images, score

logger = logging.getLogger(__name__)

__all__ = ["RISE_LIMIT", "TAIL", "CurveRecorder", "mean_curve", "read_curve", "tail_rise"]

#: Share of a training's steps, at its end, over which the plateau check measures the rise.
TAIL = 0.2
#: Largest rise of validation Dice (a fraction: 0.01 = 1 point) over the last `TAIL` of steps of a converged curve.
RISE_LIMIT = 0.01


class CurveRecorder:
    """Validation Dice of a training after each of its validations, into ``run/curve.json``.

    Parameters
    ----------
    run : Path
        The training's run folder (Ultralytics' ``weights/last.pt`` is read from it).
    data : Path
        The ``data.yaml`` it trains on: its ``path`` and ``val`` give the val images, and
        ``<path>/truth/val`` their truth (an export made without it gives Dice None).
    batch : int
        Images per batch (steps = images seen / batch).
    imgsz : int
        Inference size, pixels.
    conf : float
        Confidence threshold of the predicted instances.
    device : str
        ``"cpu"``, ``"0"``, ...
    """

    def __init__(self, run: Path, data: Path, *, batch: int, imgsz: int, conf: float, device: str):
        spec = yaml.safe_load(Path(data).read_text())
        root = Path(spec["path"])
        self.images, self.truth = root / spec["val"], root / "truth" / "val"
        self.run, self.batch, self.imgsz, self.conf, self.device = Path(run), batch, imgsz, conf, device
        self.points: list[dict] = []
        if not self.truth.is_dir():
            logger.warning("%s has no truth/val: the learning curve of %s has no validation Dice "
                           "(re-export in a new run folder)", root, run)

    @property
    def callbacks(self) -> dict:
        """Ultralytics event -> callback, for `training.train.train`."""
        return {"on_fit_epoch_end": self.on_fit_epoch_end}

    def on_fit_epoch_end(self, trainer) -> None:
        """Record a point if this epoch was validated (not the final evaluation of ``best.pt``)."""
        if trainer.fitness is None or trainer.epoch >= trainer.epochs:
            return
        seen = (trainer.epoch + 1) * len(trainer.train_loader.dataset)
        self.points.append({"epoch": trainer.epoch + 1, "images_seen": seen, "steps": seen / self.batch,
                            "val_dice": self._dice(Path(trainer.last)),
                            "mask_map50": float(trainer.metrics.get("metrics/mAP50(M)", float("nan")))})
        with atomic_file(self.run / "curve.json") as staging:
            staging.write_text(json.dumps(self.points, indent=1))

    def _dice(self, weights: Path) -> float | None:
        if not self.truth.is_dir():
            return None
        from ultralytics import YOLO  # imported by then, offline (training.offline)

        pred = self.run / "curve_pred"
        predict_label_images(YOLO(str(weights), task="segment"), self.images, pred, imgsz=self.imgsz,
                             conf=self.conf, device=self.device)
        return score(pred, self.truth)["dice"]


def read_curve(run: Path) -> list[dict] | None:
    """The points of ``run/curve.json`` (`CurveRecorder`), or None for a run without one."""
    path = Path(run) / "curve.json"
    return json.loads(path.read_text()) if path.is_file() else None


def mean_curve(curves: list[list[dict]], key: str = "val_dice") -> tuple[np.ndarray, np.ndarray] | None:
    """Steps and the mean over seeds of `key`, point by point, of one arm's curves.

    The seeds of an arm validate at the same steps; a curve cut short (early stopping) cuts
    the mean to its length.

    Returns
    -------
    (steps, values) : ndarray of float64, shape (P,) each, or None
        None when a curve is missing, empty or without `key` values.
    """
    if not curves or any(not curve for curve in curves):
        return None
    length = min(len(curve) for curve in curves)
    values = [[point.get(key) for point in curve[:length]] for curve in curves]
    if any(v is None for row in values for v in row):
        return None
    return (np.array([p["steps"] for p in curves[0][:length]], dtype=np.float64),
            np.asarray(values, dtype=np.float64).mean(axis=0))


def tail_rise(steps: np.ndarray, values: np.ndarray, tail: float = TAIL) -> float | None:
    """The rise of a curve over its last `tail` of steps, from a least-squares line.

    The window runs from ``(1 - tail) * steps[-1]`` (the curve interpolated there) to the last
    point; the rise is the line's slope times the window's length.

    Parameters
    ----------
    steps : ndarray, shape (P,)
        Increasing training steps of the validations.
    values : ndarray, shape (P,)
        The validation figure at each (e.g. Dice as a fraction).
    tail : float
        In (0, 1].

    Returns
    -------
    float or None
        In the units of `values`; None for fewer than two points.
    """
    steps, values = np.asarray(steps, dtype=np.float64), np.asarray(values, dtype=np.float64)
    if len(steps) < 2:
        return None
    start = (1 - tail) * steps[-1]
    inside = steps > start
    x = np.concatenate([[start], steps[inside]])
    y = np.concatenate([[np.interp(start, steps, values)], values[inside]])
    slope = np.polyfit(x, y, 1)[0]
    return float(slope * (steps[-1] - start))
