"""The training package: the smoke experiment end to end (offline), the leak check, the scoring."""

import csv
import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from synthpack.errors import SynthpackInputError
from synthpack.io import read_label_image, write_label_image
from synthpack.library.core import ParticleLibrary
from synthpack.scan.split import VAL_FRACTION, central_block, slice_splits
from training.arms import budget_slices, make_arms, synthetic_images
from training.compute import plan_compute
from training.curves import RISE_LIMIT, tail_rise
from training.evaluate import score
from training.experiment import ExperimentConfig, _trained, plan_arms
from training.report import compute_line, convergence_lines
from training.stats import paired_bootstrap

ROOT = Path(__file__).resolve().parents[1]

# Runs `python -m <training module>` with every Internet connection and name lookup refused and recorded.
NETWORK_GUARD = r"""
import runpy, socket, sys
module = sys.argv[1]
attempts = []
connect = socket.socket.connect

def guarded_connect(self, address):
    if self.family in (socket.AF_INET, socket.AF_INET6):
        attempts.append(repr(address))
        raise OSError("network disabled by the test")
    return connect(self, address)

def guarded_getaddrinfo(host, *args, **kwargs):
    attempts.append(repr(host))
    raise socket.gaierror("network disabled by the test")

socket.socket.connect = guarded_connect
socket.getaddrinfo = guarded_getaddrinfo
sys.argv = [module, *sys.argv[2:]]
try:
    runpy.run_module(module, run_name="__main__", alter_sys=True)
finally:
    print("NETWORK ATTEMPTS:", len(attempts), attempts, file=sys.stderr)
"""


def run_offline(module: str, *args: str, timeout: float = 900) -> subprocess.CompletedProcess:
    """``python -m module args`` from the checkout root, offline."""
    return subprocess.run(
        [sys.executable, "-c", NETWORK_GUARD, module, *args],
        capture_output=True, text=True, timeout=timeout, cwd=ROOT,
    )


@pytest.fixture(scope="module")
def smoke(tmp_path_factory) -> Path:
    """The `smoke` experiment, run once for this module with the network refused."""
    out = tmp_path_factory.mktemp("smoke")
    # a few minutes on two free cores; equal steps make the small arms run many short epochs, and
    # the limit leaves room for a machine shared with other work
    result = run_offline("training.experiment", "--config", "smoke", "--out", str(out), timeout=1800)
    assert result.returncode == 0, result.stderr[-4000:]
    assert "NETWORK ATTEMPTS: 0 []" in result.stderr, result.stderr[-2000:]
    return out


@pytest.mark.slow
def test_smoke_experiment_writes_every_arm_and_test_set(smoke):
    for name in ("report.md", "results.csv", "results.json", "dice.png"):
        assert (smoke / name).stat().st_size > 0
    rows = list(csv.DictReader((smoke / "results.csv").open()))
    arms = {row["arm"] for row in rows}
    assert arms == {"large", "large+syn", "large+syn-nopp", "small", "small+syn",
                    "large:syn", "large:syn-rand", "large@5", "large@5+syn", "unet_large", "unet_large+syn",
                    "unet3d_large", "unet3d_large+syn", "unet3d_large+syn-first"}
    assert {(row["arm"], row["test_set"]) for row in rows} == {(a, t) for a in arms for t in ("large", "small")}
    for row in rows:
        assert 0.0 <= float(row["dice"]) <= 1.0 and 0.0 <= float(row["instance_f1"]) <= 1.0
        assert int(row["n_slices"]) == 26  # central 20% of 128 slices
        assert row["family"] == (row["arm"].split("_")[0] if "_" in row["arm"] else "yolo")  # unet_, unet3d_
        assert (row["mask_map50"] == "") == (row["family"] != "yolo")  # Ultralytics' mAP50: YOLO only
    report = (smoke / "report.md").read_text()
    for heading in ("Table 1", "Table 2", "(94.5%)", "(90.9%)", "Synthetic packs alone", "Label efficiency",
                    "large+syn − large |", "large:syn-rand − large:syn |", "large@5+syn − large@5 |",
                    "unet_large+syn − unet_large |", "unet_large − large |", "test: large, F1@0.5", "U-Net arms",
                    "unet3d_large+syn − unet3d_large |", "unet3d_large − unet_large |", "3D U-Net arms",
                    "Packs first, then real", "unet3d_large+syn-first − unet3d_large+syn |"):
        assert heading in report
    assert (smoke / "label_efficiency.png").stat().st_size > 0
    comparisons = json.loads((smoke / "results.json").read_text())["comparisons"]
    assert {(c["a"], c["b"]) for c in comparisons} >= {("large:syn", "large"), ("large@5+syn", "large@5")}
    for c in comparisons:
        assert c["low"] <= c["difference"] <= c["high"] and c["n_slices"] == 26
        assert c["f1"]["low"] <= c["f1"]["difference"] <= c["f1"]["high"] and c["f1"]["n_slices"] == 26


