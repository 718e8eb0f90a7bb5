"""The experiment's report: tables of the paper's layout with intervals, the arm comparisons, the charts.

Cells give the foreground Dice pooled over a test scan's slices and the matched-instance F1 at
IoU 0.5 pooled the same way, mean ± sample standard deviation over the training seeds. Each
comparison (`COMPARISONS` within each model family, `FAMILY_COMPARISONS` between them) is a
paired difference of two arms on one test scan, in Dice and in F1, each with its bootstrap 95%
interval over test slices and seeds (`training.stats.paired_bootstrap`).
"""

from __future__ import annotations

import os
import platform
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from synthpack import __version__

from .arms import MODEL_FAMILIES, Arm, dataset_images
from .compute import COMPUTE_MODES, ArmPlan
from .curves import RISE_LIMIT, TAIL, mean_curve, tail_rise
from .stats import Difference, paired_bootstrap

__all__ = ["COMPARISONS", "FAMILY_COMPARISONS", "Comparison", "compare_arms", "compute_line", "convergence_lines", "report_markdown",
           "save_chart", "save_label_efficiency", "save_learning_curves"]

#: The paper's Dice scores (%), by training set, then test set (Tables 1 and 2).
PAPER_DICE = {
    "large": {"large": 94.5, "small": 77.0},
    "large+syn": {"large": 96.0, "small": 80.1},
    "large+syn-nopp": {"large": 94.9, "small": 76.9},
    "small": {"large": 92.4, "small": 90.1},
    "small+syn": {"large": 94.8, "small": 90.9},
    "small+syn-nopp": {"large": 92.4, "small": 88.8},
}
#: Comparison groups: (group, arm a, arm b) name patterns, ``{s}`` the scan, ``{k}`` a label budget; made for
#: the arms of each model family (its name prefix before each, `training.arms.MODEL_FAMILIES`).
COMPARISONS = (
    ("table1", "{s}+syn", "{s}"),
    ("table2", "{s}+syn", "{s}+syn-nopp"),
    ("synthetic only", "{s}:syn", "{s}"),
    ("synthetic only", "{s}:syn-rand", "{s}:syn"),
    ("label budget", "{s}@{k}+syn", "{s}@{k}"),
    ("label budget", "{s}@{k}+syn", "{s}"),
    ("packs first", "{s}+syn-first", "{s}+syn"),
    ("packs first", "{s}+syn-first", "{s}"),
    ("packs first", "{s}@{k}+syn-first", "{s}@{k}+syn"),
    ("packs first", "{s}@{k}+syn-first", "{s}@{k}"),
    ("packs first", "{s}@{k}+syn-first", "{s}"),
)
#: The model families against each other on the same training set: ``{u}`` the 2D U-Net arms' prefix, ``{v}``
#: the 3D U-Net's (YOLO's is empty).
FAMILY_COMPARISONS = tuple(("model family", a + suffix, b + suffix)
                           for a, b in (("{u}{s}", "{s}"), ("{v}{s}", "{u}{s}")) for suffix in ("", "+syn", ":syn"))
#: Score names in the tables' headers.
SCORE_NAMES = {"dice": "Dice", "instance_f1": "F1@0.5", "instance_dice": "instance Dice", "mask_map50": "mAP50"}


@dataclass(frozen=True)
class Comparison:
    """Arm `a` minus arm `b` on the test slices of `test_set`: `difference` in Dice, `f1` in F1 (fractions)."""

    group: str
    a: str
    b: str
    test_set: str
    difference: Difference
    f1: Difference

    def to_dict(self) -> dict:
        """JSON-able dict: the Dice difference's fields, and the F1 difference's under ``f1``."""
        return {"group": self.group, "a": self.a, "b": self.b, "test_set": self.test_set,
                **self.difference.to_dict(), "f1": self.f1.to_dict()}


def _pairs(config, scan: str) -> list[tuple[str, str, str]]:
    """(group, a, b) of every comparison of `scan`: `COMPARISONS` in each family, then `FAMILY_COMPARISONS`."""
    pairs = [(group, prefix + a.format(s=scan, k=k), prefix + b.format(s=scan, k=k))
             for group, a, b in COMPARISONS for prefix, _ in MODEL_FAMILIES.values()
             for k in (config.budgets if "{k}" in a else [None])]
    prefixes = {"u": MODEL_FAMILIES["unet"][0], "v": MODEL_FAMILIES["unet3d"][0]}
    return pairs + [(group, a.format(s=scan, **prefixes), b.format(s=scan, **prefixes))
                    for group, a, b in FAMILY_COMPARISONS]


