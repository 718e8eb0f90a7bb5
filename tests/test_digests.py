"""Same config and seed, same bytes: digests of a small run recorded before a refactor.

The digests in ``tests/data/digests.json`` were recorded with synthpack 0.2.0 before the
architecture refactor (issue 12), and re-recorded for 0.3.0, where the post-processing
recipe ``default`` became ``generic`` (the same volumes) and the manifests gained the
resolved post-processing mode; and for 0.4.0, where packs are poured to the source's solid
fraction with margin-corrected collision shapes (new placements and labels), the calibrated
post-processing and the library gained the measured scanner artefacts and pore histogram,
and the YOLO export's files name the new version; and when Zarr packs became OME-Zarr
stores (the same level-0 arrays under the new paths ``0``, ``clean/0`` and
``labels/instances/0``). A refactor that does not mean to change behaviour must
keep them; a change that must change the bytes re-records them with
``SYNTHPACK_RECORD_DIGESTS=1 pytest tests/test_digests.py`` and says why in its commit.

What is hashed: every file of a library, a placements file, packs (TIFF and Zarr, with
each post-processing mode) and a YOLO export. JSON files are hashed without the values
that describe the run rather than the result (timings, versions), and text files with the
run's temporary folder replaced by a placeholder; ``.npz``
archives by their arrays (zip entries carry a timestamp); Zarr stores by all their arrays.
"""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path

import numpy as np
import pytest
import zarr

from synthpack._atomic import RECORD as FILE_RECORD
from synthpack.config import PackConfig
from synthpack.export import export_yolo
from synthpack.generate import generate_pack
from synthpack.library import ParticleLibrary
from synthpack.physics import pour

RECORDED = Path(__file__).parent / "data" / "digests.json"
RECORD = os.environ.get("SYNTHPACK_RECORD_DIGESTS") == "1"
#: JSON keys that describe how a run went (and where: a GPU gives the same within float rounding), not
#: what it made; a manifest's ``files`` (sizes and
#: checksums) are derived from the files hashed here and from placements.json's timing.
_RUN_KEYS = {"timings", "seconds", "versions", "files", "devices"}

CONFIG = PackConfig().replace(pour={"n_particles": 48, "batch_size": 24}, reconstruct={"chunks": [32, 64, 64]})
MODES = ("generic", "none", "match_source", "calibrated")


def _json_digest(value):
    if isinstance(value, dict):
        return {k: _json_digest(v) for k, v in sorted(value.items()) if k not in _RUN_KEYS}
    if isinstance(value, list):
        return [_json_digest(v) for v in value]
    return value


def _array_digest(array: np.ndarray) -> str:
    array = np.ascontiguousarray(array)
    return hashlib.sha256(str(array.dtype).encode() + str(array.shape).encode() + array.tobytes()).hexdigest()


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
        group = zarr.open_group(str(store), mode="r")
        for key, node in sorted(group.members(max_depth=None), key=lambda member: member[0]):
            if isinstance(node, zarr.Array):  # every level of every image of an OME-Zarr store
                digests[f"{store.relative_to(root).as_posix()}/{key}"] = _array_digest(node[...])
    return digests


@pytest.fixture(scope="module")
def run_digests(large_library: ParticleLibrary, tmp_path_factory) -> dict[str, dict[str, str]]:
    root = tmp_path_factory.mktemp("digests")
    digests = {}
    large_library.save(root / "library")
    digests["library"] = tree_digest(root / "library")
    placements = pour(large_library, 12, 6, seed=3, progress=False)
    placements.save(root / "placements" / "placements.json")
    digests["placements"] = tree_digest(root / "placements")
    for index, mode in enumerate(MODES):
        out = root / f"packs-{mode}"
        generate_pack(large_library, index, CONFIG.replace(postprocess=mode), out)
        digests[f"pack-{mode}"] = tree_digest(out)
    generate_pack(large_library, 0, CONFIG.replace(postprocess="generic"), root / "packs-zarr", format="zarr")
    digests["pack-zarr"] = tree_digest(root / "packs-zarr")
    export_yolo(root / "yolo", packs=[root / "packs-generic"], progress=False)
    digests["yolo"] = tree_digest(root / "yolo")
    if RECORD:
        RECORDED.parent.mkdir(exist_ok=True)
        RECORDED.write_text(json.dumps(digests, indent=1, sort_keys=True) + "\n")
    return digests


@pytest.mark.slow
@pytest.mark.parametrize("what", ["library", "placements", *(f"pack-{m}" for m in MODES), "pack-zarr", "yolo"])
def test_same_config_and_seed_give_the_recorded_bytes(run_digests, what):
    recorded = json.loads(RECORDED.read_text())
    assert run_digests[what] == recorded[what]
