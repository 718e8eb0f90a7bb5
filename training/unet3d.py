"""The experiment's third model family: a MONAI 3D U-Net on `PatchDataset` patches of the border-core target.

The 2D U-Net (`training.unet`) sees one slice at a time; ParticleSeg3D and nnU-Net segment
grains in 3D. This family trains the same network in 3D on the volumes the 2D arms slice, so
it runs the same arms on the same splits and is scored by the same per-slice statistics:

Volumes
    An arm's training volumes (`arm_volumes`): the real scan's training slices (its
    ``PatchDataset(split="train")`` with the export's ``val_fraction``: the test block and
    the val slices next to it are never in a patch) for the kinds with real slices, and the
    packs' tomograms whole (calibrated, randomised, or the clean volumes for ``syn-nopp``)
    for the kinds with packs. Label budgets (K real slices spread over the volume) have no
    3D form: the family refuses ``budget`` arms. Grey values are mapped by the real scan's
    export window (``export.json``: ``window``) to [0, 1], as the slices' 8-bit images are;
    the border-core target (`synthpack.export.nnunet.semantic_target`, 6-neighbours) is
    made on each whole volume, then cut with its patches.
Patches and compute
    Every 3D arm takes the plan of the family's largest arm (`training.experiment.plan_arms`,
    in ``unet3d.batch`` patches a step): an epoch is as many random patches
    (``UNet3DSettings.patch``) as that arm's training slices (after Ultralytics'
    ``fraction``), each volume's share in proportion to its training slices, so every 3D
    arm sees the same patches in the same steps and validates at the same steps. Patch
    origins are `PatchDataset`'s ``"random"`` draws (seeded by the training's data stream and the
    epoch); each patch is flipped along each axis and its in-slice axes swapped at random.
Prediction and scores
    A split's block of slices is predicted with half a patch of context on each side (the
    neighbouring slices' grey values only) by ``monai.inferers.sliding_window_inference``,
    the most probable class per voxel, instances by `recover_instances` in 3D: the
    nnU-Net export's `instances_from_target`, or seeds from the predicted interior eroded
    by 1-3 voxels where that scores a better F1@0.5 on the arm's own val slices
    (`choose_seed_erosion`: model selection, never the test slices); each
    slice of the block is then cut into its instances' 4-connected parts, as the exports'
    truth images are (`synthpack.export.yolo.slice_polygons`), written as label images of the
    export's slice names and scored by `training.evaluate.score` against the export's truth:
    the same foreground Dice, instance F1 and per-slice counts as the other families.
"""

from __future__ import annotations

import json
import logging
import math
import os
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy import ndimage

from synthpack.dataset.patches import PatchDataset
from synthpack.errors import SynthpackInputError
from synthpack.export.nnunet import instances_from_target, semantic_target
from synthpack.export.yolo import slice_polygons
from synthpack.io import atomic_file, write_label_image
from synthpack.scan.core import Scan
from synthpack.scan.split import slice_splits
from synthpack.store.pack import open_pack

from .compute import ArmPlan
from .evaluate import score, write_scores
from .train import TrainSettings
from .unet import WINDOW_OVERLAP, UNetSettings, _torch_device, fit, load_model

logger = logging.getLogger(__name__)

__all__ = ["KIND_VOLUMES", "SEED_EROSIONS", "UNet3DSettings", "Volume", "arm_volumes", "choose_seed_erosion",
           "evaluate_unet3d", "predict_block", "predict_split", "recover_instances", "train_unet3d", "window_of"]

#: Arm kinds of the 3D family and which volumes they train on: (real training slices, pack volumes' kind).
KIND_VOLUMES = {"real": (True, None), "syn": (True, "tomogram"), "syn-nopp": (True, "clean"),
                "syn-only": (False, "tomogram"), "syn-rand": (False, "tomogram"), "syn-first": (True, "tomogram")}
_SLICE_NAME = re.compile(r"_a(\d)_s(\d+)$")
#: Seed erosions tried on each arm's val slices (`choose_seed_erosion`), voxels; 0 is the nnU-Net export's recovery.
SEED_EROSIONS = (0, 1, 2, 3)
_FACES = ndimage.generate_binary_structure(3, 1)


