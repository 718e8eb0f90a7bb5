"""Benchmark the post-processing on a torch device against the NumPy path (issue 17).

Run from the repository root (about a minute on 2 cores at the default size)::

    .venv/bin/python bench/bench_postprocess_device.py [--size 256] [--device cpu|cuda] [--repeats 2]

A two-phase float32 volume of ``size^3`` voxels is post-processed with the calibrated
pipeline's transforms (`~synthpack.artefacts.Calibration.pipeline`: Gaussian blur,
coloured noise, beam hardening, rings) by `~synthpack.artefacts.blockwise.apply_blockwise`
in the default chunks (64, 256, 256), once with NumPy and once on the torch `--device`,
in turn (NumPy, device, NumPy, ...) so a busy machine slows both alike. It prints the
best seconds and million voxels per second of each, and the largest difference between
their outputs relative to the intensity range. ``--device cpu`` runs the torch code on
the CPU: a check of its cost, not the GPU figure.
"""

from __future__ import annotations

import argparse
import os
import platform
import time

import numpy as np
from scipy import ndimage

from synthpack.artefacts import BeamHardening, ColouredNoise, Compose, GaussianBlur, RingArtefacts
from synthpack.artefacts.blockwise import apply_blockwise

CHUNKS = (64, 256, 256)
PORE, GRAIN = 0.2, 1.0


def _volume(size: int) -> np.ndarray:
    rng = np.random.default_rng(0)
    grains = ndimage.gaussian_filter(rng.standard_normal((size,) * 3).astype(np.float32), 4.0) > 0
    return (np.where(grains, GRAIN, PORE) + 0.02 * rng.standard_normal((size,) * 3)).astype(np.float32)


def _pipeline(size: int) -> Compose:
    return Compose([
        GaussianBlur(sigma=1.0),
        ColouredNoise(pore_power=[2e-4, 1e-4, 4e-5, 2e-5], grain_power=[3e-4, 2e-4, 1e-4, 5e-5], pore_level=PORE,
                      grain_level=GRAIN, pore_std=0.02, grain_std=0.03),
        BeamHardening(strength=0.08, keep="mean"),
        RingArtefacts(amplitude=0.03, n_rings=3, width=1.5, radii=[size * 0.1, size * 0.2, size * 0.35],
                      amplitudes=[0.03, -0.02, 0.01]),
    ])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=256, help="side of the cubic volume, voxels")
    parser.add_argument("--device", default="cpu", help="torch device of the device path (cpu, cuda, cuda:N)")
    parser.add_argument("--repeats", type=int, default=2, help="runs of each path")
    parser.add_argument("--threads", type=int, default=None, help="blocks at once (default: CPU cores)")
    args = parser.parse_args()
    volume = _volume(args.size)
    pipeline = _pipeline(args.size)
    print(f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores; volume {volume.shape} float32, "
          f"{volume.size / 1e6:.1f} M voxels; chunks {CHUNKS}")
    outputs = {"numpy": np.empty_like(volume), args.device: np.empty_like(volume)}
    best = {name: float("inf") for name in outputs}
    for _ in range(args.repeats):
        for name, device in (("numpy", None), (args.device, args.device)):
            start = time.perf_counter()
            apply_blockwise(pipeline, volume, outputs[name], 3, CHUNKS, threads=args.threads, device=device)
            best[name] = min(best[name], time.perf_counter() - start)
    for name, seconds in best.items():
        label = "NumPy" if name == "numpy" else f"torch on {name}"
        print(f"{label:>16}: {seconds:6.2f} s, {volume.size / seconds / 1e6:6.1f} M voxels/s")
    difference = np.abs(outputs[args.device] - outputs["numpy"]).max() / np.ptp(outputs["numpy"])
    print(f"largest difference: {difference:.2e} of the intensity range")


if __name__ == "__main__":
    main()
