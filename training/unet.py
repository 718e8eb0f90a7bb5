"""The experiment's second model family: a MONAI 2D U-Net on the border-core target, instances by watershed.

Granular-CT users segment grains with U-Net-style models that predict a border-core target and
split instances from it (the nnU-Net-based ParticleSeg3D); `synthpack export-nnunet` writes that
target in 3D. Here it is made per slice from the same YOLO exports the YOLO family trains on, so
both families train on the same arms, splits and slices:

Target
    `slice_target`: `synthpack.export.nnunet.semantic_target` of a slice's truth image (as a
    one-slice volume, so only in-slice neighbours count): 0 background, 1 grain interior, 2
    boundary (the grain pixels with a 4-neighbour of another label: one pixel wide, on both
    sides of a contact). The experiment's exports write the truth images of every split
    (``truth/<split>/``).
Network and loss
    ``monai.networks.nets.UNet`` (2D, one input channel, three classes; `UNetSettings`) and
    ``monai.losses.DiceCELoss`` (softmax, one-hot target); AdamW, its learning rate decayed
    polynomially (power 0.9, as nnU-Net) to 0 over the training's steps.
Training compute
    The arm's plan (`training.compute.ArmPlan`): `plan.epochs` epochs of its first `plan.images`
    training slices in name order (as Ultralytics' ``fraction`` keeps them), each epoch a fresh
    random order, cut into batches of `plan.batch` slices across the epochs' ends. Every step
    but perhaps the last takes a full batch and the training sees exactly `plan.images_seen`
    slices in ``ceil(images_seen / batch)`` optimizer steps: arms of equal images seen take
    equal steps. A ``syn-first`` arm (`training.arms`) takes the same items in the same steps,
    every epoch of its packs' slices first (`item_order`). Each slice of a batch is a random
    ``train.imgsz`` square crop at its own resolution (grains keep their pixel size; a smaller
    slice is padded with background), turned by one of the 8 flips and quarter turns at random.
Validation and model selection
    After the step that completes each of the plan's validation epochs (`ArmPlan.validation_epochs`,
    or only the last with the option ``val: false``) the real val slices are predicted and their
    foreground Dice scored (`training.evaluate.score`) into ``curve.json`` (the points of
    `training.curves`); the weights of the best validation are ``weights/best.pt``.
Prediction
    Whole slices at their own resolution by ``monai.inferers.sliding_window_inference``
    (``imgsz`` windows, overlap 1/4, Gaussian blending), the most probable class per pixel,
    then `target_instances`: the nnU-Net export's `instances_from_target` on the slice
    (4-connected interior components as seeds, grown over the boundary pixels by watershed),
    written as label images as the YOLO family writes them
    (`training.evaluate.predict_label_images`).

Seeds: a training seed spawns (`numpy.random.SeedSequence`) one stream for the weights'
initialisation and one for the slices' order and crops. MONAI and torch are imported by the
functions that use them (MONAI takes seconds to import).
"""

from __future__ import annotations

import dataclasses
import json
import logging
import math
import os
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml
from PIL import Image

from synthpack.errors import SynthpackInputError
from synthpack.export.nnunet import instances_from_target, semantic_target
from synthpack.io import atomic_file, read_label_image, write_label_image

from .arms import synthetic_images
from .compute import ArmPlan
from .evaluate import score, write_scores
from .train import TrainSettings, resolve_device, unknown_fields

logger = logging.getLogger(__name__)

__all__ = ["N_CLASSES", "UNetSettings", "build_model", "evaluate_unet", "item_order", "load_model",
           "predict_label_images", "predict_labels", "slice_target", "split_images", "target_instances", "train_unet"]

#: Output classes: background 0, grain interior 1, boundary 2 (`synthpack.export.nnunet.LABELS`).
N_CLASSES = 3
#: Sliding-window prediction: overlap of neighbouring windows (a fraction of the window).
WINDOW_OVERLAP = 0.25


