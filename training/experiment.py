"""The paper's augmentation experiment (section 4, Tables 1 and 2) with YOLOv8-seg and a U-Net, fully offline.

For every real scan of the config (by default the built-in ``large`` and
``small`` samples):

1. build a particle library from its TRAINING slices only (particles reaching
   the central 20% test block along ``axis`` are dropped, and the intensity
   statistics skip that block: `ParticleLibrary.from_scan(exclude_slices=...)`);
2. generate the synthetic packs from that library (`synthpack.generate_packs`),
   calibrated and, for the ``syn-rand`` arms, with ``postprocess: randomised``;
3. export the YOLO datasets that share the real scan's train/val/test slices and
   intensity window: ``<scan>`` (real only), ``<scan>+syn`` (real + the packs'
   post-processed tomograms), ``<scan>+syn-nopp`` (real + the packs' clean
   tomograms, the paper's "without post-processing" arm) and ``<scan>+syn-rand``
   (real + the randomised packs), with the truth label images of every split;
   arms that train on part of an export get a training list of their own
   (`training.arms`: packs alone, label budgets).

Then every arm (`training.arms.ARM_KINDS`) of every model family (``train.model_family``:
YOLOv8-seg, `training.train.train`, and/or a 2D U-Net on the border-core target,
`training.unet.train_unet`, whose arms the ``unet.arms`` section picks) is trained from
scratch once per seed, for the images seen its plan gives (`training.compute`: by default
the same images seen and steps for every arm of both families) with its learning curve on
the real val slices (`training.curves`), and scored on the test slices of EVERY real scan
(`training.evaluate.evaluate`, `training.unet.evaluate_unet`): foreground Dice,
matched-instance Dice and F1 at IoU 0.5, and (YOLO) Ultralytics' mask mAP50, with
per-slice foreground and instance counts. The run folder gets
``results.csv`` (one row per arm, seed and test set), ``results.json`` (with every
comparison), ``report.md`` (`training.report`: Tables 1 and 2 laid out as in the
paper with the paper's figures beside ours, the packs-alone and label-efficiency
tables, each comparison's paired difference with its bootstrap 95% interval, each arm's
epochs, images seen and steps, and the learning-curve table with its not-converged warning),
``dice.png``, ``learning_curves.png`` and ``label_efficiency.png``.

A ``real`` entry marked ``optional: true`` whose files are absent (the concrete
scan of the ``cpu`` config on a fresh clone) is left out with a logged message.

Each stage is skipped when its output is complete, so an interrupted run resumes (a
training done under another compute plan is refused).

Run from the checkout root::

    python -m training.experiment --config smoke --out runs/smoke     # minutes, CPU
    python -m training.experiment --config cpu --out runs/cpu         # hours on 2 cores
    python -m training.experiment --config paper --out runs/paper     # GPU
"""

from __future__ import annotations

import argparse
import csv
import functools
import io
import json
import logging
import os
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import yaml

from synthpack.pipeline.config import PackConfig
from synthpack.errors import SynthpackInputError
from synthpack.export.yolo import export_yolo
from synthpack.pipeline.generate import generate_packs
from synthpack.io import atomic_file, read_scan
from synthpack.library.core import ParticleLibrary
from synthpack.store.pack import find_packs
from synthpack.scan.samples import SAMPLE_NAMES, sample_scan
from synthpack.scan.core import Scan
from synthpack.scan.split import central_block

from .arms import ARM_KINDS, DEFAULT_KINDS, EXPORT_SUFFIXES, Arm, dataset_images, make_arms, subset_dataset
from .compute import ArmPlan, plan_compute
from .curves import CurveRecorder, read_curve
from .evaluate import evaluate, score, write_scores
from .offline import offline_ultralytics
from .report import compare_arms, report_markdown, save_chart, save_label_efficiency, save_learning_curves
from .train import TrainSettings, resolve_device, train
from .unet import UNetSettings, evaluate_unet, train_unet
from .unet3d import (KIND_VOLUMES, UNet3DSettings, arm_volumes, choose_seed_erosion, evaluate_unet3d, train_unet3d,
                     window_of)

logger = logging.getLogger("training.experiment")  # not __name__: "__main__" under python -m

