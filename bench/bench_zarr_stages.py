"""Benchmark a Zarr pack's reads and levels: blocks read with their halo a row at a time, level 1 made as written.

Run from the repository root (about a minute on 2 cores)::

    .venv/bin/python bench/bench_zarr_stages.py [--shape 256 768 768] [--repeats 2] [--workdir DIR]

A volume of ``--shape`` voxels (float32, smooth structure plus noise, like a clean pack) is
written as a pack's Zarr volume (shards of the render's 64 x 256 x 256 chunks, each a chunk
of single slices; the pack's codec), then, each ``--repeats`` times, alternated, in one run:

1. **Halo reads** (the post-processing's blur reads every block with a halo of 5 voxels):
   each block read on its own (`_read_with_halo`, the code before 0.15) against the rows of
   blocks read as one strip across x (`blockwise._HaloReads`, 0.15). Both give the same
   bytes (checked).
2. **The calibrated post-processing's pass** (`apply_blockwise` of a blur and coloured
   noise) from the Zarr volume into memory, before (per-block reads, by the strip reader
   switched off) and after, and from the same volume in memory (no reads: the compute alone).
3. **Levels**: the volume written chunk by chunk through a plain array, then
   `write_levels` (before 0.15), against written through a `LevelledVolume` (its level 1 made
   as the chunks are written), then `write_levels` of the rest; the written seconds included
   both ways, and the levels checked equal.

Prints each figure and its ratio, after / before, measured in this run.
"""

from __future__ import annotations

import argparse
import os
import platform
import shutil
import tempfile
import time
from pathlib import Path

import numpy as np
import zarr
from scipy import ndimage

from synthpack._shared.chunks import chunk_boxes
from synthpack.artefacts import ColouredNoise, Compose, GaussianBlur
from synthpack.artefacts import blockwise
from synthpack.store.zarr_pack import create_levelled_volume, create_volume, write_levels, write_volume

CHUNKS = (64, 256, 256)  # the render's default chunks: a pack's shards
HALO = 5  # the calibrated blur's halo (sigma about 1.1 voxels)


