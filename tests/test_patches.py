"""3D patch dataset: MONAI / TorchIO items, the paper's split along an axis, sampling, workers."""

import numpy as np
import pytest
import torch
import zarr
from torch.utils.data import DataLoader

from synthpack.artefacts import GaussianNoise
from synthpack.pipeline.config import PackConfig
from synthpack.dataset import PAD_LABEL, PatchDataset, ScanSliceDataset, SyntheticParticlePackDataset
from synthpack.errors import SynthpackInputError
from synthpack.io import memmap_volume, read_box
from synthpack.store.pack import open_pack
from synthpack.scan.split import split_slices

CONFIG = PackConfig().replace(pour={"n_particles": 20, "batch_size": 10})


@pytest.fixture(scope="module")
def packs(tmp_path_factory):
    """A slice dataset over ONE small pack of the 'large' sample (built once), and the opened pack."""
    data = SyntheticParticlePackDataset(tmp_path_factory.mktemp("cache"), "large", config=CONFIG, build=True)
    return data, open_pack(data.pack_paths[0])


def box(origin, extent):
    return tuple(slice(int(o), int(o) + int(e)) for o, e in zip(origin, extent))


def covered(dataset, shape):
    """Per-voxel count of the dataset's patches (volume 0) that hold the voxel."""
    count = np.zeros(shape, dtype=np.int32)
    for i in range(len(dataset)):
        item = dataset[i]
        count[box(item["origin"], item["extent"])] += 1
    return count


def test_items_are_monai_dicts_holding_the_pack_voxels(packs):
    slices, pack = packs
    data = PatchDataset(slices, (16, 24, 32), patches_per_volume=4, split="train", axis=0)
    assert len(data) == 4
    for i in range(len(data)):
        item = data[i]
        assert item["image"].dtype == torch.float32 and item["image"].shape == (1, 16, 24, 32)
        assert item["label"].dtype == torch.int64 and item["label"].shape == (1, 16, 24, 32)
        assert item["origin"].dtype == torch.int64 and item["volume"] == 0
        assert item["source"] == "packs of sample:large"
        assert item["extent"].tolist() == [16, 24, 32]  # the train blocks are deeper than 16
        where = box(item["origin"], item["extent"])
        np.testing.assert_array_equal(item["image"][0].numpy(), pack.tomogram[where])
        np.testing.assert_array_equal(item["label"][0].numpy(), pack.labels[where])
    assert any(data[i]["label"].max() > 0 for i in range(len(data)))


@pytest.mark.parametrize(("split", "axis", "val_fraction"),
                         [("train", 0, 0.0), ("test", 0, 0.0), ("train", 2, 0.1), ("val", 1, 0.1), ("all", 0, 0.0)])
def test_grid_patches_cover_exactly_the_split_blocks(large_scan, split, axis, val_fraction):
    data = PatchDataset(large_scan, (40, 56, 48), sampling="grid", overlap=(4, 8, 0), split=split, axis=axis,
                        val_fraction=val_fraction)
    count = covered(data, large_scan.shape)
    in_split = np.zeros(large_scan.shape[axis], dtype=bool)
    in_split[split_slices(large_scan.shape[axis], split, val_fraction)] = True
    expected = np.broadcast_to(in_split.reshape([-1 if a == axis else 1 for a in range(3)]), large_scan.shape)
    np.testing.assert_array_equal(count > 0, expected)  # every split voxel, and no other voxel


@pytest.mark.parametrize("axis", [0, 2])
def test_no_test_voxel_in_any_train_patch(large_scan, axis):
    n = large_scan.shape[axis]
    test_slices = set(split_slices(n, "test").tolist())
    train = PatchDataset(large_scan, (32, 32, 32), patches_per_volume=200, split="train", axis=axis, seed=3)
    items = [train[i] for i in range(len(train))]
    assert all(item["extent"].tolist() == [32, 32, 32] for item in items)  # whole patches: none clipped
    along = {s for item in items for s in range(int(item["origin"][axis]), int(item["origin"][axis]) + 32)}
    assert not along & test_slices
    assert along == set(range(n)) - test_slices  # 200 random patches reach every train slice


