"""Train an Ultralytics YOLO segmentation model from scratch on a `synthpack export-yolo` dataset.

The model is built from its ``.yaml`` (``yolov8m-seg.yaml`` as in the paper,
``yolov8n-seg.yaml`` or ``yolov8s-seg.yaml`` on small machines), never from
pretrained weights, and Ultralytics runs offline (see `training.offline`).

Run from the checkout root::

    python -m training.train --data yolo_ds/data.yaml --out runs/real_large \
        --model yolov8n-seg.yaml --imgsz 256 --epochs 30 --batch 16 --device auto --seed 0
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import logging
import os
import time
from dataclasses import dataclass, field
from pathlib import Path

from synthpack.errors import SynthpackInputError
from synthpack.io import atomic_file

from .arms import MODEL_FAMILIES
from .compute import COMPUTE_MODES, ArmPlan, scale_epoch_options
from .offline import OFFLINE_TRAIN_ARGS, offline_ultralytics

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class TrainSettings:
    """What a training run depends on (the keys of a config's ``train`` section).

    Attributes
    ----------
    model : str
        Ultralytics model yaml, e.g. ``"yolov8n-seg.yaml"``.
    imgsz : int
        Training image size, pixels (slices are letterboxed to it).
    epochs, batch : int
        Epochs and images per batch. Under ``compute: equal_steps`` `epochs` is that of the
        arm with the most training images (unless `images_seen` is given) and the unit of
        the options counted in epochs (`training.compute`).
    compute : str
        ``"equal_steps"`` (every arm of an experiment sees the same number of images) or
        ``"fixed_epochs"`` (the paper's rule): `training.compute.COMPUTE_MODES`.
    images_seen : int or None
        Under ``equal_steps``, the training images every arm sees; None: the largest arm's
        training images times `epochs`.
    device : str
        ``"auto"`` (the first GPU when there is one, else the CPU), ``"cpu"``, ``"0"``, ...
    seed : int
        Ultralytics' seed (it trains deterministically).
    optimizer : str
        ``"SGD"``, ``"AdamW"``, ... (``"auto"`` ignores `lr0` on short runs).
    lr0 : float
        Initial learning rate.
    workers : int
        DataLoader workers.
    options : dict
        Any other ``YOLO.train`` keyword, e.g. ``{"close_mosaic": 0, "fraction": 0.5}``.
    model_family : str or list of str
        The experiment's model families (`training.arms.MODEL_FAMILIES`): ``"yolo"``,
        ``"unet"`` or both (``[yolo, unet]``, each with its own arms). The U-Net
        (`training.unet`) shares `imgsz` (its training crops), `epochs`, `batch`, `compute`,
        `images_seen`, `device`, `seed` and ``options["fraction"]`` / ``options["val"]``;
        its network and optimizer are the config's ``unet:`` section.
    """

    model: str = "yolov8n-seg.yaml"
    imgsz: int = 256
    epochs: int = 30
    batch: int = 16
    compute: str = "equal_steps"
    images_seen: int | None = None
    device: str = "auto"
    seed: int = 0
    optimizer: str = "SGD"
    lr0: float = 0.01
    workers: int = 2
    options: dict = field(default_factory=dict)
    model_family: str | list = "yolo"

    @property
    def families(self) -> tuple[str, ...]:
        """`model_family` as a tuple of family names."""
        return (self.model_family,) if isinstance(self.model_family, str) else tuple(self.model_family)

    @classmethod
    def from_dict(cls, values: dict) -> TrainSettings:
        """Settings from a config section; unknown keys are refused with the list of known ones."""
        unknown, known = unknown_fields(cls, values)
        if unknown:
            raise ValueError(f"unknown train setting(s) {', '.join(unknown)}: use {', '.join(known)} "
                             "(other YOLO.train keywords go under 'options')")
        return cls(**values)

    def __post_init__(self):
        if self.compute not in COMPUTE_MODES:
            raise SynthpackInputError(f"train.compute must be one of {', '.join(COMPUTE_MODES)}, "
                                      f"got {self.compute!r}")
        if self.images_seen is not None and (isinstance(self.images_seen, bool) or not isinstance(
                self.images_seen, int) or self.images_seen <= 0):
            raise SynthpackInputError(f"train.images_seen must be a positive number of images, got {self.images_seen!r}")
        families = self.families
        if not families or len(set(families)) != len(families) or not set(families) <= set(MODEL_FAMILIES):
            raise SynthpackInputError(f"train.model_family must be one of {', '.join(MODEL_FAMILIES)} or a list of "
                                      f"them (each once), got {self.model_family!r}")


def unknown_fields(cls, values: dict) -> tuple[list[str], list[str]]:
    """The keys of a config section `values` that are no field of the dataclass `cls`, and its fields (both sorted)."""
    known = {f.name for f in dataclasses.fields(cls)}
    return sorted(set(values) - known), sorted(known)


def resolve_device(device: str) -> str:
    """``"auto"`` -> ``"0"`` when CUDA is available, else ``"cpu"``; other values unchanged."""
    if device != "auto":
        return device
    import torch

    return "0" if torch.cuda.is_available() else "cpu"


def _validation_schedule(epochs: list[int] | None, wanted: bool, images: int | None):
    """An ``on_train_epoch_end`` callback: validate after the given epochs only.

    Ultralytics validates after every epoch (``val: true``) or only after the last one
    (``val: false``), and keeps the last validation's fitness on the epochs it skips, which
    would save those epochs' weights as ``best.pt``: the callback clears it, so only
    validated weights are ever "best".

    Parameters
    ----------
    epochs : list of int or None
        1-based epochs to validate after (`training.compute.ArmPlan.validation_epochs`);
        None: every epoch.
    wanted : bool
        The ``val`` option: False validates only after the last epoch, as Ultralytics does.
    images : int or None
        The plan's training images of an epoch, checked against the dataset Ultralytics built.
    """
    due = None if epochs is None else set(epochs)

    def on_train_epoch_end(trainer) -> None:
        n = len(trainer.train_loader.dataset)
        if images is not None and n != images:
            raise RuntimeError(f"Ultralytics trains on {n} images an epoch, the compute plan on {images}: "
                               "training.compute.effective_images no longer matches Ultralytics")
        trainer.args.val = wanted and (due is None or trainer.epoch + 1 in due)
        trainer.fitness = None

    return on_train_epoch_end


def train(data: str | os.PathLike, out: str | os.PathLike, settings: TrainSettings,
          config_dir: str | os.PathLike | None = None, *, plan: ArmPlan | None = None,
          callbacks: dict | None = None) -> Path:
    """Train a model on the dataset `data` and return its best weights.

    Parameters
    ----------
    data : path-like
        ``data.yaml`` of a `synthpack export-yolo` folder (or the folder).
    out : path-like
        Run folder: Ultralytics writes ``out/weights/{best,last}.pt`` and
        ``out/results.csv``; ``out/train.json`` records the settings and time.
    settings : TrainSettings
    config_dir : path-like, optional
        Ultralytics' config folder (default ``out/ultralytics``); see `offline_ultralytics`.
    plan : training.compute.ArmPlan, optional
        This arm's epochs (instead of ``settings.epochs``), the factor of its options counted
        in epochs and its validation interval (`training.compute`); None: ``settings.epochs``,
        a validation after every epoch.
    callbacks : dict, optional
        Ultralytics event -> callback, e.g. `training.curves.CurveRecorder.callbacks`.

    Returns
    -------
    Path
        ``out/weights/best.pt``.
    """
    data, out = Path(data), Path(out).resolve()
    if data.is_dir():
        data = data / "data.yaml"
    if not data.is_file():
        raise FileNotFoundError(f"{data} not found: give the data.yaml of a `synthpack export-yolo` folder")
    yolo = offline_ultralytics(config_dir or out / "ultralytics")
    from ultralytics.utils import DEFAULT_CFG_DICT

    epochs, options = settings.epochs, dict(settings.options)
    if plan is not None:
        epochs = plan.epochs
        options.update(scale_epoch_options(options, DEFAULT_CFG_DICT, plan.epoch_scale))
    model = yolo(settings.model, task="segment")
    model.add_callback("on_train_epoch_end", _validation_schedule(
        plan.validation_epochs if plan else None, bool(options.get("val", True)), plan.images if plan else None))
    for event, callback in (callbacks or {}).items():
        model.add_callback(event, callback)
    device = resolve_device(settings.device)
    start = time.perf_counter()
    model.train(
        data=str(data), imgsz=settings.imgsz, epochs=epochs, batch=settings.batch, device=device,
        seed=settings.seed, deterministic=True, optimizer=settings.optimizer, lr0=settings.lr0,
        workers=settings.workers, project=str(out.parent), name=out.name, exist_ok=True, verbose=False,
        **OFFLINE_TRAIN_ARGS, **options,
    )
    seconds = time.perf_counter() - start
    best = out / "weights" / "best.pt"
    if not best.is_file():
        raise RuntimeError(f"training finished without {best}: see the Ultralytics log above")
    record = {"data": str(data), "device": device, "seconds": seconds, **dataclasses.asdict(settings),
              "epochs": epochs, "options": options, "plan": plan.to_dict() if plan else None}
    with atomic_file(out / "train.json") as staging:  # the experiment takes it as "this run is done"
        staging.write_text(json.dumps(record, indent=1))
    logger.info("trained %s on %s in %.0f s: %s", settings.model, data, seconds, best)
    return best


def main(argv: list[str] | None = None) -> None:
    defaults = TrainSettings()
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", required=True, help="data.yaml of a synthpack export-yolo folder")
    parser.add_argument("--out", required=True, help="run folder (weights, results.csv, train.json)")
    for name in ("model", "imgsz", "epochs", "batch", "device", "seed", "optimizer", "lr0", "workers"):
        value = getattr(defaults, name)
        parser.add_argument(f"--{name}", type=type(value), default=value, help=f"default {value}")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    values = {k: v for k, v in vars(args).items() if k not in ("data", "out")}
    print(train(args.data, args.out, TrainSettings(**values)))


if __name__ == "__main__":
    main()