@dataclass(frozen=True)
class UNetSettings:
    """The U-Net family's network, optimizer and compute (the keys of a config's ``unet:`` section but ``arms``).

    Attributes
    ----------
    channels : tuple of int
        Feature channels per level, e.g. ``(16, 32, 64, 128)``.
    strides : tuple of int
        Downsampling factor between levels, one fewer than `channels`; their product must
        divide the training crop (``train.imgsz``).
    num_res_units : int
        Residual units per level (MONAI's ``num_res_units``; 0: plain convolutions).
    lr : float
        AdamW's initial learning rate.
    weight_decay : float
        AdamW's weight decay.
    images_seen : int or None
        The family's training budget: every U-Net arm sees this many training images
        (``train.compute: equal_steps``), planned apart from the YOLO arms; None:
        ``train.images_seen`` (or its default, the largest U-Net arm's images times
        ``train.epochs``). A U-Net from scratch needs more steps than a YOLO model of the
        same run to stop improving.
    """

    channels: tuple = (16, 32, 64, 128)
    strides: tuple = (2, 2, 2)
    num_res_units: int = 2
    lr: float = 0.002
    weight_decay: float = 1e-4
    images_seen: int | None = None

    @classmethod
    def from_dict(cls, values: dict) -> UNetSettings:
        """Settings from a config section; unknown keys are refused with the list of known ones."""
        unknown, known = unknown_fields(cls, values)
        if unknown:
            raise SynthpackInputError(f"unknown unet setting(s) {', '.join(unknown)}: use arms, {', '.join(known)}")
        values = {k: tuple(v) if isinstance(v, list) else v for k, v in values.items()}
        return cls(**values)

    def __post_init__(self):
        levels = (*self.channels, *self.strides)
        if (len(self.channels) < 2 or len(self.strides) != len(self.channels) - 1
                or not all(isinstance(v, int) and not isinstance(v, bool) and v > 0 for v in levels)):
            raise SynthpackInputError(f"unet.channels needs at least 2 positive ints and unet.strides one fewer, "
                                      f"got channels {self.channels!r}, strides {self.strides!r}")
        if self.images_seen is not None and (isinstance(self.images_seen, bool) or not isinstance(
                self.images_seen, int) or self.images_seen <= 0):
            raise SynthpackInputError(f"unet.images_seen must be a positive number of images, got {self.images_seen!r}")

    def check_crop(self, imgsz: int) -> None:
        """Refuse a training crop that the strides do not divide."""
        factor = math.prod(self.strides)
        if imgsz % factor:
            raise SynthpackInputError(f"train.imgsz {imgsz} is the U-Net's training crop and must be a multiple of "
                                      f"{factor}, the product of unet.strides {self.strides}")


def slice_target(labels: np.ndarray) -> np.ndarray:
    """The border-core target of one slice's instance labels (the nnU-Net export's, within the slice).

    Parameters
    ----------
    labels : ndarray of int, shape (H, W)
        Instance labels, 0 = background.

    Returns
    -------
    ndarray of uint8, shape (H, W)
        0 background, 1 grain interior, 2 boundary (`synthpack.export.nnunet.semantic_target`
        of the slice as a one-slice volume).
    """
    return semantic_target(np.asarray(labels)[None])[0]


def target_instances(target: np.ndarray) -> np.ndarray:
    """Instance labels of one slice from its (predicted) border-core target.

    Parameters
    ----------
    target : ndarray of int, shape (H, W)
        0 background, 1 grain interior, 2 boundary.

    Returns
    -------
    ndarray of int32, shape (H, W)
        `synthpack.export.nnunet.instances_from_target` of the slice as a one-slice volume:
        the 4-connected interior components as seeds, grown over the boundary pixels by
        watershed; grain pixels no seed reaches are instances of their own.
    """
    return instances_from_target(np.asarray(target)[None])[0]


