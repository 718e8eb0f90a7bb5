"""Volumes larger than memory: packs streamed chunk by chunk into OME-Zarr, read back slice by slice.

The stores are OME-Zarr images (NGFF 0.5): read back by ome-zarr-py, validated by ome-zarr-models.
"""

from __future__ import annotations

import filecmp
import json
import shutil

import numpy as np
import pytest
import torch
import zarr
from scipy import ndimage

from synthpack.pipeline.config import PackConfig
from synthpack.dataset import SyntheticParticlePackDataset
from synthpack.export import export_yolo
from synthpack.errors import SynthpackInputError
from synthpack.pipeline.generate import build_pack, generate_packs
from synthpack.io import read_scan, read_volume
from synthpack.store.pack import _file_records, open_pack, pack_format
from synthpack._shared.chunks import chunk_boxes
import synthpack.store.zarr_pack as zarr_pack_module
from synthpack.store.zarr_pack import (LevelledVolume, create_levelled_volume, create_volume, level_shapes,
                                     open_volumes, write_levels, write_volume)

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
    whole = build_pack(large_library, config.replace(run={"chunks": [512, 512, 512]}), seed=4, progress=False)
    small = config.replace(run={"chunks": [8, 24, 20]})
    group = zarr.open_group(str(tmp_path / "volumes.zarr"), mode="w")
    chunked = build_pack(large_library, small, seed=4, progress=False, threads=2,
                         allocate=lambda name, shape, dtype, chunks: group.create_array(
                             name, shape=shape, dtype=dtype, chunks=chunks))
    assert isinstance(chunked.labels, zarr.Array)
    # the chunks cut through grains: some grain has voxels on both sides of a chunk boundary in z
    labels = whole.labels
    assert any(set(np.unique(labels[z - 1])) & set(np.unique(labels[z])) - {0} for z in range(8, labels.shape[0], 8))
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
    assert zarr_pack.labels.chunks[0] == 1 and zarr_pack.labels.shards[0] == CONFIG.run.chunks[0]
    # an OME-Zarr image (level 0 only: the pack is smaller than 2 x MIN_LEVEL_SIZE), no scratch store left
    assert sorted(p.name for p in (zarr_pack.path / "pack.zarr").iterdir() if p.is_dir()) == ["0", "clean", "labels"]
    assert sorted(p.name for p in zarr_pack.path.iterdir()) == [".synthpack-files", "manifest.json", "pack.zarr",
                                                                "placements.json"]


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
    from_zarr = SyntheticParticlePackDataset(tmp_path / "cache", tmp_path / "library", format="ome-zarr", **kwargs)
    from_tiff = SyntheticParticlePackDataset(tmp_path / "cache", tmp_path / "library", **kwargs)
    assert from_zarr.cache_dir != from_tiff.cache_dir and len(from_zarr) == len(from_tiff)
    assert isinstance(from_zarr._volumes(0)[0], zarr.Array)
    for i in (0, len(from_zarr) // 2, len(from_zarr) - 1):
        (image, target), (expected_image, expected) = from_zarr[i], from_tiff[i]
        assert torch.equal(image, expected_image)
        assert torch.equal(target["instance_map"], expected["instance_map"])


def _read_ome(store):
    """(image node, label node) as ome-zarr-py reads the store."""
    ome_io, ome_reader = pytest.importorskip("ome_zarr.io"), pytest.importorskip("ome_zarr.reader")
    nodes = list(ome_reader.Reader(ome_io.parse_url(str(store)))())
    labels = [n for n in nodes if any(isinstance(s, ome_reader.Label) for s in n.specs)]
    assert len(labels) == 1 and nodes[0].metadata["name"] == "tomogram"
    return nodes[0], labels[0]


def _validated(store):
    """The store as ome-zarr-models' NGFF 0.5 image model (raises if it is not a valid one)."""
    models = pytest.importorskip("ome_zarr_models.v05.image")
    return models.Image.from_zarr(zarr.open_group(str(store), mode="r"))


def _mean_2x(volume: np.ndarray) -> np.ndarray:
    padded = np.pad(volume, [(0, n % 2) for n in volume.shape], mode="edge").astype(np.float64)
    z, y, x = (n // 2 for n in padded.shape)
    return padded.reshape(z, 2, y, 2, x, 2).mean(axis=(1, 3, 5))


def test_ome_zarr_reader_reads_the_tiff_packs_volumes_and_voxel_size(packs):
    tiff, zarr_pack = packs
    assert zarr_pack.manifest["format"] == "zarr" and pack_format("ome-zarr") == "zarr"
    store = zarr_pack.path / "pack.zarr"
    image, label = _read_ome(store)
    ome_io, ome_reader = pytest.importorskip("ome_zarr.io"), pytest.importorskip("ome_zarr.reader")
    voxel = list(tiff.voxel_size)
    for node in (image, label):
        assert node.metadata["coordinateTransformations"] == [[{"type": "scale", "scale": voxel}]]
        assert [(a["name"], a["type"], a["unit"]) for a in node.metadata["axes"]] == [
            (axis, "space", "micrometer") for axis in "zyx"]
    np.testing.assert_array_equal(np.asarray(image.data[0]), tiff.tomogram)
    np.testing.assert_array_equal(np.asarray(label.data[0]), tiff.labels)
    assert _validated(store).labels.label_paths == ["instances"]
    # the noise-free volume is a second image of the store, which NGFF readers open on its own
    (clean,) = list(ome_reader.Reader(ome_io.parse_url(str(store / "clean")))())
    np.testing.assert_array_equal(np.asarray(clean.data[0]), tiff.clean)


def test_downsampled_levels_have_their_scale_and_overlay_the_labels(packs, tmp_path):
    tiff, zarr_pack = packs
    store = shutil.copytree(zarr_pack.path / "pack.zarr", tmp_path / "pack.zarr")
    assert write_levels(store, tiff.voxel_size, tiff.unit, min_size=16) == 2
    image, label = _read_ome(store)
    voxel = np.asarray(tiff.voxel_size)
    assert image.metadata["coordinateTransformations"][1] == [
        {"type": "scale", "scale": list(2 * voxel)}, {"type": "translation", "translation": list(voxel / 2)}]
    assert label.metadata["coordinateTransformations"][1] == [{"type": "scale", "scale": list(2 * voxel)}]
    np.testing.assert_allclose(np.asarray(image.data[1]), _mean_2x(tiff.tomogram), rtol=1e-6, atol=1e-6)
    np.testing.assert_array_equal(np.asarray(label.data[1]), tiff.labels[::2, ::2, ::2])
    _validated(store)  # ome-zarr-models also checks that the label levels match the image's


@pytest.mark.parametrize("written", ["chunk by chunk", "whole", "levelled", "levelled, off the grid"])
def test_levels_written_block_by_block_equal_those_of_the_whole_volume(tmp_path, written):
    rng = np.random.default_rng(0)
    shape = (37, 50, 45)  # odd sizes: the last voxel of an odd axis is averaged with itself
    tomogram = rng.random(shape, dtype=np.float32)
    labels = rng.integers(0, 9, shape).astype(np.int32)
    store = tmp_path / "pack.zarr"
    level_one = []
    for name, volume in (("tomogram", tomogram), ("clean", tomogram), ("labels", labels)):
        if written == "whole":  # in memory, Zarr's own chunks: as StagedPack.write_volumes writes it
            write_volume(store, name, volume, (2.0, 1.0, 1.0), "mm")
        elif written == "chunk by chunk":
            array = create_volume(store, name, shape, volume.dtype, (2.0, 1.0, 1.0), "mm", chunks=(1, 16, 16),
                                  shards=(8, 16, 16))
            for z in range(0, shape[0], 8):
                array[z:z + 8] = volume[z:z + 8]
        else:  # level 1 made as the blocks are written (a pack's tomogram and labels), in any order
            array = create_levelled_volume(store, name, shape, volume.dtype, (2.0, 1.0, 1.0), "mm",
                                           chunks=(1, 16, 16), shards=(8, 16, 16), min_size=8)
            assert isinstance(array, LevelledVolume) is (name != "clean")
            boxes = list(chunk_boxes(shape, (8, 16, 16)))
            for lo, hi in reversed(boxes):
                array[tuple(slice(a, b) for a, b in zip(lo, hi))] = volume[tuple(slice(a, b) for a, b in zip(lo, hi))]
            if written.endswith("grid"):  # a block written again off the even grid: level 1 is rebuilt
                array[3:9, 5:20, :] = volume[3:9, 5:20, :]
            if isinstance(array, LevelledVolume):
                assert array.level_one is not written.endswith("grid")
                level_one += [name] if array.level_one else []
    assert level_shapes(shape, 8) == [shape, (19, 25, 23), (10, 13, 12)]
    assert write_levels(store, (2.0, 1.0, 1.0), "mm", min_size=8, threads=2, level_one=level_one) == 3
    group = zarr.open_group(str(store), mode="r")
    expected_image, expected_labels, exact = tomogram, labels, tomogram
    for level in (1, 2):
        expected_image, expected_labels = _mean_2x(expected_image), expected_labels[::2, ::2, ::2]
        exact = zarr_pack_module._mean_2x(exact)  # the same bytes, made block by block or from the whole
        np.testing.assert_array_equal(group[str(level)][...], exact)
        np.testing.assert_allclose(group[str(level)][...], expected_image, rtol=1e-6)
        np.testing.assert_array_equal(group[f"labels/instances/{level}"][...], expected_labels)
        assert group[str(level)].attrs["voxel_size"] == [2.0 * 2**level, 2**level, 2**level]
    assert group.attrs["ome"]["multiscales"][0]["axes"][0]["unit"] == "millimeter"
    np.testing.assert_array_equal(open_volumes(store)["labels"][...], labels)
    _validated(store)


def test_read_volume_and_read_scan_read_a_pack_store(packs):
    tiff, zarr_pack = packs
    store = zarr_pack.path / "pack.zarr"
    volume, size, unit = read_volume(store)
    np.testing.assert_array_equal(volume, tiff.tomogram)
    assert size == tiff.voxel_size and unit == "um"
    np.testing.assert_array_equal(read_volume(store, name="clean")[0], tiff.clean)
    np.testing.assert_array_equal(read_volume(store / "labels" / "instances")[0], tiff.labels)
    scan = read_scan(store, store)
    np.testing.assert_array_equal(scan.labels, tiff.labels)
    assert scan.voxel_size == tiff.voxel_size and scan.unit == "um"
    with pytest.raises(SynthpackInputError, match="no image named 'noise'"):
        read_volume(store, name="noise")


def test_packs_of_the_plain_zarr_layout_still_open(packs, tmp_path):
    tiff, zarr_pack = packs
    legacy = shutil.copytree(zarr_pack.path, tmp_path / "pack_0000")
    store = legacy / "pack.zarr"
    for name, path in (("tomogram", "0"), ("clean", "clean/0"), ("labels", "labels/instances/0")):
        shutil.move(store / path, tmp_path / name)
    for path in ("clean", "labels"):
        shutil.rmtree(store / path)
    for name in ("tomogram", "clean", "labels"):
        shutil.move(tmp_path / name, store / name)
    root = json.loads((store / "zarr.json").read_text())
    root["attributes"] = {}
    (store / "zarr.json").write_text(json.dumps(root))
    manifest = json.loads((legacy / "manifest.json").read_text())
    manifest["files"] = _file_records(legacy)
    (legacy / "manifest.json").write_text(json.dumps(manifest))
    pack = open_pack(legacy, verify=True)
    for name in ("tomogram", "clean", "labels"):
        np.testing.assert_array_equal(getattr(pack, name)[:], getattr(tiff, name))
