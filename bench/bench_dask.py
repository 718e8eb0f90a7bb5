"""Benchmark many packs on Dask and packs larger than memory (the "Scale" issue).

Run from the repository root::

    .venv/bin/python bench/bench_dask.py [--workdir DIR] [--packs 8] [--sizes 256 512 1024] [--skip-speedup]

It prints Markdown for two targets:

1. Speed-up over packs: K small packs (the ``large`` sample library, 60 grains
   each in batches of 30, TIFF) built by ``generate_packs`` on a local Dask
   cluster of 1 worker, then of 2 workers, in the same run (wall time from the
   call to its return, cluster start-up included). Target: >= 1.7x on 2 cores.
   The two runs' packs are also compared byte for byte.
2. Peak memory and time against volume size: ``synthpack generate --format
   zarr`` (one pack, built in the command's own process) of about 256^3, 512^3
   and 1024^3 voxels, in a subprocess whose resident set size (the sum over the
   process and all its children) is sampled every 0.1 s with psutil. The grains
   have the same size in voxels at every volume size: the library's grains
   scaled by 4 (about 90 voxels across), so the 1024^3 pack needs about a
   thousand grains and its pour takes minutes, not hours; the tube's radius and
   the grain count are chosen to fill a cube of about the target size. Every
   stage runs, pour included; the table also gives the stages' seconds from the
   manifest and the seconds per 10^6 output voxels of the stages that scale with
   the volume (reconstruction and post-processing, Zarr writes included). Target: peak
   RSS at 1024^3 < 2x that at 256^3.
"""

from __future__ import annotations

import argparse
import filecmp
import math
import os
import platform
import shutil
import tempfile
import time
from pathlib import Path

import psutil

from synthpack.pipeline.config import PackConfig
from synthpack.pipeline.generate import generate_packs
from synthpack.library.core import ParticleLibrary
from synthpack.store.pack import PACK_VOLUMES
from synthpack.scan.samples import sample_scan

from _measure import TreeRss, generate_zarr_pack, load_average

SPEEDUP_CONFIG = PackConfig().replace(pour={"n_particles": 60, "batch_size": 30})
GRAIN_SCALE = 4.0
MARGIN, WALL, BASE = 4, 3, 3  # voxels: Grid.covering's default margin, Tube.for_library's wall and base
#: Solid fraction used to size the grain count: grains ~90 voxels across in a tube a few grains
#: wide pack more loosely than the library default of 0.55 (measured: 0.55 overfilled by ~25%).
PACKING_GUESS = 0.45


def speedup(library: ParticleLibrary, workdir: Path, n_packs: int) -> list[str]:
    lines = ["## 1. Packs on 1 vs 2 Dask workers", "",
             f"{n_packs} packs of {SPEEDUP_CONFIG.pour.n_particles} grains (batches of "
             f"{SPEEDUP_CONFIG.pour.batch_size}), `large` sample library, TIFF; `generate_packs(..., workers=W)` "
             "(a LocalCluster of W single-threaded worker processes), wall time including the cluster's "
             f"start-up. Load average before: {load_average()}.", "",
             "| workers | seconds | s per pack | CPU s of the run's processes | cores it got (CPU s / s) "
             "| peak RSS, all processes (MiB) |", "|---|---|---|---|---|---|"]
    seconds = {}
    for workers in (1, 2):
        out = workdir / f"speedup_w{workers}"
        shutil.rmtree(out, ignore_errors=True)
        start = time.perf_counter()
        with TreeRss(os.getpid()) as rss:
            generate_packs(library, out, n_packs, SPEEDUP_CONFIG, workers=workers, progress=False)
        seconds[workers] = time.perf_counter() - start
        lines.append(f"| {workers} | {seconds[workers]:.1f} | {seconds[workers] / n_packs:.2f} | {rss.cpu_seconds:.1f} "
                     f"| {rss.cpu_seconds / seconds[workers]:.2f} | {rss.peak / 2**20:.0f} |")
    identical = all(
        filecmp.cmp(workdir / "speedup_w1" / f"pack_{k:04d}" / f"{v}.tif",
                    workdir / "speedup_w2" / f"pack_{k:04d}" / f"{v}.tif", shallow=False)
        for k in range(n_packs) for v in PACK_VOLUMES)
    ratio = seconds[1] / seconds[2]
    lines += ["", f"Speed-up, 1 worker / 2 workers: **{ratio:.2f}x** (target >= 1.7x: "
              f"{'met' if ratio >= 1.7 else 'MISSED'}; with other work on the machine the 2-worker run gets "
              "fewer than 2 cores: see 'cores it got'). Packs of the two runs byte-identical: "
              f"{'yes' if identical else 'NO'}. Load average after: {load_average()}.", ""]
    return lines


