"""Measurements the benchmarks share: load average, the peak RSS and CPU time of a process tree, and a
measured ``synthpack generate --format zarr`` run.

Imported by the scripts in this folder (``python bench/bench_x.py`` puts the folder on
``sys.path``); not part of the package.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import threading
import time
from pathlib import Path

import psutil
import yaml

__all__ = ["TreeRss", "generate_zarr_pack", "load_average"]


def load_average() -> str:
    """The 1, 5 and 15 minute load averages, ``"a/b/c"``."""
    return "/".join(f"{v:.2f}" for v in os.getloadavg())


class TreeRss:
    """Peak of the summed RSS of a process and all its descendants, and their CPU seconds, sampled in a thread.

    ``cpu_seconds`` is the sum over the processes seen of their last sampled user + system
    time, less the root's time at the start: divided by the wall time, the cores the
    measured work actually got (the machine is shared).

    Parameters
    ----------
    pid : int
        The root process.
    interval : float
        Seconds between samples.
    """

    def __init__(self, pid: int, interval: float = 0.1) -> None:
        self.process = psutil.Process(pid)
        self.interval = interval
        self.peak = 0
        self._cpu: dict[int, float] = {}
        self._start_cpu = sum(self.process.cpu_times()[:2])
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._sample, daemon=True)

    @property
    def cpu_seconds(self) -> float:
        return sum(self._cpu.values()) - self._start_cpu

    def _sample(self) -> None:
        while not self._stop.is_set():
            total = 0
            try:
                for process in [self.process, *self.process.children(recursive=True)]:
                    try:
                        total += process.memory_info().rss
                        self._cpu[process.pid] = sum(process.cpu_times()[:2])
                    except psutil.Error:
                        continue
            except psutil.Error:
                break
            self.peak = max(self.peak, total)
            self._stop.wait(self.interval)

    def __enter__(self) -> TreeRss:
        self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self._stop.set()
        self._thread.join()


def generate_zarr_pack(library_dir: Path, config: dict, out: Path) -> tuple[dict, float, TreeRss]:
    """One pack by ``synthpack generate --format zarr`` in a subprocess, measured.

    The config is written next to `out` (``out.with_suffix(".yaml")``).

    Returns
    -------
    manifest : dict
        The pack's manifest (``timings`` holds the stages' seconds).
    wall : float
        Seconds from the start of the subprocess to its end.
    rss : TreeRss
        Its process tree's peak RSS and CPU time.
    """
    config_path = out.with_suffix(".yaml")
    config_path.write_text(yaml.safe_dump(config))
    exe = Path(sys.executable).with_name("synthpack")
    start = time.perf_counter()
    child = subprocess.Popen([str(exe), "-q", "generate", "--library", str(library_dir), "--config",
                              str(config_path), "--out", str(out), "--format", "zarr"])
    with TreeRss(child.pid) as rss:
        code = child.wait()
    wall = time.perf_counter() - start
    if code:
        raise RuntimeError(f"synthpack generate into {out} failed (exit {code})")
    return json.loads((out / "pack_0000" / "manifest.json").read_text()), wall, rss