@pytest.mark.slow
@pytest.mark.parametrize("family", ["unet", "unet3d"])
def test_smoke_unet_arms_train_for_their_planned_steps_and_write_their_predictions_and_scores(smoke, family):
    plans = json.loads((smoke / "results.json").read_text())["compute"]
    steps = {}
    batch = {"unet": 16, "unet3d": 2}[family]  # the smoke config's train.batch and unet3d.batch
    for arm in (f"{family}_large", f"{family}_large+syn"):
        plan = plans[arm]
        # the 2D U-Net: the YOLO arm's plan of the same dataset; the 3D U-Net: every arm the largest arm's
        # plan (its epochs are random patches), in its batches
        yolo = plans[arm.removeprefix(f"{family}_") if family == "unet" else "large+syn"]
        assert plan == {**yolo, "batch": batch, "steps": yolo["images_seen"] / batch}
        record = json.loads((smoke / "runs" / arm / "seed0" / "train.json").read_text())
        assert record["family"] == family and record["plan"] == plan and record["images_seen"] == plan["images_seen"]
        assert record["steps_taken"] == math.ceil(plan["images_seen"] / plan["batch"])
        steps[arm] = record["steps_taken"]
        assert (smoke / "runs" / arm / "seed0" / "weights" / "best.pt").is_file()
        for test_set in ("large", "small"):
            folder, truth = smoke / "eval" / arm / "seed0" / test_set, smoke / "data" / test_set / "truth" / "test"
            names = sorted(p.name for p in truth.glob("*.png"))
            assert names and names == sorted(p.name for p in (folder / "pred").glob("*.png"))
            assert read_label_image(folder / "pred" / names[0]).shape == read_label_image(truth / names[0]).shape
            scores, again = json.loads((folder / "scores.json").read_text()), score(folder / "pred", truth)
            assert scores["mask_map50"] is None
            if family == "unet3d":  # its seed erosion, chosen once on its own scan's val slices
                chosen = json.loads((folder.parent / "seed_erosion.json").read_text())
                assert scores["seed_erosion"] == chosen["erosion"] in (0, 1, 2, 3) and len(chosen["val_f1"]) == 4
            assert (scores["dice"], scores["instance_f1"]) == (again["dice"], again["instance_f1"])
    # 45 and 82 training images (half of 90 and of 163): the same steps
    assert (plans[f"{family}_large"]["images"] != plans[f"{family}_large+syn"]["images"]) == (family == "unet")
    assert steps[f"{family}_large"] == steps[f"{family}_large+syn"]
    if family == "unet3d":  # the packs-first twin of unet3d_large+syn: its plan and steps, its pack patches first
        twin = json.loads((smoke / "runs" / "unet3d_large+syn" / "seed0" / "train.json").read_text())
        first = json.loads((smoke / "runs" / "unet3d_large+syn-first" / "seed0" / "train.json").read_text())
        assert first["plan"] == twin["plan"] and first["steps_taken"] == twin["steps_taken"]
        assert 0 < first["items_first"] < twin["plan"]["images"] and twin["items_first"] is None


