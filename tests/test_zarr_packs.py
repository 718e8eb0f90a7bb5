"""Volumes larger than memory: packs streamed chunk by chunk into Zarr, read back slice by slice."""

from __future__ import annotations

import filecmp

import numpy as np
import pytest
import torch
import zarr
from scipy import ndimage

from synthpack.config import PackConfig
from synthpack.dataset import SyntheticParticlePackDataset
from synthpack.export import export_yolo
from synthpack.generate import build_pack, generate_packs
from synthpack.pack import open_pack

CONFIG = PackConfig().replace(pour={"n_particles": 8, "batch_size": 8})


@pytest.fixture(scope="module")
def packs(large_library, tmp_path_factory):
    """One pack of CONFIG as TIFF and as Zarr."""
    out = tmp_path_factory.mktemp("packs")
    (tiff,) = generate_packs(large_library, out / "tiff", 1, CONFIG, workers=0, progress=False)
    (zarr_pack,) = generate_packs(large_library, out / "zarr", 1, CONFIG, format="zarr", workers=0, progress=False)
    return open_pack(tiff), open_pack(zarr_pack)


def test_chunked_zarr_build_equals_in_memory_build_voxel_for_voxel(large_library, tmp_path):
    sigma = 0.8
    config = CONFIG.replace(postprocess=[{"name": "gaussian_blur", "sigma": sigma}])
    whole = build_pack(large_library, config.replace(reconstruct={"chunks": [512, 512, 512]}), seed=4, progress=False)
    small = config.replace(reconstruct={"chunks": [8, 24, 20]})
    group = zarr.open_group(str(tmp_path / "volumes.zarr"), mode="w")
    chunked = build_pack(large_library, small, seed=4, progress=False, threads=2,
                         allocate=lambda name, shape, dtype, chunks: group.create_array(
                             name, shape=shape, dtype=dtype, chunks=chunks))
    assert isinstance(chunked.labels, zarr.Array)
    # the chunks cut through grains: some grain has voxels in more than one chunk
    labels = whole.labels
    split = set(np.unique(labels[:8])) & set(np.unique(labels[8:16])) - {0}
    assert split
    np.testing.assert_array_equal(chunked.labels[:], labels)
    np.testing.assert_array_equal(chunked.clean[:], whole.clean)
    # Gaussian blur with a halo equals the blur of the whole volume
    np.testing.assert_array_equal(chunked.tomogram[:], whole.tomogram)
    np.testing.assert_array_equal(whole.tomogram, ndimage.gaussian_filter(whole.clean, sigma, output=np.float32))
    assert chunked.manifest["n_labels"] == whole.manifest["n_labels"]
    assert chunked.manifest["contested_voxels"] == whole.manifest["contested_voxels"]


def test_zarr_and_tiff_packs_hold_the_same_voxels(packs):
    tiff, zarr_pack = packs
    assert zarr_pack.manifest["format"] == "zarr" and isinstance(zarr_pack.tomogram, zarr.Array)
    for name in ("tomogram", "clean", "labels"):
        np.testing.assert_array_equal(getattr(zarr_pack, name)[:], getattr(tiff, name))
    # one compressed chunk per slice of a block: a z slice is read without its neighbours
    assert zarr_pack.labels.chunks[0] == 1 and zarr_pack.labels.shards[0] == CONFIG.reconstruct.chunks[0]
    assert sorted(p.name for p in (zarr_pack.path / "pack.zarr").iterdir() if p.is_dir()) == [
        "clean", "labels", "tomogram"]


def test_yolo_export_of_a_zarr_pack_equals_that_of_the_tiff_pack(packs, tmp_path):
    tiff, zarr_pack = packs
    for name, pack in (("tiff", tiff), ("zarr", zarr_pack)):
        export_yolo(tmp_path / name, packs=[pack.path], progress=False)
    compared = filecmp.dircmp(tmp_path / "tiff" / "labels" / "train", tmp_path / "zarr" / "labels" / "train")
    assert compared.left_list and not compared.diff_files and not compared.left_only
    compared = filecmp.dircmp(tmp_path / "tiff" / "images" / "test", tmp_path / "zarr" / "images" / "test")
    assert compared.left_list and not compared.diff_files


def test_dataset_serves_zarr_packs_slice_by_slice(large_library, tmp_path):
    large_library.save(tmp_path / "library")
    kwargs = dict(config=CONFIG, split="all", axis=1, dense_masks=False)
    from_zarr = SyntheticParticlePackDataset(tmp_path / "cache", tmp_path / "library", format="zarr", **kwargs)
    from_tiff = SyntheticParticlePackDataset(tmp_path / "cache", tmp_path / "library", **kwargs)
    assert from_zarr.cache_dir != from_tiff.cache_dir and len(from_zarr) == len(from_tiff)
    assert isinstance(from_zarr._volumes(0)[0], zarr.Array)
    for i in (0, len(from_zarr) // 2, len(from_zarr) - 1):
        (image, target), (expected_image, expected) = from_zarr[i], from_tiff[i]
        assert torch.equal(image, expected_image)
        assert torch.equal(target["instance_map"], expected["instance_map"])