def compare_arms(config, slices: dict) -> list[Comparison]:
    """Every comparison (`_pairs`) whose two arms ran, on every test set, paired by seed and slice.

    `slices`: ``(arm, seed, test set)`` -> per-slice counts, foreground pixels then instances
    (`training.experiment.SLICE_COUNTS`, `training.experiment.run_arms`).
    """
    arms, seeds = set(config.arms), config.seeds
    comparisons = []
    for scan in config.real:
        for group, a, b in _pairs(config, scan):
            if a not in arms or b not in arms:
                continue
            for test_set in config.real:
                counts = [np.stack([slices[(arm, seed, test_set)] for seed in seeds]) for arm in (a, b)]
                comparisons.append(Comparison(group, a, b, test_set, paired_bootstrap(*(c[..., :3] for c in counts)),
                                              paired_bootstrap(*(c[..., 3:] for c in counts))))
    return comparisons


def summarise(rows: list[dict]) -> dict:
    """(arm, test set) -> mean and sample standard deviation over seeds of each score (None where it has none)."""
    table: dict = {}
    for row in rows:
        table.setdefault((row["arm"], row["test_set"]), []).append(row)
    summary = {}
    for key, group in table.items():
        summary[key] = {"n_seeds": len(group)}
        for name in SCORE_NAMES:
            values = np.array([r[name] for r in group if r.get(name) is not None], dtype=float)
            summary[key][name] = float(values.mean()) if len(values) else None
            summary[key][name + "_sd"] = float(values.std(ddof=1)) if len(values) > 1 else 0.0
    return summary


def _cell(summary: dict, arm: str, test_set: str, score: str = "dice") -> str:
    entry = summary.get((arm, test_set))
    if entry is None or entry[score] is None:
        return "-"
    text = f"{100 * entry[score]:.1f}%"
    if entry["n_seeds"] > 1:
        text += f" ± {100 * entry[score + '_sd']:.1f}"
    paper = PAPER_DICE.get(arm, {}).get(test_set) if score == "dice" else None
    return text + (f" ({paper:.1f}%)" if paper is not None else "")


def _table(summary: dict, arms: list[str], test_sets: list[str], scores: tuple[str, ...] = ("dice",)) -> list[str]:
    """A table of `arms`: one column per test set and score (the score named in the header when several)."""
    columns = [(t, score) for t in test_sets for score in scores]
    named = len(scores) > 1
    lines = ["| training set | " + " | ".join(f"test: {t}" + (f", {SCORE_NAMES[score]}" if named else "")
                                           for t, score in columns) + " |",
             "|---|" + "---|" * len(columns)]
    lines += [f"| {arm} | " + " | ".join(_cell(summary, arm, t, score) for t, score in columns) + " |"
              for arm in arms if any((arm, t) in summary for t in test_sets)]
    return lines


def _interval(d: Difference) -> str:
    mark = " *" if d.excludes_zero else ""
    return f"{100 * d.difference:+.1f} [{100 * d.low:+.1f}, {100 * d.high:+.1f}]{mark}"


def _differences(comparisons: list[Comparison], group: str, test_sets: list[str]) -> list[str]:
    """Rows ``a − b`` of one group: the differences in Dice and F1 points with their 95% intervals, per test set."""
    pairs = list(dict.fromkeys((c.a, c.b) for c in comparisons if c.group == group))
    if not pairs:
        return []
    found = {(c.a, c.b, c.test_set): c for c in comparisons}

    def cells(a: str, b: str, t: str) -> str:
        c = found.get((a, b, t))
        return " | ".join((_interval(c.difference), _interval(c.f1)) if c else ("-", "-"))

    lines = ["| difference (points) | " + " | ".join(f"test: {t}, Dice | test: {t}, F1@0.5" for t in test_sets) + " |",
             "|---|" + "---|" * (2 * len(test_sets))]
    lines += [f"| {a} − {b} | " + " | ".join(cells(a, b, t) for t in test_sets) + " |" for a, b in pairs]
    return ["", *lines]


