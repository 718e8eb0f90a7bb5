"""What `synthpack generate` prints, through the real command line: readable at the default level,
nothing with --quiet, the details with --verbose; and a voxel size given in px stays in px."""

from __future__ import annotations

import json
import logging
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import tifffile

from synthpack.scan.samples import sample_scan

MAX_LINE = 120
#: A decimal number with more than 6 significant digits (e.g. 179.05899047851562).
LONG_FLOAT = re.compile(r"(?<![\w.])0*(\d+)\.(\d+)")


@pytest.fixture(scope="module")
def scan_files(tmp_path_factory) -> Path:
    """A crop of the 'small' sample as two TIFFs that record no voxel size, and a config, in one folder."""
    folder = tmp_path_factory.mktemp("scan")
    scan = sample_scan("small", seed=0)
    crop = (slice(0, 64), slice(0, 80), slice(0, 80))
    tifffile.imwrite(folder / "scan.tif", scan.tomogram[crop])
    tifffile.imwrite(folder / "labels.tif", scan.labels[crop].astype(np.uint16))
    (folder / "config.yaml").write_text("postprocess: match_source\n", encoding="utf-8")
    return folder


def _generate(folder: Path, out: str, *options: str, config: str = "config.yaml",
              workers: int = 0) -> subprocess.CompletedProcess:
    """``synthpack generate`` of 20-grain packs of the scan in `folder`, run there (relative paths)."""
    argv = [sys.executable, "-m", "synthpack", "generate", "--tomogram", "scan.tif", "--labels", "labels.tif",
            "--voxel-size", "1", "--unit", "px", "--config", config, "--n-particles", "20",
            "--batch-size", "20", "--workers", str(workers), "--out", out, *options]
    env = dict(os.environ, PYTHONPATH=str(Path(__file__).resolve().parents[1]))
    return subprocess.run(argv, cwd=folder, capture_output=True, text=True, env=env, timeout=600)


def _messages(run: subprocess.CompletedProcess) -> list[str]:
    """The log lines (stderr, without progress bars) and the printed lines of `run`."""
    logs = [line for line in re.split(r"[\r\n]", run.stderr) if line.startswith("synthpack: ")]
    return logs + [line for line in run.stdout.splitlines() if line.strip()]


def _significant_digits(number: re.Match) -> int:
    whole, decimals = number.groups()
    digits = (whole.lstrip("0") + decimals) if whole.strip("0") else decimals.lstrip("0")
    return len(digits)


def test_default_output_is_one_short_rounded_line_per_step(scan_files):
    run = _generate(scan_files, "default")
    assert run.returncode == 0, run.stderr
    lines = _messages(run)
    assert any(line.startswith("synthpack: source: grains ") for line in lines), lines
    for line in lines:
        assert len(line) <= MAX_LINE, line
        assert "SourceStatistics(" not in line and "ScannerArtefacts(" not in line, line
        assert "None" not in line, line
        assert all(_significant_digits(n) <= 6 for n in LONG_FLOAT.finditer(line)), line
    assert len(lines) == len(set(lines)), lines
    assert "Traceback" not in run.stderr


def test_quiet_prints_nothing_on_success(scan_files):
    # 20 grains are too few for a bulk, so a target would give a warning (shown under --quiet): none asked here
    (scan_files / "no_target.yaml").write_text("postprocess: match_source\npour:\n  target_solid_fraction: null\n",
                                              encoding="utf-8")
    run = _generate(scan_files, "quiet", "--quiet", config="no_target.yaml")
    assert run.returncode == 0, run.stderr
    assert run.stdout == "" and run.stderr == ""
    assert (scan_files / "quiet" / "pack_0000" / "manifest.json").is_file()


def test_verbose_shows_the_details_and_excludes_quiet(scan_files):
    run = _generate(scan_files, "verbose", "-v")
    assert run.returncode == 0, run.stderr
    assert "SourceStatistics(" in run.stderr and "edge spread: " in run.stderr and "noise estimate: " in run.stderr
    assert "synthpack: source: grains " in run.stderr  # the INFO lines too
    both = _generate(scan_files, "both", "-v", "-q")
    assert both.returncode == 2 and "not allowed with argument" in both.stderr.splitlines()[-1]
    assert not (scan_files / "both").exists()


