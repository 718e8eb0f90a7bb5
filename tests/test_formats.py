"""Tests for the HDF5, MetaImage, NRRD, NIfTI and raw readers of synthpack.io.

Every file is written by the format's reference library. The volume is
anisotropic and non-cubic (shape 5 x 7 x 9, voxel 3 x 2 x 1), so a reader
that swaps axes or reverses the voxel size fails.
"""

from __future__ import annotations

import sys

import h5py
import nibabel
import nrrd
import numpy as np
import pytest
import SimpleITK as sitk

from synthpack.cli import main
from synthpack.errors import SynthpackInputError
from synthpack.io import read_scan, read_volume
from synthpack.library.core import ParticleLibrary

SHAPE = (5, 7, 9)  # (z, y, x)
VOXEL = (3.0, 2.0, 1.0)  # (dz, dy, dx)


@pytest.fixture
def volume() -> np.ndarray:
    """uint16 (z, y, x) whose every voxel holds a distinct value."""
    return np.arange(np.prod(SHAPE), dtype=np.uint16).reshape(SHAPE) * 7


def labels_of(volume: np.ndarray) -> np.ndarray:
    labels = np.zeros(volume.shape, np.int32)
    labels[1:4, 2:6, 3:8] = 1
    return labels


def one_line_error(call, match: str) -> str:
    with pytest.raises(SynthpackInputError, match=match) as info:
        call()
    message = str(info.value)
    assert "\n" not in message
    return message


# --------------------------------------------------------------------------- #
# HDF5
# --------------------------------------------------------------------------- #


def test_hdf5_dataset_after_a_colon_with_element_size_um(tmp_path, volume):
    with h5py.File(tmp_path / "scan.h5", "w") as file:
        file.create_dataset("entry/data", data=volume).attrs["element_size_um"] = VOXEL
        file.create_dataset("entry/other", data=volume[::-1])
    for data, size, unit in (read_volume(f"{tmp_path / 'scan.h5'}:/entry/data"),
                             read_volume(tmp_path / "scan.h5", name="entry/data")):
        np.testing.assert_array_equal(data, volume)
        assert data.dtype == np.uint16 and size == VOXEL and unit == "um"


def test_hdf5_voxel_size_from_a_parent_group_and_lone_3d_dataset(tmp_path, volume):
    with h5py.File(tmp_path / "scan.hdf5", "w") as file:
        file["scan"] = volume
        file["scan"].attrs["unrelated"] = 1
        file.attrs["voxel_size"] = VOXEL
        file.attrs["unit"] = b"micron"
        file["slice"] = volume[0]  # 2D: not a candidate
    data, size, unit = read_volume(tmp_path / "scan.hdf5")
    np.testing.assert_array_equal(data, volume)
    assert size == VOXEL and unit == "um"


def test_hdf5_tomogram_and_labels_in_one_file_are_told_apart(tmp_path, volume):
    with h5py.File(tmp_path / "both.h5", "w") as file:
        file["tomogram"] = volume.astype(np.float32)
        file["labels"] = labels_of(volume)
        file["labels"].attrs["spacing"] = 0.5
        file["labels"].attrs["units"] = "mm"
    scan = read_scan(tmp_path / "both.h5", tmp_path / "both.h5")
    np.testing.assert_array_equal(scan.tomogram, volume)
    np.testing.assert_array_equal(scan.labels, labels_of(volume))
    assert scan.voxel_size == (0.5, 0.5, 0.5) and scan.unit == "mm"


def test_hdf5_bad_inputs_give_one_line_errors(tmp_path, volume):
    path = tmp_path / "scan.h5"
    with h5py.File(path, "w") as file:
        file["a/first"] = volume
        file["b/second"] = volume
        file["flat"] = volume[0]
    message = one_line_error(lambda: read_volume(path), "cannot tell which 3D dataset")
    assert "a/first" in message and "b/second" in message and f"{path}:/path/to/dataset" in message
    message = one_line_error(lambda: read_volume(f"{path}:/a/missing"), "has no dataset '/a/missing'")
    assert "['a/first', 'b/second']" in message
    one_line_error(lambda: read_scan(f"{path}:/flat", labels_of(volume)), "3D")
    with h5py.File(tmp_path / "none.h5", "w") as file:
        file["flat"] = volume[0]
    one_line_error(lambda: read_volume(tmp_path / "none.h5"), "holds no 3D dataset")
    with h5py.File(tmp_path / "bad_size.h5", "w") as file:
        file["v"] = volume
        file["v"].attrs["element_size_um"] = (1.0, -2.0, 1.0)
    one_line_error(lambda: read_volume(tmp_path / "bad_size.h5"), "invalid voxel size")


