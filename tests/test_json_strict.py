"""Every JSON file synthpack writes is strict JSON, and a pack's files repeat byte for byte for a seed."""

import json
import math
import subprocess
import sys

import numpy as np
import pytest

from synthpack._shared.strict_json import dumps


def _strict(text: str):
    """`text` parsed by a parser that refuses NaN and Infinity, as strict JSON parsers do."""
    def refuse(constant):
        raise ValueError(f"not JSON: {constant}")
    return json.loads(text, parse_constant=refuse)


def test_dumps_writes_non_finite_numbers_as_null_and_numpy_as_python():
    text = dumps({"a": math.nan, "b": [np.float32(np.inf), -math.inf], "c": np.arange(2), "d": np.int64(3)})
    assert _strict(text) == {"a": None, "b": [None, None], "c": [0, 1], "d": 3}
    with pytest.raises(TypeError):
        dumps({"x": object()})


def _generate(out, config, library):
    run = subprocess.run([sys.executable, "-m", "synthpack", "-q", "generate", "--library", str(library), "--config",
                          str(config), "--n-particles", "4", "--batch-size", "4", "--seed", "2", "--out", str(out)],
                         capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    return out / "pack_0000"


def _without_timings(manifest: dict) -> dict:
    manifest = dict(manifest)
    manifest.pop("timings")
    return manifest


@pytest.mark.slow
def test_a_tiny_pack_is_strict_json_and_repeats_byte_for_byte(tmp_path, large_library):
    """4 grains: no bulk region, so the packing fraction is unknown (it was a bare NaN in the manifest)."""
    config = tmp_path / "pack.yaml"
    config.write_text("postprocess: randomised\n")
    library = large_library.save(tmp_path / "library")
    first, second = (_generate(tmp_path / name, config, library) for name in ("a", "b"))
    manifests = [_strict((pack / "manifest.json").read_text()) for pack in (first, second)]
    placements = _strict((first / "placements.json").read_text())
    assert manifests[0]["pour_checks"]["packing_fraction"] is None and placements["checks"]["packing_fraction"] is None
    assert "seconds" not in placements["checks"] and manifests[0]["timings"]["pour_engine"] > 0
    names = sorted(p.name for p in first.iterdir())
    assert names == sorted(p.name for p in second.iterdir()) and "placements.json" in names
    for name in names:
        if name != "manifest.json":
            assert (first / name).read_bytes() == (second / name).read_bytes(), name
    assert _without_timings(manifests[0]) == _without_timings(manifests[1])
