import logging
import os
import pickle
import shutil

import numpy as np
import pytest
import torch
from torch.utils.data import ConcatDataset, DataLoader
from torchvision import tv_tensors
from torchvision.transforms import v2

from synthpack.artefacts import GaussianNoise
from synthpack.pipeline.config import PackConfig
from synthpack.dataset import (
    ScanSliceDataset,
    SyntheticParticlePackDataset,
    collate_fn,
    collate_stacked,
    expand_masks,
    instance_target,
)
from synthpack.errors import SynthpackInputError
from synthpack.io import write_tiff
from synthpack.store.pack import open_pack
from synthpack.scan.split import split_slices

CONFIG = PackConfig().replace(pour={"n_particles": 20, "batch_size": 10})


@pytest.fixture(scope="module")
def root(tmp_path_factory):
    """A cache root holding the library and ONE small pack of the 'large' sample."""
    path = tmp_path_factory.mktemp("cache")
    SyntheticParticlePackDataset(path, "large", config=CONFIG, build=True)
    return path


@pytest.fixture(scope="module")
def pack(root):
    return open_pack(SyntheticParticlePackDataset(root, "large", config=CONFIG).pack_paths[0])


def dataset(root, **kwargs):
    return SyntheticParticlePackDataset(root, "large", config=CONFIG, **kwargs)


def boxes_of(masks: torch.Tensor) -> torch.Tensor:
    """XYXY pixel-edge boxes of (N, H, W) masks."""
    rows, cols = masks.any(dim=2), masks.any(dim=1)
    first = lambda a: a.float().argmax(dim=1)  # noqa: E731
    last = lambda a: a.shape[1] - a.flip(1).float().argmax(dim=1)  # noqa: E731
    return torch.stack([first(cols), first(rows), last(cols), last(rows)], dim=1).float()


def assert_same_items(a, b):
    (image_a, target_a), (image_b, target_b) = a, b
    torch.testing.assert_close(image_a, image_b, rtol=0, atol=0)
    assert target_a.keys() == target_b.keys()
    for key in target_a:
        if isinstance(target_a[key], torch.Tensor):
            assert torch.equal(target_a[key], target_b[key]), key
        else:
            assert target_a[key] == target_b[key], key


@pytest.mark.parametrize("axis", [0, 1, 2])
def test_item_format_and_content(root, pack, axis):
    data = dataset(root, split="all", axis=axis)
    assert len(data) == pack.shape[axis]
    index = len(data) // 2
    image, target = data[index]
    where = (slice(None),) * axis + (index,)
    labels = np.asarray(pack.labels[where])
    height, width = labels.shape
    assert isinstance(image, tv_tensors.Image) and image.dtype == torch.float32
    assert image.shape == (1, height, width)
    np.testing.assert_array_equal(image[0].numpy(), pack.tomogram[where])
    ids = np.unique(labels[labels > 0])
    n = len(ids)
    assert n > 0
    masks, boxes = target["masks"], target["boxes"]
    assert isinstance(masks, tv_tensors.Mask) and masks.dtype == torch.bool and masks.shape == (n, height, width)
    assert isinstance(boxes, tv_tensors.BoundingBoxes) and boxes.format == tv_tensors.BoundingBoxFormat.XYXY
    assert tuple(boxes.canvas_size) == (height, width) and boxes.shape == (n, 4)
    assert target["labels"].dtype == torch.int64 and torch.equal(target["labels"], torch.ones(n, dtype=torch.int64))
    np.testing.assert_array_equal(target["instance_ids"].numpy(), ids)
    for mask, value in zip(masks, ids):
        np.testing.assert_array_equal(mask.numpy(), labels == value)
    torch.testing.assert_close(boxes.as_subclass(torch.Tensor), boxes_of(masks))
    assert isinstance(target["semantic"], tv_tensors.Mask) and target["semantic"].shape == (height, width)
    np.testing.assert_array_equal(target["semantic"].numpy(), labels > 0)
    assert (target["pack"], target["slice"]) == (0, index)


def test_empty_slice_has_empty_targets():
    target = instance_target(np.zeros((5, 7), dtype=np.uint16))
    assert target["masks"].shape == (0, 5, 7) and target["boxes"].shape == (0, 4)
    assert target["labels"].shape == (0,) and not target["semantic"].any()


@pytest.mark.parametrize("axis", [0, 1, 2])
def test_train_and_test_slices_follow_the_paper_split(root, pack, axis):
    n = pack.shape[axis]
    train, test = dataset(root, split="train", axis=axis), dataset(root, split="test", axis=axis)
    np.testing.assert_array_equal(train.slices(0), split_slices(n, "train"))
    np.testing.assert_array_equal(test.slices(0), split_slices(n, "test"))
    train_items = {train[i][1]["slice"] for i in range(len(train))}
    test_items = {test[i][1]["slice"] for i in range(len(test))}
    assert not train_items & test_items
    assert train_items | test_items == set(range(n))