@pytest.mark.slow
def test_smoke_arms_train_for_equal_steps_and_record_their_learning_curves(smoke):
    results = json.loads((smoke / "results.json").read_text())
    plans = results["compute"]
    budget = max(plan["images"] for plan in plans.values())  # the smoke config: 1 epoch of the largest arm
    assert len({plan["epochs"] for plan in plans.values()}) > 1
    for arm, plan in plans.items():
        assert plan["compute"] == "equal_steps" and budget <= plan["images_seen"] < budget + plan["images"]
        record = json.loads((smoke / "runs" / arm / "seed0" / "train.json").read_text())
        assert record["epochs"] == plan["epochs"] and record["plan"] == plan
        if not arm.startswith("unet_"):  # the smoke config's train.imgsz_by_scan: small's YOLO arms at 96 px
            assert record["imgsz"] == (96 if arm.startswith("small") else 64), arm
        curve = results["curves"][arm]["0"]
        assert curve[-1]["epoch"] == plan["epochs"] and curve[-1]["images_seen"] == plan["images_seen"]
        assert all(0.0 <= point["val_dice"] <= 1.0 for point in curve)
    rows = list(csv.DictReader((smoke / "results.csv").open()))
    assert {int(row["images_seen"]) for row in rows} == {plan["images_seen"] for plan in plans.values()}
    report = (smoke / "report.md").read_text()
    assert "**Training compute: equal steps" in report and "## Learning curves" in report
    assert "at 64 px (small's arms at 96 px, its slices upscaled)" in report
    assert (smoke / "learning_curves.png").stat().st_size > 0


def _train_list(smoke, arm):
    data = yaml.safe_load((smoke / "data" / arm / "data.yaml").read_text())
    return [Path(line) for line in Path(data["train"]).read_text().splitlines()], data


@pytest.mark.slow
def test_new_arms_train_on_packs_alone_or_on_their_label_budget_and_validate_on_real_slices(smoke):
    for arm, export in (("large:syn", "large+syn"), ("large:syn-rand", "large+syn-rand")):
        images, data = _train_list(smoke, arm)
        assert images and all(p.name.startswith("syn_") and p.is_file() for p in images)
        assert data["val"] == "images/val" and Path(data["path"]).name == export
    real_slices = slice_splits(128, VAL_FRACTION)["train"]
    for arm, with_packs in (("large@5", False), ("large@5+syn", True)):
        images, data = _train_list(smoke, arm)
        real = [p for p in images if p.name.startswith("real_")]
        assert len(real) == 5 and all(int(p.stem.rsplit("_s", 1)[1]) in real_slices for p in real)
        assert any(p.name.startswith("syn_") for p in images) == with_packs
        assert data["test"] == "images/test"
    manifest = json.loads((smoke / "packs-randomised" / "large" / "pack_0000" / "manifest.json").read_text())
    assert manifest["postprocess_mode"] == "randomised" and manifest["randomised"]["drawn"]


@pytest.mark.parametrize("n_slices", [20, 37, 100, 128, 301])
def test_label_budget_slices_never_include_a_test_or_val_slice(n_slices):
    parts = slice_splits(n_slices, VAL_FRACTION)
    forbidden = set(parts["test"]) | set(parts["val"])
    for k in range(len(parts["train"]) + 1):
        chosen = budget_slices(n_slices, k, VAL_FRACTION)
        assert len(set(chosen.tolist())) == len(chosen) == k
        assert not forbidden & set(chosen.tolist())
        if k >= 2:  # spread over the whole training part, on both sides of the test block
            assert chosen[0] == parts["train"][0] and chosen[-1] == parts["train"][-1]


def _counts(rng, dice, n_seeds=3, n_slices=26):
    true = rng.integers(200, 400, size=(n_seeds, n_slices))
    hit = np.clip(rng.normal(dice, 0.03, size=true.shape), 0, 1)
    intersection = (hit * true).astype(np.int64)
    return np.stack([intersection, true, true], axis=-1)


def test_bootstrap_interval_contains_zero_for_identical_arms_and_excludes_it_for_different_ones():
    rng = np.random.default_rng(1)
    a, b = _counts(rng, 0.80), _counts(rng, 0.80)
    same = paired_bootstrap(a, a.copy())
    assert same.low <= 0 <= same.high and same.difference == 0
    alike = paired_bootstrap(a, b)  # two arms of the same quality: noise only
    assert alike.low <= 0 <= alike.high
    better = paired_bootstrap(_counts(rng, 0.90), b)
    assert better.excludes_zero and better.low > 0.05
    assert paired_bootstrap(a, b, seed=3) == paired_bootstrap(a, b, seed=3)