def test_the_thin_test_block_is_padded_with_the_pad_label(large_scan):
    n = large_scan.shape[1]
    start, stop = split_slices(n, "test")[[0, -1]]
    data = PatchDataset(large_scan, (32, 40, 32), patches_per_volume=3, split="test", axis=1)
    assert stop + 1 - start < 40  # the test block (26 slices) is thinner than the patch
    for i in range(len(data)):
        item = data[i]
        origin, extent = item["origin"].tolist(), item["extent"].tolist()
        assert origin[1] == start and extent == [32, stop + 1 - start, 32]
        label, image = item["label"][0].numpy(), item["image"][0].numpy()
        np.testing.assert_array_equal(label[:, extent[1]:], PAD_LABEL)
        np.testing.assert_array_equal(image[:, extent[1]:], 0.0)
        np.testing.assert_array_equal(label[:, :extent[1]], large_scan.labels[box(origin, extent)])
        assert (label[:, :extent[1]] >= 0).all()


def test_random_patches_are_reproducible_per_index_and_new_each_epoch(large_scan):
    make = lambda: PatchDataset(large_scan, (16, 16, 16), patches_per_volume=8,  # noqa: E731
                                transform=GaussianNoise(std=0.1), seed=5)
    a, b = make(), make()
    for i in reversed(range(len(a))):  # any order: an item depends only on its index
        assert torch.equal(a[i]["origin"], b[i]["origin"]) and torch.equal(a[i]["image"], b[i]["image"])
    first = [a[i]["origin"].tolist() for i in range(len(a))]
    a.set_epoch(1)
    assert [a[i]["origin"].tolist() for i in range(len(a))] != first
    noisy = a[0]
    clean = large_scan.tomogram[box(noisy["origin"], noisy["extent"])]
    assert 0.05 < float((noisy["image"][0].numpy() - clean).std()) < 0.15  # the noise is in the patch


def test_a_dataloader_with_two_workers_stacks_the_same_patches(large_scan):
    data = PatchDataset(ScanSliceDataset(large_scan), (8, 16, 24), patches_per_volume=4,
                        transform=GaussianNoise(std=0.05))
    data.set_epoch(2)
    batches = list(DataLoader(data, batch_size=2, num_workers=2))
    assert len(batches) == 2
    for b, batch in enumerate(batches):
        assert batch["image"].shape == (2, 1, 8, 16, 24) and batch["image"].dtype == torch.float32
        assert batch["label"].shape == (2, 1, 8, 16, 24) and batch["label"].dtype == torch.int64
        assert batch["origin"].shape == (2, 3)
        for j in range(2):
            item = data[2 * b + j]  # the main process agrees with the workers
            assert torch.equal(batch["image"][j], item["image"]) and torch.equal(batch["label"][j], item["label"])


@pytest.mark.parametrize(("kwargs", "message"), [
    ({"patch_size": (8, 8)}, "patch_size must be three integers"),
    ({"patch_size": (8, 0, 8)}, "patch_size must be three integers"),
    ({"patch_size": (8, 8, 8), "sampling": "tiles"}, "sampling must be"),
    ({"patch_size": (8, 8, 8), "sampling": "grid", "overlap": 8}, "overlap"),
    ({"patch_size": (8, 8, 8), "split": "val"}, "val_fraction > 0"),
    ({"patch_size": (8, 8, 8), "val_fraction": 0.9}, "val_fraction must be in"),
    ({"patch_size": (8, 8, 8), "patches_per_volume": 0}, "patches_per_volume"),
])
def test_bad_input_says_what_to_do(large_scan, kwargs, message):
    with pytest.raises(SynthpackInputError, match=message):
        PatchDataset(large_scan, **kwargs)


def test_a_slice_dataset_with_a_transform_is_refused(large_scan):
    with pytest.raises(SynthpackInputError, match="give the transform to PatchDataset"):
        PatchDataset(ScanSliceDataset(large_scan, transform=GaussianNoise(std=0.1)), (8, 8, 8))


def test_read_box_reads_one_box_of_a_memmap_or_zarr_array(tmp_path):
    volume = np.arange(12 * 10 * 9, dtype=np.int32).reshape(12, 10, 9)
    np.save(tmp_path / "v.npy", volume)
    stored = zarr.create_array(tmp_path / "v.zarr", data=volume, chunks=(4, 4, 4))
    expected = volume[3:8, 2:10, 0:4]
    for source in (memmap_volume(tmp_path / "v.npy"), stored):
        np.testing.assert_array_equal(read_box(source, (3, 2, 0), (5, 8, 4)), expected)
    with pytest.raises(ValueError, match="not inside"):
        read_box(volume, (10, 0, 0), (5, 1, 1))