@dataclass(frozen=True)
class UNet3DSettings(UNetSettings):
    """The 3D U-Net family's network, patches and compute (a config's ``unet3d:`` section but ``arms``).

    Attributes
    ----------
    patch : tuple of 3 int
        ``(D, H, W)`` voxels of a training patch and of a prediction window, each a multiple
        of the strides' product and no larger than the thinnest training block (the real
        scan's training slices on either side of its val and test slices) or volume.
    batch : int
        Patches per optimizer step.

    The rest as `training.unet.UNetSettings` (``images_seen`` counts patches here).
    """

    channels: tuple = (8, 16, 32, 64)
    patch: tuple = (24, 48, 48)
    batch: int = 2

    def __post_init__(self):
        super().__post_init__()
        factor = math.prod(self.strides)
        if (len(self.patch) != 3 or not all(isinstance(v, int) and not isinstance(v, bool) and v > 0 and v % factor == 0
                                            for v in self.patch)):
            raise SynthpackInputError(f"unet3d.patch must be 3 positive multiples of {factor} (the product of "
                                      f"unet3d.strides), got {self.patch!r}")
        if isinstance(self.batch, bool) or not isinstance(self.batch, int) or self.batch < 1:
            raise SynthpackInputError(f"unet3d.batch must be a positive number of patches, got {self.batch!r}")


@dataclass(frozen=True)
class Volume:
    """One training volume of a 3D arm.

    Attributes
    ----------
    scan : Scan
        Grey values mapped to [0, 1] (float32) and the instance labels.
    split : {"train", "all"}
        The slices patches come from: the real scan's training slices, or all of a pack's.
    """

    scan: Scan
    split: str


def window_of(export: str | os.PathLike) -> tuple[float, float]:
    """The intensity window ``(lo, hi)`` of an export (its ``export.json``), grey values mapped to [0, 1] by it."""
    lo, hi = json.loads((Path(export) / "export.json").read_text())["window"]
    return float(lo), float(hi)


def _scaled(tomogram: np.ndarray, window: tuple[float, float]) -> np.ndarray:
    """`tomogram` mapped by `window` to [0, 1], float32."""
    lo, hi = window
    return np.clip((np.asarray(tomogram, np.float32) - lo) / (hi - lo), 0.0, 1.0)


def arm_volumes(kind: str, scan: Scan, packs: list[str | os.PathLike], window: tuple[float, float]) -> list[Volume]:
    """The training volumes of a 3D arm of `kind` (`KIND_VOLUMES`): the real `scan`'s and/or the `packs`'.

    Parameters
    ----------
    kind : str
        A key of `KIND_VOLUMES`.
    scan : Scan
        The arm's real scan.
    packs : list of path-like
        Its pack folders (calibrated, or randomised for ``syn-rand``).
    window : (float, float)
        The real scan's export window.
    """
    if kind not in KIND_VOLUMES:
        raise SynthpackInputError(f"the 3D U-Net has no {kind!r} arms (label budgets of spread slices have no 3D "
                                  f"form): give unet3d.arms of {', '.join(KIND_VOLUMES)}")
    real, volume = KIND_VOLUMES[kind]
    if volume and not packs:
        raise FileNotFoundError(f"a 3D {kind!r} arm trains on packs, and none were given")
    volumes = [Volume(Scan(_scaled(scan.tomogram, window), scan.labels, source=scan.source), "train")] if real else []
    for folder in packs if volume else []:
        pack = open_pack(folder)
        grey = pack.clean if volume == "clean" else pack.tomogram
        volumes.append(Volume(Scan(_scaled(grey[:], window), np.asarray(pack.labels[:]), source=str(folder)), "all"))
    return volumes


def _shares(total: int, weights: list[int]) -> list[int]:
    """`total` split in proportion to `weights` (largest remainders), each share at least 1."""
    exact = np.asarray(weights, float) * total / sum(weights)
    shares = np.floor(exact).astype(int)
    shares[np.argsort(shares - exact, kind="stable")[:total - shares.sum()]] += 1
    return np.maximum(shares, 1).tolist()


