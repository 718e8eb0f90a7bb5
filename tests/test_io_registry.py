"""The input formats come from one registry (synthpack.io._registry): a new format is one
module and one `Format` line, and detection, SUPPORTED_FORMATS and the CLI help follow."""

from __future__ import annotations

import os
import subprocess
import sys

import numpy as np
import pytest

from synthpack import cli
from synthpack.errors import SynthpackInputError
from synthpack.io import SUPPORTED_FORMATS, _registry, read_scan, read_volume

TOY = _registry.Format("a toy file", "toy_format:read_toy", suffixes=(".toy",),
                       description="toy text volume (.toy)", help="toy text volume (.toy)")


def write_toy(path, volume, voxel=None):
    lines = ["shape " + " ".join(map(str, volume.shape))]
    if voxel is not None:
        lines.append("voxel " + " ".join(map(str, voxel)))
    path.write_text("\n".join(lines + [" ".join(map(str, volume.ravel()))]) + "\n")
    return path


@pytest.fixture
def toy_registered(monkeypatch):
    """The registry with the toy format's one line added (undone after the test)."""
    monkeypatch.setattr(_registry, "FORMATS", (*_registry.FORMATS, TOY))


def test_a_toy_format_is_one_module_and_one_registry_line(tmp_path, toy_registered):
    rng = np.random.default_rng(0)
    tomogram = rng.integers(0, 1000, size=(3, 4, 5))
    labels = np.zeros((3, 4, 5), dtype=np.int64)
    labels[1:, 1:3, 1:4] = 1
    scan = read_scan(write_toy(tmp_path / "scan.toy", tomogram, (2.0, 1.0, 1.0, "um")),
                     write_toy(tmp_path / "labels.toy", labels))
    np.testing.assert_array_equal(scan.tomogram, tomogram)
    np.testing.assert_array_equal(scan.labels, labels)
    assert (scan.voxel_size, scan.unit) == ((2.0, 1.0, 1.0), "um")
    # its reader's errors name the format; the lists of formats name it too
    (tmp_path / "bad.toy").write_text("not a toy\n")
    with pytest.raises(SynthpackInputError, match="bad.toy is not a toy file"):
        read_volume(tmp_path / "bad.toy")
    (tmp_path / "broken.toy").write_text("shape 2 2 2\n1 2 3\n")
    with pytest.raises(SynthpackInputError, match="cannot read .*broken.toy as a toy file: cannot reshape"):
        read_volume(tmp_path / "broken.toy")
    (tmp_path / "scan.foo").write_text("")
    with pytest.raises(SynthpackInputError, match=r"not a supported volume file .*toy text volume \(\.toy\)"):
        read_volume(tmp_path / "scan.foo")
    assert _registry.tomogram_help().endswith(", or toy text volume (.toy)")


def test_an_unregistered_format_is_refused_with_the_list_of_formats(tmp_path):
    path = write_toy(tmp_path / "scan.toy", np.ones((2, 2, 2), dtype=int))
    with pytest.raises(SynthpackInputError, match=r"extension '\.toy'\)\. Supported formats: multi-page TIFF") as info:
        read_volume(path)
    assert "toy" not in str(info.value).split("Supported formats:")[1]


def test_supported_formats_and_the_cli_help_come_from_the_registry():
    formats = _registry.FORMATS
    assert SUPPORTED_FORMATS == tuple(f.description for f in formats if f.description)
    assert cli._TOMOGRAM_HELP == _registry.tomogram_help()
    result = subprocess.run([sys.executable, "-m", "synthpack", "label", "--help"], capture_output=True,
                            text=True, timeout=60, env={**os.environ, "COLUMNS": "10000"})
    assert result.returncode == 0, result.stderr
    shown = " ".join(result.stdout.split())
    for term in (f.help for f in formats if f.help):
        assert term in shown


@pytest.mark.parametrize("fmt", [f for f in _registry.FORMATS if f.suffixes], ids=lambda f: f.name)
def test_each_suffix_of_the_registry_picks_its_reader(tmp_path, fmt):
    for suffix in fmt.suffixes:
        path = tmp_path / f"scan{suffix.upper()}"
        path.write_bytes(b"")
        reader, name = _registry._reader_for(path)
        assert (reader, name) == (fmt.load_reader(), fmt.name)


def test_the_path_grammar_after_a_colon_comes_from_the_registry(tmp_path):
    for fmt in _registry.FORMATS:
        for suffix in fmt.suffixes:
            path, spec = _registry._split_spec(f"{tmp_path}/scan{suffix}:{fmt.spec}")
            if fmt.spec is None:
                assert (path.name, spec) == (f"scan{suffix}:None", None)
            else:
                assert (path, spec) == (tmp_path / f"scan{suffix}", fmt.spec)


def test_a_folder_of_two_formats_is_refused(tmp_path):
    (tmp_path / "slice.tif").write_bytes(b"")
    (tmp_path / "block0.nc").write_bytes(b"")
    with pytest.raises(SynthpackInputError, match="holds both TIFF slices and NetCDF blocks"):
        read_volume(tmp_path)