CONFIG_DIR = Path(__file__).parent / "configs"

RESULT_COLUMNS = ("arm", "family", "train_scan", "kind", "budget", "seed", "test_set", "dice", "dice_mean_of_slices",
                  "instance_dice", "instance_f1", "mask_map50", "n_slices", "n_true", "n_pred", "n_matched",
                  "train_seconds", "epochs", "images_seen", "steps")
#: Per-slice counts of a score (`training.evaluate.score`), in the order of the experiment's count arrays:
#: foreground pixels (the Dice's), then instances (the F1's; `training.stats.pooled_dice` pools both).
SLICE_COUNTS = ("fg_intersection", "fg_pred", "fg_true", "n_matched", "n_pred", "n_true")
#: Splits of the exports with truth images: train for the U-Net's targets, val for the learning curves, test
#: for the scores.
TRUTH_SPLITS = ("train", "val", "test")
#: Relative paths of ``real:`` entries are taken from the checkout root.
CHECKOUT = Path(__file__).resolve().parents[1]


@dataclass(frozen=True)
class ExperimentConfig:
    """A parsed experiment config (see ``training/configs/*.yaml``).

    Attributes
    ----------
    name : str
    real : dict
        Scan name -> ``{"sample": "large", "seed": 0}`` or
        ``{"tomogram": path, "labels": path, "voxel_size": ..., "unit": ..., "optional": bool}``
        (relative paths from the checkout root). An ``optional`` entry whose files are
        absent is left out, with a logged message.
    axis : int
        Slicing axis of the split, the library's excluded block and the exports.
    n_packs : int
        Synthetic packs per real scan.
    packs : dict
        Scan name -> PackConfig of its packs (``syn-rand`` packs take it with
        ``postprocess: randomised``).
    train : TrainSettings
    seeds : list of int
        Training seeds; every arm is trained once per seed.
    conf : float
        Confidence threshold of the predicted instances.
    kinds : dict
        Arm kind (`training.arms.ARM_KINDS`) -> the real scans it is run for
        (config ``arms:``: a list of kinds for every scan, or kind -> ``all`` or a
        list of scans; default every kind but ``syn-first`` for every scan:
        `training.arms.DEFAULT_KINDS`).
    budgets : list of int
        The label budgets K of the ``budget`` arms (config ``budgets:``; ``all``, the
        whole training part, is the ``real`` and ``syn`` arms themselves).
    unet : training.unet.UNetSettings
        The U-Net family's network and optimizer (config ``unet:``).
    unet_kinds : dict
        The U-Net family's arms, as `kinds` (config ``unet.arms``; default `kinds`); run
        when ``train.model_family`` names ``unet``.
    unet3d : training.unet3d.UNet3DSettings
        The 3D U-Net family's network, patches and optimizer (config ``unet3d:``).
    unet3d_kinds : dict
        Its arms, as `kinds` (config ``unet3d.arms``; default `kinds` less ``budget``); run
        when ``train.model_family`` names ``unet3d``.
    imgsz_by_scan : dict
        Scan name -> YOLO's image size for the arms trained on that scan (config
        ``train.imgsz_by_scan``; their slices upscaled so that small grains span enough
        pixels), used in training and in every evaluation of those arms; other arms
        take ``train.imgsz``. The U-Net's training crops are ``train.imgsz`` for every scan.
    """

    name: str
    real: dict
    axis: int
    n_packs: int
    packs: dict
    train: TrainSettings
    seeds: list
    conf: float
    kinds: dict = field(default_factory=dict)
    budgets: list = field(default_factory=list)
    unet: UNetSettings = field(default_factory=UNetSettings)
    unet_kinds: dict = field(default_factory=dict)
    unet3d: UNet3DSettings = field(default_factory=UNet3DSettings)
    unet3d_kinds: dict = field(default_factory=dict)
    imgsz_by_scan: dict = field(default_factory=dict)

    @classmethod
    def load(cls, config: str | os.PathLike) -> ExperimentConfig:
        """Read a config: a name in ``training/configs`` (``smoke``, ``cpu``, ``paper``) or a YAML path."""
        path = Path(config)
        if not path.is_file():
            path = CONFIG_DIR / f"{config}.yaml"
        if not path.is_file():
            names = ", ".join(sorted(p.stem for p in CONFIG_DIR.glob("*.yaml")))
            raise SynthpackInputError(f"no experiment config {config}: give a YAML file or one of {names}")
        data = yaml.safe_load(path.read_text()) or {}
        synthetic = data.get("synthetic", {})
        common = PackConfig.from_dict(synthetic.get("pack", {}))
        listed = data.get("real", {"large": {"sample": "large"}, "small": {"sample": "small"}})
        per_scan = synthetic.get("scans", {})
        unknown = sorted(set(per_scan) - set(listed))
        if unknown:
            raise SynthpackInputError(f"synthetic.scans names unknown scans {unknown}: use names of 'real'")
        real = {name: spec for name, spec in listed.items() if _present(name, spec)}
        unet = dict(data.get("unet") or {})
        unet_arms = unet.pop("arms", data.get("arms"))
        unet3d = dict(data.get("unet3d") or {})
        explicit = "arms" in unet3d
        unet3d_kinds = _kinds(unet3d.pop("arms", data.get("arms")), list(listed), list(real))
        if not explicit:
            unet3d_kinds.pop("budget", None)  # label budgets of spread slices have no 3D form
        unknown_kinds = sorted(set(unet3d_kinds) - set(KIND_VOLUMES))
        if unknown_kinds:
            raise SynthpackInputError(f"unet3d.arms names {unknown_kinds}, which have no 3D form (label budgets are "
                                      f"slices spread over the volume): use {', '.join(KIND_VOLUMES)}")
        train = dict(data.get("train") or {})
        imgsz_by_scan = _imgsz_by_scan(train.pop("imgsz_by_scan", None) or {}, list(listed))
        kinds = _kinds(data.get("arms"), list(listed), list(real))
        settings = TrainSettings.from_dict(train)
        if "syn-first" in kinds and "yolo" in settings.families:
            raise SynthpackInputError("arms: syn-first orders the batches, which ultralytics draws itself for YOLO: "
                                      "list it under unet.arms or unet3d.arms instead")
        return cls(
            name=data.get("name", path.stem), real=real, axis=int(data.get("axis", 0)),
            n_packs=int(synthetic.get("n_packs", 1)),
            packs={name: common.replace(**per_scan.get(name, {})) for name in real},
            train=settings,
            seeds=[int(s) for s in data.get("seeds", [0])],
            conf=float(data.get("evaluate", {}).get("conf", 0.25)),
            kinds=kinds,
            budgets=_budgets(data.get("budgets", [])),
            unet=UNetSettings.from_dict(unet),
            unet_kinds=_kinds(unet_arms, list(listed), list(real)),
            unet3d=UNet3DSettings.from_dict(unet3d), unet3d_kinds=unet3d_kinds,
            imgsz_by_scan={name: size for name, size in imgsz_by_scan.items() if name in real},
        )

    def imgsz(self, arm: Arm) -> int:
        """The image size `arm` trains and is evaluated at: its scan's `imgsz_by_scan` for YOLO, else ``train.imgsz``."""
        return self.imgsz_by_scan.get(arm.scan, self.train.imgsz) if arm.family == "yolo" else self.train.imgsz

    @property
    def arm_list(self) -> list[Arm]:
        """Every arm: those of each model family of ``train.model_family``, scan by scan (`training.arms.make_arms`)."""
        kinds = {"yolo": self.kinds, "unet": self.unet_kinds, "unet3d": self.unet3d_kinds}
        return [arm for family in self.train.families for arm in make_arms(kinds[family], self.budgets, family)]

    @property
    def arms(self) -> list[str]:
        """Names of the arms, e.g. ``large``, ``large+syn``, ``large:syn``, ``large@5+syn``, ``unet_large``, ..."""
        return [arm.name for arm in self.arm_list]


