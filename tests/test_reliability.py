"""Bad input, taken as a new user would give it (issue 13): one line, exit 2, before any work.

Every case runs the real command line in a subprocess and checks the exit code, that the
first line of stderr says what is wrong, that no traceback is printed, and what is left
on disk: user files next to an output are never touched, and no temporary file is left.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import tifffile

ROOT = Path(__file__).resolve().parents[1]


#: The command line run as user id ``sys.argv[1]``: the interpreter starts as root and imports the
#: command line and what its parser imports, then gives up root, with all its capabilities, before
#: ``main`` runs. The checkout, its virtualenv and the interpreter may lie in a folder only root can
#: read (a fresh clone under ``/root`` in CI), which a process started as that user could not import from.
_AS_USER = """
import os, sys
from synthpack import cli
uid = int(sys.argv.pop(1))
cli._parser()
os.setgroups([])
os.setresgid(uid, uid, uid)
os.setresuid(uid, uid, uid)
sys.exit(cli.main())
"""


def run(*args: str, cwd: Path, user: int | None = None) -> subprocess.CompletedProcess:
    command = [sys.executable, "-m", "synthpack.cli", "-q", *args]
    if user is not None:
        command = [sys.executable, "-c", _AS_USER, str(user), "-q", *args]
    env = dict(os.environ, PYTHONPATH=str(ROOT), HOME=str(cwd), MPLCONFIGDIR=str(cwd / ".mpl"))
    return subprocess.run(command, cwd=cwd, env=env, capture_output=True, text=True, timeout=300)


def assert_refused(result: subprocess.CompletedProcess, *words: str, code: int = 2) -> None:
    assert result.returncode == code, result.stderr
    assert "Traceback" not in result.stderr, result.stderr
    first = result.stderr.strip().splitlines()[0]
    assert first.startswith("synthpack: error:"), result.stderr
    for word in words:
        assert word in first, first


def leftovers(folder: Path) -> list[str]:
    """Temporary names synthpack would have left behind."""
    return sorted(p.name for p in folder.rglob(".*tmp-*"))


@pytest.fixture(scope="module")
def library(tmp_path_factory, blob_scan_files) -> Path:
    """A library of the blob scan's three whole grains: what is tested is the command line, not the grains."""
    folder = tmp_path_factory.mktemp("library")
    tomogram, labels = blob_scan_files
    result = run("library", "build", "--tomogram", str(tomogram), "--labels", str(labels), "--out", "lib",
                 "--workers", "1", cwd=folder)
    assert result.returncode == 0, result.stderr
    return folder / "lib"


@pytest.fixture
def user_folder(tmp_path: Path) -> Path:
    """A folder of the user's, with a file that must survive everything."""
    (tmp_path / "precious").mkdir()
    (tmp_path / "precious" / "thesis.txt").write_text("four years of work")
    (tmp_path / "notes.txt").write_text("my notes")
    return tmp_path


def user_files_intact(folder: Path) -> bool:
    return ((folder / "precious" / "thesis.txt").read_text() == "four years of work"
            and (folder / "notes.txt").read_text() == "my notes")


# 1. library build never replaces a folder or a file that is not a library
@pytest.mark.parametrize("out", ["precious", "notes.txt"])
def test_library_build_refuses_a_user_folder_or_file(user_folder, out):
    result = run("library", "build", "--sample", "large", "--out", out, cwd=user_folder)
    assert_refused(result, out)
    assert user_files_intact(user_folder)
    assert leftovers(user_folder) == []
    assert sorted(p.name for p in (user_folder / "precious").iterdir()) == ["thesis.txt"]


def test_library_build_overwrite_writes_into_a_user_folder_and_keeps_its_files(user_folder, blob_scan_files):
    tomogram, labels = blob_scan_files
    result = run("library", "build", "--tomogram", str(tomogram), "--labels", str(labels), "--workers", "1",
                 "--out", "precious", "--overwrite", cwd=user_folder)
    assert result.returncode == 0, result.stderr
    assert user_files_intact(user_folder)
    assert (user_folder / "precious" / "library.json").is_file()
    assert leftovers(user_folder) == []