def test_an_optional_real_scan_without_its_files_is_skipped_with_a_message(tmp_path, caplog):
    config = tmp_path / "c.yaml"
    config.write_text(yaml.safe_dump({"real": {
        "large": {"sample": "large"},
        "gone": {"tomogram": str(tmp_path / "no.tif"), "labels": str(tmp_path / "no_labels.tif"), "optional": True}},
        "synthetic": {"scans": {"gone": {"pour": {"n_particles": 10}}}}}))
    with caplog.at_level("WARNING", logger="training.experiment"):
        loaded = ExperimentConfig.load(config)
    assert list(loaded.real) == ["large"] and "gone" not in loaded.packs
    assert "real scan gone skipped" in caplog.text and "no.tif" in caplog.text
    assert "gone" not in " ".join(loaded.arms)


def test_the_cpu_config_runs_its_arms_over_three_seeds_with_the_concrete_scan_where_present():
    config = ExperimentConfig.load("cpu")
    assert len(config.seeds) >= 3 and config.budgets
    present = (ROOT.parent / "shared" / "data" / "concrete" / "concrete_neutron.tif").is_file()
    assert ("concrete" in config.real) == present
    names = set(config.arms)
    for scan in config.real:  # every scan, both model families: real, real + packs, packs alone
        assert {scan, scan + "+syn", scan + ":syn"} <= names
        assert {"unet_" + scan, "unet_" + scan + "+syn", "unet_" + scan + ":syn"} <= names
    # the kinds beyond the paper on the built-in sample
    assert {"large:syn-rand", f"large@{config.budgets[0]}", f"large@{config.budgets[0]}+syn"} <= names
    # YOLO on concrete's small grains at 192 px, every other arm at train.imgsz
    sizes = {arm.name: config.imgsz(arm) for arm in config.arm_list}
    assert {sizes[name] for name in names if name.startswith("large")} == {config.train.imgsz}
    if present:
        assert sizes["concrete"] == sizes["concrete+syn"] == 192 != config.train.imgsz == sizes["unet_concrete"]
        # the 3D U-Net on the real scan, where the 2D one has room to gain
        assert {"unet3d_concrete", "unet3d_concrete+syn", "unet3d_concrete:syn"} <= names
        # pretraining on the packs, then the real slices, at equal steps: the U-Nets on the real scan
        assert {"unet_concrete+syn-first", "unet_concrete@14+syn-first", "unet3d_concrete+syn-first"} <= names
        assert not any(name.endswith("-first") for name in names if not name.startswith("unet"))


def test_image_sizes_by_scan_name_scans_of_the_config_and_whole_sizes(tmp_path):
    for value, match in (({"gone": 192}, "unknown scans"), ({"large": 19.5}, "whole image sizes"), ([192], "map")):
        config = tmp_path / "c.yaml"
        config.write_text(yaml.safe_dump({"real": {"large": {"sample": "large"}}, "train": {"imgsz_by_scan": value}}))
        with pytest.raises(SynthpackInputError, match=match):
            ExperimentConfig.load(config)


@pytest.mark.slow
def test_synthetic_arms_add_pack_slices_to_the_real_training_slices(smoke):
    for scan in ("large", "small"):
        real = json.loads((smoke / "data" / scan / "export.json").read_text())["images"]
        for arm in [scan + "+syn"] + [scan + "+syn-nopp"] * (scan == "large"):
            mixed = json.loads((smoke / "data" / arm / "export.json").read_text())["images"]
            assert mixed["val"] == real["val"] and mixed["test"] == real["test"]
            assert mixed["train"] > real["train"]


@pytest.mark.slow
def test_no_test_slice_reaches_the_particle_libraries(smoke):
    for scan in ("large", "small"):
        library = ParticleLibrary.load(smoke / "libraries" / scan)
        start, stop = central_block(library.source_shape[0])
        assert library.settings["exclude_slices"] == [start, stop]
        assert len(library) > 0
        for particle in library:
            z0, z1 = particle.bbox[0], particle.bbox[3]
            assert z1 <= start or z0 >= stop, f"particle {particle.label} of {scan} reaches the test block"