def _ratios(summary: dict, scans: list[str], test_sets: list[str]) -> list[str]:
    """``scan:syn`` Dice as a share of ``scan``'s (the real-only arm), per test set (mean over seeds)."""
    def ratio(a: str, b: str, t: str) -> str:
        if (a, t) not in summary or (b, t) not in summary or summary[(b, t)]["dice"] == 0:
            return "-"
        return f"{100 * summary[(a, t)]['dice'] / summary[(b, t)]['dice']:.0f}%"

    scans = [prefix + s for prefix, _ in MODEL_FAMILIES.values() for s in scans]
    rows = [f"| {s}:syn / {s} | " + " | ".join(ratio(s + ":syn", s, t) for t in test_sets) + " |"
            for s in scans if any((s + ":syn", t) in summary for t in test_sets)]
    if not rows:
        return []
    return ["", "| share of the real-only Dice | " + " | ".join(f"test: {t}" for t in test_sets) + " |",
            "|---|" + "---|" * len(test_sets), *rows]


def _dataset_lines(arms: list[Arm], out: Path, plans: dict[str, ArmPlan]) -> list[str]:
    lines = ["| training set | train images | val images | test images | epochs | images seen | steps |",
             "|---|---|---|---|---|---|---|"]
    for arm in arms:
        images, plan = dataset_images(out / "data", arm.dataset), plans[arm.name]
        used = "" if plan.images == images["train"] else f" ({plan.images} used)"
        lines.append(f"| {arm.name} ({arm.description}) | {images['train']}{used} | {images['val']} | "
                     f"{images['test']} | {plan.epochs} | {plan.images_seen} | {plan.steps:.0f} |")
    return lines


def compute_line(plans: dict[str, ArmPlan], families: dict[str, str] | None = None) -> str:
    """The report's sentence on training compute: the mode, clearly labelled, and its range of steps per model family.

    `families`: arm -> its model family (`training.arms.MODEL_FAMILIES`); each family is
    planned on its own (`training.experiment.plan_arms`). Default: one family.
    """
    if not plans:
        return "No arm trained."
    plan = next(iter(plans.values()))
    families = families or {arm: "" for arm in plans}
    spans = []
    for family in dict.fromkeys(families[arm] for arm in plans):
        members = [p for arm, p in plans.items() if families[arm] == family]
        seen, steps = [p.images_seen for p in members], [p.steps for p in members]
        span = (f"{min(seen)} to {max(seen)} training images seen, {min(steps):.0f} to {max(steps):.0f} steps"
                if min(seen) != max(seen) else f"{seen[0]} training images seen, {steps[0]:.0f} steps")
        spans.append(f"{MODEL_FAMILIES[family][1].split(' (')[0]}: {span}" if family else span)
    return (f"**Training compute: {COMPUTE_MODES[plan.compute]}** ({'; '.join(spans)}; steps = images seen / "
            f"batch {plan.batch}; each arm's in the Datasets table).")


def convergence_lines(config, curves: dict) -> list[str]:
    """The learning-curve table (every arm) and a warning line for each real-only arm still rising.

    `curves`: arm -> seed -> points (`training.curves.CurveRecorder`). An arm's figures are
    of its mean curve over the seeds (`training.curves.mean_curve`): its last validation
    Dice, the best, and the rise over its last `TAIL` of steps (`training.curves.tail_rise`).
    """
    lines = [f"| training set | validations | last val Dice | best val Dice | rise over the last "
             f"{100 * TAIL:.0f}% of steps |", "|---|---|---|---|---|"]
    warnings = []
    for arm in config.arm_list:
        mean = mean_curve(list(curves.get(arm.name, {}).values()))
        if mean is None:
            lines.append(f"| {arm.name} | - | - | - | - |")
            continue
        steps, dice = mean
        rise = tail_rise(steps, dice)
        lines.append(f"| {arm.name} | {len(steps)} | {100 * dice[-1]:.1f}% | {100 * dice.max():.1f}% | "
                     + ("-" if rise is None else f"{100 * rise:+.1f}") + " |")
        if arm.kind == "real" and rise is not None and rise > RISE_LIMIT:
            warnings.append(
                f"**Warning: the real-only arm `{arm.name}` has not converged**: its validation Dice still rises "
                f"by {100 * rise:+.1f} points over its last {100 * TAIL:.0f}% of steps (more than "
                f"{100 * RISE_LIMIT:.0f}); its differences to other arms may be those of a longer training "
                "(raise `train.images_seen` or `train.epochs`).")
    return [*warnings, *([""] if warnings else []), *lines]


