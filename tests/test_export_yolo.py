import json
import logging
import os
from pathlib import Path

import numpy as np
from scipy import ndimage
import pytest
import tifffile
import yaml
from PIL import Image
from skimage import measure

from synthpack.cli import main
from synthpack.errors import SynthpackInputError
from synthpack.export import export_yolo
from synthpack.export.slices import open_sources, to_uint8
from synthpack.export.yolo import rasterize_yolo_labels, slice_polygons, yolo_label_text
from synthpack.io import write_tiff
from synthpack.store.pack import open_pack
from synthpack.scan.split import slice_splits, split_slices

SPLIT_NAMES = ("train", "val", "test")


RING_HOLE = int(np.count_nonzero(np.hypot(*np.mgrid[-3:4, -3:4]) < 3))


@pytest.fixture(scope="module")
def export(export_pack_dir, shapes_scan, tmp_path_factory):
    out = tmp_path_factory.mktemp("yolo") / "dataset"
    summary = export_yolo(out, packs=[export_pack_dir], real=[shapes_scan], truth_splits=SPLIT_NAMES, progress=False)
    return out, summary


def label_files(out):
    return sorted((out / "labels").glob("*/*.txt"))


def grain_dice_of_slice(text, grains, min_area=0):
    """Per-grain Dice of the union of the rasterised polygons assigned to each grain (by majority).

    The expected mask of a grain is its section minus its 4-connected parts below `min_area` pixels.
    """
    parts = measure.label(grains, background=0, connectivity=1)
    expected = np.where(np.bincount(parts.ravel())[parts] >= min_area, grains, 0)
    masks = rasterize_yolo_labels(text, grains.shape)
    union = {g: np.zeros(grains.shape, bool) for g in np.unique(expected[expected > 0]).tolist()}
    for mask in masks:
        owners = grains[mask]
        union[int(np.bincount(owners[owners > 0]).argmax())] |= mask
    return {g: 2 * np.count_nonzero(m & (expected == g)) / (m.sum() + np.count_nonzero(expected == g))
            for g, m in union.items()}


def test_round_trip_of_pack_slices_gives_back_the_grains(export, export_pack_dir):
    out, summary = export
    pack = open_pack(export_pack_dir)
    labels = np.asarray(pack.labels)
    scores = []
    for path in label_files(out):
        if not path.name.startswith("syn_"):
            continue
        index = int(path.stem.rsplit("_s", 1)[1])
        dice = grain_dice_of_slice(path.read_text(), labels[index], min_area=10)
        scores += dice.values()
        for grain, score in dice.items():
            if score < 0.99:  # a polygon has no holes: only a part with a hole may differ, by its hole
                part = labels[index] == grain
                hole = np.count_nonzero(ndimage.binary_fill_holes(part)) - np.count_nonzero(part)
                assert hole > 0 and score >= 2 * part.sum() / (2 * part.sum() + hole) - 0.02
    assert len(scores) > 300
    assert np.mean(scores) >= 0.99
    assert np.mean(np.array(scores) == 1.0) > 0.95  # exact outlines: only parts with holes differ
    assert sum(summary.images.values()) == pack.shape[0] + 20
    assert sum(summary.instances.values()) == sum(len(p.read_text().splitlines()) for p in label_files(out))


def test_concave_grain_cut_in_two_and_a_ring_round_trip(export, shapes_scan):
    out, summary = export
    scan = shapes_scan
    for index in range(20):
        split = next(s for s in SPLIT_NAMES if (out / "labels" / s / f"real_scan0_a0_s{index:04d}.txt").exists())
        text = (out / "labels" / split / f"real_scan0_a0_s{index:04d}.txt").read_text()
        grains = scan.labels[index].astype(np.int64)
        scores = grain_dice_of_slice(text, grains)
        assert scores.get(1, 1.0) == 1.0 and scores.get(3, 1.0) == 1.0  # the U (1 or 2 parts) and the C: exact
        ring = np.count_nonzero(grains == 2)
        assert scores[2] == pytest.approx(2 * ring / (2 * ring + RING_HOLE))  # hole filled
        n_lines = len(text.splitlines())
        u_parts = 1 if index < 2 else 2 if index < 18 else 0
        assert n_lines == u_parts + 1 + (4 <= index < 16)
        truth = np.array(Image.open(out / "truth" / split / f"real_scan0_a0_s{index:04d}.png"))
        assert truth.max() == n_lines and np.array_equal(truth > 0, grains > 0)
    assert sum(summary.hole_pixels.values()) >= 20 * RING_HOLE


