"""The COCO export (`synthpack export-coco`): read back by pycocotools, masks equal to the labels."""

import json
import os
import sys

import numpy as np
import pytest
from PIL import Image
from scipy import ndimage

from synthpack.cli import main
from synthpack.errors import SynthpackInputError
from synthpack.export import export_coco, export_yolo
from synthpack.io import write_tiff
from synthpack.store.pack import open_pack
from synthpack.scan.samples import sample_scan

COCO = pytest.importorskip("pycocotools.coco").COCO
# pycocotools' decode calls np.array(copy=False) on NumPy 2
pytestmark = pytest.mark.filterwarnings("ignore:__array__ implementation:DeprecationWarning")
SPLIT_NAMES = ("train", "val", "test")


@pytest.fixture(scope="module")
def small_sample():
    return sample_scan("small", seed=0)


@pytest.fixture(scope="module")
def inputs(export_pack_dir, shapes_scan, small_sample):
    """Export arguments: the pack, the shapes (pieces, holes) and the small real sample."""
    return {"packs": [export_pack_dir], "real": [shapes_scan, small_sample], "progress": False}


@pytest.fixture(scope="module")
def coco(inputs, tmp_path_factory):
    out = tmp_path_factory.mktemp("coco") / "dataset"
    return out, export_coco(out, **inputs)


def label_volumes(export_pack_dir, shapes_scan, small_sample):
    """Label volume of each exported source, by source name."""
    return {"syn_pack_0000": np.asarray(open_pack(export_pack_dir).labels), "real_scan0": shapes_scan.labels,
            "real_scan1": small_sample.labels}


def test_masks_read_back_by_pycocotools_equal_the_label_instances(coco, export_pack_dir, shapes_scan,
                                                                   small_sample):
    out, summary = coco
    volumes = label_volumes(export_pack_dir, shapes_scan, small_sample)
    seen_images, seen_dropped = 0, 0
    for split in SPLIT_NAMES:
        dataset = COCO(str(out / "annotations" / f"instances_{split}.json"))
        assert dataset.loadCats(dataset.getCatIds()) == [{"id": 1, "name": "particle", "supercategory": "particle"}]
        assert len(dataset.getImgIds()) == summary.images[split]
        n_annotations, n_empty = 0, 0
        for image in dataset.loadImgs(dataset.getImgIds()):
            source, index = image["file_name"][: -len(".png")].rsplit("_a0_s", 1)
            labels = volumes[source][int(index)]
            picture = np.array(Image.open(out / "images" / split / image["file_name"]))
            assert picture.shape == labels.shape == (image["height"], image["width"])
            values, sizes = np.unique(labels[labels > 0], return_counts=True)
            expected = values[sizes >= 10].tolist()  # the default min_area
            seen_dropped += int(np.sum(sizes < 10))
            annotations = dataset.loadAnns(dataset.getAnnIds(imgIds=image["id"]))
            assert sorted(a["instance_label"] for a in annotations) == expected
            for annotation in annotations:
                mask = dataset.annToMask(annotation).astype(bool)
                instance = labels == annotation["instance_label"]
                assert np.array_equal(mask, instance)  # exact: pieces and holes included
                rows, cols = np.nonzero(instance)
                assert annotation["area"] == instance.sum()
                assert annotation["bbox"] == [cols.min(), rows.min(), np.ptp(cols) + 1, np.ptp(rows) + 1]
                assert annotation["iscrowd"] == 0 and annotation["category_id"] == 1
                assert isinstance(annotation["segmentation"]["counts"], str)  # compressed RLE
            n_annotations += len(annotations)
            n_empty += not annotations  # slices without instances stay, as images without annotations
            seen_images += 1
        assert n_annotations == summary.annotations[split] > 0 and n_empty == summary.empty_images[split]
    assert seen_images == sum(v.shape[0] for v in volumes.values())
    assert seen_dropped == sum(summary.dropped_instances.values()) > 0


