"""The 3D U-Net family: its patches stay in the training slices, its 3D instance recovery on a clean pack, its
settings (the training runs in tests/test_training.py's smoke experiment)."""

import json

import numpy as np
import pytest
import torch

from synthpack.errors import SynthpackInputError
from synthpack.export import export_yolo
from synthpack.export.nnunet import instances_from_target, semantic_target
from synthpack.export.yolo import slice_polygons
from synthpack.io import read_label_image
from synthpack.scan.core import Scan
from synthpack.scan.split import slice_splits
from synthpack.store.pack import open_pack
from training.evaluate import score
from training.unet3d import UNet3DSettings, _Patches, arm_volumes, predict_split, recover_instances, window_of


@pytest.fixture(scope="module")
def pack_scan(export_pack_dir) -> Scan:
    """The clean 20-grain pack as a real scan (its clean volume and exact labels)."""
    pack = open_pack(export_pack_dir)
    return Scan(np.asarray(pack.clean[:]), np.asarray(pack.labels[:]), source="clean pack")


@pytest.fixture(scope="module")
def pack_export(pack_scan, tmp_path_factory):
    """The pack exported as the experiment exports a real scan: truth images of its val and test slices."""
    out = tmp_path_factory.mktemp("unet3d") / "export"
    export_yolo(out, real=[pack_scan], split="paper", val_fraction=0.1, truth_splits=("val", "test"), progress=False)
    return out


def _oracle():
    """A 1x1x1 convolution whose most probable class is the border-core class c held as the grey value c / 2.

    Logits at x = 0, 0.5, 1: class 0 always 0, class 1 ``20 x - 5``, class 2 ``60 x - 40``.
    """
    model = torch.nn.Conv3d(1, 3, 1)
    with torch.no_grad():
        model.weight[:] = torch.tensor([0.0, 20.0, 60.0]).reshape(3, 1, 1, 1, 1)
        model.bias[:] = torch.tensor([0.0, -5.0, -40.0])
    return model.eval()


def test_the_3d_recovery_of_a_clean_pack_test_slices_is_the_nnunet_exports_and_scores_dice_one(
        pack_scan, pack_export, tmp_path):
    target = semantic_target(pack_scan.labels)
    settings = json.loads((pack_export / "export.json").read_text())["settings"]
    truth = pack_export / "truth" / "test"
    n_parts = predict_split(_oracle(), target.astype(np.float32) / 2, truth, tmp_path / "pred", patch=(8, 32, 32),
                            min_area=settings["min_area"])
    test = slice_splits(pack_scan.shape[0], 0.1)["test"]
    start, stop = int(test[0]), int(test[-1]) + 1
    # the reference: the nnU-Net export's recovery on the test block with 4 slices (half the patch) either side
    reference = instances_from_target(target[start - 4:stop + 4])[4:4 + stop - start]
    names = sorted(p.name for p in truth.glob("*.png"))
    assert names == sorted(p.name for p in (tmp_path / "pred").glob("*.png")) and len(names) == stop - start
    written = 0
    for offset, name in enumerate(names):
        expected = slice_polygons(reference[offset], min_area=settings["min_area"]).parts
        predicted = read_label_image(tmp_path / "pred" / name)
        assert np.array_equal(predicted, expected), name
        written += int(expected.max(initial=0))
    assert n_parts == written > 50
    scores = score(tmp_path / "pred", truth)
    assert scores["dice"] == 1.0
    # where grains touch, a boundary voxel as near one interior as the other may go to either
    assert scores["instance_f1"] >= 0.95


