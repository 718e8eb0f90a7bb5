"""Tests for synthpack.io: readers, writers, metadata and input errors."""

from __future__ import annotations

import logging
import os
import subprocess
import sys

import netCDF4
import numpy as np
import pytest
import tifffile
import zarr

from synthpack import io
from synthpack.errors import SynthpackInputError
from synthpack.io import read_scan, read_volume, write_tiff, write_zarr
from synthpack.scan.core import Scan

SHAPE = (6, 20, 24)


@pytest.fixture
def tomogram() -> np.ndarray:
    rng = np.random.default_rng(0)
    return rng.normal(100.0, 10.0, SHAPE).astype(np.float32)


@pytest.fixture
def labels() -> np.ndarray:
    volume = np.zeros(SHAPE, dtype=np.int32)
    volume[1:4, 2:8, 3:9] = 1
    volume[2:5, 10:16, 12:20] = 2
    volume[0:2, 14:19, 2:6] = 7
    return volume


def write_netcdf(path, variables: dict, voxel_size_xyz=None, voxel_unit=None) -> None:
    """Write a Mango-style NetCDF file: dims (z, y, x), one variable per entry."""
    shape = next(iter(variables.values())).shape
    with netCDF4.Dataset(path, mode="w") as dataset:
        for dim, n in zip("zyx", shape):
            dataset.createDimension(dim, n)
        for name, data in variables.items():
            dataset.createVariable(name, data.dtype, ("z", "y", "x"))[:] = data
        if voxel_size_xyz is not None:
            dataset.voxel_size_xyz = np.asarray(voxel_size_xyz, dtype=float)
            dataset.voxel_unit = voxel_unit


# --------------------------------------------------------------------------- #
# Round trips
# --------------------------------------------------------------------------- #


def test_tiff_stack_round_trip_keeps_voxel_size_and_unit(tmp_path, tomogram):
    data = (tomogram * 10).astype(np.uint16)
    path = write_tiff(tmp_path / "tomo.tif", data, (2.0, 0.5, 0.3), "um")

    with tifffile.TiffFile(path) as tif:  # what Fiji reads
        assert tif.is_imagej
        assert tif.series[0].axes == "ZYX"
        assert tif.imagej_metadata["unit"] == "micron"
        assert tif.imagej_metadata["spacing"] == pytest.approx(2.0)

    volume, voxel_size, unit = read_volume(path)
    np.testing.assert_array_equal(volume, data)
    assert volume.dtype == np.uint16
    assert voxel_size == pytest.approx((2.0, 0.5, 0.3), rel=1e-6)
    assert unit == "um"


def test_write_tiff_converts_dtypes_by_a_fixed_rule(tmp_path, labels, tomogram):
    cases = {
        "labels_int64": (labels.astype(np.int64), True, np.uint16),
        "tomo_int64": (labels.astype(np.int64) * 100_000 - 5, False, np.float32),
        "tomo_float64": (tomogram.astype(np.float64), False, np.float32),
        "tomo_int16_neg": (labels.astype(np.int16) - 3, False, np.float32),
        "mask_bool": (labels > 0, False, np.uint8),
        "tomo_float32": (tomogram, False, np.float32),
    }
    for name, (data, is_labels, dtype) in cases.items():
        path = write_tiff(tmp_path / f"{name}.tif", data, 1.0, labels=is_labels)
        volume, _, _ = read_volume(path)
        assert volume.dtype == dtype, name
        np.testing.assert_allclose(volume, data.astype(dtype), err_msg=name)


def test_write_tiff_refuses_labels_beyond_uint16(tmp_path, labels):
    big = labels.astype(np.int64) * 70_000
    with pytest.raises(SynthpackInputError, match="write_zarr"):
        write_tiff(tmp_path / "labels.tif", big, 1.0, labels=True)
    with pytest.raises(SynthpackInputError, match="must be integers"):
        write_tiff(tmp_path / "labels.tif", labels + 0.5, 1.0, labels=True)
    assert list(tmp_path.iterdir()) == []