def _imgsz_by_scan(value: dict, listed: list[str]) -> dict[str, int]:
    """``train.imgsz_by_scan``, checked: names of ``real`` to positive whole image sizes."""
    if not isinstance(value, dict):
        raise SynthpackInputError(f"train.imgsz_by_scan must map scan names to image sizes, got {value!r}")
    unknown = sorted(set(value) - set(listed))
    if unknown:
        raise SynthpackInputError(f"train.imgsz_by_scan names unknown scans {unknown}: use names of 'real'")
    bad = {name: size for name, size in value.items() if isinstance(size, bool) or not isinstance(size, int) or size < 32}
    if bad:
        raise SynthpackInputError(f"train.imgsz_by_scan needs whole image sizes of at least 32 px, got {bad}")
    return dict(value)


def _present(name: str, spec: dict) -> bool:
    """Whether a ``real`` entry is to be run: False (logged) for an ``optional`` one whose files are absent."""
    if not spec.get("optional"):
        return True
    missing = [str(_path(spec[key])) for key in ("tomogram", "labels") if key in spec and not _path(spec[key]).exists()]
    if missing:
        logger.warning("real scan %s skipped: %s not found (an optional entry; put the data there to include it)",
                       name, ", ".join(missing))
    return not missing


def _path(value: str) -> Path:
    """A ``real`` entry's path: relative ones from the checkout root."""
    path = Path(value).expanduser()
    return path if path.is_absolute() else CHECKOUT / path


