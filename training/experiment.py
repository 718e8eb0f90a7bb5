"""The paper's augmentation experiment (section 4, Tables 1 and 2) with YOLOv8-seg, fully offline.

For every real scan of the config (by default the built-in ``large`` and
``small`` samples):

1. build a particle library from its TRAINING slices only (particles reaching
   the central 20% test block along ``axis`` are dropped, and the intensity
   statistics skip that block: `ParticleLibrary.from_scan(exclude_slices=...)`);
2. generate the synthetic packs from that library (`synthpack.generate_packs`);
3. export three YOLO datasets that share the real scan's train/val/test slices
   and intensity window: ``<scan>`` (real only), ``<scan>+syn`` (real + the packs'
   post-processed tomograms) and ``<scan>+syn-nopp`` (real + the packs' clean
   tomograms, the paper's "without post-processing" arm).

Then every arm is trained from scratch once per seed (`training.train.train`)
and scored on the test slices of EVERY real scan (`training.evaluate.evaluate`):
foreground Dice, matched-instance Dice and Ultralytics' mask mAP50. The run folder gets
``results.csv`` (one row per arm, seed and test set), ``results.json``,
``report.md`` (Tables 1 and 2 laid out as in the paper, the paper's figures beside
ours) and ``dice.png``.

Each stage is skipped when its output is complete, so an interrupted run resumes.

Run from the checkout root::

    python -m training.experiment --config smoke --out runs/smoke     # minutes, CPU
    python -m training.experiment --config cpu --out runs/cpu         # under an hour on 2 cores
    python -m training.experiment --config paper --out runs/paper     # GPU
"""

from __future__ import annotations

import argparse
import csv
import io
import json
import logging
import os
import platform
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

from synthpack import __version__
from synthpack.config import PackConfig
from synthpack.errors import SynthpackInputError
from synthpack.export.yolo import export_yolo
from synthpack.generate import generate_packs
from synthpack.io import atomic_file, read_scan
from synthpack.library import ParticleLibrary
from synthpack.samples import SAMPLE_NAMES, sample_scan
from synthpack.scan import Scan
from synthpack.split import central_block

from .evaluate import evaluate
from .offline import offline_ultralytics
from .train import TrainSettings, resolve_device, train

logger = logging.getLogger("training.experiment")  # not __name__: "__main__" under python -m

CONFIG_DIR = Path(__file__).parent / "configs"

#: The paper's Dice scores (%), by training set, then test set (Tables 1 and 2).
PAPER_DICE = {
    "large": {"large": 94.5, "small": 77.0},
    "large+syn": {"large": 96.0, "small": 80.1},
    "large+syn-nopp": {"large": 94.9, "small": 76.9},
    "small": {"large": 92.4, "small": 90.1},
    "small+syn": {"large": 94.8, "small": 90.9},
    "small+syn-nopp": {"large": 92.4, "small": 88.8},
}

#: Arm suffixes: real only, real + synthetic, real + synthetic without post-processing.
ARM_KINDS = {"": "real only", "+syn": "real + synthetic", "+syn-nopp": "real + synthetic w/o post-processing"}
RESULT_COLUMNS = ("arm", "train_scan", "kind", "seed", "test_set", "dice", "dice_mean_of_slices", "instance_dice",
                  "mask_map50", "n_slices", "n_true", "n_pred", "n_matched", "train_seconds")


