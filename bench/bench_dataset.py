"""Throughput of SyntheticParticlePackDataset: 256 x 256 slices with instance targets, from the cache.

The pack is built (or taken from the cache) by the dataset itself from the 'large'
sample: 400 grains poured into a tube of inner radius 1200 um, which makes a
grid of about 255 x 255 voxels across (10 um voxels). Every slice along axis 0 is
read (split "all") through a DataLoader with 0 and 2 workers (persistent workers,
shuffled): dense masks with `collate_fn` in batches of 8, and compact targets
(``dense_masks=False``) with `collate_stacked` in batches of 8, 16 and 32, after one
warm-up epoch, for at least ``--seconds`` per row; the loop only counts the items
it receives. The baseline,
measured in the same run on the same slices, reads the image and label slices
straight from NumPy memory maps of the pack's TIFF files (a copy of each slice,
no targets). A diagnostic row has the 2 workers build every item and drop it,
which separates building items from handing them to the main process (each
tensor goes through new shared memory).

Run::

    python bench/bench_dataset.py [--root DIR] [--seconds 4]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np
import torch
from torch.utils.data import DataLoader, Dataset

from synthpack.pipeline.config import PackConfig
from synthpack.dataset import SyntheticParticlePackDataset, collate_fn, collate_stacked
from synthpack.io import memmap_volume

#: Batch sizes of the compact rows (ultralytics trains with 16 by default).
BATCH_SIZES = (8, 16, 32)
CONFIG = PackConfig().replace(pour={"n_particles": 400, "batch_size": 50, "tube_radius": 1200.0})


def _rate(run_epoch, seconds: float) -> float:
    """Items per second over whole epochs, at least `seconds` long, after one warm-up epoch."""
    run_epoch()
    items, start = 0, time.perf_counter()
    while time.perf_counter() - start < seconds:
        items += run_epoch()
    return items / (time.perf_counter() - start)


def _memmap_epoch(tomogram: np.ndarray, labels: np.ndarray, slices: np.ndarray):
    def run() -> int:
        for s in slices:
            np.array(tomogram[s], dtype=np.float32)
            np.array(labels[s])
        return len(slices)

    return run


def _loader_epoch(loader: DataLoader):
    def run() -> int:
        return sum(len(batch[0]) for batch in loader)

    return run


class _BuiltAndDropped(Dataset):
    """Builds each item of `dataset` in the worker and returns only a flag (nothing big crosses processes)."""

    def __init__(self, dataset: SyntheticParticlePackDataset) -> None:
        self.dataset = dataset

    def __len__(self) -> int:
        return len(self.dataset)

    def __getitem__(self, index: int) -> int:
        self.dataset[index]
        return 1


def _fresh_shared_page_us(mib: int = 4, repeats: int = 20) -> float:
    """Microseconds per 4 KiB page to move a written tensor to new shared memory, as the DataLoader does."""
    nbytes = mib * 2**20
    elapsed = 0.0
    for _ in range(repeats):
        tensor = torch.empty(nbytes, dtype=torch.uint8)
        tensor.numpy()[::4096] = 1
        start = time.perf_counter()
        tensor.share_memory_()
        elapsed += time.perf_counter() - start
    return elapsed / repeats / (nbytes // 4096) * 1e6


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--root", type=Path,
                        help="cache directory (default: a temporary one, removed at the end, so the pack is built)")
    parser.add_argument("--seconds", type=float, default=4.0, help="least timing per row (default 4)")
    args = parser.parse_args()
    if args.root is not None:
        run(args.root, args.seconds)
        return
    with tempfile.TemporaryDirectory(prefix="synthpack-bench-dataset-") as root:
        run(Path(root), args.seconds)


def run(root: Path, seconds: float) -> None:
    """Build or reuse the pack under `root`, time every reader for at least `seconds`, print the table."""
    dataset = SyntheticParticlePackDataset(root, "large", split="all", config=CONFIG)
    cached = (dataset.cache_dir / "pack_0000" / "manifest.json").is_file()
    start = time.perf_counter()
    dataset.build()
    build_s = time.perf_counter() - start
    path = dataset.pack_paths[0]
    tomogram = memmap_volume(path / "tomogram.tif")
    labels = memmap_volume(path / "labels.tif")
    slices = dataset.slices(0)
    instances = np.array([len(dataset[i][1]["labels"]) for i in range(len(dataset))])
    bytes_per_item = 4 * tomogram[0].size + tomogram[0].size * (1 + instances.mean())

    baseline = _rate(_memmap_epoch(tomogram, labels, slices), seconds)
    rows = [("NumPy memmap: image + label slice (baseline)", baseline)]
    compact = SyntheticParticlePackDataset(root, "large", split="all", config=CONFIG, dense_masks=False)
    for data, kind, collate, batch_sizes in ((dataset, "dense masks, collate_fn", collate_fn, (8,)),
                                             (compact, "dense_masks=False, collate_stacked", collate_stacked,
                                              BATCH_SIZES)):
        for batch_size in batch_sizes:
            for workers in (0, 2):
                loader = DataLoader(data, batch_size=batch_size, shuffle=True, collate_fn=collate,
                                    num_workers=workers, persistent_workers=workers > 0)
                rows.append((f"dataset + DataLoader, {kind}, batch {batch_size}, {workers} workers",
                             _rate(_loader_epoch(loader), seconds)))
    dropped = DataLoader(_BuiltAndDropped(dataset), batch_size=8, shuffle=True, collate_fn=lambda b: (b,),
                         num_workers=2, persistent_workers=True)
    diagnostic = _rate(_loader_epoch(dropped), seconds)

    print(f"pack {path.name}: {tomogram.shape[0]} x {tomogram.shape[1]} x {tomogram.shape[2]} voxels "
          f"({'checked in the cache' if cached else 'built'} in {build_s:.1f} s), {len(slices)} slices of "
          f"{tomogram.shape[1]} x {tomogram.shape[2]} along axis 0, {instances.mean():.1f} instances per slice "
          f"on average (max {instances.max()}), {bytes_per_item / 2**20:.2f} MiB per item (image + masks + semantic)")
    print()
    print("| reader | slices / s | ratio to memmap |")
    print("|---|---|---|")
    for name, rate in rows:
        print(f"| {name} | {rate:,.0f} | {rate / baseline:.3f} |")
    print(f"| diagnostic: 2 workers build each item and drop it (nothing sent back) | {diagnostic:,.0f} "
          f"| {diagnostic / baseline:.3f} |")
    print()
    print(f"Moving a tensor to new shared memory (as the DataLoader does with each tensor a worker returns) "
          f"costs {_fresh_shared_page_us():.2f} us per 4 KiB page on this machine.")
    for name, rate in rows:
        if name.endswith(", 2 workers"):
            print(f"{name}: {rate:,.0f} slices/s (target >= 1,000)")


if __name__ == "__main__":
    main()
