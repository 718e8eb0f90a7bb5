"""Benchmark one large pack end to end against the machine's memory-bandwidth floor (issue 17).

Run from the repository root::

    .venv/bin/python bench/bench_scale.py [--quick] [--grains 10000] [--width 1000] [--workdir DIR]

What it does, all in one run:

1. Builds the particle library of the built-in ``large`` sample (grains about 23
   voxels across).
2. ``synthpack generate --format zarr`` of one pack of ``--grains`` grains (10,000;
   2,000 with ``--quick``) scaled by ``--scale`` (2: about 46 voxels across) in a
   tube ``--width`` voxels wide (1,000), the default calibrated post-processing, in
   a subprocess whose peak RSS (summed over the process tree) is sampled every 0.1 s.
   Prints the wall time of each stage (from the pack's manifest), the voxels per
   second of each voxel stage and the peak RSS.
3. The bandwidth floor of the same run: the time to copy the pack's three volumes
   (tomogram and clean float32, labels) once in memory with ``np.copyto``, and to
   write them once as Zarr with the pack's own codec, chunks and shards. Both are
   timed on slabs of the pack's own data (so memory stays small) and scaled to the
   whole volume. The voxel stages' time is printed as a ratio to the copy floor.
4. The pour's cost per grain against a pour of a tenth as many grains (at least
   200) in the same tube, at the same scale, in the same run: flat cost as the pack
   grows means a ratio near 1.

Targets (issue 17): the 10,000-grain pack in <= 600 s wall on 2 cores (pour <= 300 s,
voxel stages and writes <= 200 s), peak RSS <= 2 GiB, voxel stages within 10x of the
copy floor, pour s/grain at 10,000 grains <= 1.3x that at 1,000.
"""

from __future__ import annotations

import argparse
import math
import os
import platform
import tempfile
import time
from pathlib import Path

import numpy as np
import zarr

from synthpack.pipeline.config import PackConfig
from synthpack.library.core import ParticleLibrary
from synthpack.store.pack import PACK_VOLUMES
from synthpack.physics import pour
from synthpack.scan.samples import sample_scan
from synthpack.store.zarr_pack import VOLUME_PATHS

from _measure import generate_zarr_pack, load_average

WALL_VOXELS = 3 + 2  # Tube.for_library's wall and clearance, voxels: the tube's outer width is about --width
SLAB_SLICES = 64  # slices per timed slab of the floor


def tube_radius(library: ParticleLibrary, width: int) -> float:
    """Inner radius (physical units) of a tube whose outer width is about `width` voxels."""
    return (width / 2 - WALL_VOXELS) * float(library.voxel_size[1])


def _best_of(repeats: int, action) -> float:
    best = math.inf
    for _ in range(repeats):
        start = time.perf_counter()
        action()
        best = min(best, time.perf_counter() - start)
    return best


def bandwidth_floor(store: Path, workdir: Path) -> dict[str, dict[str, float]]:
    """Seconds to copy each pack volume once in memory, and to write it once with its Zarr codec.

    Timed on one slab of `SLAB_SLICES` slices of the volume's own data (best of 3),
    scaled by the volume's slice count.
    """
    floor = {}
    for name in PACK_VOLUMES:
        array = zarr.open_array(str(store / VOLUME_PATHS[name]), mode="r")  # full resolution
        depth = min(SLAB_SLICES, array.shape[0])
        start = (array.shape[0] - depth) // 2
        slab = np.ascontiguousarray(array[start:start + depth])
        target = np.empty_like(slab)
        copy = _best_of(3, lambda: np.copyto(target, slab))
        shards = array.shards or array.chunks
        depth_written = max(shards[0], depth - depth % shards[0])
        slab = np.ascontiguousarray(array[start:start + depth_written]) if depth_written != depth else slab
        copy_store = workdir / f"floor_{name}.zarr"
        written = zarr.create_array(store=str(copy_store), shape=slab.shape, dtype=array.dtype, chunks=array.chunks,
                                    shards=array.shards, compressors=array.compressors, overwrite=True)
        write = _best_of(3, lambda: written.__setitem__(slice(None), slab))
        stored = sum(f.stat().st_size for f in copy_store.rglob("*") if f.is_file())
        slices = array.shape[0]
        floor[name] = {"copy": copy * slices / depth, "zarr": write * slices / depth_written,
                       "ratio": slab.nbytes / stored, "codec": str(array.compressors)}
    return floor


