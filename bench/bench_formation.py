"""Benchmark the cost of the image-formation model against the render it replaced (issue 14).

Run from the repository root (about 2 minutes on 2 cores)::

    .venv/bin/python bench/bench_formation.py [--grains 150] [--repeats 3]

Both arms build the same pack (the "large" sample library, the same pour and seed) with
`synthpack.pipeline.generate.build_pack` and read its per-stage timings from the manifest:

* **baseline** (synthpack 0.2's image): whole-voxel render (``reconstruct.partial_volume:
  false``) and the ``generic`` post-processing (the 0.2 default recipe);
* **model**: the partial-volume render and the ``calibrated`` post-processing (PSF fitted to
  the source's edge spread, noise with the source's per-phase spectrum), the 0.3 default.

It prints the seconds of reconstruct + post-process per million voxels of each arm and
their ratio. The arms are built in turn (baseline, model, baseline, model, ...), so a busy
machine slows both alike. A run's first model pack prepares the partial-volume crops of the
grains it places; later packs of the run (in the same process) find them prepared
(`synthpack.render.crop_cache.CACHE_BYTES`), so the model's first pack is reported apart and
the ratio is that of the best later packs against the best baseline. Target: model <= 1.5x
baseline. The pour is the same in both arms and is not counted.
"""

from __future__ import annotations

import argparse
import os
import platform
import time

from synthpack.pipeline.config import PackConfig
from synthpack.pipeline.generate import build_pack
from synthpack.library.core import ParticleLibrary
from synthpack.scan.samples import sample_scan

ARMS = {
    "baseline (0.2: whole voxels + generic)": {"reconstruct": {"partial_volume": False}, "postprocess": "generic"},
    "model (0.3: partial volume + calibrated)": {},
}


def seconds_per_megavoxel(library: ParticleLibrary, config: PackConfig) -> tuple[float, int]:
    """Reconstruct + post-process seconds per 10^6 voxels of one build, and the voxel count."""
    pack = build_pack(library, config, seed=0, progress=False)
    timings = pack.manifest["timings"]
    voxels = int(pack.labels.size)
    return (timings["reconstruct"] + timings["postprocess"]) / voxels * 1e6, voxels


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--grains", type=int, default=150, help="grains in the pack (default 150)")
    parser.add_argument("--repeats", type=int, default=3, help="builds per arm (the model one more); the best counts (default 3)")
    args = parser.parse_args()
    print(f"Machine: {os.cpu_count()} CPUs, {platform.platform()}, Python {platform.python_version()}")
    library = ParticleLibrary.from_scan(sample_scan("large"), workers=1, progress=False)
    base = PackConfig().replace(pour={"n_particles": args.grains, "batch_size": 50})
    start = time.perf_counter()
    configs = {name: base.replace(**changes) for name, changes in ARMS.items()}
    runs: dict[str, list[float]] = {name: [] for name in ARMS}
    for _ in range(args.repeats + 1):  # the model's first build is its cold one
        for name, config in configs.items():
            value, voxels = seconds_per_megavoxel(library, config)
            runs[name].append(value)
    (baseline_name, baseline), (model_name, model) = runs.items()
    best_baseline, cold, warm = min(baseline), model[0], min(model[1:])
    print(f"\n{args.grains} grains, {voxels / 1e6:.1f} M voxels, best of {args.repeats} (+1 cold model build)\n")
    print("| arm | reconstruct + post-process, s per 10^6 voxels |\n|---|---|")
    print(f"| {baseline_name} | {best_baseline:.3f} |")
    print(f"| {model_name}, first pack of a run | {cold:.3f} |")
    print(f"| {model_name}, later packs | {warm:.3f} |")
    print(f"\n**model / baseline: {warm / best_baseline:.2f}x** (first pack {cold / best_baseline:.2f}x; "
          f"target <= 1.5x); benchmark wall time {time.perf_counter() - start:.0f} s")

if __name__ == "__main__":
    main()