# 2. pour --out a folder
def test_pour_refuses_a_folder_as_its_output_file(user_folder, library):
    result = run("pour", "--library", str(library), "--out", "precious", cwd=user_folder)
    assert_refused(result, "precious", "folder")
    assert user_files_intact(user_folder) and leftovers(user_folder) == []


def test_pour_refuses_a_user_file_and_replaces_its_own(user_folder, library):
    result = run("pour", "--library", str(library), "--out", "notes.txt", "--n-particles", "4",
                 "--batch-size", "4", cwd=user_folder)
    assert_refused(result, "notes.txt", "not a placements file")
    assert user_files_intact(user_folder)
    for _ in range(2):  # the second run replaces the first run's placements
        result = run("pour", "--library", str(library), "--out", "p.json", "--n-particles", "4",
                     "--batch-size", "4", cwd=user_folder)
        assert result.returncode == 0, result.stderr
    assert leftovers(user_folder) == []


# 3. staging folders: cleaned when the final rename fails, and when a killed run left them
def test_a_failed_final_rename_leaves_no_staging_folder(tmp_path, monkeypatch):
    from synthpack.io import atomic as _atomic

    target = tmp_path / "out"
    real_replace = os.replace

    def failing_replace(src, dst):
        if Path(dst) == target:
            raise PermissionError(13, "Permission denied", str(dst))
        return real_replace(src, dst)

    monkeypatch.setattr(_atomic.os, "replace", failing_replace)
    with pytest.raises(PermissionError):
        with _atomic.atomic_directory(target) as staging:
            (staging / "data.txt").write_text("x")
    assert sorted(p.name for p in tmp_path.iterdir()) == []


