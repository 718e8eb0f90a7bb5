"""Paired differences between the same arms of two experiment run folders (not a test).

The experiment's report pairs the arms of one run. Two runs of the same config but for the
packs (here exact against segmented labels) share their seeds and real test slices, so their
arms pair the same way: this prints ``b - a`` per arm, and each run's arm against the real-only
arm of the first run, in foreground Dice and F1@0.5 points with the paired bootstrap 95 %
interval over test slices and seeds (`training.stats.paired_bootstrap`). Used for
docs/experiment-cpu.md's segmented-labels section:

    PYTHONPATH=. python docs/compare_runs.py RUN_EXACT RUN_SEGMENTED --scan sand \
        --arms unet_sand:syn unet_sand+syn-first --real unet_sand
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from training.experiment import SLICE_COUNTS
from training.stats import paired_bootstrap


def slice_counts(run: Path, arm: str, seeds: list[int], scan: str) -> np.ndarray:
    """Per seed and test slice, the counts `training.stats.paired_bootstrap` reads, int64 (S, N, 6)."""
    rows = []
    for seed in seeds:
        slices = json.loads((run / "eval" / arm / f"seed{seed}" / scan / "scores.json").read_text())["slices"]
        rows.append([[row[key] for key in SLICE_COUNTS] for row in slices])
    return np.asarray(rows, dtype=np.int64)


def difference(label: str, b: np.ndarray, a: np.ndarray) -> str:
    """``b - a`` in Dice and F1 points with their intervals."""
    dice, f1 = paired_bootstrap(b[..., :3], a[..., :3]), paired_bootstrap(b[..., 3:], a[..., 3:])
    return (f"{label}: Dice {100 * dice.difference:+.2f} [{100 * dice.low:+.2f}, {100 * dice.high:+.2f}], "
            f"F1 {100 * f1.difference:+.1f} [{100 * f1.low:+.1f}, {100 * f1.high:+.1f}]")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("first", type=Path, help="run folder a (holds the real-only arm)")
    parser.add_argument("second", type=Path, help="run folder b")
    parser.add_argument("--scan", required=True, help="the real test set's name")
    parser.add_argument("--arms", nargs="+", required=True, help="arms both runs trained")
    parser.add_argument("--real", required=True, help="the real-only arm of the first run")
    parser.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2])
    args = parser.parse_args()
    real = slice_counts(args.first, args.real, args.seeds, args.scan)
    for arm in args.arms:
        a, b = (slice_counts(run, arm, args.seeds, args.scan) for run in (args.first, args.second))
        print(difference(f"{arm}: second - first", b, a))
        print(difference(f"{arm}: first - {args.real}", a, real))
        print(difference(f"{arm}: second - {args.real}", b, real))


if __name__ == "__main__":
    main()