def test_training_patches_hold_only_training_slices_and_each_volume_its_share(pack_scan, pack_export,
                                                                              export_pack_dir):
    window = window_of(pack_export)
    settings = UNet3DSettings(channels=(4, 8), strides=(2,), patch=(8, 16, 16))
    train = slice_splits(pack_scan.shape[0], 0.1)["train"]
    real = _Patches(arm_volumes("real", pack_scan, [export_pack_dir], window), settings, 0, 0.1, seed=3)
    assert len(real) == len(train)  # an epoch: as many patches as the arm's training slices
    generator = torch.Generator().manual_seed(0)
    seen = set()
    for epoch in range(3):
        for k in range(len(real)):
            item = (real.sets[0].set_epoch(epoch), real.sets[0][k])[1]
            z = int(item["origin"][0])
            assert int(item["extent"][0]) == 8
            seen |= set(range(z, z + 8))
    assert seen <= set(train.tolist()) and len(seen) > 0.8 * len(train)
    x, y = real.batch(torch.arange(4), torch.zeros(4, dtype=torch.int64), generator)
    assert x.shape == y.shape == (4, 1, 8, 16, 16) and x.dtype == torch.float32 and y.dtype == torch.int64
    assert 0.0 <= float(x.min()) and float(x.max()) <= 1.0 and set(torch.unique(y).tolist()) <= {0, 1, 2}
    mixed = _Patches(arm_volumes("syn", pack_scan, [export_pack_dir], window), settings, 0, 0.1, seed=3)
    assert [len(s) for s in mixed.sets] == [len(train), pack_scan.shape[0]]
    assert np.array_equal(mixed.synthetic, np.repeat([False, True], [len(train), pack_scan.shape[0]]))
    assert not real.synthetic.any() and len(real.synthetic) == len(real)  # what a packs-first order puts first
    alone = arm_volumes("syn-only", pack_scan, [export_pack_dir], window)
    assert [v.split for v in alone] == ["all"]
    clean = arm_volumes("syn-nopp", pack_scan, [export_pack_dir], window)[1].scan.tomogram
    assert not np.array_equal(clean, alone[0].scan.tomogram)  # the clean volume, not the post-processed one
    with pytest.raises(FileNotFoundError, match="trains on packs"):
        arm_volumes("syn", pack_scan, [], window)
    with pytest.raises(SynthpackInputError, match="no 'budget' arms"):
        arm_volumes("budget", pack_scan, [], window)
    with pytest.raises(SynthpackInputError, match="does not fit"):
        _Patches(arm_volumes("real", pack_scan, [], window), UNet3DSettings(patch=(64, 16, 16)), 0, 0.1, seed=3)


def test_3d_unet_settings_are_checked():
    settings = UNet3DSettings.from_dict({"patch": [16, 32, 32], "batch": 4, "channels": [8, 16], "strides": [2]})
    assert settings.patch == (16, 32, 32) and settings.batch == 4
    for bad in ([12, 32, 32], [16, 32], [0, 32, 32]):
        with pytest.raises(SynthpackInputError, match="unet3d.patch"):
            UNet3DSettings.from_dict({"patch": bad})
    with pytest.raises(SynthpackInputError, match="unet3d.batch"):
        UNet3DSettings.from_dict({"batch": 0})
    with pytest.raises(SynthpackInputError, match="unknown unet setting"):
        UNet3DSettings.from_dict({"depth": 3})


def test_eroded_seeds_keep_apart_two_grains_whose_predicted_boundary_has_a_hole():
    labels = np.zeros((12, 12, 24), np.int32)
    labels[1:11, 1:11, 1:12], labels[1:11, 1:11, 12:23] = 1, 2  # two boxes sharing a 10 x 10 face
    target = semantic_target(labels)
    assert np.array_equal(recover_instances(target, 0), instances_from_target(target))
    holed = target.copy()
    holed[5:7, 5:7, 11:13] = 1  # a 2 x 2 hole in the boundary on both sides of the face
    assert recover_instances(holed, 0).max() == 1  # the interiors meet through it: one grain
    for erosion in (1, 2):
        recovered = recover_instances(holed, erosion)
        assert recovered.max() == 2
        for grain in (1, 2):  # each box comes back as one instance, all but the hole's voxels
            ids, counts = np.unique(recovered[labels == grain], return_counts=True)
            assert counts.max() >= (labels == grain).sum() - 8
