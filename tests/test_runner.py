"""Many packs as Dask tasks: the same bytes serially and on a cluster, failures isolated, reruns."""

from __future__ import annotations

import copy
import dataclasses
import filecmp
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from synthpack.cli import main
from synthpack.pipeline.config import PackConfig
from synthpack.errors import PackBuildError, SynthpackInputError
from synthpack.pipeline.generate import generate_packs, pack_name
from synthpack.store.pack import PACK_VOLUMES, is_complete_pack
from synthpack.physics import Placements
from synthpack.pipeline.runner import run_packs

CONFIG = PackConfig().replace(seed=3, pour={"n_particles": 6, "batch_size": 6})
N_PACKS = 3


@pytest.fixture(scope="module")
def cluster():
    """A local Dask cluster of two worker processes, reached by its address like any existing cluster."""
    distributed = pytest.importorskip("distributed")
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                  dashboard_address=":0") as local:
        yield local


@pytest.fixture(scope="module")
def serial_run(large_library, tmp_path_factory):
    out = tmp_path_factory.mktemp("serial")
    generate_packs(large_library, out, N_PACKS, CONFIG, workers=0, progress=False)
    return out


def _same_pack(a, b) -> bool:
    """Byte-identical volumes and identical placements (placements.json also holds the pour's timing)."""
    volumes = all(filecmp.cmp(a / f"{name}.tif", b / f"{name}.tif", shallow=False) for name in PACK_VOLUMES)
    pa, pb = Placements.load(a / "placements.json"), Placements.load(b / "placements.json")
    return volumes and all(np.array_equal(getattr(pa, f), getattr(pb, f))
                           for f in ("indices", "positions", "quaternions", "scales"))


def test_serial_and_two_workers_give_identical_packs(large_library, serial_run, cluster, tmp_path):
    paths = generate_packs(large_library, tmp_path, N_PACKS, CONFIG, scheduler=cluster.scheduler_address,
                           progress=False)
    assert [p.name for p in paths] == [pack_name(k) for k in range(N_PACKS)]
    for path in paths:
        assert _same_pack(serial_run / path.name, path), path.name


def test_a_failing_pack_is_reported_the_others_complete_and_a_rerun_builds_it(
        large_library, serial_run, cluster, tmp_path):
    # a library whose particle used by pack 1 only has lost its mask (a corrupt crop)
    used = [set(Placements.load(serial_run / pack_name(k) / "placements.json").indices.tolist())
            for k in range(N_PACKS)]
    broken = min(used[1] - used[0] - used[2])
    corrupt = copy.copy(large_library)
    corrupt.particles = list(large_library.particles)
    corrupt.particles[broken] = dataclasses.replace(
        corrupt.particles[broken], mask=np.zeros_like(corrupt.particles[broken].mask))

    with pytest.raises(PackBuildError, match=f"1 of 3 packs failed.*pack_0001: SynthpackInputError: "
                                             f"library particle.*{broken}.*empty mask") as failed:
        generate_packs(corrupt, tmp_path, N_PACKS, CONFIG, scheduler=cluster.scheduler_address, progress=False)
    assert list(failed.value.failures) == ["pack_0001"]
    assert [is_complete_pack(tmp_path / pack_name(k)) for k in range(N_PACKS)] == [True, False, True]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["pack_0000", "pack_0002"]  # nothing half-written

    stamps = {k: (tmp_path / pack_name(k) / "labels.tif").stat().st_mtime_ns for k in (0, 2)}
    generate_packs(large_library, tmp_path, N_PACKS, CONFIG, workers=0, progress=False)
    assert {k: (tmp_path / pack_name(k) / "labels.tif").stat().st_mtime_ns for k in (0, 2)} == stamps
    assert _same_pack(serial_run / "pack_0001", tmp_path / "pack_0001")


def test_cli_reports_packs_failed_on_their_input_in_one_line_with_exit_code_2(
        large_library, serial_run, tmp_path, capsys):
    used = set(Placements.load(serial_run / "pack_0000" / "placements.json").indices.tolist())
    corrupt = copy.copy(large_library)
    corrupt.particles = [dataclasses.replace(p, mask=np.zeros_like(p.mask)) if i in used else p
                         for i, p in enumerate(large_library)]
    corrupt.save(tmp_path / "library")
    code = main(["-q", "generate", "--library", str(tmp_path / "library"), "--out", str(tmp_path / "out"),
                 "--seed", "3", "--n-particles", "6", "--batch-size", "6", "--workers", "0",
                 "--target-solid-fraction", "none"])  # 6 grains have no bulk: a target would warn
    error = capsys.readouterr().err
    assert code == 2
    assert "1 of 1 packs failed (pack_0000: SynthpackInputError: library particle" in error
    assert "run the same command again" in error and error.count("\n") == 1
    assert "Traceback" not in error