def test_write_tiff_uses_bigtiff_above_the_size_limit(tmp_path, monkeypatch, tomogram):
    monkeypatch.setattr(io.tiff, "_BIGTIFF_BYTES", 0)
    path = write_tiff(tmp_path / "big.tif", tomogram, (1.0, 2.0, 2.0), "mm")
    with tifffile.TiffFile(path) as tif:
        assert tif.is_bigtiff
    volume, voxel_size, unit = read_volume(path)
    np.testing.assert_array_equal(volume, tomogram)
    assert voxel_size == pytest.approx((1.0, 2.0, 2.0)) and unit == "mm"


def test_tiff_metadata_variants(tmp_path, tomogram):
    data = tomogram.astype(np.float32)
    tifffile.imwrite(tmp_path / "mu.tif", data, imagej=True, resolution=(2.0, 2.0),
                     metadata={"spacing": 0.5, "unit": "\\u00B5m", "axes": "ZYX"})
    assert read_volume(tmp_path / "mu.tif")[1:] == ((0.5, 0.5, 0.5), "um")

    tifffile.imwrite(tmp_path / "cm.tif", data, resolution=(2000.0, 2000.0),
                     resolutionunit="CENTIMETER")
    voxel_size, unit = read_volume(tmp_path / "cm.tif")[1:]
    assert voxel_size == pytest.approx((5.0, 5.0, 5.0)) and unit == "um"

    tifffile.imwrite(tmp_path / "dpi.tif", data, resolution=(72.0, 72.0),
                     resolutionunit="INCH")
    assert read_volume(tmp_path / "dpi.tif")[1:] == (None, None)

    tifffile.imwrite(tmp_path / "pixel.tif", data, imagej=True,
                     metadata={"unit": "pixel", "axes": "ZYX"})
    assert read_volume(tmp_path / "pixel.tif")[1:] == (None, None)


def test_tiff_folder_is_stacked_in_natural_order(tmp_path):
    folder = tmp_path / "slices"
    folder.mkdir()
    for k in range(12):
        tifffile.imwrite(folder / f"slice_{k}.tif", np.full((20, 24), k, np.uint16),
                         imagej=True, resolution=(1 / 0.4, 1 / 0.4),
                         metadata={"unit": "um"})
    (folder / "notes.txt").write_text("not a slice")

    volume, voxel_size, unit = read_volume(folder)
    assert volume.shape == (12, 20, 24)
    assert [int(volume[k, 0, 0]) for k in range(12)] == list(range(12))
    assert voxel_size == pytest.approx((0.4, 0.4, 0.4)) and unit == "um"


def test_npy_round_trip(tmp_path, labels):
    np.save(tmp_path / "labels.npy", labels)
    volume, voxel_size, unit = read_volume(tmp_path / "labels.npy")
    np.testing.assert_array_equal(volume, labels)
    assert (voxel_size, unit) == (None, None)


def test_zarr_round_trip_keeps_attrs_and_chunks(tmp_path, tomogram):
    path = write_zarr(tmp_path / "tomo.zarr", tomogram, (3.0, 1.0, 1.0), "um",
                      chunks=(2, 10, 12))
    array = zarr.open(str(path), mode="r")
    assert array.chunks == (2, 10, 12)
    assert array.attrs["voxel_size"] == [3.0, 1.0, 1.0] and array.attrs["unit"] == "um"

    volume, voxel_size, unit = read_volume(path)
    np.testing.assert_array_equal(volume, tomogram)
    assert voxel_size == (3.0, 1.0, 1.0) and unit == "um"

    write_zarr(path, tomogram[:, :10], 2.0, "mm")  # replaces the whole store
    volume, voxel_size, unit = read_volume(path)
    assert volume.shape == (6, 10, 24) and voxel_size == (2.0, 2.0, 2.0) and unit == "mm"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["tomo.zarr"]