@dataclass(frozen=True)
class ExperimentConfig:
    """A parsed experiment config (see ``training/configs/*.yaml``).

    Attributes
    ----------
    name : str
    real : dict
        Scan name -> ``{"sample": "large", "seed": 0}`` or
        ``{"tomogram": path, "labels": path, "voxel_size": ..., "unit": ...}``.
    axis : int
        Slicing axis of the split, the library's excluded block and the exports.
    n_packs : int
        Synthetic packs per real scan.
    packs : dict
        Scan name -> PackConfig of its packs.
    train : TrainSettings
    seeds : list of int
        Training seeds; every arm is trained once per seed.
    conf : float
        Confidence threshold of the predicted instances.
    """

    name: str
    real: dict
    axis: int
    n_packs: int
    packs: dict
    train: TrainSettings
    seeds: list
    conf: float

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
        real = data.get("real", {"large": {"sample": "large"}, "small": {"sample": "small"}})
        per_scan = synthetic.get("scans", {})
        unknown = sorted(set(per_scan) - set(real))
        if unknown:
            raise SynthpackInputError(f"synthetic.scans names unknown scans {unknown}: use names of 'real'")
        return cls(
            name=data.get("name", path.stem), real=real, axis=int(data.get("axis", 0)),
            n_packs=int(synthetic.get("n_packs", 1)),
            packs={name: common.replace(**per_scan.get(name, {})) for name in real},
            train=TrainSettings.from_dict(data.get("train", {})),
            seeds=[int(s) for s in data.get("seeds", [0])],
            conf=float(data.get("evaluate", {}).get("conf", 0.25)),
        )

    @property
    def arms(self) -> list[str]:
        """Training sets, e.g. ``large``, ``large+syn``, ``large+syn-nopp``, ``small``, ..."""
        return [name + kind for name in self.real for kind in ARM_KINDS]

    def arm_parts(self, arm: str) -> tuple[str, str]:
        """``(real scan name, kind)`` of an arm, e.g. ``("large", "real + synthetic")``."""
        for name in self.real:
            for suffix, kind in ARM_KINDS.items():
                if arm == name + suffix:
                    return name, kind
        raise KeyError(arm)


def read_real_scan(spec: dict) -> Scan:
    """The scan of a ``real`` entry: a built-in sample or a tomogram/labels pair."""
    if "sample" in spec:
        if spec["sample"] not in SAMPLE_NAMES:
            raise SynthpackInputError(f"unknown sample {spec['sample']!r}: use one of {', '.join(SAMPLE_NAMES)}")
        return sample_scan(spec["sample"], seed=int(spec.get("seed", 0)))
    if "tomogram" in spec and "labels" in spec:
        return read_scan(spec["tomogram"], spec["labels"], voxel_size=spec.get("voxel_size"), unit=spec.get("unit"))
    raise SynthpackInputError(f"real scan entry {spec} needs 'sample: large|small' or 'tomogram' and 'labels'")


def prepare_data(config: ExperimentConfig, out: Path) -> dict[str, Path]:
    """Libraries, packs and YOLO exports of every real scan; returns arm -> export folder."""
    exports = {}
    for name, spec in config.real.items():
        scan = read_real_scan(spec)
        library_dir = out / "libraries" / name
        if (library_dir / "library.json").is_file():
            library = ParticleLibrary.load(library_dir)
        else:
            block = central_block(scan.shape[config.axis])
            library = ParticleLibrary.from_scan(scan, **vars(config.packs[name].library), exclude_slices=block,
                                                axis=config.axis, progress=False)
            library.save(library_dir)
        logger.info("%s: %d particles from the training slices", name, len(library))
        packs = generate_packs(library, out / "packs" / name, config.n_packs, config.packs[name],
                               source=f"experiment scan {name}", progress=False)
        arms = {name: dict(real=[scan], split="paper"),
                name + "+syn": dict(real=[scan], packs=packs, split="real-test"),
                name + "+syn-nopp": dict(real=[scan], packs=packs, split="real-test", postprocess=False)}
        for arm, options in arms.items():
            exports[arm] = out / "data" / arm
            if not (exports[arm] / "export.json").is_file():
                export_yolo(exports[arm], axis=config.axis, progress=False, **options)
    return exports


def _done(path: Path) -> dict | None:
    return json.loads(path.read_text()) if path.is_file() else None