# --------------------------------------------------------------------------- #
# ITK formats and NIfTI
# --------------------------------------------------------------------------- #


@pytest.mark.parametrize("suffix", [".mha", ".mhd"])
def test_metaimage_written_by_simpleitk(tmp_path, volume, suffix):
    image = sitk.GetImageFromArray(volume)  # array (z, y, x)
    image.SetSpacing(VOXEL[::-1])  # ITK spacing is (dx, dy, dz)
    sitk.WriteImage(image, str(tmp_path / f"scan{suffix}"))
    data, size, unit = read_volume(tmp_path / f"scan{suffix}")
    np.testing.assert_array_equal(data, volume)
    assert size == VOXEL and unit == "mm"


def test_nrrd_written_by_pynrrd(tmp_path, volume):
    header = {"space": "left-posterior-superior", "space directions": np.diag(VOXEL[::-1]),
              "space units": ["microns"] * 3}
    nrrd.write(str(tmp_path / "scan.nrrd"), volume, header, index_order="C")
    nrrd.write(str(tmp_path / "plain.nrrd"), volume, {"spacings": VOXEL[::-1]}, index_order="C")
    data, size, unit = read_volume(tmp_path / "scan.nrrd")
    np.testing.assert_array_equal(data, volume)
    assert size == VOXEL and unit == "um"
    data, size, unit = read_volume(tmp_path / "plain.nrrd")
    np.testing.assert_array_equal(data, volume)
    assert size == VOXEL and unit == "mm"


@pytest.mark.parametrize("name, units, expected", [("scan.nii.gz", "micron", "um"), ("scan.nii", "unknown", "mm")])
def test_nifti_written_by_nibabel_is_transposed_to_zyx(tmp_path, volume, name, units, expected):
    image = nibabel.Nifti1Image(volume.T, np.diag([*VOXEL[::-1], 1.0]))  # NIfTI arrays are (x, y, z)
    image.header.set_zooms(VOXEL[::-1])
    image.header.set_xyzt_units(xyz=units)
    nibabel.save(image, tmp_path / name)
    data, size, unit = read_volume(tmp_path / name)
    np.testing.assert_array_equal(data, volume)
    assert data.flags.c_contiguous and size == VOXEL and unit == expected


def test_nifti_with_a_single_time_point_is_read_as_its_volume(tmp_path, volume):
    image = nibabel.Nifti1Image(volume.T[..., None], np.diag([*VOXEL[::-1], 1.0]))  # (x, y, z, 1)
    image.header.set_zooms((*VOXEL[::-1], 1.0))
    nibabel.save(image, tmp_path / "scan.nii.gz")
    data, size, _ = read_volume(tmp_path / "scan.nii.gz")
    np.testing.assert_array_equal(data, volume)
    assert size == VOXEL


# --------------------------------------------------------------------------- #
# Raw binary
# --------------------------------------------------------------------------- #


@pytest.mark.parametrize("order", ["little", "big"])
def test_raw_volume_with_its_layout_after_a_colon(tmp_path, volume, order):
    volume.astype(np.dtype(np.uint16).newbyteorder("<" if order == "little" else ">")).tofile(tmp_path / "s.raw")
    labels_of(volume).astype(np.uint8).tofile(tmp_path / "l.raw")
    scan = read_scan(f"{tmp_path / 's.raw'}:5x7x9:uint16:{order}", f"{tmp_path / 'l.raw'}:5x7x9:uint8",
                     voxel_size=VOXEL, unit="um")
    np.testing.assert_array_equal(scan.tomogram, volume)
    assert scan.tomogram.dtype == np.uint16 and scan.tomogram.dtype.isnative
    np.testing.assert_array_equal(scan.labels, labels_of(volume))
    assert read_volume(f"{tmp_path / 's.raw'}:5x7x9:uint16:{order}")[1:] == (None, None)


