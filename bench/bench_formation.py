"""Benchmark the cost of the image-formation model against the render it replaced (issue 14).

Run from the repository root (about 2 minutes on 2 cores)::

    .venv/bin/python bench/bench_formation.py [--grains 150] [--repeats 3]

Both arms build the same pack (the "large" sample library, the same pour and seed) with
`synthpack.generate.build_pack` and read its per-stage timings from the manifest:

* **baseline** (synthpack 0.2's image): whole-voxel render (``reconstruct.partial_volume:
  false``) and the ``generic`` post-processing (the 0.2 default recipe);
* **model**: the partial-volume render and the ``calibrated`` post-processing (PSF fitted to
  the source's edge spread, noise with the source's per-phase spectrum), the 0.3 default.

It prints the seconds of reconstruct + post-process per million voxels of each arm (best
of ``--repeats``, all in this run) and their ratio. Target: model <= 1.5x baseline.
The pour is the same in both arms and is not counted.
"""

from __future__ import annotations

import argparse
import os
import platform
import time

from synthpack.config import PackConfig
from synthpack.generate import build_pack
from synthpack.library import ParticleLibrary
from synthpack.samples import sample_scan

ARMS = {
    "baseline (0.2: whole voxels + generic)": {"reconstruct": {"partial_volume": False}, "postprocess": "generic"},
    "model (0.3: partial volume + calibrated)": {},
}


def seconds_per_megavoxel(library: ParticleLibrary, config: PackConfig, repeats: int) -> tuple[float, int]:
    """Best reconstruct + post-process seconds per 10^6 voxels over `repeats` builds, and the voxel count."""
    best = float("inf")
    voxels = 0
    for _ in range(repeats):
        pack = build_pack(library, config, seed=0, progress=False)
        timings = pack.manifest["timings"]
        voxels = int(pack.labels.size)
        best = min(best, (timings["reconstruct"] + timings["postprocess"]) / voxels * 1e6)
    return best, voxels


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--grains", type=int, default=150, help="grains in the pack (default 150)")
    parser.add_argument("--repeats", type=int, default=3, help="builds per arm; the best counts (default 3)")
    args = parser.parse_args()
    print(f"Machine: {os.cpu_count()} CPUs, {platform.platform()}, Python {platform.python_version()}")
    library = ParticleLibrary.from_scan(sample_scan("large"), workers=1, progress=False)
    base = PackConfig().replace(pour={"n_particles": args.grains, "batch_size": 50})
    start = time.perf_counter()
    results = {name: seconds_per_megavoxel(library, base.replace(**changes), args.repeats)
               for name, changes in ARMS.items()}
    (baseline, voxels), (model, _) = results.values()
    print(f"\n{args.grains} grains, {voxels / 1e6:.1f} M voxels, best of {args.repeats}\n")
    print("| arm | reconstruct + post-process, s per 10^6 voxels |\n|---|---|")
    for name, (value, _) in results.items():
        print(f"| {name} | {value:.3f} |")
    print(f"\n**model / baseline: {model / baseline:.2f}x** (target <= 1.5x); "
          f"benchmark wall time {time.perf_counter() - start:.0f} s")


if __name__ == "__main__":
    main()