def run_arms(config: ExperimentConfig, out: Path, exports: dict[str, Path]) -> list[dict]:
    """Train every arm once per seed and score it on every real scan's test slices."""
    rows = []
    config_dir = out / "ultralytics"
    for arm in config.arms:
        train_scan, kind = config.arm_parts(arm)
        for seed in config.seeds:
            run = out / "runs" / arm / f"seed{seed}"
            record = _done(run / "train.json")
            if record is None:
                start = time.perf_counter()
                logger.info("training %s, seed %d", arm, seed)
                settings = TrainSettings(**{**vars(config.train), "seed": seed})
                train(exports[arm] / "data.yaml", run, settings, config_dir=config_dir)
                record = _done(run / "train.json")
                logger.info("trained %s in %.0f s", arm, time.perf_counter() - start)
            for test_set in config.real:
                folder = out / "eval" / arm / f"seed{seed}" / test_set
                scores = _done(folder / "scores.json") or evaluate(
                    run / "weights" / "best.pt", exports[test_set], folder, imgsz=config.train.imgsz,
                    conf=config.conf, device=config.train.device, config_dir=config_dir)
                rows.append({"arm": arm, "train_scan": train_scan, "kind": kind,
                             "seed": seed, "test_set": test_set, "train_seconds": round(record["seconds"], 1),
                             **{key: scores[key] for key in RESULT_COLUMNS if key in scores}})
                logger.info("%s seed %d on %s: Dice %.3f", arm, seed, test_set, scores["dice"])
    return rows


def summarise(rows: list[dict]) -> dict:
    """(arm, test set) -> mean and sample standard deviation over seeds of each score."""
    table: dict = {}
    for row in rows:
        table.setdefault((row["arm"], row["test_set"]), []).append(row)
    summary = {}
    for key, group in table.items():
        summary[key] = {"n_seeds": len(group)}
        for score in ("dice", "instance_dice", "mask_map50"):
            values = np.array([r[score] for r in group], dtype=float)
            summary[key][score] = float(values.mean())
            summary[key][score + "_sd"] = float(values.std(ddof=1)) if len(values) > 1 else 0.0
    return summary


def _cell(summary: dict, arm: str, test_set: str, score: str = "dice") -> str:
    entry = summary.get((arm, test_set))
    if entry is None:
        return "-"
    text = f"{100 * entry[score]:.1f}%"
    if entry["n_seeds"] > 1:
        text += f" ± {100 * entry[score + '_sd']:.1f}"
    paper = PAPER_DICE.get(arm, {}).get(test_set) if score == "dice" else None
    return text + (f" ({paper:.1f}%)" if paper is not None else "")


def _table(summary: dict, arms: list[str], test_sets: list[str], score: str = "dice") -> list[str]:
    lines = ["| training set | " + " | ".join(f"test: {t}" for t in test_sets) + " |",
             "|---|" + "---|" * len(test_sets)]
    lines += [f"| {arm} | " + " | ".join(_cell(summary, arm, t, score) for t in test_sets) + " |" for arm in arms]
    return lines


def _dataset_lines(config: ExperimentConfig, out: Path) -> list[str]:
    lines = ["| training set | train images | val images | test images |", "|---|---|---|---|"]
    for arm in config.arms:
        images = json.loads((out / "data" / arm / "export.json").read_text())["images"]
        lines.append(f"| {arm} ({config.arm_parts(arm)[1]}) | {images['train']} | "
                     f"{images['val']} | {images['test']} |")
    return lines