def _volume(shape: tuple[int, int, int]) -> np.ndarray:
    rng = np.random.default_rng(0)
    smooth = ndimage.zoom(rng.random(tuple(max(2, n // 16) for n in shape), dtype=np.float32), 16, order=1)
    smooth = smooth[: shape[0], : shape[1], : shape[2]]
    return np.where(smooth > 0.5, 110.0, 26.0).astype(np.float32) + rng.normal(0, 3, shape).astype(np.float32)


def _write(store: Path, name: str, volume: np.ndarray, levelled: bool):
    make = create_levelled_volume if levelled else create_volume
    array = make(store, name, volume.shape, volume.dtype, (1.0, 1.0, 1.0), "px", chunks=(1, *CHUNKS[1:]),
                 shards=CHUNKS)
    for lo, hi in chunk_boxes(volume.shape, CHUNKS):
        box = tuple(slice(a, b) for a, b in zip(lo, hi))
        array[box] = volume[box]
    return array


def _timed(action) -> float:
    start = time.perf_counter()
    action()
    return time.perf_counter() - start


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--shape", type=int, nargs=3, default=(256, 768, 768))
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--workdir", type=Path, default=None)
    args = parser.parse_args()
    shape = tuple(args.shape)
    workdir = args.workdir or Path(tempfile.mkdtemp(prefix="bench_zarr_"))
    volume = _volume(shape)
    store = workdir / "source.zarr"
    shutil.rmtree(store, ignore_errors=True)
    source = _write(store, "clean", volume, levelled=False)
    halo = np.full(3, HALO)
    boxes = list(chunk_boxes(shape, CHUNKS))
    pipeline = Compose([GaussianBlur(sigma=1.1), ColouredNoise(pore_power=[2.6, 2.8, 1.6, 0.7, 0.04, 0.01],
                                                             grain_power=[2.8, 2.4, 1.5, 0.7, 0.05, 0.01],
                                                             pore_level=26.0, grain_level=110.0)])
    print(f"# bench_zarr_stages.py ({platform.node()}, {os.cpu_count()} cores, Python {platform.python_version()}); "
          f"{shape[0]} x {shape[1]} x {shape[2]} = {volume.size / 1e6:.0f} million voxels, chunks {CHUNKS}\n")
    times: dict[str, list[float]] = {}

    def record(name: str, seconds: float) -> None:
        times.setdefault(name, []).append(seconds)

    for _ in range(args.repeats):
        strips = blockwise._HaloReads(source, halo)
        block_reads = [blockwise._read_with_halo(source, lo, hi, halo) for lo, hi in boxes[:2]]
        assert all(np.array_equal(a, strips(lo, hi)) for a, (lo, hi) in zip(block_reads, boxes[:2]))
        record("halo reads, block by block", _timed(lambda: [blockwise._read_with_halo(source, lo, hi, halo)
                                                             for lo, hi in boxes]))
        strips = blockwise._HaloReads(source, halo)
        record("halo reads, a row at a time", _timed(lambda: [strips(lo, hi) for lo, hi in boxes]))
        after, before, memory = (np.empty(shape, np.float32) for _ in range(3))
        record("post-process pass, Zarr -> memory, a row at a time",
               _timed(lambda: blockwise.apply_blockwise(pipeline, source, after, 5, CHUNKS, threads=2)))
        strip_reader, blockwise._HaloReads = blockwise._HaloReads, _PerBlock
        try:
            record("post-process pass, Zarr -> memory, block by block",
                   _timed(lambda: blockwise.apply_blockwise(pipeline, source, before, 5, CHUNKS, threads=2)))
        finally:
            blockwise._HaloReads = strip_reader
        record("post-process pass, memory -> memory",
               _timed(lambda: blockwise.apply_blockwise(pipeline, volume, memory, 5, CHUNKS, threads=2)))
        assert np.array_equal(after, before) and np.array_equal(after, memory)
        for levelled in (False, True):
            out = workdir / f"levels_{levelled}.zarr"
            shutil.rmtree(out, ignore_errors=True)

            def written() -> None:
                array = _write(out, "tomogram", volume, levelled)
                _write(out, "labels", (volume > 60).astype(np.int32), levelled)
                write_volume(out, "clean", volume[:4, :4, :4], (1.0, 1.0, 1.0), "px")  # write_levels names it
                write_levels(out, (1.0, 1.0, 1.0), "px", threads=2,
                             level_one=("tomogram", "labels") if levelled and array.level_one else ())

            record(f"tomogram + labels written, then levels ({'level 1 as written' if levelled else 'after'})",
                   _timed(written))
        first, second = (zarr.open_group(str(workdir / f"levels_{flag}.zarr"), mode="r") for flag in (False, True))
        assert all(np.array_equal(first[key][...], second[key][...]) for key in ("1", "2", "labels/instances/1"))

    print("| figure | seconds (best of the repeats) |")
    print("|---|---|")
    for name, values in times.items():
        print(f"| {name} | {min(values):.2f} |")
    pairs = (("halo reads, a row at a time", "halo reads, block by block"),
             ("post-process pass, Zarr -> memory, a row at a time",
              "post-process pass, Zarr -> memory, block by block"),
             ("tomogram + labels written, then levels (level 1 as written)",
              "tomogram + labels written, then levels (after)"))
    print()
    for after, before in pairs:
        print(f"- {after} / {before}: **{min(times[after]) / min(times[before]):.2f}x** the time")
    if args.workdir is None:
        shutil.rmtree(workdir, ignore_errors=True)


class _PerBlock:
    """The reads before 0.15: each block with its halo on its own (`_read_with_halo`)."""

    def __init__(self, source, halo: np.ndarray) -> None:
        self._source, self._halo = source, halo

    def __call__(self, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
        return blockwise._read_with_halo(self._source, lo, hi, self._halo)


if __name__ == "__main__":
    main()