def _budget_lines(config, summary: dict) -> list[str]:
    """The label-efficiency table: each scan on its own test slices, Dice against the budget K."""
    columns = ["0", *map(str, config.budgets), "all"]
    lines = ["| training set (test: its own scan) | " + " | ".join(f"K = {c}" for c in columns) + " |",
             "|---|" + "---|" * len(columns)]
    for scan, prefix in _budgeted(config):
        arm = prefix + scan
        for label, plus, zero in (("real", "", None), ("real + synthetic", "+syn", f"{arm}:syn")):
            names = [zero, *(f"{arm}@{k}{plus}" for k in config.budgets), arm + plus]
            cells = [_cell(summary, name, scan) if name else "-" for name in names]
            if any(cell != "-" for cell in cells):
                lines.append(f"| {arm}, {label} | " + " | ".join(cells) + " |")
    return lines


def _budgeted(config) -> list[tuple[str, str]]:
    """(scan, family prefix) of every scan and family with label-budget arms, in the config's order."""
    return list(dict.fromkeys((arm.scan, MODEL_FAMILIES[arm.family][0]) for arm in config.arm_list
                              if arm.kind == "budget"))


def _unet_lines(config) -> list[str]:
    """The U-Net families' settings, of those with arms."""
    families = {arm.family for arm in config.arm_list}
    return [*(_unet_line(config) if "unet" in families else []),
            *(_unet3d_line(config) if "unet3d" in families else [])]


def _unet3d_line(config) -> list[str]:
    v = config.unet3d
    return [f"3D U-Net arms (`unet3d_*`): MONAI `UNet` (3D, channels {list(v.channels)}, strides {list(v.strides)}, "
            f"{v.num_res_units} residual units) from scratch on the border-core target (6-neighbour boundary), "
            f"`DiceCELoss`, AdamW (lr {v.lr}, polynomial decay), random {' x '.join(map(str, v.patch))} voxel "
            f"patches (`PatchDataset`) of the real scan's training slices and the packs, batch {v.batch}; each test "
            "or val block predicted in 3D with half a patch of neighbouring slices as context, instances by 3D "
            "watershed from the predicted interior eroded by 0-3 voxels (chosen per arm and seed by its F1@0.5 on "
            "its own val slices: `seed_erosion.json`), each slice then cut into its instances' 4-connected parts "
            "and scored as the other families' slices.", ""]


def _unet_line(config) -> list[str]:
    u, t = config.unet, config.train
    return [f"U-Net arms (`unet_*`): MONAI `UNet` (2D, channels {list(u.channels)}, strides {list(u.strides)}, "
            f"{u.num_res_units} residual units) from scratch on the border-core target (background / interior / "
            f"1-pixel boundary), `DiceCELoss`, AdamW (lr {u.lr}, polynomial decay), random {t.imgsz} px crops at "
            f"the slices' own resolution, batch {t.batch}; whole slices predicted by sliding windows, instances "
            "by watershed from the interior components (as `synthpack.export.nnunet.instances_from_target`).", ""]


