"""Benchmark of the YOLO-seg export: throughput, polygon accuracy and file size.

It builds the particle library of the built-in 'large' sample scan, generates one
pack (``--n-particles`` grains, default 150) into a temporary folder and writes
the sample scan as TIFF files, then

1. times `export_yolo` on the pack plus the real sample (every slice along
   axis 0: windowing, PNG, polygons, label files, test truth images) and
   reports slices per second, and the time of each stage measured separately
   on the pack's slices; the baseline for the polygon stage is the naive way,
   ``find_contours(labels == k)`` on the whole slice for every instance k,
   also on one 1024 x 1024 slice tiled from the real sample (~2,900 instances);
2. for polygon simplification tolerances 0 (the default), 0.5, 0.75 and 1 px:
   vertices per polygon, label bytes per slice and the mean Dice of each
   polygon against its part, rasterised by pixel centres (skimage) and, when
   ultralytics is installed, by Ultralytics' own ``polygon2mask``;
3. the hole pixels that polygons fill, and what that costs in Dice.

Run: ``python bench/bench_export.py [--n-particles 150] [--baseline-instances 200]`` (about 1 minute)
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

import numpy as np
import tifffile
from PIL import Image
from skimage.measure import find_contours

from synthpack.pipeline.config import PackConfig
from synthpack.export import export_yolo
from synthpack.export.slices import to_uint8
from synthpack.export.yolo import rasterize_yolo_labels, slice_polygons, yolo_label_text
from synthpack.pipeline.generate import generate_packs
from synthpack.io import write_tiff
from synthpack.library.core import ParticleLibrary
from synthpack.store.pack import open_pack
from synthpack.scan.samples import sample_scan


def _ultralytics_polygon2mask(config_dir: Path):
    """Ultralytics' polygon rasteriser, offline with its settings in `config_dir`, or None without ultralytics."""
    os.environ["YOLO_OFFLINE"] = "1"
    os.environ["YOLO_CONFIG_DIR"] = str(config_dir)
    try:
        from ultralytics.data.utils import polygon2mask
    except ImportError:
        return None
    return polygon2mask


def _dice(a: np.ndarray, b: np.ndarray) -> float:
    return 2 * np.count_nonzero(a & b) / (np.count_nonzero(a) + np.count_nonzero(b))


def bench_throughput(pack_dir: Path, real: tuple[Path, Path], out: Path) -> None:
    pack = open_pack(pack_dir)
    n_pack = pack.shape[0]
    start = time.perf_counter()
    summary = export_yolo(out, packs=[pack_dir], real=[real], progress=False)
    seconds = time.perf_counter() - start
    n = sum(summary.images.values())
    print(f"\n## Export throughput (pack {'x'.join(map(str, pack.shape))} + real sample 128^3, axis 0)")
    print("| slices | label lines | seconds | slices/s |")
    print("|---|---|---|---|")
    print(f"| {n} | {sum(summary.instances.values())} | {seconds:.2f} | {n / seconds:.0f} |")

    labels, tomogram = np.asarray(pack.labels), np.asarray(pack.tomogram)
    stages = {}
    start = time.perf_counter()
    images = [to_uint8(tomogram[i], summary.window) for i in range(n_pack)]
    stages["window to 8 bits"] = time.perf_counter() - start
    start = time.perf_counter()
    for i, image in enumerate(images):
        Image.fromarray(image).save(out / f"bench_{i}.png")
    stages["PNG write"] = time.perf_counter() - start
    start = time.perf_counter()
    results = [slice_polygons(labels[i]) for i in range(n_pack)]
    stages["polygons (synthpack: one labelling pass, bounding boxes)"] = time.perf_counter() - start
    start = time.perf_counter()
    for labels_2d in labels:
        _naive_contours(labels_2d, np.unique(labels_2d)[1:])
    stages["polygons, naive baseline: find_contours(labels == k) per instance"] = time.perf_counter() - start
    start = time.perf_counter()
    for result, image in zip(results, images):
        yolo_label_text(result.polygons, image.shape)
    stages["label text"] = time.perf_counter() - start
    print(f"\nstages on the pack's {n_pack} slices ({labels.shape[1]}x{labels.shape[2]}):")
    print("| stage | ms/slice |")
    print("|---|---|")
    for name, value in stages.items():
        print(f"| {name} | {1000 * value / n_pack:.2f} |")


def _naive_contours(labels_2d: np.ndarray, ids: np.ndarray) -> None:
    for k in ids:
        find_contours((labels_2d == k).astype(np.float32), 0.5)


