import json
import subprocess
import sys
from itertools import product

import numpy as np
import pytest
import tifffile
from PIL import Image
from scipy.optimize import linear_sum_assignment

import synthpack.metrics as metrics
from synthpack.cli import main
from synthpack.errors import SynthpackInputError
from synthpack.io import read_label_image
from synthpack.metrics import (
    DiceStats,
    dice,
    dice_stats,
    evaluate_folders,
    instance_dice,
    match_instances,
    slice_dice_stats,
)


def brute_dice(pred, truth):
    both = count_p = count_t = 0
    for p, t in zip(pred.ravel().tolist(), truth.ravel().tolist()):
        both += bool(p) and bool(t)
        count_p += bool(p)
        count_t += bool(t)
    return 1.0 if count_p + count_t == 0 else 2 * both / (count_p + count_t)


def brute_matching(pred, truth, threshold):
    """Per-pair whole-image IoU, Hungarian on the thresholded matrix: (sum of pair Dice, matched pairs)."""
    p_ids, t_ids = np.unique(pred[pred > 0]), np.unique(truth[truth > 0])
    iou = np.zeros((len(p_ids), len(t_ids)))
    pair_dice = np.zeros_like(iou)
    for (i, p), (j, t) in product(enumerate(p_ids), enumerate(t_ids)):
        a, b = pred == p, truth == t
        inter = np.count_nonzero(a & b)
        iou[i, j] = inter / np.count_nonzero(a | b)
        pair_dice[i, j] = 2 * inter / (a.sum() + b.sum())
    candidates = np.where(iou >= threshold, iou, 0.0)
    rows, cols = linear_sum_assignment(candidates, maximize=True)
    keep = candidates[rows, cols] > 0
    pairs = {(int(p_ids[r]), int(t_ids[c])) for r, c in zip(rows[keep], cols[keep])}
    return float(pair_dice[rows[keep], cols[keep]].sum()), pairs