def report_markdown(config, rows: list[dict], comparisons: list[Comparison], out: Path, seconds: float,
                    device: str, plans: dict[str, ArmPlan], curves: dict) -> str:
    """The report: settings, compute, datasets, learning curves, Tables 1 and 2 with the paper's figures and the
    intervals, the new arms."""
    summary = summarise(rows)
    tests = list(config.real)
    names = set(config.arms)
    prefixes = [prefix for prefix, _ in MODEL_FAMILIES.values()]
    pick = lambda *suffixes: [p + s + x for p in prefixes for s in config.real for x in suffixes  # noqa: E731
                              if p + s + x in names]
    both = ("dice", "instance_f1")
    t = config.train
    equal = any(plan.compute == "equal_steps" for plan in plans.values())
    lines = [
        f"# Augmentation experiment `{config.name}`",
        "",
        f"synthpack {__version__}; "
        + (f"YOLO arms: {t.model} from scratch (no pretrained weights) at {t.imgsz} px"
           + "".join(f" ({name}'s arms at {size} px, its slices upscaled)" for name, size in config.imgsz_by_scan.items())
           + f", batch {t.batch}, "
           f"optimizer {t.optimizer} (lr0 {t.lr0}), confidence threshold {config.conf}; "
           if "yolo" in t.families else "")
        + f"device `{device}` "
        f"({platform.processor() or platform.machine()}, {os.cpu_count()} cores); training seeds "
        f"{', '.join(map(str, config.seeds))}; {config.n_packs} synthetic pack(s) per real scan, built from "
        f"its training slices only; slices along axis {config.axis}; total {seconds / 60:.1f} min.",
        "",
        *_unet_lines(config),
        "Cells: foreground Dice on the test set (central 20% of the slices of that real scan), pooled over its "
        "slices, and the matched-instance F1 at IoU 0.5 (instances matched one to one per slice, counts pooled "
        "over the slices)" + (", mean ± sample standard deviation over the seeds" if len(config.seeds) > 1 else "")
        + "; the paper's Dice in brackets where the scan names match the paper's (large, small) for YOLO. "
        "Differences: `a − b` in Dice and F1 points, paired by test slice and seed, with the bootstrap 95% "
        "interval over test slices and seeds in brackets; `*` where the interval excludes 0.",
        "",
        compute_line(plans, {arm.name: arm.family for arm in config.arm_list}),
        "",
        "## Datasets",
        "",
        "Real slices are split as in the paper (central 20% test; validation: the training slices next to "
        "the test block); synthetic slices are all training slices. Every arm selects its model on the real "
        "val slices of its scan; `scan@K` arms train on K real training slices spaced evenly over the training "
        "part (never a val or test slice).",
        "",
        *_dataset_lines(config.arm_list, out, plans),
        "",
        "## Learning curves: foreground Dice on the real val slices against steps",
        "",
        ("Every arm validates once per epoch of the largest arm, at the same steps," if equal else
         "Every arm validates after each of its epochs,") + " and keeps its best validated weights (its model). "
        "Figures of the mean curve over the seeds; chart: `learning_curves.png`.",
        "",
        *convergence_lines(config, curves),
        "",
        "## Table 1: real data alone and with synthetic packs",
        "",
        *_table(summary, pick("", "+syn"), tests, both),
        *_differences(comparisons, "table1", tests),
        "",
        "## Table 2: synthetic packs with and without post-processing",
        "",
        *_table(summary, pick("+syn", "+syn-nopp"), tests, both),
        *_differences(comparisons, "table2", tests),
    ]
    alone = [arm for p in prefixes for s in config.real if {p + s + ":syn", p + s + ":syn-rand"} & names
             for arm in (p + s, p + s + ":syn", p + s + ":syn-rand") if arm in names]
    if alone:
        lines += ["", "## Synthetic packs alone (no real slice in training)", "",
                  "`scan:syn`: the calibrated packs; `scan:syn-rand`: packs with `postprocess: randomised`.", "",
                  *_table(summary, alone, tests, both), *_differences(comparisons, "synthetic only", tests),
                  *_ratios(summary, tests, tests)]
    if config.budgets:
        lines += ["", "## Label efficiency: K real training slices, without and with synthetic packs", "",
                  "K = 0 with packs is `scan:syn`; K = all is `scan` and `scan+syn`. Chart: "
                  "`label_efficiency.png`.", "", *_budget_lines(config, summary),
                  *_differences(comparisons, "label budget", tests)]
    first = [arm.name for arm in config.arm_list if arm.packs_first]
    if first:
        lines += ["", "## Packs first, then real: pretraining on the packs at equal steps", "",
                  "`+syn-first` arms train on their `+syn` twin's slices, as many times each in as many steps, "
                  "every epoch of the pack slices first, then every epoch of the real ones; only the order "
                  "differs.", "", *_table(summary, first, tests, both),
                  *_differences(comparisons, "packs first", tests)]
    if any(c.group == "model family" for c in comparisons):
        lines += ["", "## Model families on the same training set: the 2D U-Net against YOLO, the 3D U-Net against "
                  "the 2D", "", *_table(summary, pick("", "+syn", ":syn"), tests, both),
                  *_differences(comparisons, "model family", tests)]
    lines += [
        "",
        "## Matched-instance F1 (IoU >= 0.5, matched one to one per slice), every arm",
        "",
        *_table(summary, config.arms, tests, ("instance_f1",)),
        "",
        "## Matched-instance Dice (IoU >= 0.5, unmatched instances count 0)",
        "",
        *_table(summary, config.arms, tests, ("instance_dice",)),
        "",
    ]
    yolo = [arm.name for arm in config.arm_list if arm.family == "yolo"]
    if yolo:
        lines += ["## Ultralytics mask mAP50 (YOLO arms)", "", *_table(summary, yolo, tests, ("mask_map50",)), ""]
    lines += [
        "Every row (arm, seed, test set) is in `results.csv`, every comparison in `results.json`; the chart "
        "is `dice.png`.",
    ]
    return "\n".join(lines) + "\n"


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def save_chart(config, rows: list[dict], plans: dict[str, ArmPlan], path: Path) -> None:
    """Grouped bars of the Dice of every arm on every test set, the paper's figures as black marks."""
    plt = _pyplot()
    summary = summarise(rows)
    arms, tests = config.arms, list(config.real)
    width = 0.8 / len(arms)
    fig, ax = plt.subplots(figsize=(2.5 + 0.25 * len(arms) * len(tests), 4))
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
    compute = next(iter(plans.values())).compute.replace("_", " ") if plans else ""
    ax.set_title(f"{config.name}: {', '.join(config.train.families)}, {compute}")
    ax.legend(fontsize=6, loc="lower right", ncol=max(1, len(arms) // 8))
    fig.tight_layout()
    fig.savefig(path, dpi=110, format="png")
    plt.close(fig)


def save_label_efficiency(config, rows: list[dict], out: Path, path: Path) -> None:
    """Dice on each scan's own test slices against the label budget K, without (dashed) and with packs.

    K = all is drawn at the scan's number of real training slices (its real-only export in
    `out`), K = 0 with packs is the ``scan:syn`` arm. Error bars: the standard deviation over
    the seeds.
    """
    plt = _pyplot()
    summary = summarise(rows)
    n_train = {scan: dataset_images(out / "data", scan)["train"] for scan in config.real}
    fig, ax = plt.subplots(figsize=(6, 4))
    for index, (scan, prefix) in enumerate(_budgeted(config)):
        colour, arm = f"C{index}", prefix + scan
        for plus, zero, style in (("", None, "--"), ("+syn", f"{arm}:syn", "-")):
            points = [(0, zero)] + [(k, f"{arm}@{k}{plus}") for k in config.budgets] + [(n_train[scan], arm + plus)]
            points = [(k, summary[(name, scan)]) for k, name in points if name and (name, scan) in summary]
            if points:
                ax.errorbar([k for k, _ in points], [100 * e["dice"] for _, e in points],
                            yerr=[100 * e["dice_sd"] for _, e in points], fmt=style + "o", color=colour, capsize=3,
                            label=f"{arm}, real" + (" + synthetic" if plus else " only"))
    ax.set_xlabel("real training slices K (rightmost: all)")
    ax.set_ylabel("foreground Dice on the scan's test slices (%)")
    ax.set_ylim(0, 100)
    ax.set_title(f"{config.name}: label efficiency, {len(config.seeds)} seed(s)")
    ax.legend(fontsize=7, loc="lower right")
    fig.tight_layout()
    fig.savefig(path, dpi=110, format="png")
    plt.close(fig)


def save_learning_curves(config, curves: dict, plans: dict[str, ArmPlan], path: Path) -> None:
    """Validation Dice against steps of every arm (mean over seeds), one panel per real scan.

    Real-only arms are drawn thick; arms without a curve are left out.
    """
    plt = _pyplot()
    scans = list(dict.fromkeys(arm.scan for arm in config.arm_list)) or [""]
    fig, axes = plt.subplots(1, len(scans), figsize=(5 * len(scans), 4), squeeze=False)
    for ax, scan in zip(axes[0], scans):
        for arm in (a for a in config.arm_list if a.scan == scan):
            mean = mean_curve(list(curves.get(arm.name, {}).values()))
            if mean is not None:
                ax.plot(mean[0], 100 * mean[1], "o-", markersize=3, linewidth=2.5 if arm.kind == "real" else 1.2,
                        label=arm.name)
        ax.set_xlim(left=0)
        ax.set_xlabel("steps (images seen / batch)")
        ax.set_ylabel(f"foreground Dice on {scan}'s val slices (%)")
        ax.set_ylim(0, 100)
        ax.set_title(f"{scan}: {COMPUTE_MODES[next(iter(plans.values())).compute].split(':')[0]}" if plans else scan)
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize=7, loc="lower right")
    fig.suptitle(f"{config.name}: learning curves, {len(config.seeds)} seed(s)")
    fig.tight_layout()
    fig.savefig(path, dpi=110, format="png")
    plt.close(fig)