@pytest.mark.slow
def test_predictions_are_label_images_of_the_test_slices(smoke):
    truth = smoke / "data" / "small" / "truth" / "test"
    pred = smoke / "eval" / "large" / "seed0" / "small" / "pred"
    names = sorted(p.name for p in truth.glob("*.png"))
    assert names == sorted(p.name for p in pred.glob("*.png"))
    assert read_label_image(pred / names[0]).shape == read_label_image(truth / names[0]).shape


@pytest.mark.slow
def test_evaluate_scores_perfect_predictions_as_dice_one(smoke, tmp_path):
    data = smoke / "data" / "large"
    result = run_offline("training.evaluate", "--data", str(data), "--out", str(tmp_path),
                         "--predictions", str(data / "truth" / "test"), timeout=120)
    assert result.returncode == 0, result.stderr[-2000:]
    scores = json.loads((tmp_path / "scores.json").read_text())
    assert scores["dice"] == 1.0 and scores["instance_dice"] == 1.0
    assert scores["n_matched"] == scores["n_true"] > 0


def test_evaluate_scores_a_damaged_prediction_below_one(tmp_path):
    truth, pred = tmp_path / "truth", tmp_path / "pred"
    truth.mkdir(), pred.mkdir()
    labels = np.zeros((40, 40), np.int32)
    labels[5:15, 5:15], labels[20:30, 20:36] = 1, 2
    write_label_image(truth / "a", labels)
    damaged = labels.copy()
    damaged[20:30, 20:36] = 0  # instance 2 missed: 100 of 260 pixels found
    write_label_image(pred / "a", damaged)
    scores = score(pred, truth)
    assert scores["dice"] == pytest.approx(2 * 100 / (100 + 260))
    assert scores["n_matched"] == 1 and scores["n_true"] == 2


def test_instance_f1_is_one_for_perfect_predictions_zero_for_none_and_counts_a_split_grain(tmp_path):
    folders = {name: tmp_path / name for name in ("truth", "perfect", "none", "split")}
    for folder in folders.values():
        folder.mkdir()
    first = np.zeros((40, 40), np.int32)
    first[5:15, 5:15], first[20:30, 20:36] = 1, 2
    second = np.zeros((40, 40), np.int32)
    second[2:12, 25:35] = 1
    split = first.copy()
    split[20:30, 30:36] = 3  # grain 2 cut in two: 100 of its 160 pixels (IoU 0.625) and 60 (IoU 0.375)
    for name, labels in (("a", first), ("b", second)):
        write_label_image(folders["truth"] / name, labels)
        write_label_image(folders["perfect"] / name, labels)
        write_label_image(folders["none"] / name, np.zeros_like(labels))
        write_label_image(folders["split"] / name, split if name == "a" else labels)
    assert score(folders["perfect"], folders["truth"])["instance_f1"] == 1.0
    assert score(folders["none"], folders["truth"])["instance_f1"] == 0.0
    scores = score(folders["split"], folders["truth"])
    assert scores["dice"] == 1.0  # the same foreground
    # slice a: 2 of 3 predicted and 2 true instances matched; slice b: 1 of 1 and 1; pooled 2 * 3 / (4 + 3)
    assert [(s["n_matched"], s["n_pred"], s["n_true"]) for s in scores["slices"]] == [(2, 3, 2), (1, 1, 1)]
    assert scores["instance_f1"] == pytest.approx(6 / 7)
    counts = {name: np.array([[[s["n_matched"], s["n_pred"], s["n_true"]] for s in score(folders[name],
                              folders["truth"])["slices"]]]) for name in ("split", "perfect")}
    assert paired_bootstrap(counts["split"], counts["perfect"]).difference == pytest.approx(6 / 7 - 1)


def test_unknown_experiment_config_is_a_clear_error(tmp_path):
    result = run_offline("training.experiment", "--config", "no-such-config", "--out", str(tmp_path), timeout=120)
    assert result.returncode == 2
    assert "smoke" in result.stderr and "cpu" in result.stderr and "paper" in result.stderr


# The training-set sizes of the cpu config's `large` arms (docs/experiment-cpu.md).
CPU_SIZES = {"large": 90, "large+syn": 205, "large:syn": 115, "large@15": 15, "large@15+syn": 130}