def report_markdown(config: ExperimentConfig, rows: list[dict], out: Path, seconds: float, device: str) -> str:
    """The report: settings, datasets, Tables 1 and 2 with the paper's figures, every score."""
    summary = summarise(rows)
    tests = list(config.real)
    table1 = [name + kind for name in config.real for kind in ("", "+syn")]
    table2 = [name + kind for name in config.real for kind in ("+syn", "+syn-nopp")]
    t = config.train
    lines = [
        f"# Augmentation experiment `{config.name}`",
        "",
        f"synthpack {__version__}; {t.model} from scratch (no pretrained weights) at {t.imgsz} px, {t.epochs} "
        f"epoch{'s' if t.epochs != 1 else ''}, batch {t.batch}, optimizer {t.optimizer} (lr0 {t.lr0}), device `{device}` "
        f"({platform.processor() or platform.machine()}, {os.cpu_count()} cores); training seeds "
        f"{', '.join(map(str, config.seeds))}; {config.n_packs} synthetic pack(s) per real scan, built from "
        f"its training slices only; slices along axis {config.axis}; confidence threshold {config.conf}; "
        f"total {seconds / 60:.1f} min.",
        "",
        "Cells: foreground Dice on the test set (central 20% of the slices of that real scan), pooled over its "
        "slices" + (", mean ± sample standard deviation over the seeds" if len(config.seeds) > 1 else "")
        + "; the paper's figure in brackets where the scan names match the paper's (large, small).",
        "",
        "## Datasets",
        "",
        "Real slices are split as in the paper (central 20% test; validation: the training slices next to "
        "the test block); synthetic slices are all training slices.",
        "",
        *_dataset_lines(config, out),
        "",
        "## Table 1: real data alone and with synthetic packs",
        "",
        *_table(summary, table1, tests),
        "",
        "## Table 2: synthetic packs with and without post-processing",
        "",
        *_table(summary, table2, tests),
        "",
        "## Matched-instance Dice (IoU >= 0.5, unmatched instances count 0)",
        "",
        *_table(summary, config.arms, tests, "instance_dice"),
        "",
        "## Ultralytics mask mAP50",
        "",
        *_table(summary, config.arms, tests, "mask_map50"),
        "",
        "Every row (arm, seed, test set) is in `results.csv`; the chart is `dice.png`.",
    ]
    return "\n".join(lines) + "\n"


def save_chart(config: ExperimentConfig, rows: list[dict], path: Path) -> None:
    """Grouped bars of the Dice of every arm on every test set, the paper's figures as black marks."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    summary = summarise(rows)
    arms, tests = config.arms, list(config.real)
    width = 0.8 / len(arms)
    fig, ax = plt.subplots(figsize=(2.5 + 1.8 * len(tests), 4))
    for k, arm in enumerate(arms):
        x = np.arange(len(tests)) + (k - (len(arms) - 1) / 2) * width
        means = [100 * summary[(arm, t)]["dice"] for t in tests]
        errors = [100 * summary[(arm, t)]["dice_sd"] for t in tests]
        ax.bar(x, means, width, yerr=errors if len(config.seeds) > 1 else None, label=arm)
        paper = [PAPER_DICE.get(arm, {}).get(t, np.nan) for t in tests]
        ax.plot(x, paper, "k_", markersize=12, label="paper" if k == 0 else None)
    ax.set_xticks(np.arange(len(tests)), [f"test: {t}" for t in tests])
    ax.set_ylabel("foreground Dice (%)")
    ax.set_ylim(0, 100)
    ax.set_title(f"{config.name}: {config.train.model}, {config.train.epochs} epochs")
    ax.legend(fontsize=7, loc="lower right")
    fig.tight_layout()
    fig.savefig(path, dpi=110, format="png")
    plt.close(fig)


def write_results(config: ExperimentConfig, rows: list[dict], out: Path, seconds: float, device: str) -> None:
    """``results.csv``, ``results.json``, ``report.md`` and ``dice.png`` in `out`."""
    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=RESULT_COLUMNS, lineterminator="\n")
    writer.writeheader()
    writer.writerows(rows)
    texts = {
        "results.csv": buffer.getvalue(),
        "results.json": json.dumps({"config": config.name, "rows": rows, "seconds": seconds}, indent=1),
        "report.md": report_markdown(config, rows, out, seconds, device),
    }
    for name, text in texts.items():
        with atomic_file(out / name) as staging:
            staging.write_text(text)
    with atomic_file(out / "dice.png") as staging:
        save_chart(config, rows, staging)


def run(config: str | os.PathLike | ExperimentConfig, out: str | os.PathLike) -> list[dict]:
    """Run the whole experiment into `out` and return its result rows."""
    config = config if isinstance(config, ExperimentConfig) else ExperimentConfig.load(config)
    out = Path(out).resolve()
    out.mkdir(parents=True, exist_ok=True)
    offline_ultralytics(out / "ultralytics")
    start = time.perf_counter()
    exports = prepare_data(config, out)
    rows = run_arms(config, out, exports)
    seconds = time.perf_counter() - start
    write_results(config, rows, out, seconds, resolve_device(config.train.device))
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
