"""Benchmark the pour: speed, scaling with the number of grains, and the paper's baseline.

Run from the repository root::

    .venv/bin/python bench/bench_pour.py            # about 6 minutes on 2 cores
    .venv/bin/python bench/bench_pour.py --quick    # 100 and 400 grains, 30-grain baseline

It builds the particle library of the built-in "large" sample scan once, then

1. pours N_SMALL and N_LARGE grains (default 500 and 2,000) with the default engine
   (pybullet, settle detection, locking), side by side as a free pour
   (``target_solid_fraction=None``) and packed to the source's bulk solid fraction
   (the default, :mod:`synthpack.physics.compaction`), and prints seconds, seconds per
   grain, packing fraction and largest interpenetration; the compaction's cost is the
   ratio of their seconds per grain (target <= 1.5), the scaling ratio is s/grain at
   N_LARGE over s/grain at N_SMALL (locking should keep it near 1; target <= 1.3);
2. emulates "the paper's way of running Blender" on the same pybullet engine: every
   batch a fixed 1,000 frames of 1/24 s with 50 substeps per frame (50,000 solver
   steps of 1/1200 s), no settle detection and no deactivation (Blender's rigid
   bodies do not sleep by default). That is slow, so it runs on fewer grains
   (--baseline-grains, in a narrower tube so the pack is deep enough for a bulk
   packing fraction) next to the default engine on the very same pour; the speed-up
   is the ratio of their seconds per grain, and the baseline's time for N grains
   is extrapolated per grain (said so in the table).
"""

from __future__ import annotations

import argparse
import dataclasses
import time

import numpy as np

from synthpack.library.core import ParticleLibrary
from synthpack.physics import Placements, PourConfig, SettleCriteria, Tube, pour
from synthpack.scan.samples import sample_scan

PAPER_FRAMES = 1000
PAPER_SUBSTEPS = 50
PAPER_FRAME_TIME = 1 / 24  # Blender's default frame rate


def _row(name: str, placements: Placements, note: str = "") -> dict:
    checks = placements.checks
    n = len(placements)
    return {
        "run": name,
        "grains": n,
        "batches": len(checks.steps_per_batch),
        "steps": sum(checks.steps_per_batch),
        "seconds": checks.seconds,
        "s_per_grain": checks.seconds / n,
        "packing": checks.packing_fraction,
        "pen_grain_vx": checks.max_grain_penetration_voxels,
        "pen_wall_vx": checks.max_wall_penetration_voxels,
        "outside": checks.n_outside,
        "note": note,
    }


def _table(rows: list[dict]) -> str:
    head = ("| run | grains | batches | solver steps | engine s | s / grain | packing fraction "
            "| max grain-grain penetration [vx] | max wall penetration [vx] | outside | note |")
    lines = [head, "|" + "---|" * 11]
    for r in rows:
        lines.append(
            f"| {r['run']} | {r['grains']} | {r['batches']} | {r['steps']:,} | {r['seconds']:.1f} "
            f"| {r['s_per_grain']:.4f} | {r['packing']:.3f} | {r['pen_grain_vx']:.2f} "
            f"| {r['pen_wall_vx']:.2f} | {r['outside']} | {r['note']} |"
        )
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true",
                        help="100 and 400 grains; 30-grain baseline")
    parser.add_argument("--batch-size", type=int, default=50)
    parser.add_argument("--baseline-grains", type=int, default=60)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    n_small, n_large = (100, 400) if args.quick else (500, 2000)
    n_baseline = 30 if args.quick else args.baseline_grains
    batch = args.batch_size

    start = time.perf_counter()
    library = ParticleLibrary.from_scan(sample_scan("large"), progress=False)
    print(f"library: {len(library)} grains from the 'large' sample in "
          f"{time.perf_counter() - start:.1f} s (built once)")

    rows = []
    target = library.statistics.solid_fraction
    for n in (n_small, n_large):
        for name, value in (("free pour (target none)", None), (f"packed to the source's {target:.3f}", "source")):
            config = PourConfig(n_particles=n, batch_size=batch, target_solid_fraction=value)
            placements = pour(library, config, args.seed, progress=False)
            reached = placements.checks.target_reached
            rows.append(_row(name, placements, "default tube" + ("" if value is None else f", reached: {reached}")))
            print(f"poured {n} grains ({name}) in {placements.checks.seconds:.1f} s")
    cost = [rows[k + 1]["s_per_grain"] / rows[k]["s_per_grain"] for k in (0, 2)]
    scaling = [rows[k + 2]["s_per_grain"] / rows[k]["s_per_grain"] for k in (0, 1)]

    d = float(np.median(library.equivalent_diameters))
    narrow = Tube(inner_radius=2.0 * d, height=25.0 * d, wall_thickness=30.0, base_thickness=30.0)
    free = PourConfig(n_particles=n_baseline, batch_size=batch, target_solid_fraction=None)
    ours = pour(library, free, args.seed, container=narrow, progress=False)
    rows.append(_row("default (settle detection)", ours, "tube r = 2 d_med, same pour as below"))
    print(f"poured {n_baseline} grains (narrow tube) in {ours.checks.seconds:.1f} s")
    paper = pour(
        library, dataclasses.replace(free, engine_options={"fixed_steps": PAPER_FRAMES, "allow_sleeping": False}),
        args.seed, container=narrow, progress=False,
        settle=SettleCriteria(time_step=PAPER_FRAME_TIME, substeps=PAPER_SUBSTEPS),
    )
    rows.append(_row(
        "paper's Blender schedule (emulated)", paper,
        f"{PAPER_FRAMES} frames x {PAPER_SUBSTEPS} substeps per batch, no settle detection",
    ))
    print(f"poured {n_baseline} grains (paper's schedule) in {paper.checks.seconds:.1f} s")
    speedup = rows[5]["s_per_grain"] / rows[4]["s_per_grain"]

    print()
    print(f"Batch size {batch}, seed {args.seed}; 'steps' of the paper's schedule count frames "
          f"(each {PAPER_SUBSTEPS} solver substeps).")
    print()
    print(_table(rows))
    print()
    print(f"Compaction cost: s/grain packed / free = {cost[0]:.2f} at {n_small}, {cost[1]:.2f} at {n_large} "
          "(target <= 1.5)")
    print(f"Scaling: s/grain at {n_large} / s/grain at {n_small} = {scaling[0]:.2f} free, {scaling[1]:.2f} packed "
          "(target <= 1.3)")
    print(f"Speed-up of settle detection over the paper's fixed schedule (same {n_baseline}-grain "
          f"pour, per grain): {speedup:.1f}x (target >= 10x)")
    for n, row in zip((n_small, n_large), (rows[0], rows[2])):  # the free pours
        print(f"  extrapolated per grain: the paper's schedule would take about "
              f"{rows[5]['s_per_grain'] * n / 60:.0f} min for {n} grains vs "
              f"{row['seconds'] / 60:.1f} min measured with settle detection")


if __name__ == "__main__":
    main()
