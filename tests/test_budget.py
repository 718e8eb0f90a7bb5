"""Issue 24: jobs too large for the machine are refused up front (rc 2, one line with the figure)."""

from __future__ import annotations

import math
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

from synthpack._shared import budget
from synthpack.errors import SynthpackInputError

REPO = Path(__file__).resolve().parents[1]


def _refused(argv: list[str], phrase: str, tmp_path: Path, created: Path) -> None:
    """Run the CLI; assert rc 2 within 20 s, one stderr line containing `phrase`, and `created` absent."""
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    start = time.perf_counter()
    run = subprocess.run([sys.executable, "-m", "synthpack", "-q", *argv], capture_output=True, text=True,
                         env=env, cwd=tmp_path, timeout=120)
    elapsed = time.perf_counter() - start
    assert run.returncode == 2, run.stderr
    assert "Traceback" not in run.stderr
    assert len(run.stderr.strip().splitlines()) == 1, run.stderr
    assert phrase in run.stderr, run.stderr
    assert not created.exists()
    assert elapsed < 20, elapsed


@pytest.fixture(scope="module")
def library_dir(large_library, tmp_path_factory) -> Path:
    return large_library.save(tmp_path_factory.mktemp("budget") / "lib")


@pytest.mark.parametrize("command", ["pour", "generate"])
def test_too_many_grains_refused_with_the_time_estimate(tmp_path, library_dir, command):
    out = tmp_path / ("p.json" if command == "pour" else "packs")
    _refused([command, "--library", str(library_dir), "--out", str(out), "--n-particles", "100000000"],
             "pouring 100,000,000 grains would take about", tmp_path, out)


def test_too_many_grains_in_config_refused(tmp_path, library_dir):
    config = tmp_path / "c.yaml"
    config.write_text("pour:\n  n_particles: 5000000\n")
    out = tmp_path / "packs"
    _refused(["generate", "--library", str(library_dir), "--out", str(out), "--config", str(config)],
             "lower pour.n_particles", tmp_path, out)


def test_huge_tube_refused_with_the_memory_estimate(tmp_path, library_dir):
    out = tmp_path / "p.json"
    _refused(["pour", "--library", str(library_dir), "--out", str(out), "--n-particles", "10",
              "--tube-radius", "1e7", "--tube-height", "1e7"], "of memory but", tmp_path, out)
    config = tmp_path / "c.yaml"
    config.write_text("pour:\n  n_particles: 10\n  tube_radius: 10000000.0\n  tube_height: 10000000.0\n")
    out = tmp_path / "packs"
    _refused(["generate", "--library", str(library_dir), "--out", str(out), "--config", str(config)],
             "of memory but", tmp_path, out)


def test_huge_scale_refused_with_the_memory_estimate(tmp_path, library_dir):
    config = tmp_path / "c.yaml"
    config.write_text("pour:\n  n_particles: 10\n  scale: 1000\nreconstruct:\n  view: tube\n")  # the tube asked for: no fallback warning
    out = tmp_path / "packs"
    _refused(["generate", "--library", str(library_dir), "--out", str(out), "--config", str(config)],
             "of memory but", tmp_path, out)


@pytest.mark.parametrize("command", ["label", "library"])
def test_huge_raw_volume_refused_before_reading(tmp_path, command):
    big = tmp_path / "big.raw"
    with open(big, "wb") as f:
        # sparse, so no disk is used: 320 GiB, more than any test machine's memory (the case was 40 GiB)
        os.truncate(f.fileno(), 20480 * 4096 * 4096)
    spec = f"{big}:20480x4096x4096:uint8"
    if command == "label":
        out = tmp_path / "labels.tif"
        argv = ["label", "--tomogram", spec, "--out", str(out)]
    else:
        out = tmp_path / "lib"
        argv = ["library", "build", "--tomogram", spec, "--labels", spec, "--out", str(out)]
    _refused(argv, "320.0 GiB of memory", tmp_path, out)


def test_labelling_estimate_uses_the_readme_figure():
    """A 10^12-voxel volume at 30 B/voxel is far beyond any machine; the message names the voxels."""
    with pytest.raises(SynthpackInputError, match="1,000,000,000,000 voxels"):
        budget.check_volume((10_000,) * 3, budget.LABEL_BYTES_PER_VOXEL, "labelling", "crop")


def test_demo_sized_jobs_are_far_below_8_gib(large_library):
    """The demo's `large` sample (labelled at 30 B/voxel) and its default pack fit with room to spare."""
    from synthpack.pipeline.config import PackConfig
    from synthpack.render import Grid
    from synthpack.scan.samples import sample_scan

    shape = sample_scan("large", seed=0).tomogram.shape
    assert math.prod(shape) * budget.LABEL_BYTES_PER_VOXEL < 2**30  # under 1 GiB, against 8
    config = PackConfig()
    for interior in (False, True):  # the demo's pack is an interior crop of `large`: the wider tube
        tube = config.pour.tube(large_library, interior=interior)
        grid = Grid.covering(tube.outer_radius, -tube.base_thickness, tube.height, large_library.voxel_size)
        assert math.prod(grid.shape) * budget.PACK_BYTES_PER_VOXEL < 2**30
        assert config.pour.grains(large_library, interior=interior) < budget.MAX_POUR_GRAINS
    assert budget.MAX_POUR_GRAINS > 10_000  # the 10,000-grain benchmark pour is accepted


def test_huge_npy_refused_before_reading(tmp_path):
    """The .npy header gives the shape; nothing is allocated (the file is sparse)."""
    import numpy as np

    from synthpack.io import read_volume

    np.lib.format.open_memmap(tmp_path / "big.npy", mode="w+", dtype=np.float32, shape=(2048, 4096, 4096))
    with pytest.raises(SynthpackInputError, match=r"reading .*big\.npy \(2048x4096x4096"):
        read_volume(tmp_path / "big.npy")
