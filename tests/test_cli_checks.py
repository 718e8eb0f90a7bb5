"""Issue 24's adversarial inputs through the real command line: each is refused up front.

Every case must exit with status 2, print one line on stderr that names the cause (no
traceback) and leave the folder it ran in as it was: no output folder, no partial file.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]
VOXEL = ("--voxel-size", "1", "--unit", "um")  # .npy records none: without it a warning line comes first


def _files(folder: Path) -> set[Path]:
    return set(folder.rglob("*"))


def _refused(folder: Path, *args: str) -> str:
    """Run ``python -m synthpack -q ARGS`` in `folder`; assert the refusal; return its stderr line."""
    before = _files(folder)
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    result = subprocess.run([sys.executable, "-m", "synthpack", "-q", *args], cwd=folder, env=env,
                            capture_output=True, text=True, timeout=120)
    assert result.returncode == 2, result.stderr
    assert "Traceback" not in result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("synthpack: error: "), result.stderr
    assert _files(folder) == before
    return lines[0]


@pytest.fixture
def scans(tmp_path, blob_scan) -> Path:
    """`tmp_path` holding the blob scan (tomo.npy, labels.npy), a constant and an all-zero tomogram
    of its shape, and its first 3 slices (tomo3.npy, labels3.npy)."""
    np.save(tmp_path / "tomo.npy", blob_scan.tomogram)
    np.save(tmp_path / "labels.npy", blob_scan.labels)
    np.save(tmp_path / "constant.npy", np.full(blob_scan.tomogram.shape, 0.5, np.float32))
    np.save(tmp_path / "zero.npy", np.zeros(blob_scan.tomogram.shape, np.float32))
    np.save(tmp_path / "tomo3.npy", blob_scan.tomogram[:3])
    np.save(tmp_path / "labels3.npy", blob_scan.labels[:3])
    return tmp_path


@pytest.mark.parametrize("tomogram", ["zero.npy", "constant.npy"])
def test_library_build_refuses_a_scan_without_contrast(scans, tomogram):
    line = _refused(scans, "library", "build", "--tomogram", tomogram, "--labels", "labels.npy", *VOXEL, "--out", "lib")
    assert "the scan has no contrast" in line


@pytest.mark.parametrize("tomogram", ["zero.npy", "constant.npy"])
def test_label_refuses_a_scan_without_contrast(scans, tomogram):
    line = _refused(scans, "label", "--tomogram", tomogram, *VOXEL, "--out", "labels_out.tif")
    assert "the scan has no contrast" in line


@pytest.mark.parametrize(("patch", "cause"), [("0", "must be a whole number of voxels >= 2"),
                                               ("1", "must be a whole number of voxels >= 2"),
                                               ("5000", "does not fit the source's 40x50 slices")])
def test_compare_refuses_a_patch_that_is_too_small_or_does_not_fit(scans, patch, cause):
    line = _refused(scans, "compare", "--source", "tomo.npy", "labels.npy", *VOXEL, "--out", "report", "--patch", patch)
    assert cause in line


def test_export_yolo_refuses_a_file_given_as_a_pack_folder(scans):
    (scans / "afile.txt").write_text("not a pack\n")
    line = _refused(scans, "export-yolo", "--packs", "afile.txt", "--out", "dataset")
    assert "afile.txt is a file, not a pack folder" in line


def test_export_yolo_says_a_3_slice_scan_is_too_small_for_a_val_split(scans):
    line = _refused(scans, "export-yolo", "--real", "tomo3.npy", "labels3.npy", "--split", "real-test",
                    "--out", "dataset")
    assert "too few slices along axis 0" in line and "has 3" in line and "5 slices for a val slice" in line


@pytest.mark.parametrize(("window", "cause"), [(("0", "1e999"), "the window must be finite, got (0, inf)"),
                                                (("nan", "1"), "the window must be finite"),
                                                (("1", "0"), "the window needs lo < hi")])
def test_export_yolo_refuses_a_window_that_is_not_finite_or_empty(scans, window, cause):
    line = _refused(scans, "export-yolo", "--real", "tomo.npy", "labels.npy", "--window", *window,
                    "--out", "dataset")
    assert cause in line


def test_voxel_size_errors_show_plain_numbers(scans):
    line = _refused(scans, "library", "build", "--tomogram", "tomo.npy", "--labels", "labels.npy",
                    "--voxel-size", "0", "--out", "lib")
    assert "voxel size (0, 0, 0) must be positive and finite" in line and "np.float64" not in line


def test_config_naming_a_folder_is_refused(scans):
    (scans / "configs").mkdir()
    line = _refused(scans, "generate", "--sample", "small", "--config", "configs", "--out", "o")
    assert "is a folder, not a file" in line


def test_generate_refuses_a_cuda_device_torch_does_not_see_before_the_library(scans):
    pytest.importorskip("torch")
    (scans / "device.yaml").write_text("run:\n  device: cuda:99\n")
    line = _refused(scans, "generate", "--sample", "small", "--config", "device.yaml", "--out", "o")
    assert "run.device cuda:99: torch sees" in line


def test_a_file_recording_an_invalid_voxel_size_shows_plain_numbers(tmp_path):
    nib = pytest.importorskip("nibabel")
    image = nib.Nifti1Image(np.linspace(0, 1, 512, dtype=np.float32).reshape(8, 8, 8), np.eye(4))
    image.header.set_xyzt_units("mm")
    image.header["pixdim"][1] = np.inf  # nibabel reads the zooms back as np.float32
    nib.save(image, tmp_path / "scan.nii")
    line = _refused(tmp_path, "label", "--tomogram", "scan.nii", "--out", "labels.tif")
    assert "scan.nii records an invalid voxel size [1.0, 1.0, inf]" in line and "np.float" not in line