def test_zarr_group_holds_tomogram_and_labels(tmp_path, tomogram, labels):
    store = tmp_path / "pack.zarr"
    write_zarr(store, tomogram, (1.0, 0.5, 0.5), "um", name="tomogram")
    write_zarr(store, labels, (1.0, 0.5, 0.5), "um", name="labels")
    write_zarr(store, labels * 2, (1.0, 0.5, 0.5), "um", name="labels")  # replaced

    scan = read_scan(store, store)
    np.testing.assert_array_equal(scan.tomogram, tomogram)
    np.testing.assert_array_equal(scan.labels, labels * 2)
    assert scan.voxel_size == (1.0, 0.5, 0.5) and scan.unit == "um"
    np.testing.assert_array_equal(read_volume(store, name="labels")[0], labels * 2)
    with pytest.raises(SynthpackInputError, match="cannot tell which array"):
        read_volume(store)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["pack.zarr"]


def test_write_zarr_never_replaces_a_folder_that_is_not_a_store(tmp_path, tomogram):
    (tmp_path / "data").mkdir()
    (tmp_path / "data" / "precious.txt").write_text("keep me")
    with pytest.raises(SynthpackInputError, match="not a Zarr store"):
        write_zarr(tmp_path / "data", tomogram, 1.0, "um")
    assert (tmp_path / "data" / "precious.txt").read_text() == "keep me"


def test_netcdf_files_read_like_mango(tmp_path, tomogram, labels):
    fov = labels.astype(np.uint8)
    fov[:, 0, :] = 255  # outside the field of view
    write_netcdf(tmp_path / "tomo.nc", {"tomo": tomogram}, (0.002, 0.002, 0.004), "mm")
    write_netcdf(tmp_path / "labels.nc", {"labels": fov})

    scan = read_scan(tmp_path / "tomo.nc", tmp_path / "labels.nc")
    np.testing.assert_array_equal(scan.tomogram, tomogram)
    expected = labels.copy()
    expected[:, 0, :] = 0
    np.testing.assert_array_equal(scan.labels, expected)
    assert scan.voxel_size == pytest.approx((0.004, 0.002, 0.002))  # xyz -> zyx
    assert scan.unit == "mm"

    write_netcdf(tmp_path / "both.nc", {"tomo": tomogram, "labels": fov})
    both = read_scan(tmp_path / "both.nc", tmp_path / "both.nc", voxel_size=1.0)
    np.testing.assert_array_equal(both.labels, expected)


def test_netcdf_blocks_are_concatenated_along_z(tmp_path, labels):
    outside = np.iinfo(np.int32).max
    volume = labels.copy()
    volume[:, :, -1] = outside
    folder = tmp_path / "labels_nc"
    folder.mkdir()
    for k, z0 in enumerate((0, 2, 4)):
        write_netcdf(folder / f"block{k:08d}.nc", {"labels": volume[z0:z0 + 2]},
                     (0.5, 0.5, 0.5), "micron")

    read, voxel_size, unit = read_volume(folder)
    assert read.dtype == np.int32
    expected = labels.copy()
    expected[:, :, -1] = 0
    np.testing.assert_array_equal(read, expected)
    assert voxel_size == (0.5, 0.5, 0.5) and unit == "um"


def test_netcdf_without_known_variable_names_those_present(tmp_path, tomogram):
    write_netcdf(tmp_path / "density.nc", {"density": tomogram})
    with pytest.raises(SynthpackInputError, match="variables present: \\['density'\\]"):
        read_scan(tmp_path / "density.nc", tmp_path / "density.nc")
    volume, _, _ = read_volume(tmp_path / "density.nc", name="density")
    np.testing.assert_array_equal(volume, tomogram)


def test_netcdf_labels_file_is_not_taken_as_tomogram(tmp_path, labels):
    write_netcdf(tmp_path / "labels.nc", {"labels": labels})
    with pytest.raises(SynthpackInputError, match="the tomogram volume"):
        read_scan(tmp_path / "labels.nc", tmp_path / "labels.nc")


# --------------------------------------------------------------------------- #
# Voxel size resolution
# --------------------------------------------------------------------------- #