def test_truth_images_score_the_rasterised_labels_with_evaluate(export, tmp_path):
    out, summary = export
    pred = tmp_path / "pred"
    pred.mkdir()
    for path in sorted((out / "labels" / "test").glob("*.txt")):
        shape = np.array(Image.open(out / "images" / "test" / f"{path.stem}.png")).shape
        image = np.zeros(shape, np.uint16)
        for k, mask in enumerate(rasterize_yolo_labels(path.read_text(), shape)):
            image[mask] = k + 1
        Image.fromarray(image).save(pred / f"{path.stem}.png")
    assert main(["-q", "evaluate", "--pred", str(pred), "--truth", str(out / "truth" / "test"),
                 "--out", str(tmp_path / "report")]) == 0
    report = json.loads((tmp_path / "report" / "evaluation.json").read_text())["summary"]
    assert report["n_files"] == summary.images["test"]
    assert report["n_matched"] == summary.instances["test"]  # every labelled part found; fragments are misses
    assert report["n_true"] - report["n_matched"] == summary.dropped_fragments["test"]
    assert report["pooled"]["dice"] > 0.99


def test_polygons_of_fragments_holes_and_diagonal_pixels():
    labels = np.zeros((12, 12), np.int32)
    labels[1:6, 1:6] = 4
    labels[3, 3] = 0  # one-pixel hole
    labels[8, 8] = labels[9, 9] = 4  # diagonal pixels: two 4-connected parts, below min_area
    result = slice_polygons(labels, min_area=2)
    assert len(result.polygons) == 1 and result.dropped_fragments == 2 and result.hole_pixels == 1
    assert result.instance_ids.tolist() == [4] and result.instance_pixels == 24
    assert sorted(np.unique(result.parts).tolist()) == [0, 1, 2, 3]
    square = rasterize_yolo_labels(yolo_label_text(result.polygons, labels.shape), labels.shape)[0]
    assert np.array_equal(square, np.pad(np.ones((5, 5), bool), ((1, 6), (1, 6))))
    kept = slice_polygons(labels, min_area=1)
    masks = rasterize_yolo_labels(yolo_label_text(kept.polygons, labels.shape), labels.shape)
    assert [int(m.sum()) for m in masks] == [25, 1, 1]
    assert len(kept.polygons[0]) == 8  # straight runs removed: 4 sides and 4 cut corners (of 20 points)
    simplified = slice_polygons(labels, tolerance=1.0).polygons[0]
    assert 3 <= len(simplified) <= 4


def test_split_is_the_papers_central_block_with_val_next_to_it(export, export_pack_dir):
    out, _ = export
    manifest = json.loads((out / "export.json").read_text())
    assert manifest["settings"]["split"] == "paper"
    for source in manifest["sources"]:
        n = source["shape"][0]
        indices = {s: sorted(int(p.stem.rsplit("_s", 1)[1]) for p in (out / "images" / s).glob(f"{source['name']}_*"))
                   for s in SPLIT_NAMES}
        assert indices["test"] == split_slices(n, "test").tolist()
        assert sorted(sum(indices.values(), [])) == list(range(n))
        start, stop = indices["test"][0], indices["test"][-1] + 1
        n_val = len(indices["val"])
        before = sum(i < start for i in indices["val"])  # val: the train slices next to the test block
        assert indices["val"] == list(range(start - before, start)) + list(range(stop, stop + n_val - before))
        assert n_val == round(0.3 * n) - round(0.2 * n) > 0 and abs(2 * before - n_val) <= 1
        assert source["slices"] == {s: len(indices[s]) for s in SPLIT_NAMES}
    plan = slice_splits(10, 0.1)
    assert plan["test"].tolist() == [4, 5] and plan["val"].tolist() == [3] and len(plan["train"]) == 7
    assert slice_splits(100, 0.1)["val"].tolist() == [35, 36, 37, 38, 39, 60, 61, 62, 63, 64]