def _kinds(value: list | dict | None, listed: list[str], present: list[str]) -> dict[str, list[str]]:
    """The config's ``arms`` as kind -> scans (those present), checked."""
    if value is None:
        value = list(DEFAULT_KINDS)
    if isinstance(value, list):
        value = {kind: "all" for kind in value}
    if not isinstance(value, dict):
        raise SynthpackInputError(f"arms must be a list of arm kinds or a mapping kind -> scans, got {value!r}")
    kinds = {}
    for kind, scans in value.items():
        if kind not in ARM_KINDS:
            raise SynthpackInputError(f"unknown arm kind {kind!r}: use {', '.join(ARM_KINDS)}")
        scans = listed if scans == "all" else list(scans)
        unknown = sorted(set(scans) - set(listed))
        if unknown:
            raise SynthpackInputError(f"arms.{kind} names unknown scans {unknown}: use names of 'real' or all")
        kinds[kind] = [scan for scan in scans if scan in present]
    return kinds


def _budgets(value: list) -> list[int]:
    """The config's ``budgets``: positive slice counts, ``all`` dropped (it is the ``real`` and ``syn`` arms)."""
    budgets = [k for k in value if k != "all"]
    if not all(isinstance(k, int) and not isinstance(k, bool) and k > 0 for k in budgets):
        raise SynthpackInputError(f"budgets must be positive numbers of real slices or all, got {value!r}")
    return sorted(set(budgets))


def read_real_scan(spec: dict) -> Scan:
    """The scan of a ``real`` entry: a built-in sample or a tomogram/labels pair."""
    if "sample" in spec:
        if spec["sample"] not in SAMPLE_NAMES:
            raise SynthpackInputError(f"unknown sample {spec['sample']!r}: use one of {', '.join(SAMPLE_NAMES)}")
        return sample_scan(spec["sample"], seed=int(spec.get("seed", 0)))
    if "tomogram" in spec and "labels" in spec:
        return read_scan(_path(spec["tomogram"]), _path(spec["labels"]), voxel_size=spec.get("voxel_size"),
                         unit=spec.get("unit"))
    raise SynthpackInputError(f"real scan entry {spec} needs 'sample: large|small' or 'tomogram' and 'labels'")


def _library(config: ExperimentConfig, name: str, scan: Scan, out: Path) -> ParticleLibrary:
    """The particle library of the training slices of `scan` (built once, then loaded)."""
    library_dir = out / "libraries" / name
    if (library_dir / "library.json").is_file():
        return ParticleLibrary.load(library_dir)
    block = central_block(scan.shape[config.axis])
    library = ParticleLibrary.from_scan(scan, **vars(config.packs[name].library), exclude_slices=block,
                                        axis=config.axis, progress=False)
    library.save(library_dir)
    return library