def test_voxel_size_precedence(tmp_path, tomogram, labels, caplog):
    write_tiff(tmp_path / "tomo.tif", tomogram, (2.0, 1.0, 1.0), "um")
    write_tiff(tmp_path / "labels.tif", labels, (9.0, 9.0, 9.0), "um", labels=True)

    with caplog.at_level(logging.INFO, logger="synthpack.io"):
        scan = read_scan(tmp_path / "tomo.tif", tmp_path / "labels.tif")
    assert scan.voxel_size == pytest.approx((2.0, 1.0, 1.0)) and scan.unit == "um"
    assert "using the tomogram's" in caplog.text

    caplog.clear()
    with caplog.at_level(logging.INFO, logger="synthpack.io"):
        scan = read_scan(tmp_path / "tomo.tif", labels, voxel_size=5.0)
    assert scan.voxel_size == (5.0, 5.0, 5.0) and scan.unit == "um"
    assert "overrides" in caplog.text
    assert scan.metadata["voxel_size_from"] == "argument"

    scan = read_scan(tmp_path / "tomo.tif", labels, unit="mm")  # converted
    assert scan.voxel_size == pytest.approx((0.002, 0.001, 0.001)) and scan.unit == "mm"


def test_missing_voxel_size_defaults_to_px_with_a_warning(tmp_path, tomogram, labels,
                                                          caplog):
    with caplog.at_level(logging.WARNING, logger="synthpack.io"):
        scan = read_scan(tomogram, labels)
    assert isinstance(scan, Scan)
    assert scan.voxel_size == (1.0, 1.0, 1.0) and scan.unit == "px"
    assert "--voxel-size" in caplog.text


# --------------------------------------------------------------------------- #
# Bad input
# --------------------------------------------------------------------------- #


def test_missing_file(tmp_path, labels):
    missing = tmp_path / "nowhere.tif"
    with pytest.raises(SynthpackInputError, match="does not exist") as info:
        read_scan(missing, labels)
    assert str(missing) in str(info.value)
    assert not isinstance(info.value, FileNotFoundError)


@pytest.mark.parametrize("name, fmt", [("broken.tif", "TIFF"), ("broken.nc", "NetCDF"),
                                       ("broken.npy", "NumPy")])
def test_corrupt_file(tmp_path, labels, name, fmt):
    (tmp_path / name).write_bytes(b"\x00garbage, not a volume\xff" * 8)
    with pytest.raises(SynthpackInputError, match=f"cannot read .*{name} as {fmt}"):
        read_scan(tmp_path / name, labels)


@pytest.mark.parametrize("writer", [
    lambda path, volume: write_tiff(path, volume, (1, 1, 1)),
    lambda path, volume: tifffile.imwrite(path, volume),
    lambda path, volume: tifffile.imwrite(path, volume, metadata=None, compression="zlib"),
], ids=["imagej", "tifffile", "compressed-without-metadata"])
@pytest.mark.parametrize("kept", [0.1, 0.5, 0.99])
def test_truncated_tiff_is_named_as_such(tmp_path, tomogram, writer, kept, caplog):
    """Issue 13 case 9: a stack cut in half was read as its first slice ("2 dimension(s)")."""
    writer(tmp_path / "whole.tif", np.tile(tomogram, (4, 1, 1)))
    data = (tmp_path / "whole.tif").read_bytes()
    (tmp_path / "cut.tif").write_bytes(data[: int(len(data) * kept)])
    with pytest.raises(SynthpackInputError, match="cut.tif looks truncated .* Re-export or copy the file again"):
        read_volume(tmp_path / "cut.tif")
    assert not [r for r in caplog.records if r.name == "tifffile"]