class _Patches:
    """Random border-core patches of an arm's volumes: `per_epoch` an epoch (default: as many as the arm's training
    slices), each volume's share in proportion to its training slices."""

    def __init__(self, volumes: list[Volume], settings: UNet3DSettings, axis: int, val_fraction: float, seed: int,
                 per_epoch: int | None = None):
        slices = [len(slice_splits(v.scan.shape[axis], val_fraction)["train"]) if v.split == "train"
                  else v.scan.shape[axis] for v in volumes]
        self.sets = [PatchDataset(v.scan, settings.patch, split=v.split, axis=axis, val_fraction=val_fraction,
                                  seed=seed, patches_per_volume=n)
                     for v, n in zip(volumes, _shares(per_epoch or sum(slices), slices))]
        self.targets = [semantic_target(v.scan.labels) for v in volumes]
        self.offsets = np.cumsum([0] + [len(s) for s in self.sets])
        #: bool (len(self),): the items cut from a pack (a volume of split "all"), for a packs-first order
        self.synthetic = np.repeat([v.split == "all" for v in volumes], [len(s) for s in self.sets])
        for patches in self.sets:
            thinnest, shape = int(np.min(np.diff(patches.blocks(0), axis=1))), patches.volumes.volume_shapes()[0]
            if thinnest < settings.patch[axis] or any(n < p for n, p in zip(shape, settings.patch)):
                raise SynthpackInputError(
                    f"unet3d.patch {settings.patch} does not fit {patches.volumes.describe_source()} (shape "
                    f"{shape}, training blocks {thinnest} slices thick along axis {axis}): lower unet3d.patch")

    def __len__(self) -> int:
        return int(self.offsets[-1])

    def batch(self, indices, epochs, generator):
        """Patches `indices` of `epochs` as (x, y), float32 and int64 (B, 1, D, H, W), flipped at random."""
        import torch

        xs, ys = [], []
        for index, epoch in zip(indices.tolist(), epochs.tolist()):
            k = int(np.searchsorted(self.offsets, index, side="right")) - 1
            patches = self.sets[k]
            patches.set_epoch(epoch)
            item = patches[index - int(self.offsets[k])]
            box = tuple(slice(o, o + n) for o, n in zip(item["origin"].tolist(), item["extent"].tolist()))
            x, y = item["image"][0], torch.from_numpy(self.targets[k][box].astype(np.int64))
            flips = [axis for axis in range(3) if int(torch.randint(2, (1,), generator=generator))]
            swap = int(torch.randint(2, (1,), generator=generator)) and x.shape[1] == x.shape[2]
            x, y = (a.flip(flips) if flips else a for a in (x, y))
            x, y = (a.transpose(1, 2) if swap else a for a in (x, y))
            xs.append(x.contiguous())
            ys.append(y.contiguous())
        return torch.stack(xs)[:, None], torch.stack(ys)[:, None]


def recover_instances(target: np.ndarray, erosion: int = 0) -> np.ndarray:
    """Instance labels of a predicted border-core volume, from its interior eroded by `erosion` voxels.

    Parameters
    ----------
    target : ndarray of int, shape (Z, Y, X)
        0 background, 1 grain interior, 2 boundary.
    erosion : int
        0: `instances_from_target` (the 6-connected interior components grown over the
        boundary; exact on a clean target). Above 0: the interior eroded `erosion` times by
        the 6-neighbourhood, so that a boundary missed by a voxel or two between grains
        that share broad faces does not join them; its 6-connected components grown over
        the grain voxels by watershed of the negated distance to the background; grain
        voxels no seed reaches become instances of their own.

    Returns
    -------
    ndarray of int32, shape (Z, Y, X)
    """
    from skimage.segmentation import watershed

    if not erosion:
        return instances_from_target(target)
    grain = target > 0
    seeds, n_seeds = ndimage.label(ndimage.binary_erosion(target == 1, _FACES, iterations=erosion), _FACES)
    grown = watershed(-ndimage.distance_transform_edt(grain), seeds, mask=grain).astype(np.int32)
    rest, _ = ndimage.label(grain & (grown == 0), _FACES)
    grown[rest > 0] = rest[rest > 0] + n_seeds
    return grown