def test_a_grain_cut_in_two_is_one_annotation_and_a_ring_keeps_its_hole(coco, shapes_scan):
    out, _ = coco
    split = next(s for s in SPLIT_NAMES if (out / "images" / s / "real_scan0_a0_s0005.png").exists())
    dataset = COCO(str(out / "annotations" / f"instances_{split}.json"))
    (image,) = [i for i in dataset.dataset["images"] if i["file_name"] == "real_scan0_a0_s0005.png"]
    masks = {a["instance_label"]: dataset.annToMask(a).astype(bool)
             for a in dataset.loadAnns(dataset.getAnnIds(imgIds=image["id"]))}
    assert sorted(masks) == [1, 2, 3]
    assert ndimage.label(masks[1])[1] == 2  # the U's two arms: one annotation
    assert np.count_nonzero(ndimage.binary_fill_holes(masks[2]) & ~masks[2]) > 0  # the ring's hole stays
    ids = [a["id"] for s in SPLIT_NAMES
           for a in json.loads((out / "annotations" / f"instances_{s}.json").read_text())["annotations"]]
    assert sorted(ids) == list(range(1, len(ids) + 1))  # unique across the splits


def test_same_images_and_splits_as_the_yolo_export(coco, inputs, tmp_path):
    out, summary = coco
    yolo = export_yolo(tmp_path / "yolo", truth_splits=(), **inputs)
    assert yolo.window == summary.window and yolo.sources == summary.sources
    for split in SPLIT_NAMES:
        names = sorted(p.name for p in (out / "images" / split).iterdir())
        assert names == sorted(p.name for p in (tmp_path / "yolo" / "images" / split).iterdir())
        listed = json.loads((out / "annotations" / f"instances_{split}.json").read_text())["images"]
        assert sorted(i["file_name"] for i in listed) == names
        for name in names[:: max(1, len(names) // 5)]:
            assert (out / "images" / split / name).read_bytes() == (tmp_path / "yolo" / "images" / split / name
                                                                    ).read_bytes()
    manifest = json.loads((out / "coco_export.json").read_text())
    assert manifest["format"] == "synthpack-coco-instances" and manifest["annotations"] == summary.annotations


def test_export_coco_command_refuses_to_overwrite_and_says_why_in_one_line(export_pack_dir, shapes_scan, tmp_path,
                                                                            capsys):
    write_tiff(tmp_path / "shapes.tif", shapes_scan.tomogram, shapes_scan.voxel_size, shapes_scan.unit)
    write_tiff(tmp_path / "shapes_labels.tif", shapes_scan.labels, shapes_scan.voxel_size, shapes_scan.unit,
               labels=True)
    argv = ["-q", "export-coco", "--packs", str(export_pack_dir.parent), "--real", str(tmp_path / "shapes.tif"),
            str(tmp_path / "shapes_labels.tif"), "--split", "real-test", "--window", "0", "1", "--min-area", "1"]
    assert main([*argv, "--out", str(tmp_path / "ds")]) == 0
    assert "| test |" in capsys.readouterr().out
    test = json.loads((tmp_path / "ds" / "annotations" / "instances_test.json").read_text())
    assert test["images"] and all(i["file_name"].startswith("real_shapes_") for i in test["images"])
    assert test["info"]["intensity_window"] == [0.0, 1.0]
    assert main([*argv, "--out", str(tmp_path / "ds")]) == 0  # an earlier COCO export is replaced
    (tmp_path / "mine").mkdir()
    (tmp_path / "mine" / "notes.txt").write_text("keep me")
    export_yolo(tmp_path / "yolo", packs=[export_pack_dir], progress=False, truth_splits=())
    for out in ("mine", "yolo"):  # a folder of the user's, and another kind of export: refused
        capsys.readouterr()
        assert main([*argv, "--out", str(tmp_path / out)]) == 2
        error = capsys.readouterr().err
        assert error.count("\n") == 1 and "not a COCO dataset written by synthpack" in error
    assert (tmp_path / "mine" / "notes.txt").read_text() == "keep me"
    assert not (tmp_path / "yolo" / "annotations").exists()
    assert main(["-q", "export-coco", "--out", str(tmp_path / "x"), "--packs", str(export_pack_dir),
                 "--min-area", "0"]) == 2
    assert "min_area must be >= 1" in capsys.readouterr().err
    with pytest.raises(SynthpackInputError, match="nothing to export"):
        export_coco(tmp_path / "x", progress=False)
    assert not (tmp_path / "x").exists()
    assert not [p for p in os.listdir(tmp_path) if p.startswith(".")]  # no temporary folders left


def test_without_pycocotools_the_export_says_how_to_install_it_before_any_work(monkeypatch, export_pack_dir,
                                                                                 tmp_path):
    monkeypatch.setitem(sys.modules, "pycocotools.mask", None)  # import fails, as when not installed
    with pytest.raises(SynthpackInputError, match=r'pip install "synthpack\[coco\]"'):
        export_coco(tmp_path / "x", packs=[export_pack_dir], progress=False)
    assert not (tmp_path / "x").exists()
