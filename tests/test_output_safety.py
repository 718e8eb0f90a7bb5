"""Replacing synthpack's own earlier output deletes only the files it recorded (issue 24), through the CLI."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from synthpack.io.atomic import RECORD

ROOT = Path(__file__).resolve().parents[1]


def run(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    return subprocess.run([sys.executable, "-m", "synthpack", "-q", *args], cwd=cwd, env=env,
                          capture_output=True, text=True, timeout=300)


@pytest.fixture
def scan_files(tmp_path, blob_scan_files) -> Path:
    """The blob scan as t.tif / l.tif in `tmp_path` (four grains, 30x40x50)."""
    for path in blob_scan_files:
        shutil.copy(path, tmp_path / path.name)
    return tmp_path


def files(folder: Path) -> dict[str, bytes]:
    return {p.relative_to(folder).as_posix(): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def test_library_build_into_an_earlier_library_keeps_the_users_file(scan_files):
    build = ("library", "build", "--tomogram", "t.tif", "--labels", "l.tif", "--out", "lib")
    assert run(*build, cwd=scan_files).returncode == 0
    notes = scan_files / "lib" / "my_notes.txt"
    notes.write_bytes(b"my notes\x00\xff")
    (scan_files / "lib" / "runs").mkdir()
    (scan_files / "lib" / "runs" / "a.csv").write_text("1,2\n")
    result = run(*build, cwd=scan_files)
    assert result.returncode == 0, result.stderr
    assert notes.read_bytes() == b"my notes\x00\xff"
    assert (scan_files / "lib" / "runs" / "a.csv").read_text() == "1,2\n"
    assert run("library", "info", "lib", cwd=scan_files).returncode == 0
    assert "my_notes.txt" not in (scan_files / "lib" / RECORD).read_text()


def test_export_yolo_keeps_user_files_and_removes_its_stale_ones(scan_files):
    assert run("export-yolo", "--real", "t.tif", "l.tif", "--out", "yolo", cwd=scan_files).returncode == 0
    out = scan_files / "yolo"
    (out / "README_mine.md").write_text("# mine\n")
    (out / "mine" / "deeper").mkdir(parents=True)
    (out / "mine" / "deeper" / "x.txt").write_text("x")
    stale = sorted((out / "images" / "train").iterdir())[0]
    assert "_a0_" in stale.name
    result = run("export-yolo", "--real", "t.tif", "l.tif", "--out", "yolo", "--axis", "2", cwd=scan_files)
    assert result.returncode == 0, result.stderr
    assert (out / "README_mine.md").read_text() == "# mine\n"
    assert (out / "mine" / "deeper" / "x.txt").read_text() == "x"
    assert not stale.exists() and not list(out.rglob("*_a0_*"))  # the earlier export's slices are gone
    assert list((out / "images" / "train").glob("*_a2_*"))


def test_a_user_file_where_the_new_export_writes_is_refused_and_nothing_changes(scan_files):
    export = ("export-yolo", "--real", "t.tif", "l.tif", "--out", "yolo")
    assert run(*export, cwd=scan_files).returncode == 0
    out = scan_files / "yolo"
    name = sorted((out / "images" / "val").iterdir())[0].name
    (out / "truth" / "val").mkdir()
    (out / "truth" / "val" / name).write_bytes(b"my own truth")
    before = files(out)
    result = run(*export, "--truth-splits", "test", "val", cwd=scan_files)
    assert result.returncode == 2
    messages = [line for line in result.stderr.splitlines() if "synthpack:" in line]
    assert len(messages) == 1 and "synthpack: error: cannot write the YOLO dataset" in messages[0]
    assert "Traceback" not in result.stderr
    assert f"truth/val/{name} was not written by synthpack" in result.stderr
    assert files(out) == before
    assert not [p for p in scan_files.iterdir() if p.name.startswith(".yolo")]  # no temporary folder left


def test_an_earlier_output_without_a_record_loses_nothing(scan_files):
    build = ("library", "build", "--tomogram", "t.tif", "--labels", "l.tif", "--out", "lib")
    assert run(*build, cwd=scan_files).returncode == 0
    lib = scan_files / "lib"
    (lib / RECORD).unlink()  # as written by synthpack 0.6
    (lib / "old_extra.npz").write_bytes(b"old")
    result = run(*build, cwd=scan_files)
    assert result.returncode == 0, result.stderr
    assert (lib / "old_extra.npz").read_bytes() == b"old"
    assert "did not record its files" in result.stderr  # -q keeps warnings
    assert np.load(lib / "crops.npz").files


def test_an_earlier_output_moved_aside_by_a_killed_run_is_put_back_with_the_users_file(scan_files):
    build = ("library", "build", "--tomogram", "t.tif", "--labels", "l.tif", "--out", "lib")
    assert run(*build, cwd=scan_files).returncode == 0
    (scan_files / "lib" / "my_notes.txt").write_text("my notes\n")
    gone = subprocess.Popen([sys.executable, "-c", "pass"])
    gone.wait()  # its PID no longer runs: a run killed between moving lib aside and renaming the new one in
    (scan_files / "lib").rename(scan_files / f".lib.tmp-old-{gone.pid}-0123abcd")
    result = run(*build, cwd=scan_files)
    assert result.returncode == 0, result.stderr
    assert "put back" in result.stderr  # -q keeps warnings
    assert (scan_files / "lib" / "my_notes.txt").read_text() == "my notes\n"
    assert not [p for p in scan_files.iterdir() if p.name.startswith(".lib")]