def test_images_use_one_window_and_the_chosen_volume(export, export_pack_dir, shapes_scan, tmp_path):
    out, summary = export
    pack = open_pack(export_pack_dir)
    scan = shapes_scan
    lo, hi = np.percentile(scan.tomogram, [0.5, 99.5])
    assert summary.window == pytest.approx((lo, hi))
    data = (out / "data.yaml").read_text()
    assert f"[{lo:.6g}, {hi:.6g}]" in data
    index = int(split_slices(pack.shape[0], "test")[0])
    name = f"syn_pack_0000_a0_s{index:04d}.png"
    image = np.array(Image.open(out / "images" / "test" / name))
    assert image.dtype == np.uint8 and np.array_equal(image, to_uint8(pack.tomogram[index], summary.window))
    clean = export_yolo(tmp_path / "clean", packs=[export_pack_dir.parent], postprocess=False, split="paper",
                        truth_splits=(), progress=False)
    assert clean.window == pytest.approx(tuple(np.percentile(pack.clean[:], [0.5, 99.5])), rel=1e-3)
    image = np.array(Image.open(tmp_path / "clean" / "images" / "test" / name))
    assert np.array_equal(image, to_uint8(pack.clean[index], clean.window))
    assert not (tmp_path / "clean" / "truth").exists()
    assert clean.sources[0]["volume"] == "clean"


def test_ultralytics_reads_the_dataset_without_corrupt_or_missing_labels(export, monkeypatch, tmp_path):
    monkeypatch.setenv("YOLO_OFFLINE", "1")
    monkeypatch.setenv("YOLO_CONFIG_DIR", str(tmp_path / "ultralytics"))
    pytest.importorskip("ultralytics")
    from ultralytics.data.dataset import YOLODataset
    from ultralytics.data.utils import polygon2mask

    out, summary = export
    data = yaml.safe_load((out / "data.yaml").read_text())
    assert data["names"] == {0: "particle"} and Path(data["path"]) == out.resolve()
    for split in SPLIT_NAMES:
        dataset = YOLODataset(img_path=str(Path(data["path"]) / data[split]), data=data, task="segment",
                              augment=False, imgsz=160)
        cache = np.load(out / "labels" / f"{split}.cache", allow_pickle=True).item()
        found, missing, empty, corrupt, total = cache["results"]
        assert (missing, corrupt) == (0, 0) and cache["msgs"] == []
        assert found == total == summary.images[split] and empty == summary.empty_images[split]
        assert sum(len(label["segments"]) for label in dataset.labels) == summary.instances[split]
        assert dataset[0]["masks"].shape[-2:] == (40, 40)  # polygons rasterised by ultralytics
    # at native resolution ultralytics' rasteriser (cv2.fillPoly) gives back the exact parts, holes aside
    scores = []
    for path in sorted((out / "labels" / "test").glob("*.txt")):
        truth = np.array(Image.open(out / "truth" / "test" / f"{path.stem}.png"))
        height, width = truth.shape
        for k, line in enumerate(path.read_text().splitlines()):
            xy = np.array(line.split()[1:], dtype=float).reshape(-1, 2) * [width, height]
            mask = polygon2mask((height, width), [xy.ravel()]).astype(bool)
            part = truth == k + 1
            scores.append(2 * np.count_nonzero(mask & part) / (mask.sum() + part.sum()))
    assert len(scores) == summary.instances["test"]
    assert np.mean(np.array(scores) == 1.0) > 0.95 and np.mean(scores) > 0.99