def test_staging_left_by_a_killed_run_is_removed_by_the_next_run(tmp_path, library):
    out = tmp_path / "packs"
    dead = out / ".pack_0000.tmp-999999999-0123abcd"  # no process has this PID
    dead.mkdir(parents=True)
    (dead / "labels.tif").write_bytes(b"x" * 1000)
    old_style = out / ".pack_0000.tmp-89abcdef"  # left by synthpack 0.2
    old_style.mkdir()
    result = run("generate", "--library", str(library), "--out", "packs", "--n-particles", "6", "--batch-size",
                 "6", "--workers", "0", cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    assert sorted(p.name for p in out.iterdir()) == ["pack_0000"]


# 4. output paths that cannot be written, refused before any work
def test_outputs_in_a_folder_the_user_cannot_write(tmp_path, library):
    locked = tmp_path / "locked"
    locked.mkdir()
    locked.chmod(0o555)
    tmp_path.chmod(0o777)
    user = 65534 if os.geteuid() == 0 else None  # root writes anywhere: run as "nobody"
    for args in (("library", "build", "--sample", "large", "--out", "locked/lib"),
                 ("pour", "--library", str(library), "--out", "locked/p.json")):
        result = run(*args, cwd=tmp_path, user=user)
        assert_refused(result, "locked")
    assert list(locked.iterdir()) == []


@pytest.mark.parametrize("args", [
    ("generate", "--sample", "large", "--out", "notes.txt"),
    ("demo", "--out", "notes.txt/x"),
    ("compare", "--sample", "large", "--packs", "missing", "--out", "notes.txt"),
    ("export-yolo", "--packs", "missing", "--out", "notes.txt"),
    ("export-coco", "--packs", "missing", "--out", "notes.txt"),
])
def test_outputs_where_a_file_is_in_the_way(user_folder, args):
    result = run(*args, cwd=user_folder)
    assert_refused(result, "notes.txt")
    assert user_files_intact(user_folder)


# 5. config values checked when the config is read, not inside the pack build
@pytest.mark.parametrize("text, words", [
    ("pour: {scale: -1}", ["pour.scale"]),
    ("pour: {scale: 0}", ["pour.scale"]),
    ("pour: {scale: .nan}", ["pour.scale"]),
    ("pour: {scale: [1, 2, 3]}", ["pour.scale"]),
    ("pour: {scale: big}", ["pour.scale"]),
    ("pour: {scale: []}", ["pour.scale"]),
    ("pour: {tube_height: .inf}", ["pour.tube_height"]),
    ("reconstruct: {wall_intensity: .nan}", ["reconstruct.wall_intensity"]),
    ("pour: {n_particles: 5\nseed: [", ["not valid YAML", "line 2"]),
])
def test_bad_config_values_stop_before_any_work(tmp_path, text, words):
    (tmp_path / "config.yaml").write_text(text)
    result = run("generate", "--sample", "large", "--config", "config.yaml", "--out", "packs", cwd=tmp_path)
    assert_refused(result, *words)
    assert not (tmp_path / "packs").exists()


def test_a_config_that_is_not_utf8(tmp_path):
    (tmp_path / "config.yaml").write_bytes(b"\xff\xfepour: {}")
    result = run("generate", "--sample", "large", "--config", "config.yaml", "--out", "packs", cwd=tmp_path)
    assert_refused(result, "not UTF-8")


# 7. options that were silently replaced, or that broke a later stage
@pytest.mark.parametrize("option", ["--tube-radius", "--tube-height"])
@pytest.mark.parametrize("value", ["0", "-5", "nan"])
def test_tube_size_must_be_positive(tmp_path, library, option, value):
    result = run("pour", "--library", str(library), "--out", "p.json", option, value, cwd=tmp_path)
    assert_refused(result, option)
    assert not (tmp_path / "p.json").exists()


def test_a_voxel_size_that_would_underflow(tmp_path):
    labels = np.zeros((20, 20, 20), np.uint16)
    labels[5:15, 5:15, 5:15] = 1
    tifffile.imwrite(tmp_path / "t.tif", (labels * 100).astype(np.uint16))
    tifffile.imwrite(tmp_path / "l.tif", labels)
    result = run("library", "build", "--tomogram", "t.tif", "--labels", "l.tif", "--voxel-size", "1e-300",
                 "--out", "lib", cwd=tmp_path)
    assert_refused(result, "voxel size")
    assert not (tmp_path / "lib").exists()


# 10-11. corrupt packs are never taken as complete
@pytest.fixture
def pack(tmp_path, library) -> Path:
    result = run("generate", "--library", str(library), "--out", "packs", "--n-particles", "8", "--batch-size",
                 "8", "--workers", "0", cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    return tmp_path / "packs" / "pack_0000"


def test_a_truncated_labels_file_is_rebuilt_by_a_rerun_and_refused_by_the_export(pack, library):
    labels = pack / "labels.tif"
    whole = labels.read_bytes()
    labels.write_bytes(whole[: len(whole) // 2])
    result = run("export-yolo", "--packs", str(pack.parent), "--out", "yolo", cwd=pack.parent.parent)
    assert_refused(result, "incomplete")
    result = run("generate", "--library", str(library), "--out", "packs", "--n-particles", "8", "--batch-size",
                 "8", "--workers", "0", cwd=pack.parent.parent)
    assert result.returncode == 0, result.stderr
    assert labels.read_bytes() == whole


def test_labels_replaced_by_random_content_are_refused_by_the_export(pack):
    from synthpack.io import write_tiff
    from synthpack.store.pack import is_complete_pack, open_pack

    opened = open_pack(pack)
    noise = np.random.default_rng(0).integers(0, 60000, opened.shape).astype(opened.labels.dtype)
    write_tiff(pack / "labels.tif", noise, opened.voxel_size, opened.unit, labels=True)
    assert is_complete_pack(pack)  # same size: only the checksum tells
    result = run("export-yolo", "--packs", str(pack), "--out", "yolo", cwd=pack.parent.parent)
    assert_refused(result, "corrupt", "labels.tif")
    assert not (pack.parent.parent / "yolo").exists()


# 6. an engine that cannot run here is reported once, before any work
def test_blender_missing_is_one_line_before_any_work(tmp_path, library, monkeypatch):
    monkeypatch.delenv("SYNTHPACK_BLENDER", raising=False)
    for args in (("generate", "--sample", "large", "--engine", "blender", "--n-packs", "2", "--out", "packs"),
                 ("pour", "--library", str(library), "--engine", "blender", "--out", "p.json")):
        result = run(*args, cwd=tmp_path)
        assert_refused(result, "Blender")
        assert result.stderr.count("\n") == 1
    assert sorted(p.name for p in tmp_path.iterdir() if not p.name.startswith(".")) == []
