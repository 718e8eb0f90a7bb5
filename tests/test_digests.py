"""Same config and seed, same result: a small run built twice, and a portable record of it.

Two claims, tested separately (issue 24):

* **Same machine, same bytes.** A library, a placements file, packs (TIFF and Zarr, with
  each post-processing mode) and a YOLO export are built twice: once in this process and
  once in a second Python process (another hash seed), which builds its own library from
  the sample. Every file of the two runs must have the same digest (:func:`tree_digest`).
* **Any machine, the recorded result.** ``tests/data/digests.json`` records what stays
  the same on another x86-64 CPU. Float results depend in their last bits on the CPU's
  vector code paths (numpy's SIMD dispatch, OpenBLAS's kernels: ``NPY_DISABLE_CPU_FEATURES``
  and ``OPENBLAS_CORETYPE`` change them), so only integer arrays (labels, masks, mesh
  faces) are hashed; float arrays are recorded by sums, extremes and a weighted sum, and
  ``library.json`` and ``particles.csv`` by their values, all compared within
  :data:`RTOL` (relative) or :data:`ATOL` (absolute, for values near zero). Last-bit
  changes are ~1e-16 relative; the source's edge fit converges differently by up to
  ~3e-7 (OpenBLAS Haswell kernels against SkylakeX); a change of behaviour moves them far
  more than 1e-5. A rigid-body pour is chaotic: a last-bit change of its inputs gives
  other placements, so placements, packs and exports are recorded by their layout only
  (file names with numbers masked, JSON keys, array dtypes and ranks) and their content is
  covered by the same-machine test.

A change that must change the record re-records it with
``SYNTHPACK_RECORD_DIGESTS=1 pytest tests/test_digests.py`` and says why in its commit.

Files are digested without what describes the run rather than the result: JSON values
named in :data:`_RUN_KEYS` (timings, versions), the run's temporary folder in text files
(replaced by a placeholder), and the timestamps of ``.npz`` zip entries (archives are
digested by their arrays); Zarr stores by all their arrays.
"""

from __future__ import annotations

import csv
import hashlib
import json
import math
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import tifffile
import zarr

from synthpack.io.atomic import RECORD as FILE_RECORD
from synthpack.pipeline.config import PackConfig
from synthpack.export import export_yolo
from synthpack.pipeline.generate import generate_pack
from synthpack.library.core import ParticleLibrary
from synthpack.physics import PourConfig, pour
from synthpack.scan.samples import sample_scan

ROOT = Path(__file__).resolve().parents[1]
RECORDED = Path(__file__).parent / "data" / "digests.json"
RECORD = os.environ.get("SYNTHPACK_RECORD_DIGESTS") == "1"
#: Tolerance of recorded float values, relative and absolute (see the module docstring).
RTOL, ATOL = 1e-5, 1e-12
#: JSON keys that describe how a run went (and where: a GPU gives the same within float rounding), not
#: what it made; a manifest's ``files`` (sizes and
#: checksums) are derived from the files hashed here and from placements.json's timing.
_RUN_KEYS = {"timings", "seconds", "versions", "files", "devices"}

CONFIG = PackConfig().replace(pour={"n_particles": 24, "batch_size": 12}, run={"chunks": [32, 64, 64]})
MODES = ("generic", "none", "match_source", "calibrated")
#: The run's outputs, by folder: the library, then those that follow a pour.
POURED = ("placements", *(f"packs-{m}" for m in MODES), "packs-zarr", "yolo")
CASES = ("library", *POURED)


def build(root: Path, library: ParticleLibrary) -> None:
    """Build every output of the run into the folders :data:`CASES` of `root`."""
    library.save(root / "library")
    pour(library, PourConfig(n_particles=12, batch_size=6), 3, progress=False).save(
        root / "placements" / "placements.json")
    for index, mode in enumerate(MODES):
        generate_pack(library, index, CONFIG.replace(postprocess=mode), root / f"packs-{mode}")
    generate_pack(library, 0, CONFIG.replace(postprocess="generic"), root / "packs-zarr", format="zarr")
    export_yolo(root / "yolo", packs=[root / "packs-generic"], progress=False)


# --- same machine: digests of every file -------------------------------------------------


def _json_digest(value):
    if isinstance(value, dict):
        return {k: _json_digest(v) for k, v in sorted(value.items()) if k not in _RUN_KEYS}
    if isinstance(value, list):
        return [_json_digest(v) for v in value]
    return value


