"""Benchmark the render's compiled kernel (``reconstruct.kernel: numba``) against the SciPy render, same run.

Run from the repository root (about 3-4 minutes on 2 cores, the pour included)::

    .venv/bin/python bench/bench_render_kernel.py [--grains 300] [--repeats 2] [--workdir DIR]

One pour of ``--grains`` grains of the "large" sample library (batches of 100, seed 0;
reused from ``--workdir`` when it holds it) is rendered as ``generate.build_pack`` renders
it (`pose_maps` + `reconstruct`, default `ReconstructConfig`: linear intensities, partial
volume, pore texture and wall) with ``kernel="scipy"`` and ``kernel="numba"``,
alternated, ``--repeats`` times each, on one thread (so CPU seconds are one core's) and
on two. It prints a Markdown table of the render's wall and CPU seconds per kernel and
their ratio, checks that the labels and contested voxels are equal and prints the
largest intensity difference. Then the kernel's compile time: a child process renders
a small scene twice with an empty numba cache (``NUMBA_CACHE_DIR`` a new folder), and
a second child with that cache filled; each prints its first and second render.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numba
import numpy as np
import scipy

from synthpack.library.core import ParticleLibrary
from synthpack.physics import Placements, PourConfig, pour
from synthpack.pipeline.config import ReconstructConfig
from synthpack.render import Background, Grid, pose_maps, reconstruct
from synthpack.scan.samples import sample_scan

from _measure import load_average

KERNELS = ("scipy", "numba")


def placements_of(library: ParticleLibrary, grains: int, workdir: Path) -> tuple[Placements, str]:
    """The benchmark's pour, reused from `workdir` where it was saved."""
    path = workdir / f"placements_large_{grains}.json"
    if path.exists():
        return Placements.load(path), f"placements reused from {path}"
    placements = pour(library, PourConfig(n_particles=grains, batch_size=100), 0, progress=False)
    placements.save(path)
    return placements, f"poured in {placements.checks.seconds:.0f} s, saved to {path}"


def render(library: ParticleLibrary, placements: Placements, grid: Grid, kernel: str, workers: int):
    """`pose_maps` + `reconstruct` as ``generate.build_pack`` calls them: wall s, CPU s, (clean, labels, contested)."""
    config = ReconstructConfig(kernel=kernel)
    partial_volume = config.partial_volume_of(library.statistics)
    tube = placements.tube
    wall, cpu = time.perf_counter(), time.process_time()
    maps = pose_maps([p.mask for p in library], placements.indices, placements.rotation_matrices(),
                     placements.positions, placements.scales, grid, reach=config.surface.reach(partial_volume))
    result = reconstruct(
        [(p.tomogram, p.mask) for p in library], maps, grid, Background.from_source(library.statistics, config),
        tube=(tube.inner_radius, tube.outer_radius, -tube.base_thickness), order=config.order, seed=0,
        chunks=(64, 256, 256), workers=workers, partial_volume=partial_volume, surface=config.surface,
        kernel=config.kernel,
    )
    return time.perf_counter() - wall, time.process_time() - cpu, result


