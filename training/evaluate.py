"""Score a trained YOLO segmentation model on the test slices of a `synthpack export-yolo` folder.

Four figures per test set (and the per-slice counts behind the Dice and the F1):

- **Dice**: foreground Dice of the predicted against the true particle masks
  (paper eq. 12), pooled over every pixel of the test slices (and the mean of the
  per-slice values);
- **instance Dice**: Dice of instances matched one to one by IoU >= 0.5,
  unmatched instances counting 0 (`synthpack.metrics`);
- **instance F1**: matched-instance F1 at IoU 0.5, ``2 matched / (predicted + true)``
  instances, matched one to one per test slice (Hungarian on IoU >= 0.5,
  `synthpack.metrics.match_instances`), the counts pooled over the slices;
- **mask mAP50**: Ultralytics' own mask mAP at IoU 0.5 on the same slices (YOLO only).

Predicted instances are drawn at the slices' full resolution (``retina_masks``),
most confident last, into 16-bit label images under ``OUT/pred/``, and scored
against the export's ``truth/test/`` images. ``--predictions DIR`` scores label
images made elsewhere instead of running a model.

Run from the checkout root::

    python -m training.evaluate --weights runs/real_large/weights/best.pt --data yolo_ds --out eval_large
"""

from __future__ import annotations

import argparse
import json
import logging
import os
from pathlib import Path

import numpy as np

from synthpack.io import atomic_file, write_label_image
from synthpack.metrics import evaluate_folders

from .offline import offline_ultralytics
from .train import resolve_device

logger = logging.getLogger(__name__)


def predict_label_images(model, images: Path, out: Path, *, imgsz: int, conf: float = 0.25, device: str = "cpu",
                         batch: int = 16) -> int:
    """Predict instances on every PNG of `images` and write them as label images into `out`.

    Parameters
    ----------
    model : ultralytics.YOLO
    images, out : Path
        Folder of slices, folder for ``<name>.png`` label images (uint16, one id per
        instance, 0 = background, at the slice's resolution).
    imgsz : int
        Inference size, pixels.
    conf : float
        Confidence threshold of the kept instances.
    device : str
    batch : int
        Slices per forward pass.

    Returns
    -------
    int
        Number of instances written.
    """
    out.mkdir(parents=True, exist_ok=True)
    paths = sorted(images.glob("*.png"))
    total = 0
    for start in range(0, len(paths), batch):
        chunk = [str(p) for p in paths[start:start + batch]]
        for path, result in zip(chunk, model.predict(chunk, imgsz=imgsz, conf=conf, device=device,
                                                      retina_masks=True, verbose=False)):
            labels = np.zeros(result.orig_shape, dtype=np.int32)
            if result.masks is not None:
                masks = result.masks.data.cpu().numpy() > 0.5
                order = np.argsort(result.boxes.conf.cpu().numpy())  # most confident drawn last
                for k, j in enumerate(order, start=1):
                    labels[masks[j]] = k
                total += len(order)
            write_label_image(out / Path(path).stem, labels)
    return total


def mask_map50(model, data: Path, *, imgsz: int, device: str, out: Path) -> float:
    """Ultralytics' mask mAP at IoU 0.5 on the ``test`` split of the export's ``data.yaml``."""
    metrics = model.val(data=str(data / "data.yaml"), split="test", imgsz=imgsz, device=device, plots=False,
                        verbose=False, project=str(out.parent), name=out.name, exist_ok=True)
    return float(metrics.seg.map50)


def score(predictions: str | os.PathLike, truth: str | os.PathLike) -> dict:
    """Dice figures of the label images in `predictions` against those in `truth` (one row per slice).

    Returns
    -------
    dict
        ``dice``, ``instance_dice`` and ``instance_f1`` (pooled over the slices),
        ``dice_mean_of_slices``, ``n_slices``, ``n_true``, ``n_pred``, ``n_matched``, and
        ``slices``: per slice (in name order) its ``file``, ``dice``, foreground pixels
        ``fg_intersection``, ``fg_pred``, ``fg_true`` and instances ``n_matched``,
        ``n_pred``, ``n_true`` (what `training.stats.paired_bootstrap` resamples).
    """
    report = evaluate_folders(predictions, truth)
    summary = report.summary
    return {
        "dice": summary["pooled"]["dice"],
        "instance_dice": summary["pooled"]["instance_dice_micro"],
        "instance_f1": summary["pooled"]["f1"],
        "dice_mean_of_slices": summary["mean_of_rows"]["dice"],
        "n_slices": summary["n_rows"],
        "n_true": summary["n_true"], "n_pred": summary["n_pred"], "n_matched": summary["n_matched"],
        "slices": [{"file": row["file"], "dice": row["dice"], "fg_intersection": stats.fg_intersection,
                    "fg_pred": stats.fg_pred, "fg_true": stats.fg_true, "n_matched": stats.n_matched,
                    "n_pred": stats.n_pred, "n_true": stats.n_true}
                   for row, stats in zip(report.rows, report.stats)],
    }


def write_scores(out: Path, scores: dict) -> None:
    """Write ``out/scores.json`` atomically (the experiment takes it as "this evaluation is done")."""
    with atomic_file(out / "scores.json") as staging:
        staging.write_text(json.dumps(scores, indent=1))


def evaluate(weights: str | os.PathLike, data: str | os.PathLike, out: str | os.PathLike, *, imgsz: int = 256,
             conf: float = 0.25, device: str = "auto", config_dir: str | os.PathLike | None = None) -> dict:
    """Predict the test slices of the export `data` with `weights` and score them.

    Writes ``out/pred/*.png`` (predicted label images) and ``out/scores.json``.

    Returns
    -------
    dict
        `score`'s figures plus ``mask_map50``, ``n_pred_instances``, ``weights``, ``data``, ``conf``.
    """
    data, out = Path(data), Path(out).resolve()
    truth = data / "truth" / "test"
    if not truth.is_dir():
        raise FileNotFoundError(f"{truth} not found: give a `synthpack export-yolo` folder with test slices")
    yolo = offline_ultralytics(config_dir or out / "ultralytics")
    model = yolo(str(weights), task="segment")
    device = resolve_device(device)
    n_pred = predict_label_images(model, data / "images" / "test", out / "pred", imgsz=imgsz, conf=conf,
                                  device=device)
    scores = score(out / "pred", truth)
    scores.update(mask_map50=mask_map50(model, data, imgsz=imgsz, device=device, out=out / "val"),
                  n_pred_instances=n_pred, weights=str(weights), data=str(data), conf=conf)
    write_scores(out, scores)
    return scores


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", required=True, help="a synthpack export-yolo folder (its truth/test is the truth)")
    parser.add_argument("--out", required=True, help="output folder (pred/, scores.json)")
    source = parser.add_mutually_exclusive_group(required=True)
    source.add_argument("--weights", help="trained model (.pt) to predict the test slices with")
    source.add_argument("--predictions", help="score these label images instead (one per test slice, same names)")
    parser.add_argument("--imgsz", type=int, default=256, help="inference size (default 256)")
    parser.add_argument("--conf", type=float, default=0.25, help="confidence threshold (default 0.25)")
    parser.add_argument("--device", default="auto", help="auto, cpu, 0, ... (default auto)")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    if args.predictions:
        scores = score(args.predictions, Path(args.data) / "truth" / "test")
        write_scores(Path(args.out), scores)
    else:
        scores = evaluate(args.weights, args.data, args.out, imgsz=args.imgsz, conf=args.conf, device=args.device)
    print(json.dumps(scores, indent=1))


if __name__ == "__main__":
    main()