def test_raw_layout_errors(tmp_path, volume):
    volume.tofile(tmp_path / "s.raw")
    raw = tmp_path / "s.raw"
    one_line_error(lambda: read_volume(raw), "layout is missing")
    one_line_error(lambda: read_volume(f"{raw}:5x7x9:uint16"), "byte order of uint16 is missing")
    one_line_error(lambda: read_volume(f"{raw}:9x7x5x1:uint16:little"), "not three positive integers")
    message = one_line_error(lambda: read_volume(f"{raw}:5x7x9:float32:little"), "check the shape and dtype")
    assert f"is {volume.nbytes:,} bytes" in message and f"take {2 * volume.nbytes:,}" in message


# --------------------------------------------------------------------------- #
# Bad files and missing packages
# --------------------------------------------------------------------------- #


@pytest.mark.parametrize("name, fmt", [("broken.h5", "HDF5"), ("broken.mha", "MetaImage"),
                                       ("broken.nrrd", "NRRD"), ("broken.nii", "NIfTI")])
def test_corrupt_file_gives_a_one_line_error(tmp_path, volume, name, fmt):
    (tmp_path / name).write_bytes(b"\x00garbage, not a volume\xff\n" * 8)
    one_line_error(lambda: read_scan(tmp_path / name, labels_of(volume)), f"cannot read .*{name} as {fmt}")


def test_cli_error_on_a_corrupt_metaimage_is_one_line_even_from_itk(tmp_path, volume, capfd):
    """ITK's MetaIO prints its parse errors on the process's stderr: they are held back."""
    (tmp_path / "broken.mha").write_bytes(b"NDims = 3\nnot a header\n")
    np.save(tmp_path / "labels.npy", labels_of(volume))
    code = main(["-q", "library", "build", "--tomogram", str(tmp_path / "broken.mha"), "--labels",
                 str(tmp_path / "labels.npy"), "--out", str(tmp_path / "lib")])
    assert code == 2
    error = capfd.readouterr().err.strip()
    assert len(error.splitlines()) == 1 and "cannot read" in error and "as MetaImage" in error
    assert "ITK ERROR" not in error and ".cxx" not in error


@pytest.mark.parametrize("name, module, extra", [("x.h5", "h5py", "formats"), ("x.nrrd", "nrrd", "formats"),
                                                 ("x.nii.gz", "nibabel", "formats"),
                                                 ("x.mhd", "SimpleITK", "metaimage")])
def test_missing_reader_package_says_what_to_install(tmp_path, monkeypatch, name, module, extra):
    (tmp_path / name).write_bytes(b"whatever")
    monkeypatch.setitem(sys.modules, module, None)  # import fails as if not installed
    one_line_error(lambda: read_volume(tmp_path / name), f'pip install "synthpack\\[{extra}\\]"')


# --------------------------------------------------------------------------- #
# Command line
# --------------------------------------------------------------------------- #


def test_library_build_from_hdf5_datasets(tmp_path, blob_scan, capsys):
    with h5py.File(tmp_path / "scan.h5", "w") as file:
        file["entry/tomo_data"] = blob_scan.tomogram
        file["entry/segmentation"] = blob_scan.labels
        file["entry"].attrs["element_size_um"] = blob_scan.voxel_size
    h5 = tmp_path / "scan.h5"
    code = main(["-q", "library", "build", "--tomogram", f"{h5}:/entry/tomo_data", "--labels",
                 f"{h5}:/entry/segmentation", "--min-voxels", "100", "--out", str(tmp_path / "lib"),
                 "--workers", "1"])
    assert code == 0
    library = ParticleLibrary.load(tmp_path / "lib")
    assert library.voxel_size == blob_scan.voxel_size == (2.0, 1.0, 1.0)
    assert [p.label for p in library] == [1, 2, 3]
    capsys.readouterr()
    code = main(["-q", "library", "build", "--tomogram", str(h5), "--labels", str(h5),
                 "--out", str(tmp_path / "lib2")])
    assert code == 2
    error = capsys.readouterr().err.strip()
    assert len(error.splitlines()) == 1 and "cannot tell which 3D dataset" in error