def prepare_data(config: ExperimentConfig, out: Path) -> dict[str, Path]:
    """Libraries, packs, YOLO exports and arm datasets of every real scan; returns arm -> ``data.yaml``.

    Exports (``data/<scan><suffix>``, `training.arms.EXPORT_SUFFIXES`) share the real
    scan's train/val/test slices and intensity window; only those some arm needs are made.
    """
    arms = config.arm_list
    data = {}
    for name, spec in config.real.items():
        own = [arm for arm in arms if arm.scan == name]
        needed = {arm.export for arm in own} | {"real"}  # every scan's real export holds its test slices
        scan = read_real_scan(spec)
        library = _library(config, name, scan, out)
        logger.info("%s: %d particles from the training slices", name, len(library))
        packs = {}
        if needed & {"syn", "syn-nopp"}:
            packs["calibrated"] = generate_packs(library, out / "packs" / name, config.n_packs, config.packs[name],
                                                 source=f"experiment scan {name}", progress=False)
        if "syn-rand" in needed:
            packs["randomised"] = generate_packs(
                library, out / "packs-randomised" / name, config.n_packs,
                config.packs[name].replace(postprocess="randomised"),
                source=f"experiment scan {name}, randomised", progress=False)
        options = {"real": dict(real=[scan], split="paper"),
                   "syn": dict(real=[scan], packs=packs.get("calibrated"), split="real-test"),
                   "syn-nopp": dict(real=[scan], packs=packs.get("calibrated"), split="real-test", postprocess=False),
                   "syn-rand": dict(real=[scan], packs=packs.get("randomised"), split="real-test")}
        exports = {}
        for export in sorted(needed):
            exports[export] = out / "data" / (name + EXPORT_SUFFIXES[export])
            if not (exports[export] / "export.json").is_file():
                export_yolo(exports[export], axis=config.axis, progress=False, truth_splits=TRUTH_SPLITS,
                            **options[export])
        data[name] = exports["real"] / "data.yaml"  # the test set of scan `name`
        for arm in own:
            if arm.whole_export:
                data[arm.name] = exports[arm.export] / "data.yaml"
            else:
                subset_dataset(exports[arm.export], out / "data" / arm.dataset, arm)
                data[arm.name] = out / "data" / arm.dataset / "data.yaml"
    return data


def _done(path: Path) -> dict | None:
    return json.loads(path.read_text()) if path.is_file() else None


def _scores(folder: Path, arm: Arm, weights: Path, test_data: Path, config: ExperimentConfig,
            config_dir: Path, test_scan: Callable[[], Scan], erosion: Callable[[], int]) -> dict:
    """The scores of `arm`'s `weights` on a test set: evaluated once, then read back.

    `test_scan()` is the test set's real scan (the 3D U-Net predicts its volume), `erosion()`
    the 3D U-Net's seed erosion chosen on its own val slices. Scores of an earlier run without
    the instance F1 or per-slice counts get them from its predictions.
    """
    scores = _done(folder / "scores.json")
    if scores is None and arm.family == "unet3d":
        return evaluate_unet3d(weights, test_scan(), test_data.parent, folder, patch=config.unet3d.patch,
                               erosion=erosion(), device=config.train.device)
    if scores is None and arm.family == "unet":
        return evaluate_unet(weights, test_data.parent, folder, imgsz=config.train.imgsz, device=config.train.device)
    if scores is None:
        return evaluate(weights, test_data.parent, folder, imgsz=config.imgsz(arm), conf=config.conf,
                        device=config.train.device, config_dir=config_dir)
    if "instance_f1" not in scores or any(key not in (scores.get("slices") or [{}])[0] for key in SLICE_COUNTS):
        again = score(folder / "pred", test_data.parent / "truth" / "test")
        scores.update(instance_f1=again["instance_f1"], slices=again["slices"])
        write_scores(folder, scores)
    return scores


def plan_arms(config: ExperimentConfig, out: Path) -> dict[str, ArmPlan]:
    """Every arm's epochs, images seen and steps (`training.compute.plan_compute`) from its dataset in `out`.

    Each model family is planned on its own: its arms take equal steps among themselves, the
    U-Net's budget ``unet.images_seen`` where given (`training.unet.UNetSettings`). The 3D
    U-Net's arms all take the plan of the largest one, in patches of ``unet3d.batch`` a step:
    its epochs are random patches, as many as that arm's training slices (`training.unet3d`).
    """
    plans: dict[str, ArmPlan] = {}
    for family in config.train.families:
        sizes = {arm.name: dataset_images(out / "data", arm.dataset)["train"]
                 for arm in config.arm_list if arm.family == family}
        settings = config.train
        own = {"unet": config.unet, "unet3d": config.unet3d}.get(family)
        if own is not None and own.images_seen is not None:
            settings = replace(settings, images_seen=own.images_seen)
        if family == "unet3d":  # random patches: every arm's epoch is the largest arm's training slices
            sizes = dict.fromkeys(sizes, max(sizes.values()))
            settings = replace(settings, batch=config.unet3d.batch)
        plans.update(plan_compute(settings, sizes))
    return {arm.name: plans[arm.name] for arm in config.arm_list}