def random_labels(rng, shape, n):
    """Blocky random label image: coarse random ids upsampled, so instances overlap partially."""
    coarse = rng.integers(0, n + 1, size=tuple(max(1, s // 3) for s in shape))
    out = coarse
    for axis, s in enumerate(shape):
        out = np.repeat(out, 3, axis=axis).take(np.arange(s), axis=axis, mode="clip")
    return out


def test_dice_matches_brute_force_on_random_masks():
    rng = np.random.default_rng(0)
    for shape, density in [((17, 23), 0.3), ((6, 9, 11), 0.7), ((40,), 0.05), ((5, 5), 0.0)]:
        pred = (rng.random(shape) < density) * rng.integers(1, 4, shape)
        truth = rng.random(shape) < density
        assert dice(pred, truth) == pytest.approx(brute_dice(pred, truth))


def test_dice_of_empty_masks():
    empty, full = np.zeros((4, 5), bool), np.ones((4, 5), bool)
    assert dice(empty, empty) == 1.0
    assert dice(empty, full) == 0.0 and dice(full, empty) == 0.0
    assert dice_stats(empty, empty).scores() == {"dice": 1.0, "instance_dice_macro": 1.0,
                                                  "instance_dice_micro": 1.0, "f1": 1.0}
    stats = dice_stats(empty, full)
    assert stats.instance_dice_macro == 0.0 and stats.instance_dice_micro == 0.0 and stats.n_true == 1
    with pytest.raises(SynthpackInputError, match="shape"):
        dice(empty, np.zeros((5, 4)))


def two_squares():
    truth = np.zeros((10, 10), np.int32)
    truth[0:4, 0:4] = 1  # 16 px
    truth[5:9, 5:9] = 2  # 16 px
    return truth


def test_perfect_prediction_scores_one_whatever_the_ids():
    truth = two_squares()
    pred = np.where(truth == 1, 7, np.where(truth == 2, 3, 0))
    stats = dice_stats(pred, truth)
    assert stats.scores() == {"dice": 1.0, "instance_dice_macro": 1.0, "instance_dice_micro": 1.0, "f1": 1.0}
    matches = match_instances(pred, truth)
    assert matches.true_ids.tolist() == [1, 2] and matches.pred_ids.tolist() == [7, 3]


def test_split_merged_and_missing_instances_lower_the_scores_as_hand_computed():
    truth = two_squares()
    # split: instance 1 cut into two 8 px halves -> one half matched (IoU 0.5, Dice 2/3), one spurious
    split = truth.copy()
    split[0:2, 0:4] = 3
    stats = dice_stats(split, truth)
    assert (stats.n_pred, stats.n_true, stats.n_matched) == (3, 2, 2)
    assert stats.instance_dice_macro == pytest.approx((2 / 3 + 1) / 3)
    assert stats.instance_dice_micro == pytest.approx(2 * (8 + 16) / 64)
    assert stats.dice == 1.0  # foreground Dice does not see instances
    # merge: one prediction covering both squares -> IoU 0.5 with each, one match (Dice 2/3), one miss
    merged = (truth > 0).astype(np.int32)
    stats = dice_stats(merged, truth)
    assert (stats.n_pred, stats.n_matched) == (1, 1)
    assert stats.instance_dice_macro == pytest.approx((2 / 3) / 2)
    assert stats.instance_dice_micro == pytest.approx(2 * 16 / 64)
    # missing: only instance 2 predicted, exactly
    missing = np.where(truth == 2, 2, 0)
    stats = dice_stats(missing, truth)
    assert stats.instance_dice_macro == pytest.approx(1 / 2)
    assert stats.instance_dice_micro == pytest.approx(2 * 16 / 48)
    assert stats.dice == pytest.approx(2 * 16 / 48)
    assert stats.f1 == pytest.approx(2 / 3)
    # a stricter threshold unmatches the split half: nothing of instance 1 matches
    strict = dice_stats(split, truth, iou_threshold=0.6)
    assert strict.n_matched == 1 and strict.instance_dice_macro == pytest.approx(1 / 4)


def test_matching_equals_brute_force_hungarian_on_random_label_images(monkeypatch):
    rng = np.random.default_rng(1)
    cases = [((30, 31), 12, 0.5, 0), ((8, 12, 13), 20, 0.3, 0), ((25, 25), 6, 0.2, 0),
             ((40, 40), 30, 0.1, 1), ((9, 20, 20), 40, 0.15, 2)]  # shifted: chains of candidate pairs
    for shape, n, threshold, shift in cases:
        truth = random_labels(rng, shape, n)
        pred = np.roll(truth, shift, axis=0)
        noise = rng.random(shape) < 0.25
        pred[noise] = rng.integers(0, n + 3, noise.sum())
        expected_sum, expected_pairs = brute_matching(pred, truth, threshold)
        for dense in (True, False):  # bincount table and the sparse (np.unique) table
            monkeypatch.setattr(metrics, "_DENSE_PAIRS", 1 << 22 if dense else 0)
            matches = match_instances(pred, truth, iou_threshold=threshold)
            assert matches.dice.sum() == pytest.approx(expected_sum)
            if threshold > 0.5 - 1e-9:  # unique matching at >= 0.5 here (no ties in these images)
                assert set(zip(matches.pred_ids.tolist(), matches.true_ids.tolist())) == expected_pairs
            assert len(matches.pred_ids) == len(expected_pairs)


def test_large_label_values_and_bool_masks():
    truth = two_squares().astype(np.int64) * (1 << 40)  # ids above the lookup-table range
    pred = two_squares().astype(np.uint64) * np.uint64(1 << 33)
    assert dice_stats(pred, truth).instance_dice_macro == 1.0
    assert match_instances(pred, truth).true_ids.tolist() == [1 << 40, 1 << 41]
    assert dice_stats(truth > 0, two_squares() > 0).n_true == 1
    with pytest.raises(SynthpackInputError, match="integer"):
        dice_stats(truth.astype(float), truth)
    with pytest.raises(SynthpackInputError, match="negative"):
        dice_stats(-truth, truth)


def test_per_slice_versus_per_volume_micro_and_macro():
    # truth: one 3D instance through 2 slices (4 px each) and one instance in slice 1 only (2 px)
    truth = np.zeros((2, 3, 4), np.int32)
    truth[:, 0, 0:2] = 1
    truth[:, 1, 0:2] = 1
    truth[1, 2, 2:4] = 2
    # prediction: ids change between slices (a 2D predictor), instance 2 missed
    pred = np.zeros_like(truth)
    pred[0][truth[0] == 1] = 5
    pred[1][truth[1] == 1] = 9
    per_slice = slice_dice_stats(pred, truth)
    assert [s.instance_dice_macro for s in per_slice] == [1.0, 0.5]
    assert [s.instance_dice_micro for s in per_slice] == [1.0, pytest.approx(2 * 4 / 10)]
    pooled = sum(per_slice)
    assert pooled.instance_dice_macro == pytest.approx(2 / 3)  # 2 matched of 3 instances-in-slices
    assert pooled.instance_dice_micro == pytest.approx(2 * 8 / 18)
    assert np.mean([s.instance_dice_macro for s in per_slice]) == pytest.approx(0.75)
    assert instance_dice(pred, truth, per="slice") == pytest.approx(2 / 3)
    assert instance_dice(pred, truth, per="slice", average="micro") == pytest.approx(2 * 8 / 18)
    # per volume: 5 and 9 are two 4-voxel instances against the 8-voxel instance 1: IoU 0.5 -> one match
    volume = dice_stats(pred, truth)
    assert (volume.n_pred, volume.n_true, volume.n_matched) == (2, 2, 1)
    assert volume.instance_dice_macro == pytest.approx((2 * 4 / 12) / 3)
    assert instance_dice(pred, truth, average="micro") == pytest.approx(2 * 4 / 18)
    assert sum([DiceStats(), volume]) == volume
    # slicing along another axis gives other slices, the same pooled foreground
    assert sum(slice_dice_stats(pred, truth, axis=2)).dice == pytest.approx(dice(pred, truth))


def write_folders(tmp_path):
    truth_dir, pred_dir = tmp_path / "truth", tmp_path / "pred"
    truth_dir.mkdir()
    pred_dir.mkdir()
    truth = two_squares().astype(np.uint16)
    Image.fromarray(truth).save(truth_dir / "slice_a.png")
    Image.fromarray(truth).save(pred_dir / "slice_a.png")
    half = np.where(truth == 2, 2, 0).astype(np.uint16)
    tifffile.imwrite(truth_dir / "slice_b.tif", truth)
    np.save(pred_dir / "slice_b.npy", half)
    volume = np.stack([truth, truth, np.zeros_like(truth)])
    np.save(truth_dir / "vol.npy", volume)
    tifffile.imwrite(pred_dir / "vol.tif", volume, photometric="minisblack")
    Image.fromarray(truth).save(pred_dir / "extra.png")  # no truth: ignored
    return pred_dir, truth_dir


def test_evaluate_folders_pairs_files_by_name_and_pools(tmp_path):
    pred_dir, truth_dir = write_folders(tmp_path)
    report = evaluate_folders(pred_dir, truth_dir)
    assert [(r["file"], r["slice"]) for r in report.rows] == [
        ("slice_a", ""), ("slice_b", ""), ("vol", 0), ("vol", 1), ("vol", 2)]
    assert [r["instance_dice_macro"] for r in report.rows] == [1.0, 0.5, 1.0, 1.0, 1.0]
    summary = report.summary
    assert summary["n_files"] == 3 and summary["n_true"] == 8 and summary["n_matched"] == 7
    assert summary["pooled"]["instance_dice_macro"] == pytest.approx(7 / 8)
    assert summary["mean_of_rows"]["instance_dice_macro"] == pytest.approx(4.5 / 5)
    by_volume = evaluate_folders(pred_dir, truth_dir, per="volume")
    assert [r["slice"] for r in by_volume.rows] == ["", "", ""]


def test_evaluate_command_writes_json_csv_markdown(tmp_path, capsys):
    pred_dir, truth_dir = write_folders(tmp_path)
    out = tmp_path / "report"
    assert main(["-q", "evaluate", "--pred", str(pred_dir), "--truth", str(truth_dir), "--out", str(out)]) == 0
    assert sorted(p.name for p in out.iterdir()) == [".synthpack-files", "evaluation.csv", "evaluation.json",
                                                      "evaluation.md"]
    data = json.loads((out / "evaluation.json").read_text())
    assert data["summary"]["n_rows"] == 5 and len(data["rows"]) == 5
    assert (out / "evaluation.csv").read_text().splitlines()[0].startswith("file,slice,n_true")
    assert len((out / "evaluation.csv").read_text().splitlines()) == 6
    assert "| pooled over rows |" in (out / "evaluation.md").read_text()
    assert "pooled over rows" in capsys.readouterr().out


def test_evaluate_input_errors(tmp_path):
    pred_dir, truth_dir = write_folders(tmp_path)
    run = subprocess.run([sys.executable, "-m", "synthpack.cli", "-q", "evaluate", "--pred", str(tmp_path / "nope"),
                          "--truth", str(truth_dir), "--out", str(tmp_path / "r")], capture_output=True, text=True)
    assert run.returncode == 2 and "does not exist" in run.stderr and "Traceback" not in run.stderr
    assert not (tmp_path / "r").exists()
    (pred_dir / "vol.tif").unlink()
    with pytest.raises(SynthpackInputError, match="no prediction"):
        evaluate_folders(pred_dir, truth_dir)
    np.save(pred_dir / "vol.npy", np.zeros((2, 10, 10), np.uint16))
    with pytest.raises(SynthpackInputError, match="shape"):
        evaluate_folders(pred_dir, truth_dir)
    Image.fromarray(np.zeros((10, 10, 3), np.uint8)).save(tmp_path / "rgb.png")
    with pytest.raises(SynthpackInputError, match="single-channel"):
        read_label_image(tmp_path / "rgb.png")
    np.save(tmp_path / "frac.npy", np.full((3, 3), 0.5))
    with pytest.raises(SynthpackInputError, match="fractional"):
        read_label_image(tmp_path / "frac.npy")
