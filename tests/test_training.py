"""The training package: the smoke experiment end to end (offline), the leak check, the scoring."""

import csv
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from synthpack.io import read_label_image, write_label_image
from synthpack.library import ParticleLibrary
from synthpack.split import central_block
from training.evaluate import score

ROOT = Path(__file__).resolve().parents[1]

# Runs `python -m <training module>` with every Internet connection and name lookup refused and recorded.
NETWORK_GUARD = r"""
import runpy, socket, sys
module = sys.argv[1]
attempts = []
connect = socket.socket.connect

def guarded_connect(self, address):
    if self.family in (socket.AF_INET, socket.AF_INET6):
        attempts.append(repr(address))
        raise OSError("network disabled by the test")
    return connect(self, address)

def guarded_getaddrinfo(host, *args, **kwargs):
    attempts.append(repr(host))
    raise socket.gaierror("network disabled by the test")

socket.socket.connect = guarded_connect
socket.getaddrinfo = guarded_getaddrinfo
sys.argv = [module, *sys.argv[2:]]
try:
    runpy.run_module(module, run_name="__main__", alter_sys=True)
finally:
    print("NETWORK ATTEMPTS:", len(attempts), attempts, file=sys.stderr)
"""


def run_offline(module: str, *args: str, timeout: float = 900) -> subprocess.CompletedProcess:
    """``python -m module args`` from the checkout root, offline."""
    return subprocess.run(
        [sys.executable, "-c", NETWORK_GUARD, module, *args],
        capture_output=True, text=True, timeout=timeout, cwd=ROOT,
    )


@pytest.fixture(scope="module")
def smoke(tmp_path_factory) -> Path:
    """The `smoke` experiment, run once for this module with the network refused."""
    out = tmp_path_factory.mktemp("smoke")
    result = run_offline("training.experiment", "--config", "smoke", "--out", str(out))
    assert result.returncode == 0, result.stderr[-4000:]
    assert "NETWORK ATTEMPTS: 0 []" in result.stderr, result.stderr[-2000:]
    return out


@pytest.mark.slow
def test_smoke_experiment_writes_every_arm_and_test_set(smoke):
    for name in ("report.md", "results.csv", "results.json", "dice.png"):
        assert (smoke / name).stat().st_size > 0
    rows = list(csv.DictReader((smoke / "results.csv").open()))
    arms = {row["arm"] for row in rows}
    assert arms == {"large", "large+syn", "large+syn-nopp", "small", "small+syn", "small+syn-nopp"}
    assert {(row["arm"], row["test_set"]) for row in rows} == {(a, t) for a in arms for t in ("large", "small")}
    for row in rows:
        assert 0.0 <= float(row["dice"]) <= 1.0
        assert int(row["n_slices"]) == 26  # central 20% of 128 slices
    report = (smoke / "report.md").read_text()
    for heading in ("Table 1", "Table 2", "(94.5%)", "(88.8%)"):
        assert heading in report


@pytest.mark.slow
def test_synthetic_arms_add_pack_slices_to_the_real_training_slices(smoke):
    for scan in ("large", "small"):
        real = json.loads((smoke / "data" / scan / "export.json").read_text())["images"]
        for arm in (scan + "+syn", scan + "+syn-nopp"):
            mixed = json.loads((smoke / "data" / arm / "export.json").read_text())["images"]
            assert mixed["val"] == real["val"] and mixed["test"] == real["test"]
            assert mixed["train"] > real["train"]


@pytest.mark.slow
def test_no_test_slice_reaches_the_particle_libraries(smoke):
    for scan in ("large", "small"):
        library = ParticleLibrary.load(smoke / "libraries" / scan)
        start, stop = central_block(library.source_shape[0])
        assert library.settings["exclude_slices"] == [start, stop]
        assert len(library) > 0
        for particle in library:
            z0, z1 = particle.bbox[0], particle.bbox[3]
            assert z1 <= start or z0 >= stop, f"particle {particle.label} of {scan} reaches the test block"


@pytest.mark.slow
def test_predictions_are_label_images_of_the_test_slices(smoke):
    truth = smoke / "data" / "small" / "truth" / "test"
    pred = smoke / "eval" / "large" / "seed0" / "small" / "pred"
    names = sorted(p.name for p in truth.glob("*.png"))
    assert names == sorted(p.name for p in pred.glob("*.png"))
    assert read_label_image(pred / names[0]).shape == read_label_image(truth / names[0]).shape


@pytest.mark.slow
def test_evaluate_scores_perfect_predictions_as_dice_one(smoke, tmp_path):
    data = smoke / "data" / "large"
    result = run_offline("training.evaluate", "--data", str(data), "--out", str(tmp_path),
                         "--predictions", str(data / "truth" / "test"), timeout=120)
    assert result.returncode == 0, result.stderr[-2000:]
    scores = json.loads((tmp_path / "scores.json").read_text())
    assert scores["dice"] == 1.0 and scores["instance_dice"] == 1.0
    assert scores["n_matched"] == scores["n_true"] > 0


def test_evaluate_scores_a_damaged_prediction_below_one(tmp_path):
    truth, pred = tmp_path / "truth", tmp_path / "pred"
    truth.mkdir(), pred.mkdir()
    labels = np.zeros((40, 40), np.int32)
    labels[5:15, 5:15], labels[20:30, 20:36] = 1, 2
    write_label_image(truth / "a", labels)
    damaged = labels.copy()
    damaged[20:30, 20:36] = 0  # instance 2 missed: 100 of 260 pixels found
    write_label_image(pred / "a", damaged)
    scores = score(pred, truth)
    assert scores["dice"] == pytest.approx(2 * 100 / (100 + 260))
    assert scores["n_matched"] == 1 and scores["n_true"] == 2


def test_unknown_experiment_config_is_a_clear_error(tmp_path):
    result = run_offline("training.experiment", "--config", "no-such-config", "--out", str(tmp_path), timeout=120)
    assert result.returncode == 2
    assert "smoke" in result.stderr and "cpu" in result.stderr and "paper" in result.stderr