def size_config(library: ParticleLibrary, size: int) -> dict:
    """A config whose pack fills about a size^3 grid with grains scaled by GRAIN_SCALE."""
    voxel = library.voxel_size[1]
    inner = (size - 1) / 2 - MARGIN - WALL  # voxels
    height = size - 2 * MARGIN - BASE - 1  # voxels of fill
    grain = sum(p.volume for p in library) / len(library) * GRAIN_SCALE**3 / voxel**3  # voxels
    n = int(round(PACKING_GUESS * math.pi * inner**2 * height / grain))
    return PackConfig().replace(pour={"n_particles": n, "batch_size": 50, "scale": GRAIN_SCALE,
                                      "tube_radius": inner * voxel}).to_dict()


def memory(library_dir: Path, library: ParticleLibrary, workdir: Path, sizes: list[int]) -> list[str]:
    lines = ["## 2. Peak memory and time against volume size (Zarr, chunk by chunk)", "",
             f"One pack per size, `synthpack generate --library ... --config ... --format zarr` in a subprocess; "
             f"RSS summed over the process tree, sampled every 0.1 s. Grains scaled by {GRAIN_SCALE:g} (the same "
             "size in voxels at every volume size); every stage runs, the pour included. 'voxel stages' = "
             "reconstruction + post-processing (both write Zarr chunk by chunk), the stages that scale with the "
             "volume. "
             f"Load average before: {load_average()}.", "",
             "| target | grid (z, y, x) | 10^6 voxels | grains | peak RSS (MiB) | vs first | pour s "
             "| reconstruct s | post-process s | total wall s | voxel stages s / 10^6 voxels |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    first = None
    for size in sizes:
        out = workdir / f"size_{size}"
        shutil.rmtree(out, ignore_errors=True)
        manifest, wall, rss = generate_zarr_pack(library_dir, size_config(library, size), out)
        shape = manifest["shape"]
        voxels = math.prod(shape) / 1e6
        t = manifest["timings"]
        first = first or (rss.peak, voxels)
        lines.append(
            f"| {size}^3 | {'x'.join(map(str, shape))} | {voxels:.0f} | {manifest['n_particles']} "
            f"| {rss.peak / 2**20:.0f} | {rss.peak / first[0]:.2f}x | {t['pour']:.1f} | {t['reconstruct']:.1f} "
            f"| {t['postprocess']:.1f} | {wall:.1f} | {(t['reconstruct'] + t['postprocess']) / voxels:.3f} |")
        shutil.rmtree(out, ignore_errors=True)
    growth = rss.peak / first[0]
    lines += ["", f"Peak RSS growth from the first to the last size: **{growth:.2f}x** for {voxels / first[1]:.0f}x "
              f"the voxels (target < 2x: {'met' if growth < 2 else 'MISSED'}). Load average after: {load_average()}.", ""]
    return lines


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--workdir", type=Path, default=None, help="scratch folder (default: a temporary one)")
    parser.add_argument("--packs", type=int, default=8, help="packs for the speed-up (default 8)")
    parser.add_argument("--sizes", type=int, nargs="+", default=[256, 512, 1024], help="target cube sizes")
    parser.add_argument("--skip-speedup", action="store_true")
    parser.add_argument("--skip-memory", action="store_true")
    args = parser.parse_args()
    workdir = args.workdir or Path(tempfile.mkdtemp(prefix="bench_dask_"))
    workdir.mkdir(parents=True, exist_ok=True)
    library_dir = workdir / "library_large"
    if not (library_dir / "library.json").exists():
        ParticleLibrary.from_scan(sample_scan("large"), progress=False).save(library_dir)
    library = ParticleLibrary.load(library_dir)
    lines = [f"# bench_dask.py ({platform.node()}, {os.cpu_count()} cores, "
             f"{psutil.virtual_memory().total / 2**30:.0f} GiB; other work on the machine: see load averages)", ""]
    if not args.skip_speedup:
        lines += speedup(library, workdir, args.packs)
    if not args.skip_memory:
        lines += memory(library_dir, library, workdir, args.sizes)
    print("\n".join(lines))


if __name__ == "__main__":
    main()