def test_cli_refuses_a_truncated_tiff_in_one_line(tmp_path, tomogram, labels):
    volume = np.tile(tomogram, (4, 1, 1))
    write_tiff(tmp_path / "whole.tif", volume, (1, 1, 1))
    write_tiff(tmp_path / "labels.tif", np.tile(labels, (4, 1, 1)), (1, 1, 1), labels=True)
    data = (tmp_path / "whole.tif").read_bytes()
    (tmp_path / "cut.tif").write_bytes(data[: len(data) // 2])
    run = subprocess.run([sys.executable, "-m", "synthpack.cli", "library", "build", "--tomogram",
                          str(tmp_path / "cut.tif"), "--labels", str(tmp_path / "labels.tif"),
                          "--out", str(tmp_path / "x")], capture_output=True, text=True)
    assert run.returncode == 2
    lines = run.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in run.stderr
    assert "cut.tif looks truncated" in lines[0] and f"{volume.shape[0]} images announced, 1 found" in lines[0]
    assert "Re-export or copy the file again" in lines[0]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cut.tif", "labels.tif", "whole.tif"]


def test_corrupt_slice_in_folder_is_named(tmp_path):
    folder = tmp_path / "slices"
    folder.mkdir()
    tifffile.imwrite(folder / "s1.tif", np.zeros((4, 5), np.uint8))
    (folder / "s2.tif").write_bytes(b"garbage")
    with pytest.raises(SynthpackInputError, match="s2.tif as TIFF"):
        read_volume(folder)


def test_unknown_extension(tmp_path, labels):
    (tmp_path / "tomo.png").write_bytes(b"png")
    with pytest.raises(SynthpackInputError, match="not a supported volume file") as info:
        read_scan(tmp_path / "tomo.png", labels)
    assert "TIFF" in str(info.value) and "Zarr" in str(info.value)


def test_empty_folder(tmp_path, labels):
    (tmp_path / "empty").mkdir()
    with pytest.raises(SynthpackInputError, match="is empty"):
        read_scan(tmp_path / "empty", labels)


def test_folder_of_mismatched_slices(tmp_path):
    folder = tmp_path / "slices"
    folder.mkdir()
    tifffile.imwrite(folder / "slice_1.tif", np.zeros((20, 24), np.uint16))
    tifffile.imwrite(folder / "slice_2.tif", np.zeros((20, 23), np.uint16))
    with pytest.raises(SynthpackInputError, match="same shape and dtype"):
        read_volume(folder)


def test_shape_mismatch(tmp_path, tomogram, labels):
    np.save(tmp_path / "labels.npy", labels[:, :, :-1])
    with pytest.raises(SynthpackInputError, match="differ") as info:
        read_scan(tomogram, tmp_path / "labels.npy")
    assert "labels.npy" in str(info.value)


def test_float_labels(tmp_path, tomogram, labels):
    np.save(tmp_path / "fractional.npy", labels + 0.25)
    with pytest.raises(SynthpackInputError, match="fractional"):
        read_scan(tomogram, tmp_path / "fractional.npy")

    np.save(tmp_path / "whole.npy", labels.astype(np.float32))
    with pytest.warns(UserWarning, match="whole-number"):
        scan = read_scan(tomogram, tmp_path / "whole.npy")
    assert np.issubdtype(scan.labels.dtype, np.integer)
    np.testing.assert_array_equal(scan.labels, labels)


def test_negative_labels(tmp_path, tomogram, labels):
    np.save(tmp_path / "labels.npy", labels - 1)
    with pytest.raises(SynthpackInputError, match="negative"):
        read_scan(tomogram, tmp_path / "labels.npy")


def test_2d_tiff_as_tomogram(tmp_path, tomogram, labels):
    tifffile.imwrite(tmp_path / "slice.tif", tomogram[0])
    with pytest.raises(SynthpackInputError, match="2 dimension") as info:
        read_scan(tmp_path / "slice.tif", labels)
    assert "slice.tif" in str(info.value)


def test_empty_labels(tmp_path, tomogram):
    write_tiff(tmp_path / "labels.tif", np.zeros(SHAPE, np.uint16), 1.0, labels=True)
    with pytest.raises(SynthpackInputError, match="no particle"):
        read_scan(tomogram, tmp_path / "labels.tif")


def test_nan_in_tomogram(tmp_path, tomogram, labels):
    tomogram[2, 3, 4] = np.nan
    write_tiff(tmp_path / "tomo.tif", tomogram, 1.0)
    with pytest.raises(SynthpackInputError, match="NaN"):
        read_scan(tmp_path / "tomo.tif", labels)


def test_input_of_wrong_type(labels):
    with pytest.raises(SynthpackInputError, match="file path or a NumPy array"):
        read_scan(labels.tolist(), labels)


# --------------------------------------------------------------------------- #
# Atomic writes
# --------------------------------------------------------------------------- #


def disk_full(*args, **kwargs):
    raise OSError("disk full")


def test_failed_tiff_write_leaves_nothing(tmp_path, monkeypatch, tomogram):
    out = tmp_path / "out"

    def fail_midway(file, *args, **kwargs):
        with open(file, "wb") as handle:
            handle.write(b"II*\x00 partial")
        raise OSError("disk full")

    monkeypatch.setattr(tifffile, "imwrite", fail_midway)
    with pytest.raises(OSError, match="disk full"):
        write_tiff(out / "tomo.tif", tomogram, 1.0)
    assert list(out.iterdir()) == []


def test_failed_tiff_write_keeps_the_old_file(tmp_path, monkeypatch, tomogram):
    path = write_tiff(tmp_path / "tomo.tif", tomogram, 1.0)
    before = path.read_bytes()
    monkeypatch.setattr(tifffile, "imwrite", disk_full)
    with pytest.raises(OSError):
        write_tiff(path, tomogram * 2, 1.0)
    assert path.read_bytes() == before
    assert os.listdir(tmp_path) == ["tomo.tif"]


def test_failed_zarr_write_leaves_nothing(tmp_path, monkeypatch, tomogram):
    real_create = zarr.create_array

    def fail_midway(store, **kwargs):
        real_create(store=store, **{**kwargs, "data": kwargs["data"][:1]})
        raise OSError("disk full")

    monkeypatch.setattr(zarr, "create_array", fail_midway)
    with pytest.raises(OSError, match="disk full"):
        write_zarr(tmp_path / "tomo.zarr", tomogram, 1.0, "um")
    with pytest.raises(OSError, match="disk full"):
        write_zarr(tmp_path / "pack.zarr", tomogram, 1.0, "um", name="tomogram")
    assert list(tmp_path.iterdir()) == []


def test_failed_zarr_write_keeps_the_other_arrays(tmp_path, monkeypatch, tomogram, labels):
    store = write_zarr(tmp_path / "pack.zarr", tomogram, 1.0, "um", name="tomogram")
    write_zarr(store, labels, 1.0, "um", name="labels")
    monkeypatch.setattr(zarr, "create_array", disk_full)
    with pytest.raises(OSError):
        write_zarr(store, labels * 3, 1.0, "um", name="labels")
    monkeypatch.undo()
    np.testing.assert_array_equal(read_volume(store, name="labels")[0], labels)
    assert sorted(p.name for p in store.iterdir()) == ["labels", "tomogram", "zarr.json"]


def test_an_ome_zarr_0_4_image_reads_its_full_resolution_level_with_scale_and_unit(tmp_path, tomogram):
    """NGFF 0.4 on Zarr v2: ``multiscales`` at the top of the attributes, a global scale on top of the level's."""
    root = zarr.open_group(str(tmp_path / "image.zarr"), mode="w", zarr_format=2)
    root.create_array("s0", data=tomogram)
    root.create_array("s1", data=tomogram[::2, ::2, ::2])
    root.attrs["multiscales"] = [{
        "version": "0.4", "axes": [{"name": axis, "type": "space", "unit": "millimeter"} for axis in "zyx"],
        "datasets": [{"path": f"s{k}", "coordinateTransformations": [{"type": "scale", "scale": [f, f / 2, f / 2]}]}
                     for k, f in ((0, 1.0), (1, 2.0))],
        "coordinateTransformations": [{"type": "scale", "scale": [2.0, 1.0, 1.0]}],
    }]
    volume, size, unit = read_volume(tmp_path / "image.zarr")
    np.testing.assert_array_equal(volume, tomogram)
    assert size == (2.0, 0.5, 0.5) and unit == "mm"