def test_export_command_with_real_files_and_real_test_split(export_pack_dir, shapes_scan, tmp_path, capsys):
    scan = shapes_scan
    write_tiff(tmp_path / "shapes.tif", scan.tomogram, scan.voxel_size, scan.unit)
    write_tiff(tmp_path / "shapes_labels.tif", scan.labels, scan.voxel_size, scan.unit, labels=True)
    out = tmp_path / "ds"
    argv = ["-q", "export-yolo", "--packs", str(export_pack_dir.parent), "--real", str(tmp_path / "shapes.tif"),
            str(tmp_path / "shapes_labels.tif"), "--out", str(out), "--split", "real-test", "--no-postprocess",
            "--window", "0", "1", "--truth-splits", "test", "val"]
    assert main(argv) == 0
    assert "| test |" in capsys.readouterr().out
    names = {s: sorted(p.stem for p in (out / "images" / s).iterdir()) for s in SPLIT_NAMES}
    synthetic = [n for n in names["train"] if n.startswith("syn_pack_0000_a0_")]
    assert len(synthetic) == open_pack(export_pack_dir).shape[0]  # every synthetic slice in train
    assert all(n.startswith("real_shapes_a0_") for n in names["val"] + names["test"])
    assert len(names["test"]) == 4 and len(list((out / "truth" / "val").iterdir())) == len(names["val"])
    manifest = json.loads((out / "export.json").read_text())
    assert manifest["window"] == [0.0, 1.0] and manifest["settings"]["postprocess"] is False
    assert main(argv) == 0  # an earlier export is replaced
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".ds")]  # no temporary folders left


def test_real_scan_files_keep_the_voxel_size_they_record_and_the_log_says_where_it_came_from(
        shapes_scan, tmp_path, caplog):
    """A 2D export reads real scans in pixels only where they record no voxel size, and says so.

    It passed 1 px as if given, so `export-yolo` on the README's scan logged "voxel size (1.0, 1.0, 1.0)
    px given explicitly overrides (10.0, 10.0, 10.0) um from the labels metadata": nobody gave one.
    """
    scan = shapes_scan
    tifffile.imwrite(tmp_path / "scan.tif", scan.tomogram)  # as many exports are: no voxel size
    write_tiff(tmp_path / "labels.tif", scan.labels, (10.0, 10.0, 10.0), "um", labels=True)
    tifffile.imwrite(tmp_path / "bare_labels.tif", scan.labels)
    with caplog.at_level(logging.INFO, logger="synthpack"):
        (recorded,), _ = open_sources([], [(tmp_path / "scan.tif", tmp_path / "labels.tif")], postprocess=True)
    assert (recorded.voxel_size, recorded.unit) == ((10.0, 10.0, 10.0), "um")
    assert [r.getMessage().split(": ", 1)[1] for r in caplog.records] == [
        "20x40x50 float32, voxel size 10 um (from the labels metadata)"]
    caplog.clear()
    with caplog.at_level(logging.INFO, logger="synthpack"):
        (bare,), _ = open_sources([], [(tmp_path / "scan.tif", tmp_path / "bare_labels.tif")], postprocess=True)
    assert (bare.voxel_size, bare.unit) == ((1.0, 1.0, 1.0), "px")
    assert [(r.levelname, r.getMessage().split(": ", 1)[1]) for r in caplog.records] == [
        ("INFO", "20x40x50 float32, voxel size 1 px (none recorded, none needed)")]
    caplog.clear()
    with caplog.at_level(logging.INFO, logger="synthpack"):  # a 3D export needs one: the warning
        open_sources([], [(tmp_path / "scan.tif", tmp_path / "bare_labels.tif")], postprocess=True, voxel_size=True)
    assert [r.levelname for r in caplog.records] == ["WARNING"] and "no voxel size" in caplog.records[0].getMessage()


def test_export_input_errors(export_pack_dir, tmp_path):
    (tmp_path / "precious").mkdir()
    (tmp_path / "precious" / "notes.txt").write_text("keep me")
    with pytest.raises(SynthpackInputError, match="not a YOLO dataset written by synthpack"):
        export_yolo(tmp_path / "precious", packs=[export_pack_dir], progress=False)
    assert (tmp_path / "precious" / "notes.txt").read_text() == "keep me"
    with pytest.raises(SynthpackInputError, match="neither a pack nor a folder of packs"):
        export_yolo(tmp_path / "x", packs=[tmp_path / "precious"], progress=False)
    with pytest.raises(SynthpackInputError, match="no slices for the val and test"):
        export_yolo(tmp_path / "x", packs=[export_pack_dir], split="real-test", progress=False)
    with pytest.raises(SynthpackInputError, match="nothing to export"):
        export_yolo(tmp_path / "x", progress=False)
    assert main(["-q", "export-yolo", "--packs", str(tmp_path / "missing"), "--out", str(tmp_path / "x")]) == 2
    assert not (tmp_path / "x").exists()
    assert os.listdir(tmp_path) == ["precious"]
