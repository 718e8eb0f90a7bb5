"""The U-Net family's target and instance recovery on a clean pack, and its settings (the training runs in
tests/test_training.py's smoke experiment)."""

import numpy as np
import pytest
from scipy import ndimage

from synthpack.errors import SynthpackInputError
from synthpack.export import export_yolo
from synthpack.export.nnunet import instances_from_target, semantic_target
from synthpack.io import read_label_image
from synthpack.metrics import match_instances
from training.train import TrainSettings
from training.unet import UNetSettings, item_order, slice_target, target_instances


@pytest.fixture(scope="module")
def pack_slices(export_pack_dir, tmp_path_factory):
    """The truth images of every slice of a clean 20-grain pack, as the experiment's exports write them."""
    out = tmp_path_factory.mktemp("unet") / "pack"
    export_yolo(out, [export_pack_dir], postprocess=False, truth_splits=("train",), progress=False)
    slices = [read_label_image(path) for path in sorted((out / "truth" / "train").glob("*.png"))]
    return [labels for labels in slices if labels.any()]


def _touching(labels: np.ndarray) -> set[int]:
    """Ids of the instances with a 4-neighbour of another instance."""
    found = set()
    for axis in range(2):
        a, b = np.moveaxis(labels, axis, 0)[:-1], np.moveaxis(labels, axis, 0)[1:]
        contact = (a != b) & (a > 0) & (b > 0)
        found |= set(a[contact].tolist()) | set(b[contact].tolist())
    return found


def test_the_unet_recovery_returns_a_clean_pack_slices_instances_from_its_own_target(pack_slices):
    exact_expected = exact = pixels = right = 0
    for labels in pack_slices:
        target = slice_target(labels)
        assert target.dtype == np.uint8 and set(np.unique(target).tolist()) <= {0, 1, 2}
        assert np.array_equal(target > 0, labels > 0)
        recovered = target_instances(target)
        # the nnU-Net export's recovery, on the slice alone, is the reference
        assert np.array_equal(recovered, instances_from_target(semantic_target(labels[None]))[0])
        matches = match_instances(recovered, labels)
        iou = dict(zip(matches.true_ids.tolist(), matches.iou.tolist()))
        touching = _touching(labels)
        for grain in np.unique(labels[labels > 0]).tolist():
            pieces = ndimage.label((labels == grain) & (target == 1))[1]
            if grain not in touching and pieces <= 1:  # alone, one interior: it must come back exactly
                exact_expected += 1
                exact += iou.get(grain) == 1.0
        pixels += np.count_nonzero(labels)
        right += int(matches.intersection.sum())
    assert exact_expected > 100 and exact == exact_expected
    # where sections touch, a boundary pixel as near one interior as the other may go to either
    assert right >= 0.99 * pixels


def test_model_family_and_unet_settings_are_checked():
    assert TrainSettings().families == ("yolo",)
    assert TrainSettings(model_family=["yolo", "unet"]).families == ("yolo", "unet")
    for bad in ("unets", [], ["unet", "unet"]):
        with pytest.raises(SynthpackInputError, match="model_family"):
            TrainSettings(model_family=bad)
    assert UNetSettings.from_dict({"channels": [8, 16], "strides": [2]}).channels == (8, 16)
    with pytest.raises(SynthpackInputError, match="strides"):
        UNetSettings.from_dict({"channels": [8, 16, 32], "strides": [2]})
    with pytest.raises(SynthpackInputError, match="unknown unet setting"):
        UNetSettings.from_dict({"depth": 3})
    assert UNetSettings.from_dict({"images_seen": 15400}).images_seen == 15400
    for bad in (0, -5, 2.5, True, "many"):
        with pytest.raises(SynthpackInputError, match="unet.images_seen must be a positive number"):
            UNetSettings.from_dict({"images_seen": bad})
    UNetSettings().check_crop(96)
    with pytest.raises(SynthpackInputError, match="multiple of 8"):
        UNetSettings().check_crop(100)


def test_a_packs_first_order_takes_every_item_as_often_as_the_mixed_order_with_the_packs_first():
    torch = pytest.importorskip("torch")
    first = np.zeros(11, dtype=bool)
    first[[0, 3, 4, 8, 9, 10]] = True  # 6 pack items among 11
    order, epoch_of = item_order(11, 3, torch.Generator().manual_seed(5), first)
    mixed, mixed_epochs = item_order(11, 3, torch.Generator().manual_seed(5))
    assert len(order) == len(mixed) == len(epoch_of) == 33
    assert np.array_equal(np.bincount(order.numpy(), minlength=11), np.bincount(mixed.numpy(), minlength=11))
    assert first[order[:18].numpy()].all() and not first[order[18:].numpy()].any()  # all 3 epochs of packs first
    for part in (slice(0, 18), slice(18, 33)):  # each group's epochs in turn, each a fresh random order
        assert np.array_equal(epoch_of[part].numpy(), np.sort(epoch_of[part].numpy()))
        assert np.array_equal(np.bincount(epoch_of[part].numpy()), [(part.stop - part.start) // 3] * 3)
    # the mixed order is every epoch of all the items in turn, as the training always drew it
    generator = torch.Generator().manual_seed(5)
    assert torch.equal(mixed, torch.cat([torch.randperm(11, generator=generator) for _ in range(3)]))
    assert torch.equal(mixed_epochs, torch.arange(3).repeat_interleave(11))
    for wrong in (np.ones(11, dtype=bool), np.zeros(11, dtype=bool), np.ones(5, dtype=bool)):
        with pytest.raises(SynthpackInputError, match="both pack and real"):
            item_order(11, 3, torch.Generator(), wrong)