def _trained(run: Path, plan: ArmPlan, imgsz: int) -> dict | None:
    """The ``train.json`` of a finished training, or None; refused if it followed another plan or image size.

    A record from before the compute plans counts as ``fixed_epochs`` with its epochs.
    """
    record = _done(run / "train.json")
    if record is None:
        return None
    recorded = record.get("plan") or {"compute": "fixed_epochs", "epochs": record["epochs"]}
    wanted = plan.to_dict()
    if any(recorded[key] != wanted[key] for key in ("compute", "epochs", "images") if key in recorded):
        raise SynthpackInputError(
            f"{run} was trained with {recorded['compute']} for {recorded['epochs']} epochs, this config plans "
            f"{plan.compute} for {plan.epochs}: give a new --out folder (or delete that run)")
    if record.get("imgsz", imgsz) != imgsz:
        raise SynthpackInputError(f"{run} was trained at {record['imgsz']} px, this config trains it at {imgsz} px: "
                                  "give a new --out folder (or delete that run)")
    return record


def run_arms(config: ExperimentConfig, out: Path, data: dict[str, Path],
             plans: dict[str, ArmPlan]) -> tuple[list[dict], dict, dict]:
    """Train every arm once per seed, as long as its plan says, and score it on every real scan's test slices.

    Returns
    -------
    rows : list of dict
        One per arm, seed and test set (`RESULT_COLUMNS`).
    slices : dict
        ``(arm, seed, test set)`` -> per-slice counts `SLICE_COUNTS` (foreground pixels in both,
        predicted, true; instances matched, predicted, true), int64 (N, 6), slices in name
        order (for `training.stats.paired_bootstrap`).
    curves : dict
        Arm -> seed -> its learning curve (`training.curves.CurveRecorder` points; None for
        a run trained without one).
    """
    rows, slices, curves = [], {}, {}
    config_dir = out / "ultralytics"
    device = resolve_device(config.train.device)
    scans = functools.cache(lambda name: read_real_scan(config.real[name]))  # for the 3D U-Net
    for arm in config.arm_list:
        plan = plans[arm.name]
        for seed in config.seeds:
            run = out / "runs" / arm.name / f"seed{seed}"
            record = _trained(run, plan, config.imgsz(arm))
            if record is None:
                start = time.perf_counter()
                logger.info("training %s, seed %d: %d epochs of %d images (%d images seen)", arm.name, seed,
                            plan.epochs, plan.images, plan.images_seen)
                settings = TrainSettings(**{**vars(config.train), "seed": seed, "imgsz": config.imgsz(arm)})
                if arm.family == "unet":
                    train_unet(data[arm.name], run, settings, config.unet, plan, packs_first=arm.packs_first)
                elif arm.family == "unet3d":
                    export = data[arm.scan].parent
                    folder = out / ("packs-randomised" if arm.kind == "syn-rand" else "packs") / arm.scan
                    packs = find_packs(folder) if folder.is_dir() else []
                    volumes = arm_volumes(arm.kind, scans(arm.scan), packs, window_of(export))
                    train_unet3d(volumes, export, scans(arm.scan), run, settings, config.unet3d, plan,
                                 packs_first=arm.packs_first)
                else:
                    recorder = CurveRecorder(run, data[arm.name], batch=config.train.batch,
                                             imgsz=config.imgsz(arm), conf=config.conf, device=device)
                    train(data[arm.name], run, settings, config_dir=config_dir, plan=plan,
                          callbacks=recorder.callbacks)
                record = _done(run / "train.json")
                logger.info("trained %s in %.0f s", arm.name, time.perf_counter() - start)
            curves.setdefault(arm.name, {})[seed] = read_curve(run)
            erosion = functools.cache(lambda: choose_seed_erosion(  # noqa: B023 (called within this iteration)
                run / "weights" / "best.pt", scans(arm.scan), data[arm.scan].parent, out / "eval" / arm.name /
                f"seed{seed}", patch=config.unet3d.patch, device=config.train.device))
            for test_set in config.real:
                scores = _scores(out / "eval" / arm.name / f"seed{seed}" / test_set, arm,
                                 run / "weights" / "best.pt", data[test_set], config, config_dir,
                                 functools.partial(scans, test_set), erosion)
                slices[(arm.name, seed, test_set)] = np.array(
                    [[s[key] for key in SLICE_COUNTS] for s in scores["slices"]], dtype=np.int64)
                rows.append({"arm": arm.name, "family": arm.family, "train_scan": arm.scan, "kind": arm.description,
                             "budget": arm.real_slices or "", "seed": seed,
                             "test_set": test_set, "train_seconds": round(record["seconds"], 1),
                             "epochs": plan.epochs, "images_seen": plan.images_seen, "steps": round(plan.steps, 1),
                             **{key: scores[key] for key in RESULT_COLUMNS if key in scores}})
                logger.info("%s seed %d on %s: Dice %.3f, F1@0.5 %.3f", arm.name, seed, test_set, scores["dice"],
                            scores["instance_f1"])
    return rows, slices, curves