def predict_block(model, image: np.ndarray, block: tuple[int, int], *, patch: tuple, axis: int = 0,
                  device: str = "cpu", erosion: int = 0) -> np.ndarray:
    """3D instance labels of the slices ``block`` = ``[start, stop)`` along `axis` of a [0, 1] grey volume.

    The block is predicted with half a patch depth of neighbouring slices on each side
    (clipped to the volume), by sliding windows of `patch` (overlap `WINDOW_OVERLAP`,
    Gaussian blending); instances by `recover_instances` (`erosion`) on the predicted slab.

    Returns
    -------
    ndarray of int32, the block's shape
    """
    import torch
    from monai.inferers import sliding_window_inference

    start, stop = block
    context = patch[axis] // 2
    lo, hi = max(start - context, 0), min(stop + context, image.shape[axis])
    slab = np.moveaxis(np.moveaxis(image, axis, 0)[lo:hi], 0, axis)
    with torch.no_grad():
        x = torch.as_tensor(np.ascontiguousarray(slab), dtype=torch.float32)[None, None].to(_torch_device(device))
        logits = sliding_window_inference(x, roi_size=tuple(patch), sw_batch_size=4, predictor=model,
                                          overlap=WINDOW_OVERLAP, mode="gaussian")
    labels = recover_instances(logits.argmax(dim=1)[0].cpu().numpy().astype(np.uint8), erosion)
    return np.moveaxis(np.moveaxis(labels, axis, 0)[start - lo:stop - lo], 0, axis)


def predict_split(model, image: np.ndarray, truth: Path, out: Path, *, patch: tuple, min_area: int,
                  device: str = "cpu", erosion: int = 0) -> int:
    """Predict the slices whose truth images are in `truth` and write their label images to `out`.

    The truth images' names (``<source>_a<axis>_s<index>.png``) give the slices; each
    contiguous run is one `predict_block`; each predicted slice is cut into its instances'
    4-connected parts (`slice_polygons`, parts of fewer than `min_area` pixels kept as the
    truth keeps them). Returns the number of parts written.
    """
    names = sorted(path.stem for path in Path(truth).glob("*.png"))
    if not names:
        raise FileNotFoundError(f"no truth images in {truth}")
    found = [_SLICE_NAME.search(name) for name in names]
    if not all(found) or len({int(m.group(1)) for m in found}) != 1:
        raise SynthpackInputError(f"{truth}: truth images must be named <source>_a<axis>_s<index>.png, one axis")
    axis, indices = int(found[0].group(1)), np.array([int(m.group(2)) for m in found])
    by_index = dict(zip(indices.tolist(), names))
    out.mkdir(parents=True, exist_ok=True)
    total = 0
    ordered = np.sort(indices)
    runs = np.split(ordered, np.flatnonzero(np.diff(ordered) != 1) + 1)
    for run in runs:
        block = predict_block(model, image, (int(run[0]), int(run[-1]) + 1), patch=patch, axis=axis, device=device,
                              erosion=erosion)
        for offset, index in enumerate(run.tolist()):
            parts = slice_polygons(np.take(block, offset, axis=axis), min_area=min_area).parts
            total += int(parts.max(initial=0))
            write_label_image(out / by_index[index], parts)
    return total


def _export_settings(export: Path) -> dict:
    return json.loads((export / "export.json").read_text())["settings"]