def bench_large_slice(real_labels: np.ndarray, n_baseline: int) -> None:
    """Polygons of a 1024 x 1024 slice tiled from 8 x 8 slices of the real sample (distinct ids per tile)."""
    tiles = [real_labels[20 + k].astype(np.int64) for k in range(64)]
    offset = int(real_labels.max()) + 1
    rows = [np.hstack([np.where(t > 0, t + offset * (8 * r + c), 0) for c, t in enumerate(tiles[8 * r: 8 * r + 8])])
            for r in range(8)]
    labels_2d = np.vstack(rows)
    ids = np.unique(labels_2d)[1:]
    start = time.perf_counter()
    result = slice_polygons(labels_2d)
    ours = time.perf_counter() - start
    subset = np.random.default_rng(0).choice(ids, n_baseline, replace=False)
    start = time.perf_counter()
    _naive_contours(labels_2d, subset)
    naive = (time.perf_counter() - start) * len(ids) / n_baseline
    print(f"\n## Polygons of one {labels_2d.shape[0]}x{labels_2d.shape[1]} slice with {len(ids)} instances")
    print("| method | seconds | ms/instance |")
    print("|---|---|---|")
    print(f"| synthpack `slice_polygons` ({len(result.polygons)} polygons) | {ours:.2f} | "
          f"{1000 * ours / len(ids):.3f} |")
    print(f"| naive find_contours(labels == k) (timed on {n_baseline}, scaled) | {naive:.2f} | "
          f"{1000 * naive / len(ids):.3f} |")
    print(f"\nspeed-up over naive: {naive / ours:.0f}x")


def bench_tolerance(pack_dir: Path, config_dir: Path) -> None:
    labels = np.asarray(open_pack(pack_dir).labels)
    polygon2mask = _ultralytics_polygon2mask(config_dir)
    print("\n## Polygon accuracy and size (pack slices, parts >= 10 px)")
    print("| tolerance [px] | vertices/polygon | label bytes/slice | mean part Dice (pixel centres) "
          "| mean part Dice (ultralytics polygon2mask) | share exact (ultralytics) |")
    print("|---|---|---|---|---|---|")
    for tolerance in (0.0, 0.5, 0.75, 1.0):
        vertices = size = 0
        centre, ultra, polygons = [], [], 0
        for labels_2d in labels:
            result = slice_polygons(labels_2d, tolerance=tolerance)
            text = yolo_label_text(result.polygons, labels_2d.shape)
            size += len(text.encode())
            vertices += sum(len(p) for p in result.polygons)
            polygons += len(result.polygons)
            height, width = labels_2d.shape
            for k, (mask, line) in enumerate(zip(rasterize_yolo_labels(text, labels_2d.shape), text.splitlines())):
                part = result.parts == k + 1
                centre.append(_dice(mask, part))
                if polygon2mask is not None:
                    xy = np.array(line.split()[1:], dtype=float).reshape(-1, 2) * [width, height]
                    ultra.append(_dice(polygon2mask((height, width), [xy.ravel()]).astype(bool), part))
        ultra_text = (f"{np.mean(ultra):.4f} | {np.mean(np.array(ultra) == 1.0):.3f}" if ultra
                      else "n/a (no ultralytics) | n/a")
        print(f"| {tolerance} | {vertices / polygons:.1f} | {size / len(labels):.0f} | "
              f"{np.mean(centre):.4f} | {ultra_text} |")


def bench_holes(pack_dir: Path, real: tuple[Path, Path]) -> None:
    print("\n## Holes filled by polygons")
    print("| source | parts | parts with holes | hole px / part px | mean Dice of the parts with holes |")
    print("|---|---|---|---|---|")
    sources = {"pack": np.asarray(open_pack(pack_dir).labels), "real sample": tifffile.imread(real[1])}
    for name, volume in sources.items():
        parts = holed = hole_px = part_px = 0
        costs = []
        for labels_2d in volume:
            result = slice_polygons(labels_2d)
            parts += len(result.polygons)
            hole_px += result.hole_pixels
            part_px += result.instance_pixels
            if result.hole_pixels:
                text = yolo_label_text(result.polygons, labels_2d.shape)
                for k, mask in enumerate(rasterize_yolo_labels(text, labels_2d.shape)):
                    part = result.parts == k + 1
                    if np.count_nonzero(mask & ~part):
                        holed += 1
                        costs.append(_dice(mask, part))
        mean_cost = f"{np.mean(costs):.3f}" if costs else "-"
        print(f"| {name} | {parts} | {holed} | {hole_px / part_px:.2e} | {mean_cost} |")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--n-particles", type=int, default=150)
    parser.add_argument("--baseline-instances", type=int, default=200)
    args = parser.parse_args()
    scan = sample_scan("large", seed=0)
    library = ParticleLibrary.from_scan(scan, workers=1, progress=False)
    config = PackConfig().replace(pour={"n_particles": args.n_particles, "batch_size": 50})
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        (pack_dir,) = generate_packs(library, tmp / "packs", 1, config, progress=False)
        real = (tmp / "tomogram.tif", tmp / "labels.tif")
        write_tiff(real[0], scan.tomogram, scan.voxel_size, scan.unit)
        write_tiff(real[1], scan.labels, scan.voxel_size, scan.unit, labels=True)
        bench_throughput(pack_dir, real, tmp / "yolo")
        bench_large_slice(scan.labels, args.baseline_instances)
        bench_tolerance(pack_dir, tmp / "ultralytics")
        bench_holes(pack_dir, real)


if __name__ == "__main__":
    main()
