"""Benchmarks of the foundation issue: particle extraction and library build.

1. Extraction on a 512^3 label volume with about 5,000 labels against the naive
   baseline that compares the whole volume with each label (``labels == k``),
   measured in the same run. The baseline is timed on a subset of labels and
   scaled to all of them.
2. Library build (extraction + meshing) of the built-in samples: seconds per
   particle with 1 and 2 worker processes, and the speed-up.

Run: ``python bench/bench_library.py [--size 512] [--labels 5000] [--baseline-labels 40]``
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from scipy import ndimage

from synthpack.library.core import ParticleLibrary
from synthpack.library.particles import extract_particles
from synthpack.scan.samples import sample_scan
from synthpack.scan.core import Scan


def voronoi_labels(size: int, n_labels: int, seed: int = 0) -> np.ndarray:
    """A (size,)*3 int32 volume of `n_labels` Voronoi cells with thin pore walls."""
    coarse = size // 4
    rng = np.random.default_rng(seed)
    seeds = np.zeros((coarse,) * 3, dtype=np.int32)
    flat = rng.choice(seeds.size, n_labels, replace=False)
    seeds.flat[flat] = np.arange(1, n_labels + 1, dtype=np.int32)
    _, index = ndimage.distance_transform_edt(seeds == 0, return_indices=True)
    cells = seeds[tuple(index)]
    walls = ndimage.grey_dilation(cells, size=2) != cells  # one coarse voxel of pore between cells
    cells[walls] = 0
    return np.repeat(np.repeat(np.repeat(cells, 4, 0), 4, 1), 4, 2)


def naive_extraction(scan: Scan, labels_to_do: np.ndarray, background: float) -> float:
    """Seconds for the baseline: one full-volume comparison per label."""
    start = time.perf_counter()
    for k in labels_to_do:
        mask = scan.labels == k
        where = np.nonzero(mask)
        box = tuple(slice(w.min(), w.max() + 1) for w in where)
        np.where(mask[box], scan.tomogram[box], background).astype(np.float32)
    return time.perf_counter() - start


def bench_extraction(size: int, n_labels: int, n_baseline: int) -> None:
    labels = voronoi_labels(size, n_labels)
    tomogram = np.where(labels > 0, 0.8, 0.2).astype(np.float32)
    scan = Scan(tomogram, labels)
    present = np.unique(labels)[1:]
    print(f"\n## Extraction: {size}^3 volume, {len(present)} labels")
    start = time.perf_counter()
    crops = extract_particles(scan, min_voxels=1, include_border=True, background=0.2)
    ours = time.perf_counter() - start
    subset = np.random.default_rng(1).choice(present, n_baseline, replace=False)
    naive = naive_extraction(scan, subset, 0.2) * len(present) / n_baseline
    print("| method | seconds | per label [ms] |")
    print("|---|---|---|")
    print(f"| synthpack (find_objects, one pass) | {ours:.2f} | {1000 * ours / len(crops):.2f} |")
    print(f"| naive `labels == k` (timed on {n_baseline}, scaled) | {naive:.1f} | {1000 * naive / len(present):.1f} |")
    print(f"\nspeed-up over naive: **{naive / ours:.0f}x** (target >= 50x)")


def bench_library_build() -> None:
    print("\n## Library build (extraction + meshing, 500 faces per particle)")
    print("| sample | particles | 1 worker [s] | s/particle | 2 workers [s] | s/particle | speed-up |")
    print("|---|---|---|---|---|---|---|")
    for name in ("large", "small"):
        scan = sample_scan(name)
        seconds = {}
        for workers in (1, 2):
            start = time.perf_counter()
            library = ParticleLibrary.from_scan(scan, workers=workers, progress=False)
            seconds[workers] = time.perf_counter() - start
        n = len(library)
        print(f"| {name} | {n} | {seconds[1]:.2f} | {seconds[1] / n:.4f} | {seconds[2]:.2f} | "
              f"{seconds[2] / n:.4f} | {seconds[1] / seconds[2]:.2f}x |")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--size", type=int, default=512)
    parser.add_argument("--labels", type=int, default=5000)
    parser.add_argument("--baseline-labels", type=int, default=40)
    args = parser.parse_args()
    bench_extraction(args.size, args.labels, args.baseline_labels)
    bench_library_build()


if __name__ == "__main__":
    main()