def test_equal_steps_gives_arms_of_different_sizes_the_same_steps_and_validation_steps():
    settings = ExperimentConfig.load("cpu").train
    assert settings.compute == "equal_steps"
    plans = plan_compute(settings, CPU_SIZES)
    budget = max(CPU_SIZES.values()) * settings.epochs
    assert len({plan.epochs for plan in plans.values()}) == len(plans)  # every size its own epochs
    for arm, plan in plans.items():
        assert plan.images == CPU_SIZES[arm]
        assert budget <= plan.images_seen < budget + plan.images  # equal up to less than one of its epochs
        assert plan.steps == plan.images_seen / settings.batch
        validated = np.array(plan.validation_epochs) * plan.images  # images seen at each validation
        assert len(validated) == settings.epochs  # as many chances to pick the model, at the same steps
        assert np.all(np.abs(validated - budget / settings.epochs * np.arange(1, settings.epochs + 1)) < plan.images)
    even = plan_compute(settings, {"a": 41, "b": 82, "c": 205})  # sizes dividing the budget: exactly equal
    assert {plan.steps for plan in even.values()} == {205 * settings.epochs / settings.batch}
    paper_rule = plan_compute(settings.__class__(**{**vars(settings), "compute": "fixed_epochs"}), CPU_SIZES)
    assert paper_rule["large+syn"].steps / paper_rule["large"].steps == pytest.approx(205 / 90)
    halves = plan_compute(settings.__class__(**{**vars(settings), "options": {"fraction": 0.5}}), {"a": 5, "b": 200})
    assert halves["a"].images == 2 and halves["a"].epochs == 50 * settings.epochs  # Ultralytics keeps round(2.5)


def _curve(dice, steps):
    return [{"steps": float(s), "val_dice": float(d)} for s, d in zip(steps, dice)]


def test_the_plateau_check_flags_a_rising_real_only_curve_and_not_a_flat_one():
    steps = np.linspace(13, 384, 30)
    rising = 0.9 * (1 - np.exp(-steps / 400))  # still climbing: about 5 points over the last 20%
    flat = 0.9 * (1 - np.exp(-steps / 40))  # converged long before the end
    assert tail_rise(steps, rising) > RISE_LIMIT > tail_rise(steps, flat) >= 0
    assert tail_rise(steps, flat[::-1]) < 0 and tail_rise(steps[:1], flat[:1]) is None
    config = ExperimentConfig.load("cpu")
    for dice, warned in ((rising, True), (flat, False)):
        curves = {"large": {seed: _curve(dice + 0.01 * seed, steps) for seed in config.seeds},
                  "large+syn": {seed: _curve(rising, steps) for seed in config.seeds}}  # not a real-only arm
        lines = "\n".join(convergence_lines(config, curves))
        assert ("real-only arm `large` has not converged" in lines) == warned
        assert "`large+syn`" not in lines and "| large+syn | 30 |" in lines


def test_a_run_trained_under_another_compute_plan_is_refused_on_resume(tmp_path):
    settings = ExperimentConfig.load("cpu").train
    equal = plan_compute(settings, CPU_SIZES)["large"]
    fixed = plan_compute(settings.__class__(**{**vars(settings), "compute": "fixed_epochs"}), CPU_SIZES)["large"]
    (tmp_path / "train.json").write_text(json.dumps({"seconds": 1.0, "epochs": 30}))  # a run from before the plans
    assert _trained(tmp_path, fixed, 96)["epochs"] == 30
    with pytest.raises(SynthpackInputError, match="new --out folder"):
        _trained(tmp_path, equal, 96)
    (tmp_path / "train.json").write_text(json.dumps({"seconds": 1.0, "epochs": equal.epochs, "plan": equal.to_dict(),
                                                     "imgsz": 96}))
    assert _trained(tmp_path, equal, 96)["plan"] == equal.to_dict()
    with pytest.raises(SynthpackInputError, match="trained at 96 px, this config trains it at 192 px"):
        _trained(tmp_path, equal, 192)  # a scan's image size changed (train.imgsz_by_scan)
    assert _trained(tmp_path / "none", equal, 96) is None