def test_a_run_fails_on_its_input_only_when_every_failed_pack_did():
    from synthpack.errors import PackInputError

    bad_input = SynthpackInputError("empty mask")
    only_input = PackBuildError.of({"pack_0001": bad_input}, "out", 3)
    assert isinstance(only_input, PackInputError) and isinstance(only_input, SynthpackInputError)
    assert only_input.failures == {"pack_0001": "SynthpackInputError: empty mask"}
    mixed = PackBuildError.of({"pack_0001": bad_input, "pack_0002": OSError("disk full")}, "out", 3)
    assert type(mixed) is PackBuildError and "pack_0002: OSError: disk full" in str(mixed)


@pytest.mark.parametrize(("kwargs", "message"), [
    (dict(workers=2, scheduler="tcp://127.0.0.1:1"), "not both"),
    (dict(workers=-1), "workers must be 0"),
    (dict(scheduler="tcp://127.0.0.1:1"), "cannot reach the Dask scheduler"),
])
def test_bad_cluster_settings_are_rejected(kwargs, message):
    import dask

    with dask.config.set({"distributed.comm.timeouts.connect": "1s"}), pytest.raises(SynthpackInputError, match=message):
        run_packs(print, [0], None, progress=False, **kwargs)


def _cli(*args: str) -> list[str]:
    return [sys.executable, "-m", "synthpack.cli", "-q", *args]


def _stderr_lines(stderr: str) -> list[str]:
    return [line for line in stderr.splitlines() if line]


@pytest.mark.slow
def test_a_local_cluster_run_leaves_stderr_quiet(large_library, tmp_path):
    """Issue 13 case 13: a run succeeded, then printed a CommClosedError traceback while the cluster shut down."""
    config = tmp_path / "config.yaml"
    # packs of 8 grains have no bulk to calibrate in or to judge a target by: neither asked, so no warning
    config.write_text("postprocess: none\npour:\n  target_solid_fraction: null\n")
    library = large_library.save(tmp_path / "library")  # the cluster's start and shutdown are tested, not the build
    for run in range(3):
        out = tmp_path / f"run{run}"
        result = subprocess.run(_cli("generate", "--library", str(library), "--n-packs", "3", "--workers", "2",
                                     "--n-particles", "8", "--batch-size", "8", "--config", str(config),
                                     "--out", str(out)),
                                capture_output=True, text=True, timeout=300)
        assert result.returncode == 0, result.stderr
        assert "Traceback" not in result.stderr and "CommClosedError" not in result.stderr
        assert _stderr_lines(result.stderr) == [], result.stderr
        assert sorted(p.name for p in out.iterdir()) == [pack_name(k) for k in range(3)]


def test_ctrl_c_keeps_the_complete_packs_and_says_so_in_one_line(large_library, tmp_path):
    """Issue 13 case 13: Ctrl-C printed KeyboardInterrupt tracebacks from the worker processes."""
    large_library.save(tmp_path / "library")
    out = tmp_path / "packs"
    config = tmp_path / "config.yaml"  # what is tested is the stop, not the image formation: in packs of 24 grains
    config.write_text("postprocess: none\n")  # the calibration's guard may drop a step, with a warning
    command = _cli("generate", "--library", str(tmp_path / "library"), "--n-packs", "6", "--workers", "2",
                   "--n-particles", "24", "--batch-size", "12", "--out", str(out), "--config", str(config),
                   "--target-solid-fraction", "none")  # 24 grains are too few to reach the source's: a warning
    # a terminal's run gets Ctrl-C; a pytest-xdist worker ignores SIGINT, and its children would inherit that
    process = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                               start_new_session=True, preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    deadline = time.monotonic() + 240
    while not (out / "pack_0000" / "manifest.json").exists() and process.poll() is None:
        assert time.monotonic() < deadline, "no pack completed in time"
        time.sleep(0.1)
    os.killpg(process.pid, signal.SIGINT)  # a terminal's Ctrl-C reaches the whole process group
    _, stderr = process.communicate(timeout=120)
    assert process.returncode == 130, stderr
    assert "Traceback" not in stderr
    [line] = _stderr_lines(stderr)
    complete = sorted(p.name for p in out.iterdir() if is_complete_pack(p))
    assert "pack_0000" in complete and len(complete) < 6
    assert line.startswith(f"synthpack: interrupted: {len(complete)} of 6 packs are complete in {out} (")
    assert "run the same command again to build only the" in line
    assert sorted(p.name for p in out.iterdir()) == complete  # no staging folder of a stopped pack