def split_images(data: str | os.PathLike, split: str) -> list[Path]:
    """The slice images of `split` in the dataset ``data.yaml`` `data`: a folder or a list file, sorted."""
    spec = yaml.safe_load(Path(data).read_text())
    entry = Path(spec[split])
    entry = entry if entry.is_absolute() else Path(spec["path"]) / entry
    if entry.suffix == ".txt":
        return sorted(Path(line) for line in entry.read_text().splitlines() if line.strip())
    return sorted(entry.glob("*.png"))


def _truth(image: Path) -> Path:
    """The truth label image of an export's slice ``<export>/images/<split>/<name>.png``."""
    return image.parents[2] / "truth" / image.parent.name / image.name


def _read_image(path: Path) -> np.ndarray:
    """An export's 8-bit grey slice as float32 in [0, 1], shape (H, W)."""
    with Image.open(path) as image:
        return np.asarray(image.convert("L"), dtype=np.float32) / 255.0


def _training_slices(images: list[Path], size: int) -> tuple[list, list]:
    """Images (float32) and targets (int64) of `images` as torch tensors, each padded to at least `size` a side."""
    import torch

    pictures, targets = [], []
    for path in images:
        truth = _truth(path)
        if not truth.is_file():
            raise FileNotFoundError(f"{truth} not found: the U-Net trains on the truth images of every split, which "
                                    "exports made before it lack; give the experiment a new --out folder")
        image, target = _read_image(path), slice_target(read_label_image(truth)).astype(np.int64)
        pad = [(0, max(size - n, 0)) for n in image.shape]
        pictures.append(torch.from_numpy(np.pad(image, pad)))
        targets.append(torch.from_numpy(np.pad(target, pad)))
    return pictures, targets


def _batch(pictures: list, targets: list, indices, size: int, generator):
    """Random `size` square crops of the slices `indices`, each turned by one of the 8 flips / quarter turns.

    Returns
    -------
    (x, y) : torch tensors, shapes (B, 1, size, size), float32 and int64
    """
    import torch

    xs, ys = [], []
    for i in indices.tolist():
        height, width = pictures[i].shape
        y0, x0, turns, flip = (int(torch.randint(high, (1,), generator=generator))
                               for high in (height - size + 1, width - size + 1, 4, 2))
        crop = (slice(y0, y0 + size), slice(x0, x0 + size))
        x, y = (torch.rot90(a[crop], turns) for a in (pictures[i], targets[i]))
        xs.append(x.flip(-1) if flip else x)
        ys.append(y.flip(-1) if flip else y)
    return torch.stack(xs)[:, None], torch.stack(ys)[:, None]


def _torch_device(device: str) -> str:
    """A `training.train.resolve_device` name as torch's: ``"0"`` -> ``"cuda:0"``."""
    device = resolve_device(device)
    return f"cuda:{device}" if device.isdigit() else device


def build_model(settings: UNetSettings, spatial_dims: int = 2):
    """A freshly initialised ``monai.networks.nets.UNet``: `spatial_dims` (2 or 3), 1 input channel, `N_CLASSES`
    outputs (logits)."""
    from monai.networks.nets import UNet

    return UNet(spatial_dims=spatial_dims, in_channels=1, out_channels=N_CLASSES, channels=settings.channels,
                strides=settings.strides, num_res_units=settings.num_res_units)


def _save(model, settings: UNetSettings, spatial_dims: int, path: Path) -> None:
    import torch

    with atomic_file(path) as staging:
        torch.save({"state_dict": model.state_dict(), "unet": dataclasses.asdict(settings),
                    "spatial_dims": spatial_dims}, staging)


def load_model(weights: str | os.PathLike, device: str = "cpu"):
    """The U-Net saved in `weights` (`fit`'s ``best.pt``, 2D or 3D), on `device`, in eval mode."""
    import torch

    saved = torch.load(weights, map_location=_torch_device(device), weights_only=True)
    network = {key: value for key, value in saved["unet"].items() if key in UNetSettings.__dataclass_fields__}
    model = build_model(UNetSettings.from_dict(network), saved.get("spatial_dims", 2))
    model.load_state_dict(saved["state_dict"])
    return model.to(_torch_device(device)).eval()