def test_workers_give_the_same_items_as_the_main_process(root):
    data = dataset(root, split="test", transform=[GaussianNoise(std=0.05), v2.RandomHorizontalFlip(p=1)])
    serial = DataLoader(data, batch_size=3, collate_fn=collate_fn)
    parallel = DataLoader(data, batch_size=3, collate_fn=collate_fn, num_workers=2, persistent_workers=True)
    for epoch in (0, 1):
        data.set_epoch(epoch)
        got, expected = list(parallel), list(serial)  # workers start before the main process opens the cache
        assert len(expected) == len(got) > 1
        for (images_a, targets_a), (images_b, targets_b) in zip(expected, got):
            for item_a, item_b in zip(zip(images_a, targets_a), zip(images_b, targets_b)):
                assert_same_items(item_a, item_b)
        if epoch == 0:
            first_epoch = expected
    # persistent workers saw set_epoch: epoch 1 has other noise than epoch 0
    assert not torch.equal(first_epoch[0][0][0], expected[0][0][0])


def test_pickled_dataset_is_small_after_reading(root, large_scan, tmp_path):
    data = dataset(root, split="all")
    data[0]  # opens the pack's memory maps in this process
    assert len(pickle.dumps(data)) < 50_000
    write_tiff(tmp_path / "t.tif", large_scan.tomogram, large_scan.voxel_size)
    write_tiff(tmp_path / "l.tif", large_scan.labels, large_scan.voxel_size, labels=True)
    real = ScanSliceDataset(tmp_path / "t.tif", tmp_path / "l.tif")
    real[0]
    assert len(pickle.dumps(real)) < 50_000


def test_workers_never_build(tmp_path):
    unbuilt = dataset(tmp_path)
    loader = DataLoader(unbuilt, sampler=[0, 1], num_workers=1, collate_fn=collate_fn)
    with pytest.raises(SynthpackInputError, match="never build"):
        next(iter(loader))
    assert not (tmp_path / unbuilt.cache_dir.name).exists()


def test_same_config_reuses_the_cache(root):
    first = dataset(root)
    tomogram = first.pack_paths[0] / "tomogram.tif"
    stamp = tomogram.stat().st_mtime_ns
    again = dataset(root, split="test", axis=1, seed=CONFIG.seed)
    assert again.cache_dir == first.cache_dir
    again.build()
    assert tomogram.stat().st_mtime_ns == stamp
    assert sorted(p.name for p in root.iterdir() if p.name.startswith("packs-")) == [first.cache_dir.name]


def test_changed_config_and_more_packs_build_new_packs(root, tmp_path):
    copy = tmp_path / "cache"
    shutil.copytree(root, copy)
    base = dataset(copy)
    library_dir = next(copy.glob("library-*")) / "library"
    library_stamp = (library_dir / "library.json").stat().st_mtime_ns
    changed = SyntheticParticlePackDataset(copy, "large", config=CONFIG.replace(postprocess="none"), build=True)
    assert changed.cache_dir != base.cache_dir and changed.pack_paths[0].is_dir()
    assert (library_dir / "library.json").stat().st_mtime_ns == library_stamp  # the library is reused
    assert not np.array_equal(open_pack(changed.pack_paths[0]).tomogram, open_pack(base.pack_paths[0]).tomogram)
    stamp = (base.pack_paths[0] / "labels.tif").stat().st_mtime_ns
    two = dataset(copy, n_packs=2, split="test")
    assert [p.name for p in two.pack_paths] == ["pack_0000", "pack_0001"]
    assert (two.pack_paths[0] / "labels.tif").stat().st_mtime_ns == stamp  # pack 0 kept, pack 1 built
    shapes = [open_pack(p).shape[0] for p in two.pack_paths]
    assert len(two) == sum(len(split_slices(n, "test")) for n in shapes)
    assert {two[i][1]["pack"] for i in range(len(two))} == {0, 1}
    np.testing.assert_array_equal(two.slices(1), split_slices(shapes[1], "test"))


def test_source_identity_enters_the_cache_key(root, large_scan, tmp_path):
    files = [tmp_path / "t.tif", tmp_path / "l.tif"]
    write_tiff(files[0], large_scan.tomogram, large_scan.voxel_size)
    write_tiff(files[1], large_scan.labels, large_scan.voxel_size, labels=True)
    from_files = SyntheticParticlePackDataset(tmp_path, files, config=CONFIG)  # lazy: nothing is built here
    assert from_files.cache_dir == SyntheticParticlePackDataset(tmp_path, tuple(files), config=CONFIG).cache_dir
    os.utime(files[1], ns=(0, 0))  # a rewritten label file is another source
    assert SyntheticParticlePackDataset(tmp_path, files, config=CONFIG).cache_dir != from_files.cache_dir
    library = next(root.glob("library-*")) / "library"
    from_library = SyntheticParticlePackDataset(tmp_path, library, config=CONFIG)
    assert len({from_library.cache_dir, from_files.cache_dir, dataset(tmp_path).cache_dir}) == 3
    assert not any(tmp_path.glob("packs-*"))