def _array_digest(array: np.ndarray) -> str:
    array = np.ascontiguousarray(array)
    return hashlib.sha256(str(array.dtype).encode() + str(array.shape).encode() + array.tobytes()).hexdigest()


def _zarr_arrays(store: Path):
    """(key, array) of every level of every image of an OME-Zarr store."""
    group = zarr.open_group(str(store), mode="r")
    for key, node in sorted(group.members(max_depth=None), key=lambda member: member[0]):
        if isinstance(node, zarr.Array):
            yield key, node


def tree_digest(root: Path) -> dict[str, str]:
    """Digest of every file under `root`, by relative path."""
    digests: dict[str, str] = {}
    for path in sorted(p for p in root.rglob("*") if p.is_file()):
        name = path.relative_to(root).as_posix()
        if ".zarr/" in name or path.name == FILE_RECORD:  # the record lists the files whose digests are here
            continue
        if path.suffix in (".json", ".yaml"):
            text = path.read_text().replace(str(root.parent), "<root>")
            if path.suffix == ".json":
                text = json.dumps(_json_digest(json.loads(text)), sort_keys=True)
            digests[name] = hashlib.sha256(text.encode()).hexdigest()
        elif path.suffix == ".npz":
            with np.load(path) as archive:
                digests[name] = hashlib.sha256(
                    "".join(f"{k}:{_array_digest(archive[k])}" for k in sorted(archive.files)).encode()
                ).hexdigest()
        else:
            digests[name] = hashlib.sha256(path.read_bytes()).hexdigest()
    for store in sorted(root.rglob("*.zarr")):
        for key, node in _zarr_arrays(store):
            digests[f"{store.relative_to(root).as_posix()}/{key}"] = _array_digest(node[...])
    return digests


# --- any machine: the portable record -----------------------------------------------------


def archive_record(archive: np.lib.npyio.NpzFile) -> dict:
    """An ``.npz`` archive whatever the CPU: its arrays' dtypes and shapes, a hash of its integer and boolean
    arrays, and sums and extremes of its float arrays (compared within RTOL)."""
    keys = sorted(archive.files)
    exact = [k for k in keys if archive[k].dtype.kind in "biu"]
    floats = [np.asarray(archive[k], np.float64).ravel() for k in keys if k not in exact]
    return {"arrays": [f"{k} {archive[k].dtype} {archive[k].shape}" for k in keys],
            "sha256": hashlib.sha256("".join(f"{k}:{_array_digest(archive[k])}" for k in exact).encode()).hexdigest(),
            **float_record(np.concatenate([np.zeros(0), *floats]))}


def float_record(values: np.ndarray) -> dict:
    """Float values whatever the CPU: their extreme, sums and a weighted sum (compared within RTOL)."""
    values = np.abs(np.asarray(values, dtype=np.float64).ravel())
    weights = np.arange(values.size) % 7 + 1.0  # a moved value changes the weighted sum
    return {"max_abs": float(values.max(initial=0.0)), "abs_sum": float(values.sum()),
            "square_sum": float(values @ values), "weighted_abs_sum": float(values @ weights)}


def _csv_value(text: str) -> int | float | str:
    for kind in (int, float):
        try:
            return kind(text)
        except ValueError:
            pass
    return text


def library_record(folder: Path) -> dict:
    """The portable record of a saved library: archives by :func:`archive_record`, tables and statistics by value."""
    record = {}
    for path in sorted(folder.iterdir()):
        if path.suffix == ".npz":
            with np.load(path) as archive:
                record[path.name] = archive_record(archive)
        elif path.suffix == ".json":
            record[path.name] = _json_digest(json.loads(path.read_text()))
            phases = record[path.name].get("phases", {})
            if "patch_features" in phases:  # a table of 600 x 41: by its shape and sums
                table = np.asarray(phases["patch_features"])
                phases["patch_features"] = {"shape": list(table.shape), **float_record(table)}
        elif path.name == FILE_RECORD:  # the names synthpack wrote: portable as they are
            record[path.name] = json.loads(path.read_text())
        elif path.suffix == ".csv":
            with path.open(newline="") as table:
                record[path.name] = [[_csv_value(cell) for cell in row] for row in csv.reader(table)]
        else:
            raise AssertionError(f"no portable record for {path.name}: add one here")
    return record