def test_a_voxel_size_given_in_px_is_read_logged_and_written_in_px(scan_files):
    run = _generate(scan_files, "unit")
    assert run.returncode == 0, run.stderr
    read = [line for line in _messages(run) if line.startswith("synthpack: read scan.tif")]
    assert read == ["synthpack: read scan.tif and labels.tif: 64x80x80 float32, voxel size 1 px (given)"]
    pack = scan_files / "unit" / "pack_0000"
    manifest = json.loads((pack / "manifest.json").read_text())
    assert manifest["unit"] == "px" and manifest["voxel_size"] == [1.0, 1.0, 1.0]
    with tifffile.TiffFile(pack / "tomogram.tif") as tif:
        assert tif.imagej_metadata["unit"] == "pixel"  # ImageJ's name of px, not "micron"


def test_quiet_hides_the_progress_bars_of_library_build(scan_files, tmp_path):
    env = dict(os.environ, PYTHONPATH=str(Path(__file__).resolve().parents[1]))
    argv = [sys.executable, "-m", "synthpack", "library", "build", "--tomogram", str(scan_files / "scan.tif"),
            "--labels", str(scan_files / "labels.tif"), "--voxel-size", "1", "--unit", "px", "--workers", "1",
            "--out", str(tmp_path / "lib")]
    run = subprocess.run([*argv, "-q"], capture_output=True, text=True, env=env, timeout=600)
    assert run.returncode == 0, run.stderr
    assert run.stderr == ""  # no meshing bar, no log line
    assert run.stdout.startswith("158 particles from ")  # the summary asked for
    assert json.loads((tmp_path / "lib" / "library.json").read_text())["unit"] == "px"


def test_a_warning_of_packs_built_by_dask_workers_is_shown_once(scan_files):
    config = scan_files / "calibrated.yaml"
    # 20 grains of a tiny scan: nothing to fit (and no target asked, whose per-pack warnings would differ)
    config.write_text("postprocess: calibrated\npour:\n  target_solid_fraction: null\n", encoding="utf-8")
    run = _generate(scan_files, "dask", "--n-packs", "2", "-q", config=config.name, workers=2)
    assert run.returncode == 0, run.stderr
    lines = run.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith("synthpack: postprocess: calibrated cannot be fitted"), lines
    reasons = {json.loads((scan_files / "dask" / f"pack_000{k}" / "manifest.json").read_text())
               ["postprocess_fallback"] for k in range(2)}
    # both packs fell back for one reason, each with its own figures (how deep its pour is): the first shown
    assert len({re.sub(r"[\d.]+", "#", reason) for reason in reasons}) == 1
    assert any(reason in lines[0] for reason in reasons)


def test_figures_are_rounded_by_their_meaning():
    from synthpack._shared.text import fraction, sig, voxel_size

    assert [sig(v) for v in (179.05899047851562, 0.000522144374903, 3523.4, 4116138.488007309, -0.0011492)] == [
        "179", "0.000522", "3523", "4.12e+06", "-0.00115"]
    assert (sig(None), sig(float("nan")), fraction(0.58431), fraction(None)) == ("n/a", "nan", "0.58", "n/a")
    assert (voxel_size((10.0, 10.0, 10.0), "um"), voxel_size((2.0, 1.0, 1.0), "mm")) == ("10 um", "2 x 1 x 1 mm")


def test_a_voxel_size_without_unit_says_which_unit_it_assumed(scan_files, caplog):
    from synthpack.io import read_scan

    with caplog.at_level(logging.INFO, logger="synthpack.io"):
        scan = read_scan(scan_files / "scan.tif", scan_files / "labels.tif", voxel_size=2.0)
    assert scan.unit == "um"  # the documented default
    (read,) = [r.getMessage() for r in caplog.records if r.getMessage().startswith("read ")]
    assert read.endswith("voxel size 2 um (given; no unit given or recorded: um assumed, give --unit)"), read