def test_config_as_dict_or_yaml_gives_the_same_cache(tmp_path):
    (tmp_path / "pack.yaml").write_text("pour: {n_particles: 20, batch_size: 10}\n")
    keys = {SyntheticParticlePackDataset(tmp_path, "large", config=c).cache_dir
            for c in (CONFIG, CONFIG.to_dict(), tmp_path / "pack.yaml", str(tmp_path / "pack.yaml"))}
    assert len(keys) == 1
    assert SyntheticParticlePackDataset(tmp_path, "large", config=CONFIG, seed=1).cache_dir not in keys


def test_truncated_cache_file_is_rebuilt(root, pack, tmp_path, caplog):
    copy = tmp_path / "cache"
    shutil.copytree(root, copy)
    tomogram = dataset(copy).cache_dir / "pack_0000" / "tomogram.tif"
    size = tomogram.stat().st_size
    os.truncate(tomogram, size // 2)
    rebuilt = dataset(copy, split="all")
    with caplog.at_level(logging.WARNING, logger="synthpack.dataset"):
        assert len(rebuilt) == pack.shape[0]
    assert "unusable" in caplog.text
    assert tomogram.stat().st_size == size
    np.testing.assert_array_equal(rebuilt[3][0][0].numpy(), pack.tomogram[3])


def test_cached_labels_replaced_by_random_content_are_rebuilt(root, pack, tmp_path, caplog):
    copy = tmp_path / "cache"
    shutil.copytree(root, copy)
    labels = dataset(copy).cache_dir / "pack_0000" / "labels.tif"
    noise = np.random.default_rng(0).integers(0, 60000, pack.shape).astype(pack.labels.dtype)
    write_tiff(labels, noise, pack.voxel_size, pack.unit, labels=True)  # same shape and size
    rebuilt = dataset(copy, split="all")
    with caplog.at_level(logging.WARNING, logger="synthpack.dataset"):
        assert len(rebuilt) == pack.shape[0]
    assert "checksum" in caplog.text
    np.testing.assert_array_equal(open_pack(labels.parent).labels[:], pack.labels[:])


def test_a_cached_pack_folder_that_is_a_symlink_is_replaced_not_followed(root, pack, tmp_path):
    copy = tmp_path / "cache"
    shutil.copytree(root, copy)
    cached = dataset(copy).cache_dir / "pack_0000"
    elsewhere = tmp_path / "elsewhere"
    cached.rename(elsewhere)
    cached.symlink_to(elsewhere, target_is_directory=True)
    rebuilt = dataset(copy, split="all")
    assert len(rebuilt) == pack.shape[0]
    assert cached.is_dir() and not cached.is_symlink()
    assert (elsewhere / "manifest.json").is_file()  # what the link pointed to is untouched


def test_without_postprocessing_gives_the_clean_slices(root, pack):
    clean = dataset(root, split="all", postprocess=False)
    image, _ = clean[30]
    np.testing.assert_array_equal(image[0].numpy(), pack.clean[30])
    assert not np.array_equal(image[0].numpy(), pack.tomogram[30])


def test_v2_flip_moves_image_masks_and_boxes_together(root):
    plain = dataset(root)
    flipped = dataset(root, transform=v2.RandomHorizontalFlip(p=1))
    index = len(plain) // 2
    (image, target), (image_f, target_f) = plain[index], flipped[index]
    assert isinstance(image_f, tv_tensors.Image)
    torch.testing.assert_close(image_f, image.flip(-1))
    assert torch.equal(target_f["masks"], target["masks"].flip(-1))
    assert torch.equal(target_f["semantic"], target["semantic"].flip(-1))
    assert isinstance(target_f["boxes"], tv_tensors.BoundingBoxes)
    torch.testing.assert_close(target_f["boxes"].as_subclass(torch.Tensor), boxes_of(target_f["masks"]))
    assert not torch.equal(target_f["boxes"], target["boxes"])


def test_artefact_transform_draws_fresh_noise_each_epoch(root):
    plain = dataset(root)
    noisy = dataset(root, transform=GaussianNoise(std=0.05))
    epoch0 = noisy[5][0]
    assert torch.equal(noisy[5][0], epoch0)  # same epoch, same noise
    assert (epoch0 - plain[5][0]).std() == pytest.approx(0.05, rel=0.1)
    noisy.set_epoch(1)
    assert noisy.epoch == 1
    assert not torch.equal(noisy[5][0], epoch0)
    noisy.set_epoch(0)
    assert torch.equal(noisy[5][0], epoch0)
    assert dataset(root, seed=CONFIG.seed, transform=GaussianNoise(std=0.05))[5][0].equal(epoch0)


def test_scan_dataset_splits_and_concatenates_with_synthetic(root, large_scan, tmp_path):
    real = ScanSliceDataset(large_scan, split="test", axis=1)
    np.testing.assert_array_equal(real.slices(0), split_slices(large_scan.shape[1], "test"))
    image, target = real[0]
    s = target["slice"]
    assert image.shape == (1, 128, 128) and target["pack"] == 0
    np.testing.assert_array_equal(image[0].numpy(), large_scan.tomogram[:, s])
    np.testing.assert_array_equal(target["instance_ids"].numpy(), np.unique(large_scan.labels[:, s])[1:])
    # the same scan from files on disk (memory-mapped TIFFs) gives the same items
    write_tiff(tmp_path / "t.tif", large_scan.tomogram, large_scan.voxel_size)
    write_tiff(tmp_path / "l.tif", large_scan.labels, large_scan.voxel_size, labels=True)
    from_files = ScanSliceDataset(tmp_path / "t.tif", tmp_path / "l.tif", split="test", axis=1)
    assert len(from_files) == len(real)
    assert_same_items(from_files[4], real[4])
    synthetic = dataset(root, split="test", axis=1)
    both = ConcatDataset([real, synthetic])
    assert len(both) == len(real) + len(synthetic)
    assert_same_items(both[len(real)], synthetic[0])
    images, targets = next(iter(DataLoader(both, batch_size=len(both), collate_fn=collate_fn, num_workers=2)))
    assert len(images) == len(both) and {t["pack"] for t in targets} == {0}
    assert "ScanSliceDataset" in repr(real) and "Split: test" in repr(real)


def test_repr_names_root_source_split_and_slices(root):
    text = repr(dataset(root, split="test", axis=2).build())
    assert text.startswith("Dataset SyntheticParticlePackDataset")
    for part in ("Number of datapoints:", f"Root location: {root}", "Source: sample:large", "Split: test",
                 "Axis: 2", "Packs: 1"):
        assert part in text


@pytest.mark.parametrize(
    "kwargs, message",
    [
        (dict(source="medium"), "sample name"),
        (dict(source="large", axis=3), "axis"),
        (dict(source="large", split="val"), "split"),
        (dict(source="large", n_packs=0), "n_packs"),
        (dict(source="large", transform=[v2.RandomHorizontalFlip(), GaussianNoise(std=0.1)]), "list them first"),
        (dict(source="large", transform=42), "callable"),
    ],
)
def test_bad_input_says_what_to_do(tmp_path, kwargs, message):
    with pytest.raises(SynthpackInputError, match=message):
        SyntheticParticlePackDataset(tmp_path, **kwargs)


def test_compact_targets_expand_to_the_dense_masks_after_a_flip(root):
    flip = v2.RandomHorizontalFlip(p=1)
    dense = dataset(root, split="test", transform=flip)
    compact = dataset(root, split="test", transform=flip, dense_masks=False)
    loader = DataLoader(compact, batch_size=4, collate_fn=collate_fn, num_workers=2)
    checked = 0
    for images, targets in loader:
        for image, target in zip(images, targets):
            assert "masks" not in target and target["instance_map"].dtype == torch.int32
            expected_image, expected = dense[checked]
            torch.testing.assert_close(image, expected_image, rtol=0, atol=0)
            expanded = expand_masks(target)
            assert torch.equal(expanded["masks"], expected["masks"])
            assert torch.equal(expanded["boxes"], expected["boxes"])
            checked += 1
    assert checked == len(dense) > 0
    assert expand_masks(expected) is expected


def test_collate_stacked_batches_compact_targets(root):
    compact = dataset(root, split="test", dense_masks=False)
    images, targets = next(iter(DataLoader(compact, batch_size=3, collate_fn=collate_stacked, num_workers=2)))
    assert images.shape[0] == 3 and images.shape[1] == 1
    for b in range(3):
        image, target = compact[b]
        assert torch.equal(images[b], image.as_subclass(torch.Tensor))
        assert torch.equal(targets["instance_map"][b], target["instance_map"].as_subclass(torch.Tensor))
        mine = targets["instances"][:, 0] == b
        assert torch.equal(targets["boxes"][mine], target["boxes"].as_subclass(torch.Tensor))
        assert torch.equal(targets["instances"][mine, 2], target["instance_ids"])
        assert torch.equal(targets["instances"][mine, 1], target["labels"])
        assert targets["index"][b].tolist() == [target["pack"], target["slice"]]
    with pytest.raises(SynthpackInputError, match="dense_masks=False"):
        collate_stacked([dataset(root, split="test")[0]])