def predict_labels(model, image: np.ndarray, *, imgsz: int, device: str = "cpu") -> np.ndarray:
    """Instance labels of one slice: sliding-window class probabilities, their argmax, `target_instances`.

    Parameters
    ----------
    model : torch.nn.Module
        A U-Net of `build_model`, in eval mode, on `device`.
    image : ndarray of float32, shape (H, W)
        The slice's grey values in [0, 1].
    imgsz : int
        Window size, pixels (the training crop).
    device : str

    Returns
    -------
    ndarray of int32, shape (H, W)
    """
    import torch
    from monai.inferers import sliding_window_inference

    with torch.no_grad():
        x = torch.as_tensor(image, dtype=torch.float32)[None, None].to(_torch_device(device))
        logits = sliding_window_inference(x, roi_size=(imgsz, imgsz), sw_batch_size=16, predictor=model,
                                          overlap=WINDOW_OVERLAP, mode="gaussian")
    return target_instances(logits.argmax(dim=1)[0].cpu().numpy().astype(np.uint8))


def predict_label_images(model, images: Path, out: Path, *, imgsz: int, device: str = "cpu") -> int:
    """Predict every PNG of `images` and write its instances as ``out/<name>.png`` label images.

    The format of `training.evaluate.predict_label_images`: uint16, one id per instance, 0 =
    background, at the slice's resolution. Returns the number of instances written.
    """
    out.mkdir(parents=True, exist_ok=True)
    model.eval()
    total = 0
    for path in sorted(Path(images).glob("*.png")):
        labels = predict_labels(model, _read_image(path), imgsz=imgsz, device=device)
        total += int(labels.max(initial=0))
        write_label_image(out / path.stem, labels)
    return total


def _steps(plan: ArmPlan) -> int:
    """Optimizer steps of a plan: its images seen in full batches, the last one possibly short."""
    return math.ceil(plan.images_seen / plan.batch)


def item_order(n_items: int, epochs: int, generator, first: np.ndarray | None = None):
    """The order a training takes its items in: `epochs` passes over `n_items`, each a fresh random order.

    Parameters
    ----------
    n_items : int
        Training items (slices or patches) of an epoch.
    epochs : int
    generator : torch.Generator
        The training's data stream.
    first : ndarray of bool, shape (n_items,), optional
        Items that come first: every epoch of them, then every epoch of the rest (a ``syn-first``
        arm's pack slices, `training.arms`). Default: every epoch of all the items in turn.

    Returns
    -------
    order : torch.Tensor of int64, shape (epochs * n_items,)
        Item indices.
    epoch_of : torch.Tensor of int64, same shape
        The epoch (0-based) each entry of `order` belongs to.

    Raises
    ------
    SynthpackInputError
        If `first` holds all of the items or none.
    """
    import torch

    if first is None:
        order = torch.cat([torch.randperm(n_items, generator=generator) for _ in range(epochs)])
        return order, torch.arange(epochs).repeat_interleave(n_items)
    first = np.asarray(first, dtype=bool)
    if first.shape != (n_items,) or first.all() or not first.any():
        raise SynthpackInputError(f"a packs-first training needs both pack and real training items, got "
                                  f"{int(first.sum())} pack items of {n_items}")
    order, epoch_of = [], []
    for group in (torch.from_numpy(np.flatnonzero(first)), torch.from_numpy(np.flatnonzero(~first))):
        for epoch in range(epochs):
            order.append(group[torch.randperm(len(group), generator=generator)])
            epoch_of.append(torch.full((len(group),), epoch, dtype=torch.int64))
    return torch.cat(order), torch.cat(epoch_of)