def target_speed(grains: int, repeats: int, workdir: Path) -> list[str]:
    start = time.perf_counter()
    library = ParticleLibrary.from_scan(sample_scan("large"), progress=False)
    placements, poured = placements_of(library, grains, workdir)
    tube = placements.tube
    grid = Grid.covering(tube.outer_radius, -tube.base_thickness, placements.checks.fill_height,
                         library.voxel_size, margin=4)
    n_voxels = int(np.prod(grid.shape))
    lines = ["## Render kernel: numba against SciPy", "",
             f"Library: sample 'large' ({len(library)} grains); {len(placements)} grains, batches of 100, "
             f"seed 0 ({poured}); grid {'x'.join(map(str, grid.shape))} = {n_voxels / 1e6:.2f} M voxels; "
             f"default render settings (linear, partial volume, pore texture, wall), chunks 64x256x256. "
             f"Setup {time.perf_counter() - start:.0f} s. Load average before: {load_average()}.", ""]
    render(library, placements, grid, "numba", 1)  # compiles or loads the kernel, makes the pore texture's tile
    seconds = {(kernel, workers): [] for kernel in KERNELS for workers in (1, 2)}
    results = {}
    for _ in range(repeats):
        for workers in (1, 2):
            for kernel in KERNELS:
                wall, cpu, results[kernel] = render(library, placements, grid, kernel, workers)
                seconds[kernel, workers].append((wall, cpu))
    (clean, labels, contested), (expected_clean, expected_labels, expected_contested) = \
        results["numba"], results["scipy"]
    if not np.array_equal(labels, expected_labels) or contested != expected_contested:
        raise RuntimeError("the kernels' labels differ")
    difference = float(np.abs(clean - expected_clean).max())

    def best(kernel: str, workers: int, which: int) -> float:
        return min(s[which] for s in seconds[kernel, workers])

    lines += ["| threads | SciPy wall s | numba wall s | wall ratio | SciPy CPU s | numba CPU s | CPU ratio |",
              "|---|---|---|---|---|---|---|"]
    for workers in (1, 2):
        scipy_wall, numba_wall = best("scipy", workers, 0), best("numba", workers, 0)
        scipy_cpu, numba_cpu = best("scipy", workers, 1), best("numba", workers, 1)
        lines.append(f"| {workers} | {scipy_wall:.2f} | {numba_wall:.2f} | {scipy_wall / numba_wall:.2f}x | "
                     f"{scipy_cpu:.2f} | {numba_cpu:.2f} | {scipy_cpu / numba_cpu:.2f}x |")
    lines += ["", f"Best of {repeats} alternated runs each (the render: `pose_maps` + `reconstruct`). Labels "
              f"equal ({contested} contested voxels in both); largest |clean intensity difference| "
              f"{difference:.3g} (clean range {float(np.ptp(expected_clean)):.3g}). "
              f"Load average after: {load_average()}.", ""]
    return lines


def compile_child() -> None:
    """Child process: render a 4-grain scene twice with the kernel; print the seconds of each as JSON."""
    library = ParticleLibrary.from_scan(sample_scan("large"), progress=False)
    crops = [(p.tomogram, p.mask) for p in library]
    rng = np.random.default_rng(0)
    grid = Grid.covering(120.0, -60.0, 60.0, library.voxel_size)
    maps = pose_maps([c[1] for c in crops], rng.integers(0, len(crops), 4), np.tile(np.eye(3), (4, 1, 1)),
                     rng.uniform(-40, 40, (4, 3)), np.ones(4), grid)
    times = []
    for _ in range(2):
        start = time.perf_counter()
        reconstruct(crops, maps, grid, Background(0.2), workers=1, kernel="numba")
        times.append(time.perf_counter() - start)
    print(json.dumps({"first": times[0], "second": times[1]}))


def target_compile() -> list[str]:
    lines = ["## Compile time", "", "| numba cache | first render s | second render s |", "|---|---|---|"]
    with tempfile.TemporaryDirectory(prefix="numba_cache_") as cache:
        for state in ("empty", "filled by the run before"):
            output = subprocess.run([sys.executable, __file__, "--compile-child"], capture_output=True, text=True,
                                    check=True, env={**os.environ, "NUMBA_CACHE_DIR": cache}).stdout
            times = json.loads(output.strip().splitlines()[-1])
            lines.append(f"| {state} | {times['first']:.2f} | {times['second']:.3f} |")
    lines += ["", "A 4-grain scene on a 1-chunk grid, in a new process each: the first render's excess over the "
              "second is the kernel's compilation (empty cache) or loading (filled cache).", ""]
    return lines


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--grains", type=int, default=300, help="grains poured (default 300)")
    parser.add_argument("--repeats", type=int, default=2, help="alternated renders per kernel and thread count")
    parser.add_argument("--workdir", type=Path, default=None, help="keep the pour here (default: temp)")
    parser.add_argument("--compile-child", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.compile_child:
        compile_child()
        return
    with tempfile.TemporaryDirectory(prefix="bench_render_kernel_") as temp:
        workdir = args.workdir or Path(temp)
        workdir.mkdir(parents=True, exist_ok=True)
        start = time.perf_counter()
        print(f"Machine: {os.cpu_count()} CPUs, {platform.platform()}, Python {platform.python_version()}, "
              f"numpy {np.__version__}, scipy {scipy.__version__}, numba {numba.__version__}; load average "
              f"(1/5/15 min) at start: {load_average()}.\n")
        print("\n".join(target_compile()), flush=True)
        print("\n".join(target_speed(args.grains, args.repeats, workdir)), flush=True)
        print(f"Total benchmark wall time: {time.perf_counter() - start:.0f} s.")


if __name__ == "__main__":
    main()
