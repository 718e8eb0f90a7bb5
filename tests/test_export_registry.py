"""The export formats come from one registry (synthpack.export.registry): a new format is one
module (its writer on the shared exporter) and one `ExportFormat` line, and `export` writes it."""

from __future__ import annotations

import argparse
import importlib
import json

import numpy as np
import pytest
from toy_export import TOY_OUTPUT, ToyWriter

from synthpack import cli
from synthpack.errors import SynthpackInputError
from synthpack.export import export, export_coco, export_nnunet, export_yolo, registry

TOY = registry.ExportFormat("toy", ToyWriter)
SPLIT_NAMES = ("train", "val", "test")


@pytest.fixture
def toy_registered(monkeypatch):
    """The registry with the toy format's one line added (undone after the test)."""
    monkeypatch.setattr(registry, "FORMATS", (*registry.FORMATS, TOY))


def test_a_toy_format_is_one_module_and_one_registry_line(tmp_path, toy_registered, shapes_scan):
    out = tmp_path / "toy"
    summary = export("toy", out, real=[shapes_scan], min_area=30, order="size", progress=False)
    yolo = export_yolo(tmp_path / "yolo", real=[shapes_scan], min_area=30, truth_splits=(), progress=False)
    # the shared slice loop: the YOLO export's images, names and splits, byte for byte
    for split in SPLIT_NAMES:
        names = sorted(p.name for p in (out / "images" / split).iterdir())
        assert names == sorted(p.name for p in (tmp_path / "yolo" / "images" / split).iterdir())
        assert all((out / "images" / split / n).read_bytes() == (tmp_path / "yolo" / "images" / split / n).read_bytes()
                   for n in names)
    # the toy writer's own files: every instance of >= 30 pixels, largest first
    listed = {split: 0 for split in SPLIT_NAMES}
    for split in SPLIT_NAMES:
        for path in (out / "sizes" / split).iterdir():
            labels = shapes_scan.labels[int(path.stem.rsplit("_s", 1)[1])]
            values, sizes = np.unique(labels[labels > 0], return_counts=True)
            expected = sorted(((int(v), int(n)) for v, n in zip(values, sizes) if n >= 30), key=lambda r: (-r[1], r[0]))
            assert [tuple(map(int, line.split())) for line in path.read_text().splitlines()] == expected
            listed[split] += len(expected)
    assert summary.instances == listed and summary.images == yolo.images
    assert (out / "splits.txt").read_text() == "".join(f"{s} {yolo.images[s]}\n" for s in SPLIT_NAMES)
    # the exporter's record, in the writer's marker file: the shared settings, then the writer's option
    manifest = json.loads((out / "toy_export.json").read_text())
    assert manifest["format"] == "toy-sizes" and manifest["instances"] == listed
    assert manifest["settings"] == {"axis": 0, "split": "paper", "val_fraction": 0.1, "postprocess": True,
                                    "min_area": 30, "order": "size"}
    assert manifest["sources"] == yolo.sources and manifest["window"] == list(yolo.window)
    assert summary.table().splitlines()[0] == "| split | images | instances |"
    assert registry.get_format("toy").output is TOY_OUTPUT
    # an earlier toy export is replaced; another kind of folder is refused; bad options before anything is read
    export("toy", out, real=[shapes_scan], progress=False)
    assert json.loads((out / "toy_export.json").read_text())["settings"]["order"] == "label"
    with pytest.raises(SynthpackInputError, match="not a toy dataset written by synthpack"):
        export("toy", tmp_path / "yolo", real=[shapes_scan], progress=False)
    with pytest.raises(SynthpackInputError, match="order must be one of label, size, got 'random'"):
        export("toy", tmp_path / "new", real=[shapes_scan], order="random")
    with pytest.raises(SynthpackInputError, match="unknown option.s. colour of the toy export; its options: axis, "
                                                  "split, val_fraction, postprocess, window, min_area, order"):
        export("toy", tmp_path / "new", real=[shapes_scan], colour="red")
    assert not (tmp_path / "new").exists()


def test_an_unregistered_format_is_refused_with_the_list_of_formats(tmp_path, shapes_scan):
    with pytest.raises(SynthpackInputError, match="unknown export format 'toy'; choose one of: yolo, coco, nnunet"):
        export("toy", tmp_path / "toy", real=[shapes_scan])


CASES = {"yolo": (export_yolo, {"axis": 1, "min_area": 5, "tolerance": 0.5, "truth_splits": ["train", "test"]}),
         "coco": (export_coco, {"axis": 1, "min_area": 5, "window": (0.0, 1.0)}),
         "nnunet": (export_nnunet, {"axis": 1, "split": "paper", "postprocess": False})}


@pytest.mark.parametrize("name", [f.name for f in registry.FORMATS])
def test_export_by_name_writes_what_the_format_function_writes(tmp_path, shapes_scan, name):
    pytest.importorskip({"yolo": "skimage", "coco": "pycocotools", "nnunet": "nibabel"}[name])
    function, options = CASES[name]
    by_name, direct = tmp_path / "a" / "Dataset001_Shapes", tmp_path / "b" / "Dataset001_Shapes"
    export(name, by_name, real=[shapes_scan], progress=False, **options)
    function(direct, real=[shapes_scan], progress=False, **options)
    files = sorted(p.relative_to(direct) for p in direct.rglob("*") if p.is_file())
    assert files == sorted(p.relative_to(by_name) for p in by_name.rglob("*") if p.is_file()) and len(files) > 3
    for path in files:  # the same bytes, but for the folder's own path (in the summary and data.yaml)
        assert (by_name / path).read_bytes().replace(str(by_name).encode(), str(direct).encode()) == \
            (direct / path).read_bytes(), path
    recorded = json.loads((direct / registry.get_format(name).output.marker).read_text())["settings"]
    assert all(recorded[k] == v for k, v in options.items() if k != "window")  # the window is recorded on its own


def test_the_command_line_writes_each_format_with_a_command_into_its_output():
    subparsers = next(a for a in cli._parser()._actions if isinstance(a, argparse._SubParsersAction))
    for fmt in registry.FORMATS:
        if fmt.command is None:
            continue
        assert fmt.command in subparsers.choices
        ((option, where),) = cli._OUTPUTS[fmt.command]
        module, name = where.split(":")
        assert option == "out" and getattr(importlib.import_module(module), name) is fmt.output