def train_unet(data: str | os.PathLike, out: str | os.PathLike, settings: TrainSettings, unet: UNetSettings,
               plan: ArmPlan, *, packs_first: bool = False) -> Path:
    """Train a U-Net from scratch on the dataset `data` for `plan`'s images seen and return its best weights.

    Parameters
    ----------
    data : path-like
        ``data.yaml`` (or its folder) of an export with ``truth/`` images of its train and
        val slices, or an arm's dataset folder (`training.arms.subset_dataset`).
    out : path-like
        Run folder: ``weights/{best,last}.pt``, ``curve.json`` (the validations),
        ``curve_pred/`` (the last validation's predictions) and ``train.json`` (settings,
        plan, steps taken, time; written last: it marks the training as done).
    settings : TrainSettings
        ``imgsz`` (the training crop and prediction window), ``device``, ``seed`` and
        ``options["val"]`` are read; the plan holds the rest.
    unet : UNetSettings
    plan : training.compute.ArmPlan
    packs_first : bool
        Train on the pack slices first, then on the real ones (`item_order`; a ``syn-first`` arm).

    Returns
    -------
    Path
        ``out/weights/best.pt``.
    """
    data, out = Path(data), Path(out).resolve()
    data = data / "data.yaml" if data.is_dir() else data
    unet.check_crop(settings.imgsz)
    images = split_images(data, "train")[:plan.images]
    if len(images) != plan.images:
        raise RuntimeError(f"{data} lists {len(images)} training images, the compute plan {plan.images}")
    pictures, targets = _training_slices(images, settings.imgsz)
    val_images = split_images(data, "val")
    val_truth = _truth(val_images[0]).parent if val_images else None
    if val_truth is None or not val_truth.is_dir():
        raise FileNotFoundError(f"{data} has no val slices with truth images: the U-Net selects its model on them")
    device = _torch_device(settings.device)

    def validate(model) -> float:
        predict_label_images(model, val_images[0].parent, out / "curve_pred", imgsz=settings.imgsz, device=device)
        return score(out / "curve_pred", val_truth)["dice"]

    return fit(out, settings, unet, plan, spatial_dims=2, validate=validate, data=str(data),
               batch_of=lambda indices, epochs, generator: _batch(pictures, targets, indices, settings.imgsz,
                                                                  generator),
               first=synthetic_images(data, images) if packs_first else None)


