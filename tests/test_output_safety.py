"""Replacing an earlier output deletes only what synthpack wrote there (issue 24), through the real command line.

A folder output records its files (``.synthpack-files``); a rerun into it replaces those
and keeps every other entry, removes stale files the earlier output recorded, and refuses
(exit 2, one line, nothing changed) when a new file would land on a file of the user's.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
import tifffile

from synthpack._atomic import RECORD
from synthpack.samples import sample_scan

ROOT = Path(__file__).resolve().parents[1]


def run(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    env = dict(os.environ, PYTHONPATH=str(ROOT), HOME=str(cwd), MPLCONFIGDIR=str(cwd / ".mpl"))
    return subprocess.run([sys.executable, "-m", "synthpack", *args], cwd=cwd, env=env, capture_output=True,
                          text=True, timeout=300)


def snapshot(folder: Path) -> dict[str, bytes]:
    """Every file under `folder` (relative POSIX path) and its bytes."""
    return {p.relative_to(folder).as_posix(): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def recorded(folder: Path) -> set[str]:
    return set(json.loads((folder / RECORD).read_text())["files"])


@pytest.fixture(scope="module")
def scans(tmp_path_factory) -> Path:
    """``long/`` and ``short/``: a 16- and a 10-slice crop of the small sample, both as ``t.tif`` + ``l.tif``."""
    folder = tmp_path_factory.mktemp("scans")
    scan = sample_scan("small", seed=0)
    for name, depth in (("long", 16), ("short", 10)):
        (folder / name).mkdir()
        tifffile.imwrite(folder / name / "t.tif", scan.tomogram[:depth, :64, :64])
        tifffile.imwrite(folder / name / "l.tif", scan.labels[:depth, :64, :64])
    return folder


def export(scans: Path, which: str, out: Path, *flags: str) -> subprocess.CompletedProcess:
    return run(*flags, "export-yolo", "--real", str(scans / which / "t.tif"), str(scans / which / "l.tif"),
               "--out", str(out), cwd=out.parent)


@pytest.fixture(scope="module")
def long_files(scans, tmp_path_factory) -> set[str]:
    """The files an export of the 16-slice scan writes."""
    out = tmp_path_factory.mktemp("long") / "yolo"
    result = export(scans, "long", out)
    assert result.returncode == 0, result.stderr
    return recorded(out)


def test_library_build_into_an_earlier_library_keeps_the_users_file(scans, tmp_path):
    build = ("library", "build", "--tomogram", str(scans / "short" / "t.tif"), "--labels",
             str(scans / "short" / "l.tif"), "--include-border", "--workers", "1", "--out", "lib")
    assert run(*build, cwd=tmp_path).returncode == 0
    (tmp_path / "lib" / "my_notes.txt").write_bytes(b"my notes\n")
    before = (tmp_path / "lib" / "library.json").stat().st_mtime_ns
    result = run(*build, cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    assert (tmp_path / "lib" / "my_notes.txt").read_bytes() == b"my notes\n"
    assert (tmp_path / "lib" / "library.json").stat().st_mtime_ns != before  # the library itself was replaced
    assert "kept 1 file not written by synthpack" in result.stderr and "my_notes.txt" in result.stderr
    assert "my_notes.txt" not in recorded(tmp_path / "lib")


def test_export_keeps_the_users_files_and_removes_its_own_stale_files(scans, long_files, tmp_path):
    out = tmp_path / "yolo"
    assert export(scans, "long", out).returncode == 0
    (out / "README_mine.md").write_text("# my dataset\n")
    (out / "mine").mkdir()
    (out / "mine" / "model.txt").write_text("weights here\n")
    (out / "images" / "train" / "extra.png").write_bytes(b"not synthpack's")  # inside a folder of synthpack's
    result = export(scans, "short", out)
    assert result.returncode == 0, result.stderr
    short_files = recorded(out)
    stale = long_files - short_files
    assert stale  # the 16-slice export wrote slices 10-15, which the 10-slice one does not
    assert snapshot(out).keys() == short_files | {RECORD, "README_mine.md", "mine/model.txt",
                                                   "images/train/extra.png"}
    assert (out / "README_mine.md").read_text() == "# my dataset\n"
    assert (out / "mine" / "model.txt").read_text() == "weights here\n"
    assert (out / "images" / "train" / "extra.png").read_bytes() == b"not synthpack's"


def test_a_new_file_on_a_users_file_is_refused_and_nothing_changes(scans, long_files, tmp_path):
    out = tmp_path / "yolo"
    assert export(scans, "short", out).returncode == 0
    clash = sorted(long_files - recorded(out))[0]  # written by the 16-slice export, not by this one
    (out / clash).write_bytes(b"the user's own")
    (out / "README_mine.md").write_text("mine\n")
    before = snapshot(out)
    result = export(scans, "long", out, "-q")
    assert result.returncode == 2, result.stderr
    assert "Traceback" not in result.stderr
    messages = [line for line in result.stderr.splitlines() if line.startswith("synthpack:")]  # not progress
    assert len(messages) == 1 and result.stderr.strip().endswith(messages[0]), result.stderr
    assert messages[0].startswith("synthpack: error:") and clash in messages[0], result.stderr
    assert snapshot(out) == before
    assert not [p.name for p in tmp_path.iterdir() if ".tmp-" in p.name]