def pour_per_grain(library: ParticleLibrary, n: int, radius: float, scale: float, batch_size: int) -> float:
    """Seconds per grain of a pour of `n` grains in the bench's tube, with the generate run's settings.

    The batch size is the generate run's too (until 0.10 the baseline poured in the default
    batches of 50 while the pack poured in batches of 200, so the ratio compared two settings).
    """
    config = PackConfig().replace(pour={"n_particles": n, "batch_size": min(n, batch_size), "scale": scale,
                                        "tube_radius": radius})
    start = time.perf_counter()
    pour(library, config.pour, 0, progress=False)
    return (time.perf_counter() - start) / n


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="2,000 grains instead of 10,000")
    parser.add_argument("--grains", type=int, default=None, help="grains in the pack (default 10,000; quick 2,000)")
    parser.add_argument("--scale", type=float, default=2.0, help="grain scale factor (default 2)")
    parser.add_argument("--width", type=int, default=1000, help="tube width, voxels (default 1,000)")
    parser.add_argument("--batch-size", type=int, default=200, help="grains per batch (default 200)")
    parser.add_argument("--workdir", type=Path, default=None, help="scratch folder (default: a temporary one)")
    parser.add_argument("--overlap", choices=("auto", "on", "off"), default="auto",
                        help="run.overlap: render while pouring (default auto: on from 1,000 grains)")
    args = parser.parse_args()
    grains = args.grains or (2000 if args.quick else 10_000)
    workdir = args.workdir or Path(tempfile.mkdtemp(prefix="bench_scale_"))
    workdir.mkdir(parents=True, exist_ok=True)
    print(f"# bench_scale.py ({platform.node()}, {os.cpu_count()} cores, Python {platform.python_version()}); "
          f"load average before: {load_average()}\n")

    library_dir = workdir / "library"
    if not (library_dir / "library.json").is_file():
        ParticleLibrary.from_scan(sample_scan("large", seed=0), workers=1, progress=False).save(library_dir)
    library = ParticleLibrary.load(library_dir)
    radius = tube_radius(library, args.width)
    # the whole tube (`reconstruct.view: tube`): the `large` sample shows no container, so the default view
    # would write only an interior crop the size of the sample (1213 x 257 x 257 voxels at 10,000 grains)
    config = PackConfig().replace(pour={"n_particles": grains, "batch_size": args.batch_size, "scale": args.scale,
                                        "tube_radius": radius}, reconstruct={"view": "tube"},
                                  run={"overlap": args.overlap}).to_dict()
    out = workdir / f"pack_{grains}"
    if out.exists():
        raise SystemExit(f"{out} exists: remove it or give another --workdir")
    manifest, wall, rss = generate_zarr_pack(library_dir, config, out)
    shape = manifest["shape"]
    voxels = math.prod(shape)
    t = manifest["timings"]
    overlap = manifest.get("overlap")
    # the render's own time: after the pour, and (rendering while pouring) its one thread's seconds meanwhile
    render = t["reconstruct"] + t.get("render_while_pouring", 0.0)
    voxel_stages = render + t["postprocess"]
    floor = bandwidth_floor(out / "pack_0000" / "pack.zarr", workdir)
    copy_floor = sum(f["copy"] for f in floor.values())
    zarr_floor = sum(f["zarr"] for f in floor.values())
    baseline_n = max(200, grains // 10)
    baseline = pour_per_grain(library, baseline_n, radius, args.scale, args.batch_size)
    per_grain = t["pour"] / grains

    print(f"Pack: {grains} grains of the `large` library at scale {args.scale:g} in a tube {args.width} voxels wide; "
          f"grid {' x '.join(map(str, shape))} = {voxels / 1e6:.0f} million voxels; calibrated post-processing; "
          f"Zarr. Pour checks: {manifest['pour_checks']['n_outside']} outside, packing fraction "
          f"{manifest['pour_checks']['packing_fraction']:.3f}.\n")
    print("| stage | seconds | million voxels / s |")
    print("|---|---|---|")
    print(f"| pour | {t['pour']:.1f} ({per_grain:.4f} s/grain) | |")
    if overlap:
        print(f"| render while pouring (one thread; {overlap['chunks_while_pouring']} chunks, "
              f"{overlap['drawn_again']} drawn again) | {t['render_while_pouring']:.1f} | |")
        print(f"| render after the pour (`reconstruct`) | {t['reconstruct']:.1f} | |")
    else:
        print(f"| reconstruct (Zarr writes included) | {t['reconstruct']:.1f} | {voxels / 1e6 / t['reconstruct']:.2f} |")
    print(f"| postprocess (Zarr writes included) | {t['postprocess']:.1f} | {voxels / 1e6 / t['postprocess']:.2f} |")
    print(f"| OME-Zarr levels (`write`) | {t['write']:.1f} | |")
    after_pour = t["reconstruct"] + t["postprocess"]
    print(f"| rest (start-up, library, label count, manifest) | {wall - t['pour'] - after_pour - t['write']:.1f} | |")
    print(f"| **total wall** | **{wall:.1f}** | |")
    print(f"\nPeak RSS of the process tree: **{rss.peak / 2**30:.2f} GiB** (target <= 2 GiB).\n")
    print("Bandwidth floor of the same run (the pack's volumes, timed on slabs of their own data):\n")
    print("| volume | copy once [s] | Zarr write once [s] | compression ratio | codec |")
    print("|---|---|---|---|---|")
    for name, f in floor.items():
        print(f"| {name} | {f['copy']:.2f} | {f['zarr']:.2f} | {f['ratio']:.2f} | `{f['codec']}` |")
    print(f"| all | {copy_floor:.2f} | {zarr_floor:.2f} | | |")
    print(f"\n- Voxel stages ÷ copy floor: **{voxel_stages / copy_floor:.0f}x** (target <= 10x); "
          f"÷ Zarr-write floor: **{voxel_stages / zarr_floor:.1f}x** (target <= 3x)"
          + (f"; after the pour alone ÷ Zarr-write floor: {after_pour / zarr_floor:.1f}x." if overlap else "."))
    print(f"- Overlap: wall ÷ (pour + voxel stages): **{wall / (t['pour'] + voxel_stages):.2f}** (target <= 0.7; "
          "above 1 where the stages run one after the other; the render while pouring counted in its one "
          "thread's seconds).")
    print(f"- Pour s/grain at {grains} grains ÷ at {baseline_n} (same tube, batches and run): "
          f"**{per_grain / baseline:.2f}** (target <= 1.3; {baseline:.4f} s/grain at {baseline_n}).")
    print(f"- Wall {wall:.0f} s (target <= 600 s at 10,000 grains), pour {t['pour']:.0f} s (<= 300 s), "
          f"voxel stages {voxel_stages:.0f} s (<= 200 s). Load average after: {load_average()}.")


if __name__ == "__main__":
    main()
