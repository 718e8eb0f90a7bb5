"""Where the pour's cost per grain grows: seconds of every batch of one deep pour (issue 28).

Run from the repository root::

    .venv/bin/python bench/bench_pour_growth.py                          # 2,000 grains, about 3 minutes
    .venv/bin/python bench/bench_pour_growth.py --max-hull-vertices 32   # the same pour, coarser hulls
    .venv/bin/python bench/bench_pour_growth.py --keep-quiet-grains-moving  # no early locking (before 0.12)

It pours ``--grains`` grains of the built-in ``large`` sample's library, scaled by
``--scale`` (2), in batches of ``--batch-size`` (200) into a tube ``--width`` voxels wide
(1,000): `bench_scale.py`'s pour, shorter. Each batch's wall time is read from the batch
driver's own log record (`synthpack.physics.driver` logs one per locked batch), so nothing
in the pour is changed to time it. It prints the seconds and solver steps of every batch,
and, from the same run, the seconds per grain of the second half of the batches over the
first half's: a flat cost per grain gives 1. The first batches land on the bare floor,
the later ones on a bed of locked grains. Also the pour's packing fraction, its largest
grain-grain penetration and the grains outside, to check that a cheaper setting keeps the
packing.
"""

from __future__ import annotations

import argparse
import logging
import os
import platform
import tempfile
import time
from pathlib import Path

from synthpack.library.core import ParticleLibrary
from synthpack.physics import pour
from synthpack.pipeline.config import PackConfig
from synthpack.scan.samples import sample_scan

from _measure import load_average
from bench_scale import tube_radius


class BatchClock(logging.Handler):
    """Records the time of each of the batch driver's per-batch log records."""

    def __init__(self) -> None:
        super().__init__(logging.DEBUG)
        self.times: list[float] = []
        self.steps: list[int] = []

    def emit(self, record: logging.LogRecord) -> None:
        if record.msg.startswith("Batch %d:"):
            self.times.append(record.created)
            self.steps.append(int(record.args[2]))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--grains", type=int, default=2000, help="grains poured (default 2,000)")
    parser.add_argument("--batch-size", type=int, default=200, help="grains per batch (default 200)")
    parser.add_argument("--scale", type=float, default=2.0, help="grain scale factor (default 2)")
    parser.add_argument("--width", type=int, default=1000, help="tube width, voxels (default 1,000)")
    parser.add_argument("--max-hull-vertices", type=int, default=None,
                        help="cap on each collision hull's vertices (default: the engine's)")
    parser.add_argument("--keep-quiet-grains-moving", action="store_true",
                        help="engine option lock_quiet_grains: false (the pour before issue 28's early locking)")
    parser.add_argument("--workdir", type=Path, default=None, help="where the library is kept (default: temporary)")
    args = parser.parse_args()
    workdir = args.workdir or Path(tempfile.mkdtemp(prefix="bench_pour_growth_"))
    library_dir = workdir / "library"
    if not (library_dir / "library.json").is_file():
        ParticleLibrary.from_scan(sample_scan("large", seed=0), workers=1, progress=False).save(library_dir)
    library = ParticleLibrary.load(library_dir)
    options = {} if args.max_hull_vertices is None else {"max_hull_vertices": args.max_hull_vertices}
    if args.keep_quiet_grains_moving:
        options["lock_quiet_grains"] = False
    config = PackConfig().replace(pour={"n_particles": args.grains, "batch_size": args.batch_size, "scale": args.scale,
                                        "tube_radius": tube_radius(library, args.width), "engine_options": options})
    clock = BatchClock()
    driver_log = logging.getLogger("synthpack.physics.driver")
    driver_log.addHandler(clock)
    driver_log.setLevel(logging.DEBUG)
    print(f"# bench_pour_growth.py ({platform.node()}, {os.cpu_count()} cores, Python {platform.python_version()}); "
          f"load average before: {load_average()}\n")
    start = time.time()
    placements = pour(library, config.pour, 0, progress=False)
    wall = time.time() - start
    seconds = [b - a for a, b in zip([start] + clock.times[:-1], clock.times)]  # the first also holds the set-up
    checks = placements.checks
    print(f"{args.grains} grains of the `large` library at scale {args.scale:g}, batches of {args.batch_size}, "
          f"tube {args.width} voxels wide, hull vertices {args.max_hull_vertices or 'default'}: {wall:.1f} s "
          f"({wall / args.grains:.4f} s/grain); packing fraction {checks.packing_fraction:.3f}, largest grain "
          f"penetration {checks.max_grain_penetration_voxels:.2f} voxels, {checks.n_outside} outside.\n")
    print("| batch | seconds | solver steps | seconds per 1,000 steps |")
    print("|---|---|---|---|")
    for number, (s, steps) in enumerate(zip(seconds, clock.steps)):
        print(f"| {number} | {s:.1f} | {steps} | {1000 * s / steps:.2f} |")
    sizes = [min(args.batch_size, args.grains - k * args.batch_size) for k in range(len(seconds))]
    half = len(seconds) // 2
    if half:
        ratio = (sum(seconds[half:]) / sum(sizes[half:])) / (sum(seconds[:half]) / sum(sizes[:half]))
        print(f"\n- s/grain of batches {half}-{len(seconds) - 1} over batches 0-{half - 1} (same run): **{ratio:.2f}** "
              f"(flat: 1). Load average after: {load_average()}.")


if __name__ == "__main__":
    main()