def write_results(config: ExperimentConfig, rows: list[dict], slices: dict, curves: dict,
                  plans: dict[str, ArmPlan], out: Path, seconds: float, device: str) -> None:
    """``results.csv``, ``results.json``, ``report.md`` and the charts (``dice.png``, ``learning_curves.png``,
    ``label_efficiency.png``) in `out`."""
    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=RESULT_COLUMNS, lineterminator="\n")
    writer.writeheader()
    writer.writerows(rows)
    comparisons = compare_arms(config, slices)
    texts = {
        "results.csv": buffer.getvalue(),
        "results.json": json.dumps({"config": config.name, "rows": rows, "seconds": seconds,
                                    "compute": {arm: plan.to_dict() for arm, plan in plans.items()},
                                    "curves": {arm: {str(seed): curve for seed, curve in by_seed.items()}
                                               for arm, by_seed in curves.items()},
                                    "comparisons": [c.to_dict() for c in comparisons]}, indent=1),
        "report.md": report_markdown(config, rows, comparisons, out, seconds, device, plans, curves),
    }
    for name, text in texts.items():
        with atomic_file(out / name) as staging:
            staging.write_text(text)
    with atomic_file(out / "dice.png") as staging:
        save_chart(config, rows, plans, staging)
    with atomic_file(out / "learning_curves.png") as staging:
        save_learning_curves(config, curves, plans, staging)
    if config.budgets:
        with atomic_file(out / "label_efficiency.png") as staging:
            save_label_efficiency(config, rows, out, staging)


def run(config: str | os.PathLike | ExperimentConfig, out: str | os.PathLike) -> list[dict]:
    """Run the whole experiment into `out` and return its result rows."""
    config = config if isinstance(config, ExperimentConfig) else ExperimentConfig.load(config)
    out = Path(out).resolve()
    out.mkdir(parents=True, exist_ok=True)
    offline_ultralytics(out / "ultralytics")
    start = time.perf_counter()
    data = prepare_data(config, out)
    plans = plan_arms(config, out)
    rows, slices, curves = run_arms(config, out, data, plans)
    seconds = time.perf_counter() - start
    write_results(config, rows, slices, curves, plans, out, seconds, resolve_device(config.train.device))
    logger.info("report in %s (%.1f min)", out / "report.md", seconds / 60)
    return rows


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", default="smoke", help="smoke, cpu, paper, or a YAML file (default smoke)")
    parser.add_argument("--out", required=True, help="run folder (reports, exports, weights)")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s", datefmt="%H:%M:%S")
    try:
        run(args.config, args.out)
    except (SynthpackInputError, FileNotFoundError, ValueError) as error:
        print(f"experiment: error: {error}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