def fit(out: Path, settings: TrainSettings, unet: UNetSettings, plan: ArmPlan, *, spatial_dims: int,
        batch_of: Callable, validate: Callable, data: str, first: np.ndarray | None = None) -> Path:
    """The U-Net families' training loop: `plan`'s images seen in batches, validations, the best weights.

    Parameters
    ----------
    out : Path
        Run folder (see `train_unet`).
    settings : TrainSettings
        ``device``, ``seed`` and ``options["val"]`` are read (and recorded).
    unet : UNetSettings
        The network (`build_model`), AdamW's learning rate and weight decay.
    plan : training.compute.ArmPlan
        ``plan.epochs`` epochs of ``plan.images`` training items (slices or patches), each
        epoch a fresh random order, cut into batches of ``plan.batch`` across the epochs' ends
        (`item_order`).
    spatial_dims : {2, 3}
    batch_of : callable
        ``batch_of(indices, epochs, generator) -> (x, y)``: the items `indices` (int64 tensor)
        of the epochs `epochs` (0-based, int64 tensor of the same length) as a float32 input
        batch (B, 1, ...) and an int64 border-core target (B, 1, ...), drawn with the torch
        `generator` of the training's data stream.
    validate : callable
        ``validate(model) -> float``: the real val slices' foreground Dice.
    data : str
        What it trained on, for ``train.json``.
    first : ndarray of bool, shape (plan.images,), optional
        The items trained on first (`item_order`), recorded in ``train.json`` as ``items_first``.

    Returns
    -------
    Path
        ``out/weights/best.pt``.
    """
    import torch
    from monai.losses import DiceCELoss

    device = _torch_device(settings.device)
    init_seed, data_seed = (int(s.generate_state(1)[0]) for s in np.random.SeedSequence(settings.seed).spawn(2))
    torch.manual_seed(init_seed)
    model = build_model(unet, spatial_dims).to(device)
    generator = torch.Generator().manual_seed(data_seed)
    loss_function = DiceCELoss(to_onehot_y=True, softmax=True)
    optimizer = torch.optim.AdamW(model.parameters(), lr=unet.lr, weight_decay=unet.weight_decay)
    n_steps = _steps(plan)
    schedule = torch.optim.lr_scheduler.PolynomialLR(optimizer, total_iters=n_steps, power=0.9)
    order, epoch_of = item_order(plan.images, plan.epochs, generator, first)
    due = plan.validation_epochs if settings.options.get("val", True) else [plan.epochs]
    (out / "weights").mkdir(parents=True, exist_ok=True)
    points, best, seen = [], None, 0
    start = time.perf_counter()
    for step in range(n_steps):
        model.train()
        batch = slice(step * plan.batch, (step + 1) * plan.batch)
        indices = order[batch]
        x, y = batch_of(indices, epoch_of[batch], generator)
        optimizer.zero_grad()
        loss = loss_function(model(x.to(device)), y.to(device))
        loss.backward()
        optimizer.step()
        loss = loss.item()
        schedule.step()
        seen += len(indices)
        passed = [epoch for epoch in due if epoch * plan.images <= seen]
        if not passed:
            continue
        due = due[len(passed):]
        model.eval()
        dice = validate(model)
        points.append({"epoch": passed[-1], "images_seen": seen, "steps": seen / plan.batch, "val_dice": dice,
                       "loss": loss})
        with atomic_file(out / "curve.json") as staging:
            staging.write_text(json.dumps(points, indent=1))
        if best is None or dice > best:
            best = dice
            _save(model, unet, spatial_dims, out / "weights" / "best.pt")
        logger.info("step %d/%d: loss %.3f, val Dice %.3f", step + 1, n_steps, loss, dice)
    _save(model, unet, spatial_dims, out / "weights" / "last.pt")
    seconds = time.perf_counter() - start
    family = "unet" if spatial_dims == 2 else "unet3d"
    record = {"data": data, "device": device, "seconds": seconds, "family": family,
              **dataclasses.asdict(settings), "unet": dataclasses.asdict(unet), "epochs": plan.epochs,
              "plan": plan.to_dict(), "steps_taken": n_steps, "images_seen": seen,
              "items_first": None if first is None else int(np.count_nonzero(first))}
    with atomic_file(out / "train.json") as staging:  # the experiment takes it as "this run is done"
        staging.write_text(json.dumps(record, indent=1))
    logger.info("trained a %dD U-Net on %s in %.0f s (%d steps, best val Dice %.3f)", spatial_dims, data, seconds,
                n_steps, best)
    return out / "weights" / "best.pt"


def evaluate_unet(weights: str | os.PathLike, data: str | os.PathLike, out: str | os.PathLike, *, imgsz: int,
                  device: str = "auto") -> dict:
    """Predict the test slices of the export `data` with the U-Net `weights` and score them.

    Writes ``out/pred/*.png`` (predicted label images) and ``out/scores.json``, as
    `training.evaluate.evaluate` does for the YOLO family.

    Returns
    -------
    dict
        `training.evaluate.score`'s figures plus ``mask_map50`` (None: a YOLO figure),
        ``n_pred_instances``, ``weights``, ``data``.
    """
    data, out = Path(data), Path(out).resolve()
    truth = data / "truth" / "test"
    if not truth.is_dir():
        raise FileNotFoundError(f"{truth} not found: give a `synthpack export-yolo` folder with test slices")
    model = load_model(weights, device)
    n_pred = predict_label_images(model, data / "images" / "test", out / "pred", imgsz=imgsz, device=device)
    scores = score(out / "pred", truth)
    scores.update(mask_map50=None, n_pred_instances=n_pred, weights=str(weights), data=str(data))
    write_scores(out, scores)
    return scores