def _keys(value, prefix: str = "") -> set[str]:
    if isinstance(value, dict):
        return {prefix} | {key for k, v in value.items() if k not in _RUN_KEYS for key in _keys(v, f"{prefix}.{k}")}
    if isinstance(value, list):
        return {prefix} | {key for v in value if isinstance(v, dict | list) for key in _keys(v, f"{prefix}[]")}
    return {prefix}


def layout(root: Path) -> dict[str, list[str]]:
    """What a poured output holds whatever the CPU: its files (numbers masked), JSON keys, array dtypes and ranks."""
    found: dict[str, set[str]] = {}
    for path in sorted(p for p in root.rglob("*") if p.is_file() and ".zarr/" not in p.as_posix()):
        what = found.setdefault(re.sub(r"\d+", "#", path.relative_to(root).as_posix()), set())
        if path.suffix == ".json":
            what |= _keys(json.loads(path.read_text()))
        elif path.suffix == ".tif":
            array = tifffile.TiffFile(path).series[0]
            what.add(f"{array.dtype} {len(array.shape)}d")
    for store in sorted(root.rglob("*.zarr")):
        for key, node in _zarr_arrays(store):
            found[f"{store.relative_to(root).as_posix()}/{key}"] = {f"{node.dtype} {node.ndim}d"}
    return {name: sorted(what) for name, what in sorted(found.items())}


def mismatches(actual, recorded, where: str = "") -> list[str]:
    """Where `actual` differs from `recorded`: numbers beyond RTOL/ATOL, anything else at all."""
    number = (int, float)
    if isinstance(recorded, dict) and isinstance(actual, dict):
        if actual.keys() != recorded.keys():
            return [f"{where}: keys {sorted(actual.keys() ^ recorded.keys())} added or missing"]
        return [m for k in recorded for m in mismatches(actual[k], recorded[k], f"{where}/{k}")]
    if isinstance(recorded, list) and isinstance(actual, list):
        if len(actual) != len(recorded):
            return [f"{where}: {len(actual)} items, recorded {len(recorded)}"]
        return [m for i, (a, r) in enumerate(zip(actual, recorded)) for m in mismatches(a, r, f"{where}[{i}]")]
    if (isinstance(recorded, number) and isinstance(actual, number)
            and not isinstance(recorded, bool) and not isinstance(actual, bool)):
        same = math.isclose(actual, recorded, rel_tol=RTOL, abs_tol=ATOL) or actual == recorded  # inf == inf
        return [] if same else [f"{where}: {actual!r}, recorded {recorded!r}"]
    return [] if actual == recorded else [f"{where}: {actual!r}, recorded {recorded!r}"]


# --- the runs --------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def runs(large_library: ParticleLibrary, tmp_path_factory) -> tuple[Path, Path]:
    """The run built here, and the same run built by a second process (its own library, another hash seed)."""
    here, there = tmp_path_factory.mktemp("here"), tmp_path_factory.mktemp("there")
    env = dict(os.environ, PYTHONHASHSEED="24", PYTHONPATH=os.pathsep.join(
        p for p in (str(ROOT), os.environ.get("PYTHONPATH")) if p))
    second = subprocess.Popen([sys.executable, __file__, str(there)], env=env, text=True,
                              stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    try:
        build(here, large_library)
    finally:
        output, _ = second.communicate(timeout=1200)
    assert second.returncode == 0, output
    if RECORD:
        record = {"library": library_record(here / "library"), "layout": {c: layout(here / c) for c in POURED}}
        RECORDED.write_text(json.dumps(record, indent=1, sort_keys=True) + "\n")
    return here, there


@pytest.mark.slow
@pytest.mark.parametrize("case", CASES)
def test_same_config_and_seed_give_the_same_bytes_on_the_same_machine(runs, case):
    here, there = runs
    assert tree_digest(here / case) == tree_digest(there / case)


@pytest.mark.slow
def test_the_library_matches_the_record_on_any_machine(runs):
    here, _ = runs
    recorded = json.loads(RECORDED.read_text())["library"]
    assert mismatches(library_record(here / "library"), recorded) == []


@pytest.mark.slow
@pytest.mark.parametrize("case", POURED)
def test_poured_outputs_have_the_recorded_layout_on_any_machine(runs, case):
    here, _ = runs
    assert layout(here / case) == json.loads(RECORDED.read_text())["layout"][case]


if __name__ == "__main__":  # the second run of the `runs` fixture, in its own process
    # the library as tests/conftest.py's `large_library` builds it
    build(Path(sys.argv[1]), ParticleLibrary.from_scan(sample_scan("large", seed=0), workers=1, progress=False))
