"""Benchmark the spectrum match's filter against the calibration's Gaussian blur on the same volume (issue 26).

Run from the repository root (about a minute on 2 cores)::

    .venv/bin/python bench/bench_spectrum_match.py [--side 256] [--repeats 3]

Both steps are applied block by block (`synthpack.artefacts.blockwise.apply_blockwise`, chunks of
128 voxels, 2 threads) to the same float32 volume of white noise, in turn (blur, filter, blur, ...),
so a busy machine slows both alike; the best of the repeats counts. The filter's gain is one that
`fit_gain` gives from white noise to noise blurred by 0.6 voxels (any table costs the same: the
kernel is always 25³). It prints each step's million voxels per second and the filter's time over
the blur's: what the spectrum match adds to a pack's post-processing where the guard applies it.
"""

from __future__ import annotations

import argparse
import os
import platform
import time

import numpy as np
from scipy import ndimage

from synthpack.artefacts import Compose, GaussianBlur, SpectrumMatch
from synthpack.artefacts.blockwise import apply_blockwise
from synthpack.artefacts.spectrum_match import fit_gain
from synthpack.measure.volume_spectrum import cylindrical_spectrum

CHUNKS = (128, 128, 128)


def _seconds(step: Compose, volume: np.ndarray) -> float:
    out = np.empty_like(volume)
    start = time.perf_counter()
    apply_blockwise(step, volume, out, 0, CHUNKS, threads=2)
    return time.perf_counter() - start


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--side", type=int, default=256, help="side of the cubic volume, voxels (default 256)")
    parser.add_argument("--repeats", type=int, default=3, help="runs of each step; the best counts (default 3)")
    args = parser.parse_args()
    rng = np.random.default_rng(0)
    volume = rng.normal(size=(args.side,) * 3).astype(np.float32)
    region = np.ones((64, 64, 64), bool)
    white = rng.normal(size=region.shape)
    gain = fit_gain(cylindrical_spectrum(ndimage.gaussian_filter(white, 0.6), region),
                    cylindrical_spectrum(white, region))
    match = SpectrumMatch(gain=gain.ravel().tolist(), level=0.0)
    steps = {"gaussian blur (sigma 1.08, the sand's PSF)": Compose([GaussianBlur(sigma=1.08)]),
             "spectrum match (kernel 25^3, FFT, float32)": Compose([match])}
    times: dict[str, list[float]] = {name: [] for name in steps}
    for _ in range(args.repeats):  # in turn, so that a busy machine slows both alike
        for name, step in steps.items():
            times[name].append(_seconds(step, volume))
    best = {name: min(seconds) for name, seconds in times.items()}
    voxels = volume.size / 1e6
    print(f"{platform.processor() or platform.machine()}, {os.cpu_count()} CPUs; {args.side}^3 float32, "
          f"chunks {CHUNKS[0]}^3, 2 threads, best of {args.repeats}")
    for name, seconds in best.items():
        print(f"  {name}: {seconds:.2f} s, {voxels / seconds:.1f} Mvoxel/s")
    blur, match = best.values()
    print(f"spectrum match / blur: {match / blur:.2f}x the time")


if __name__ == "__main__":
    main()