def test_each_model_family_is_planned_on_its_own_with_the_unet_budget_where_given(tmp_path):
    """The U-Net arms take equal steps among themselves at ``unet.images_seen``; the YOLO arms keep theirs."""
    config = ExperimentConfig.load("cpu")
    for arm in config.arm_list:  # the datasets' training images, as the experiment's exports record them
        folder = tmp_path / "data" / arm.dataset
        folder.mkdir(parents=True, exist_ok=True)
        size = {**CPU_SIZES, "concrete": 70, "concrete+syn": 180, "concrete:syn": 110}.get(arm.dataset, 100)
        (folder / "export.json").write_text(json.dumps({"images": {"train": size, "val": 10, "test": 20}}))
    plans = plan_arms(config, tmp_path)
    assert list(plans) == config.arms
    # the 3D U-Net's arms: all the largest one's plan (epochs of 180 random patches), 2 patches a step
    for arm in (arm for arm in config.arm_list if arm.family == "unet3d"):
        plan = plans[arm.name]
        assert (plan.images, plan.batch, plan.epochs, plan.steps) == (180, 2, 34, 3060.0), arm.name
    families = {family: {arm.name: plans[arm.name] for arm in config.arm_list if arm.family == family}
                for family in ("yolo", "unet")}
    budgets = {"yolo": 205 * config.train.epochs, "unet": config.unet.images_seen}
    assert budgets["unet"] > budgets["yolo"]
    for family, members in families.items():
        assert len({plan.images for plan in members.values()}) > 1
        for plan in members.values():
            assert budgets[family] <= plan.images_seen < budgets[family] + plan.images
    line = compute_line(plans, {arm.name: arm.family for arm in config.arm_list})
    assert "YOLOv8-seg: 6150 to" in line and f"2D U-Net: {budgets['unet']} to" in line


def test_a_packs_first_arm_trains_on_its_twins_dataset_and_only_the_unet_families_take_it(tmp_path):
    arms = {arm.name: arm for arm in make_arms({"real": ["s"], "syn": ["s"], "budget": ["s"], "syn-first": ["s"]},
                                               [5], "unet")}
    first, budget = arms["unet_s+syn-first"], arms["unet_s@5+syn-first"]
    assert (first.dataset, first.whole_export, first.packs_first, first.export) == ("s+syn", True, True, "syn")
    assert (budget.dataset, budget.real_slices, budget.whole_export) == ("s@5+syn", 5, False)
    assert budget.description == "5 real slices + synthetic, synthetic first"
    assert not any(arm.packs_first for name, arm in arms.items() if not name.endswith("-first"))
    assert [a.name for a in make_arms({"syn-first": ["s"]}, [5], "unet3d")] == ["unet3d_s+syn-first"]  # no budgets
    # which training images are pack slices: from the export's sources, for an export and an arm's subset of it
    export, subset = tmp_path / "s+syn", tmp_path / "s@5+syn"
    export.mkdir()
    subset.mkdir()
    (export / "export.json").write_text(json.dumps({"sources": [{"name": "syn_pack_0000", "kind": "synthetic"},
                                                                {"name": "real_scan0", "kind": "real"}]}))
    (subset / "dataset.json").write_text(json.dumps({"export": str(export)}))
    images = [export / "images" / "train" / name for name in
              ("real_scan0_a0_s0003.png", "syn_pack_0000_a0_s0000.png", "syn_pack_0000_a0_s0101.png")]
    assert synthetic_images(export / "data.yaml", images).tolist() == [False, True, True]
    assert synthetic_images(subset / "data.yaml", images[:2]).tolist() == [False, True]
    # YOLO's batches are ultralytics' to draw: a syn-first arm is refused there, taken by the U-Nets
    config = {"real": {"large": {"sample": "large"}}, "arms": ["real", "syn", "syn-first"],
              "train": {"model_family": ["yolo", "unet"]}}
    (tmp_path / "yolo.yaml").write_text(yaml.safe_dump(config))
    with pytest.raises(SynthpackInputError, match="unet.arms or unet3d.arms"):
        ExperimentConfig.load(tmp_path / "yolo.yaml")
    config.update(arms=["real", "syn"], unet={"arms": ["real", "syn", "syn-first"]})
    (tmp_path / "unet.yaml").write_text(yaml.safe_dump(config))
    assert ExperimentConfig.load(tmp_path / "unet.yaml").arms == ["large", "large+syn", "unet_large",
                                                                  "unet_large+syn", "unet_large+syn-first"]