def train_unet3d(volumes: list[Volume], export: str | os.PathLike, scan: Scan, out: str | os.PathLike,
                 settings: TrainSettings, unet3d: UNet3DSettings, plan: ArmPlan, *, packs_first: bool = False) -> Path:
    """Train a 3D U-Net from scratch on `volumes` for `plan`'s patches seen; return its best weights.

    Parameters
    ----------
    volumes : list of Volume
        `arm_volumes` of the arm.
    export : path-like
        The real scan's export folder: its ``val_fraction``, window and ``truth/val`` images
        (the validation's slices).
    scan : Scan
        The real scan (its val slices are predicted from its grey values).
    out : path-like
        Run folder, as `training.unet.train_unet`'s.
    settings : TrainSettings
        ``device``, ``seed``, ``options["val"]``.
    unet3d : UNet3DSettings
    plan : training.compute.ArmPlan
        Planned with ``unet3d.batch`` patches a step; its ``images`` are the patches of an
        epoch.
    packs_first : bool
        Train on the packs' patches first, then on the real scan's (`training.unet.item_order`; a
        ``syn-first`` arm).
    """
    export, out = Path(export), Path(out).resolve()
    options = _export_settings(export)
    axis, val_fraction = options["axis"], options["val_fraction"]
    data_seed = int(np.random.SeedSequence(settings.seed).spawn(3)[2].generate_state(1)[0])
    patches = _Patches(volumes, unet3d, axis, val_fraction, data_seed, per_epoch=plan.images)
    image = _scaled(scan.tomogram, window_of(export))
    device = _torch_device(settings.device)

    def validate(model) -> float:
        predict_split(model, image, export / "truth" / "val", out / "curve_pred", patch=unet3d.patch,
                      min_area=options["min_area"], device=device)
        return score(out / "curve_pred", export / "truth" / "val")["dice"]

    return fit(out, settings, unet3d, plan, spatial_dims=3, batch_of=patches.batch, validate=validate,
               data=", ".join(v.scan.source for v in volumes), first=patches.synthetic if packs_first else None)


def choose_seed_erosion(weights: str | os.PathLike, scan: Scan, export: str | os.PathLike, out: str | os.PathLike, *,
                        patch: tuple, device: str = "auto") -> int:
    """The `SEED_EROSIONS` value whose instances score the best F1@0.5 on the val slices of the arm's own scan.

    Model selection, not a test figure: `scan` and `export` are the arm's training scan and its
    export (``truth/val``). The choice and every erosion's val F1 are kept in
    ``out/seed_erosion.json`` and read back from there.
    """
    out = Path(out)
    if (out / "seed_erosion.json").is_file():
        return int(json.loads((out / "seed_erosion.json").read_text())["erosion"])
    export = Path(export)
    model, truth = load_model(weights, device), export / "truth" / "val"
    image, min_area = _scaled(scan.tomogram, window_of(export)), _export_settings(export)["min_area"]
    val_f1 = {}
    for erosion in SEED_EROSIONS:
        predict_split(model, image, truth, out / f"val_erosion{erosion}", patch=patch, min_area=min_area,
                      device=device, erosion=erosion)
        val_f1[erosion] = score(out / f"val_erosion{erosion}", truth)["instance_f1"]
    chosen = max(SEED_EROSIONS, key=lambda erosion: (val_f1[erosion], -erosion))
    with atomic_file(out / "seed_erosion.json") as staging:
        staging.write_text(json.dumps({"erosion": chosen, "val_f1": val_f1}, indent=1))
    logger.info("seed erosion %d voxels chosen on the val slices (F1@0.5 by erosion: %s)", chosen,
                {k: round(v, 3) for k, v in val_f1.items()})
    return chosen


def evaluate_unet3d(weights: str | os.PathLike, scan: Scan, export: str | os.PathLike, out: str | os.PathLike, *,
                    patch: tuple, erosion: int = 0, device: str = "auto") -> dict:
    """Predict the test slices of the real `scan` (those of its `export`) with a 3D U-Net and score them.

    Instances by `recover_instances` with `erosion` (`choose_seed_erosion`). Writes
    ``out/pred/*.png`` and ``out/scores.json`` as `training.unet.evaluate_unet` does.
    """
    export, out = Path(export), Path(out).resolve()
    truth = export / "truth" / "test"
    model = load_model(weights, device)
    n_pred = predict_split(model, _scaled(scan.tomogram, window_of(export)), truth, out / "pred", patch=patch,
                           min_area=_export_settings(export)["min_area"], device=device, erosion=erosion)
    scores = score(out / "pred", truth)
    scores.update(mask_map50=None, n_pred_instances=n_pred, weights=str(weights), data=str(export),
                  seed_erosion=erosion)
    write_scores(out, scores)
    return scores
