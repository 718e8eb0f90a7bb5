"""Benchmark the simulation reconstruction (paper section 3.4) against the paper code's method.

Run from the repository root (about 2-3 minutes on 2 cores)::

    .venv/bin/python bench/bench_reconstruct.py [--size 512] [--workdir DIR] [--skip-demo]

It prints Markdown tables for three targets:

1. Speed and quality on a real pour (the "large" sample library, 150 grains in
   batches of 50, seed 0), against the paper code's method measured in the same
   run on the same placements: per grain three successive ``scipy.ndimage.rotate``
   calls (cubic spline, ``reshape=True``) about the x, y and z axes by the Euler
   angles of ``Placements.euler_angles()`` (``R = Rz(psi) Ry(phi) Rx(theta)``),
   applied to the crop and to the mask, then pasted at the grain's position
   rounded to the nearest voxel, the last writer winning. Ours is
   ``pose_maps`` + ``reconstruct`` called as ``generate.build_pack`` calls them.
   Quality: per-grain Dice of the label volume of each method against an exact
   reference (each grain's mask resampled once by nearest neighbour on a 4x finer
   grid with the same affine map, then averaged back: a voxel is in the grain when
   more than half of its 64 sub-voxels are). Target: ours >= 10x faster and at
   least as good.
2. End to end: ``synthpack demo`` in a subprocess, its seconds per stage and the
   total wall time.
3. Peak memory of reconstructing a 512^3 pack in a child process that only loads
   the library and placements and reconstructs; the net peak (peak RSS minus the
   child's RSS just before reconstructing) against the bytes of the two output
   volumes (tomogram float32 + labels int32 = 8 bytes per voxel). Pouring the
   ~80,000 grains of the "small" library that fill a 512^3 grid would take far
   longer than this benchmark's budget, so the placements are synthesised: random
   rotations on a jittered cubic lattice whose spacing is the largest grain's
   circumscribed-sphere diameter, so no two grains overlap whatever their rotation.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import scipy
from scipy import ndimage
from scipy.spatial.transform import Rotation

from synthpack.pipeline.config import ReconstructConfig
from synthpack.library.core import ParticleLibrary
from synthpack.physics import Placements, PourConfig, pour
from synthpack.render import Background, Grid, pose_maps, reconstruct
from synthpack.scan.samples import sample_scan

from _measure import load_average

SUPERSAMPLE = 4


def _rss_kib() -> tuple[int, int]:
    """Current and peak resident set size of this process (VmRSS, VmHWM), KiB."""
    fields = {}
    for line in Path("/proc/self/status").read_text().splitlines():
        key, _, value = line.partition(":")
        if key in ("VmRSS", "VmHWM"):
            fields[key] = int(value.split()[0])
    return fields["VmRSS"], fields["VmHWM"]


# -- the paper code's method ---------------------------------------------------------


#: ``ndimage.rotate`` sorts its two axes and turns the first toward the second by the
#: angle, so a right-handed rotation about x (plane z-y) is angle -a on axes (0, 1),
#: about y (plane z-x) +a on (0, 2), about z (plane y-x) -a on (1, 2).
_ROTATE_PLANE = {"x": ((0, 1), -1.0), "y": ((0, 2), 1.0), "z": ((1, 2), -1.0)}


def rotate_about(volume: np.ndarray, axis: str, angle: float, order: int = 3) -> np.ndarray:
    """One ``ndimage.rotate`` (reshape=True) of a (z, y, x) volume by `angle` radians about world `axis`.

    The array centre stays at the centre of the (reshaped) output, so the crop centre
    (the particle-local origin) stays at the centre.
    """
    axes, sign = _ROTATE_PLANE[axis]
    return ndimage.rotate(volume, sign * np.degrees(angle), axes=axes, reshape=True, order=order)


def paper_rotate(volume: np.ndarray, theta: float, phi: float, psi: float, order: int = 3) -> np.ndarray:
    """Rotate by ``R = Rz(psi) Ry(phi) Rx(theta)``: three successive rotations, about x, then y, then z."""
    out = rotate_about(volume, "x", theta, order)
    out = rotate_about(out, "y", phi, order)
    return rotate_about(out, "z", psi, order)


def paper_place(shape: tuple[int, ...], centre_index: np.ndarray, grid_shape) -> tuple[tuple, tuple]:
    """Output and source windows pasting an array of `shape` centred at the rounded `centre_index`."""
    start = np.rint(centre_index - (np.asarray(shape) - 1) / 2.0).astype(int)
    stop = start + np.asarray(shape)
    lo = np.maximum(start, 0)
    hi = np.minimum(stop, grid_shape)
    out = tuple(slice(a, b) for a, b in zip(lo, hi))
    src = tuple(slice(a - s, b - s) for a, b, s in zip(lo, hi, start))
    return out, src


def paper_reconstruct(library: ParticleLibrary, placements: Placements, grid: Grid, background: float,
                      order: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """The paper code's reconstruction: rotate crop and mask 3 times, paste, last writer wins."""
    tomogram = np.full(grid.shape, background, dtype=np.float32)
    labels = np.zeros(grid.shape, dtype=np.int32)
    angles = placements.euler_angles()
    centres = (placements.positions[:, ::-1] - np.asarray(grid.origin)) / np.asarray(grid.voxel_size)
    for i, (index, (theta, phi, psi)) in enumerate(zip(placements.indices, angles)):
        particle = library[int(index)]
        crop = paper_rotate(particle.tomogram, theta, phi, psi, order)
        mask = paper_rotate(particle.mask.astype(np.float32), theta, phi, psi, order) > 0.5
        out, src = paper_place(mask.shape, centres[i], grid.shape)
        inside = mask[src]
        tomogram[out][inside] = crop[src][inside]
        labels[out][inside] = i + 1
    return tomogram, labels


# -- the exact reference and Dice --------------------------------------------------


def reference_mask(mask: np.ndarray, matrix: np.ndarray, offset: np.ndarray, lo: np.ndarray,
                   hi: np.ndarray) -> np.ndarray:
    """Mask resampled into the output box [lo, hi) by nearest neighbour at 4x supersampling.

    Fine voxel ``f`` of the box sits at output index ``lo - (s-1)/(2s) + f/s``; its
    crop index is ``matrix @ that + offset`` (the same affine map as ours). A voxel
    is inside when more than half of its s^3 sub-voxels are.
    """
    s = SUPERSAMPLE
    shape = tuple(int(n) for n in (hi - lo))
    fine_offset = offset + matrix @ (lo - (s - 1) / (2.0 * s))
    fine = ndimage.affine_transform(mask.astype(np.uint8), matrix / s, offset=fine_offset,
                                    output_shape=tuple(n * s for n in shape), order=0,
                                    mode="grid-constant", cval=0)
    fraction = fine.reshape(shape[0], s, shape[1], s, shape[2], s).mean(axis=(1, 3, 5))
    return fraction > 0.5


def dice(a_count: int, b_count: int, both: int) -> float:
    return 2.0 * both / (a_count + b_count) if a_count + b_count else 1.0


def per_grain_dice(labels: np.ndarray, references: list[tuple[tuple, np.ndarray]]) -> np.ndarray:
    """Dice of ``labels == i + 1`` against each grain's reference mask (window, mask)."""
    counts = np.bincount(labels.ravel(), minlength=len(references) + 1)
    return np.array([dice(int(counts[i + 1]), int(ref.sum()), int(np.count_nonzero(ref & (labels[window] == i + 1))))
                     for i, (window, ref) in enumerate(references)])


# -- target 1 ----------------------------------------------------------------------


def _background(library: ParticleLibrary, wall: bool = True) -> Background:
    return Background.from_source(library.statistics, ReconstructConfig(wall=wall))


def ours(library: ParticleLibrary, placements: Placements, grid: Grid, order: int,
         texture_and_wall: bool = True, seed: int = 0, partial_volume: bool = True):
    """pose_maps + reconstruct exactly as generate.build_pack calls them."""
    tube = placements.tube
    config = ReconstructConfig(partial_volume=partial_volume)
    fitted = config.partial_volume_of(library.statistics)
    maps = pose_maps([p.mask for p in library], placements.indices,
                     placements.rotation_matrices(), placements.positions, placements.scales, grid,
                     reach=config.surface.reach(fitted))
    background = _background(library) if texture_and_wall else Background(library.statistics.pore_mean)
    clean, labels, contested = reconstruct(
        [(p.tomogram, p.mask) for p in library], maps, grid, background,
        tube=(tube.inner_radius, tube.outer_radius, -tube.base_thickness), order=order, seed=seed,
        chunks=(64, 256, 256), partial_volume=fitted, surface=config.surface,
    )
    return maps, clean, labels, contested


def convention_check(library: ParticleLibrary, placements: Placements, maps, grid: Grid) -> list[str]:
    """Dice of one grain's paper-method mask against ours, in isolation, plus wrong conventions."""
    angles = placements.euler_angles()
    # The grain whose three angles are all far from 0 and +-pi/2: a sign or order bug shows there.
    score = np.min(np.abs(np.sin(2 * angles)), axis=1)
    k = int(np.argmax(score))
    particle = library[int(placements.indices[k])]
    lo, hi = maps.box_lo[k], maps.box_hi[k]
    weight = ndimage.affine_transform(particle.mask.astype(np.float32), maps.matrix[k],
                                      offset=maps.offset[k] + maps.matrix[k] @ lo,
                                      output_shape=tuple(int(n) for n in hi - lo), order=1,
                                      mode="grid-constant", cval=0.0)
    our_mask = np.zeros(grid.shape, dtype=bool)
    our_mask[tuple(slice(a, b) for a, b in zip(lo, hi))] = weight > 0.5
    centre = (placements.positions[k, ::-1] - np.asarray(grid.origin)) / np.asarray(grid.voxel_size)
    theta, phi, psi = angles[k]
    r_check = Rotation.from_euler("xyz", angles[k]).as_matrix()
    assert np.allclose(r_check, placements.rotation_matrices()[k]), "euler_angles() is not R = Rz Ry Rx"
    variants = {
        "as used: about x by theta, then y by phi, then z by psi": lambda m: paper_rotate(m, theta, phi, psi),
        "all signs flipped": lambda m: paper_rotate(m, -theta, -phi, -psi),
        "order reversed (z, then y, then x: R = Rx Ry Rz)": lambda m: rotate_about(
            rotate_about(rotate_about(m, "z", psi), "y", phi), "x", theta),
    }
    rows = []
    for name, rotate in variants.items():
        mask = rotate(particle.mask.astype(np.float32)) > 0.5
        out, src = paper_place(mask.shape, centre, grid.shape)
        paper_mask = np.zeros(grid.shape, dtype=bool)
        paper_mask[out] = mask[src]
        d = dice(int(our_mask.sum()), int(paper_mask.sum()), int(np.count_nonzero(our_mask & paper_mask)))
        rows.append(f"| {name} | {d:.3f} |")
        if len(rows) == 1 and d < 0.85:
            raise RuntimeError(f"paper method and ours disagree on grain {k} (Dice {d:.3f}): convention bug")
    return [f"Convention check on grain {k} (theta, phi, psi = "
            f"{', '.join(f'{np.degrees(a):.0f}' for a in angles[k])} deg): Dice of the paper-method mask "
            "against ours, in isolation", "", "| paper-method rotation | Dice vs ours |", "|---|---|", *rows]


def target_speed_quality(workdir: Path) -> tuple[list[str], float]:
    lines = ["## 1. Reconstruction against the paper code's method", ""]
    start = time.perf_counter()
    library = ParticleLibrary.from_scan(sample_scan("large"), progress=False)
    placements_path = workdir / "placements_large_150.json"
    if placements_path.exists():
        placements = Placements.load(placements_path)
        poured = f"placements reused from {placements_path}"
    else:
        placements = pour(library, PourConfig(n_particles=150, batch_size=50), 0, progress=False)
        placements.save(placements_path)
        poured = f"poured in {placements.checks.seconds:.1f} s, saved to {placements_path}"
    pour_rate = placements.checks.seconds / len(placements)
    if not np.allclose(placements.scales, 1.0):
        raise RuntimeError("the paper method here does not scale grains; pour with scale 1")
    tube = placements.tube
    grid = Grid.covering(tube.outer_radius, -tube.base_thickness, placements.checks.fill_height,
                         library.voxel_size, margin=4)
    n_voxels = int(np.prod(grid.shape))
    lines += [f"Library: sample 'large' ({len(library)} grains, crops up to "
              f"{'x'.join(map(str, np.max([p.mask.shape for p in library], axis=0)))} voxels); "
              f"{len(placements)} grains, batches of 50, seed 0 ({poured}); grid "
              f"{'x'.join(map(str, grid.shape))} = {n_voxels / 1e6:.2f} M voxels. "
              f"Setup {time.perf_counter() - start:.1f} s. Load average before: {load_average()}.", ""]

    timings = {}
    results = {}
    whole_voxels = "ours, linear, whole voxels (partial_volume: false)"
    for name, order, full, partial in (("ours, linear (default config)", 1, True, True),
                                       ("ours, cubic (order 3)", 3, True, True),
                                       ("ours, linear, no pore texture / wall", 1, False, True),
                                       (whole_voxels, 1, True, False)):
        start = time.perf_counter()
        maps, _, labels, contested = ours(library, placements, grid, order, full, partial_volume=partial)
        timings[name] = time.perf_counter() - start
        results[name] = (labels, contested)
    box_voxels = np.prod(maps.box_hi - maps.box_lo, axis=1).mean()
    grain_voxels = np.mean([library[int(i)].voxel_count for i in placements.indices])
    start = time.perf_counter()
    paper_tomogram, paper_labels = paper_reconstruct(library, placements, grid, library.statistics.pore_mean)
    timings["paper method (3 x ndimage.rotate, cubic)"] = time.perf_counter() - start
    del paper_tomogram

    start = time.perf_counter()
    references = []
    for i in range(len(placements)):
        lo, hi = maps.box_lo[i], maps.box_hi[i]
        mask = library[int(placements.indices[i])].mask
        references.append((tuple(slice(a, b) for a, b in zip(lo, hi)),
                           reference_mask(mask, maps.matrix[i], maps.offset[i], lo, hi)))
    reference_seconds = time.perf_counter() - start
    dice_scores = {name: per_grain_dice(labels, references) for name, (labels, _) in results.items()}
    dice_scores["paper method (3 x ndimage.rotate, cubic)"] = per_grain_dice(paper_labels, references)
    paper_name = "paper method (3 x ndimage.rotate, cubic)"
    baseline = timings[paper_name]
    lines += ["| method | seconds | s / 10^6 voxels | speed-up vs paper | mean Dice vs exact | min Dice | contested voxels |",
              "|---|---|---|---|---|---|---|"]
    for name in timings:
        d = dice_scores[name]
        contested = results[name][1] if name in results else "-"
        lines.append(f"| {name} | {timings[name]:.2f} | {timings[name] / n_voxels * 1e6:.3f} "
                     f"| {baseline / timings[name]:.1f}x | {d.mean():.4f} | {d.min():.4f} | {contested} |")
    main_name = "ours, linear (default config)"
    speedup = baseline / timings[main_name]
    better = dice_scores[main_name].mean() >= dice_scores[paper_name].mean()
    lines += ["", f"Speed-up of ours (default config) over the paper method: **{speedup:.1f}x** "
              f"(target >= 10x: {'met' if speedup >= 10 else 'MISSED'}). Mean per-grain Dice vs the exact "
              f"reference: ours {dice_scores[main_name].mean():.4f}, paper method "
              f"{dice_scores[paper_name].mean():.4f} (target ours >= paper: {'met' if better else 'MISSED'}). "
              f"The reference took {reference_seconds:.1f} s. Ours includes what the paper method does not do: "
              f"the pore texture and the tube wall over the whole grid (the row without them isolates the "
              f"grain rendering). The paper method pastes each rotated grain at the nearest whole voxel "
              f"(part of its Dice loss); ours places it at its exact position. Load average after: {load_average()}.", "",
              f"Each grain's mask is resampled over the box of its rotated mask: {box_voxels:,.0f} voxels on "
              f"average for grains of {grain_voxels:,.0f} voxels; intensities only at the grain's own voxels.",
              "", f"The partial-volume render (default) costs {timings[main_name] / timings[whole_voxels]:.2f}x the "
              f"whole-voxel render (the renderer before partial volume) in this run; both give the same labels "
              f"({'yes' if np.array_equal(results[main_name][0], results[whole_voxels][0]) else 'NO'}).", ""]
    lines += convention_check(library, placements, maps, grid)
    lines.append("")
    return lines, pour_rate


# -- target 2 ----------------------------------------------------------------------


def target_demo(workdir: Path) -> list[str]:
    exe = Path(sys.executable).with_name("synthpack")
    out = workdir / "demo"
    lines = ["## 2. End to end: `synthpack demo`", "", f"Load average before: {load_average()}.", ""]
    start = time.perf_counter()
    run = subprocess.run([str(exe), "demo", "--out", str(out)], capture_output=True, text=True, check=True)
    wall = time.perf_counter() - start
    stage_line = next(line for line in run.stdout.splitlines() if line.startswith("seconds per stage:"))
    stages = []
    for item in stage_line.split(":", 1)[1].split(","):
        name, _, seconds = item.strip().rpartition(" ")
        stages.append((name, float(seconds)))
    summary = next((line for line in run.stdout.splitlines() if line.startswith("synthetic pack:")), "")
    lines += ["| stage | seconds |", "|---|---|", *(f"| {n} | {s:.1f} |" for n, s in stages),
              f"| sum of stages | {sum(s for _, s in stages):.1f} |",
              f"| total wall time (incl. interpreter start, imports, writing) | {wall:.1f} |", "",
              f"`{exe.name} demo --out {out}`: {summary.strip()}", ""]
    return lines


# -- target 3 ----------------------------------------------------------------------


def circumscribed_radii(library: ParticleLibrary) -> np.ndarray:
    """Per grain, the radius (voxels) about the crop centre of a sphere holding its mask's voxel cubes."""
    radii = []
    for p in library:
        index = np.argwhere(p.mask)
        centre = (np.asarray(p.mask.shape) - 1) / 2.0
        radii.append(np.sqrt(((index - centre) ** 2).sum(axis=1)).max() + np.sqrt(3) / 2)
    return np.asarray(radii)


def lattice_placements(library: ParticleLibrary, size: int, seed: int = 0) -> dict:
    """Dense, non-overlapping synthetic placements filling a size^3 grid holding a tube."""
    rng = np.random.default_rng(seed)
    dz, dy, dx = library.voxel_size
    if not dz == dy == dx:
        raise RuntimeError("the lattice placement assumes isotropic voxels")
    voxel = dx
    radii = circumscribed_radii(library)
    spacing = 2.0 * radii.max() + 0.5  # voxels
    margin, wall, base = 4, 3, 3
    outer = size / 2.0 - margin - 0.5  # voxels
    inner = outer - wall
    # Grid: size^3, centred on the tube axis laterally, floor of the base `margin` voxels above z index 0.
    origin = (-(margin + base) * voxel, -(size - 1) / 2.0 * voxel, -(size - 1) / 2.0 * voxel)
    grid = Grid((size, size, size), origin, (voxel, voxel, voxel))
    top = (size - margin) * voxel + origin[0]
    axis = np.arange(-inner + spacing / 2, inner - spacing / 2 + 1e-9, spacing) * voxel
    zs = np.arange(spacing / 2, (top / voxel) - spacing / 2, spacing) * voxel
    x, y, z = (a.ravel() for a in np.meshgrid(axis, axis, zs, indexing="ij"))
    keep = np.hypot(x, y) <= (inner - spacing / 2) * voxel
    centres = np.column_stack([x[keep], y[keep], z[keep]])
    n = len(centres)
    indices = rng.integers(0, len(library), n)
    # Jitter inside each lattice cell's inscribed ball, keeping the grain's sphere in it.
    room = (spacing / 2 - radii[indices]) * voxel
    direction = rng.normal(size=(n, 3))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    jitter = direction * (room * rng.uniform(0, 1, n) ** (1 / 3))[:, None]
    rotations = Rotation.random(n, random_state=seed).as_matrix()
    solid = sum(int(library[int(i)].voxel_count) for i in indices)
    tube_voxels = np.pi * inner**2 * (top / voxel)
    return dict(indices=indices, rotations=rotations, positions=centres + jitter, scales=np.ones(n),
                grid_shape=np.array(grid.shape), grid_origin=np.array(grid.origin),
                voxel_size=np.array(grid.voxel_size),
                tube=np.array([inner * voxel, outer * voxel, -base * voxel]),
                spacing=spacing, packing=solid / tube_voxels)


def memory_child(workdir: Path) -> None:
    """Child process: load the library and placements, then only reconstruct; print JSON figures."""
    library = ParticleLibrary.load(workdir / "library_small")
    data = np.load(workdir / "placements_512.npz")
    grid = Grid(tuple(int(n) for n in data["grid_shape"]), tuple(data["grid_origin"]), tuple(data["voxel_size"]))
    crops = [(p.tomogram, p.mask) for p in library]
    masks = [p.mask for p in library]
    background = _background(library)
    tube = tuple(float(v) for v in data["tube"])
    baseline_rss, baseline_hwm = _rss_kib()
    start = time.perf_counter()
    maps = pose_maps(masks, data["indices"], data["rotations"], data["positions"], data["scales"], grid)
    tomogram, labels, contested = reconstruct(crops, maps, grid, background, tube=tube, order=1, seed=0,
                                              chunks=(64, 256, 256))
    seconds = time.perf_counter() - start
    _, peak_hwm = _rss_kib()
    self_maxrss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    # Labels present, counted a few slices at a time: a whole-volume np.unique or bincount
    # would copy the labels to int64 and raise the peak the parent reads.
    present = np.zeros(len(data["indices"]) + 1, dtype=bool)
    for z in range(0, labels.shape[0], 8):
        present[np.unique(labels[z : z + 8])] = True
    print(json.dumps(dict(baseline_rss_kib=baseline_rss, baseline_hwm_kib=baseline_hwm, peak_hwm_kib=peak_hwm,
                          self_maxrss_kib=self_maxrss, seconds=seconds, contested=contested,
                          n_labels=int(np.count_nonzero(present[1:])),
                          out_bytes=tomogram.nbytes + labels.nbytes)))


def target_memory(workdir: Path, size: int, pour_rate: float) -> list[str]:
    lines = [f"## 3. Peak memory of reconstructing a {size}^3 pack", ""]
    start = time.perf_counter()
    library = ParticleLibrary.from_scan(sample_scan("small"), progress=False)
    library.save(workdir / "library_small")
    data = lattice_placements(library, size)
    np.savez(workdir / "placements_512.npz", **data)
    n = len(data["indices"])
    mean_grain = float(np.mean([p.voxel_count for p in library]))
    inner_vox = data["tube"][0] / library.voxel_size[2]
    needed = int(np.pi * inner_vox**2 * size * 0.6 / mean_grain)
    lines += [f"Library: sample 'small' ({len(library)} grains, median equivalent diameter "
              f"{np.median(library.equivalent_diameters) / library.voxel_size[2]:.1f} voxels), built and "
              f"saved in {time.perf_counter() - start:.1f} s.",
              "",
              f"Placements are SYNTHESISED, not poured: filling a {size}^3 grid at a packing fraction of 0.6 "
              f"takes about {needed:,} grains; at the measured pour rate of {pour_rate:.3f} s/grain "
              f"(target 1's pour) that is about {needed * pour_rate / 60:.0f} min, over the 5-minute limit. "
              f"Instead: {n:,} grains with uniformly random rotations on a jittered cubic lattice of spacing "
              f"{data['spacing']:.1f} voxels (the largest grain's circumscribed-sphere diameter, so no two "
              f"grains overlap whatever their rotation) inside a tube of inner radius {inner_vox:.1f} voxels; "
              f"packing fraction {data['packing']:.3f} (sparser than a pour, so the grains' share of the "
              f"time is lower than in a real pack). Tube wall and pore texture on, linear interpolation, "
              f"chunks 64x256x256 (the default config).", ""]
    before = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
    load_before = load_average()
    start = time.perf_counter()
    run = subprocess.run([sys.executable, __file__, "--memory-child", str(workdir)], capture_output=True,
                         text=True, check=True)
    wall = time.perf_counter() - start
    children_maxrss = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
    child = json.loads(run.stdout.strip().splitlines()[-1])
    out_bytes = child["out_bytes"]
    raw = children_maxrss * 1024
    baseline = child["baseline_rss_kib"] * 1024
    net = raw - baseline
    self_net = child["self_maxrss_kib"] * 1024 - baseline
    ratio = net / out_bytes
    voxels = size**3
    gib = 2.0**30
    lines += ["Counted output volumes: the two arrays `reconstruct` returns, tomogram (float32) + labels "
              "(int32) = 8 bytes/voxel. (`build_pack` later adds the post-processed tomogram; that is "
              "post-processing, not reconstruction.)", "",
              "| figure | value |", "|---|---|",
              f"| grid | {size}x{size}x{size} = {voxels / 1e6:.1f} M voxels |",
              f"| grains placed / labels present | {n:,} / {child['n_labels']:,} |",
              f"| output bytes (tomogram + labels) | {out_bytes / gib:.3f} GiB |",
              f"| child baseline RSS before reconstruct (import + library + placements) | {baseline / gib:.3f} GiB |",
              f"| child peak RSS before reconstruct (VmHWM) | {child['baseline_hwm_kib'] * 1024 / gib:.3f} GiB |",
              f"| raw peak RSS, parent's RUSAGE_CHILDREN ru_maxrss (max over all children so far; was "
              f"{before * 1024 / gib:.3f} GiB before) | {raw / gib:.3f} GiB |",
              f"| raw peak RSS, child's own RUSAGE_SELF ru_maxrss | {child['self_maxrss_kib'] * 1024 / gib:.3f} GiB |",
              f"| net peak (raw - baseline) | {net / gib:.3f} GiB (child's own figure: {self_net / gib:.3f} GiB) |",
              f"| **net peak / output bytes** | **{ratio:.2f}** (target <= 3: {'met' if ratio <= 3 else 'MISSED'}) |",
              f"| reconstruct seconds (pose_maps + reconstruct) | {child['seconds']:.1f} |",
              f"| seconds per 10^6 voxels | {child['seconds'] / voxels * 1e6:.3f} |",
              f"| child wall time (incl. start and library load) | {wall:.1f} s |",
              f"| contested voxels | {child['contested']} |",
              f"| load average before / after | {load_before} / {load_average()} |", ""]
    return lines


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--size", type=int, default=512, help="edge of the memory benchmark's grid")
    parser.add_argument("--workdir", type=Path, default=None, help="keep work files here (default: temp)")
    parser.add_argument("--skip-demo", action="store_true", help="skip target 2")
    parser.add_argument("--memory-child", type=Path, default=None, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.memory_child is not None:
        memory_child(args.memory_child)
        return
    with tempfile.TemporaryDirectory(prefix="bench_reconstruct_") as temp:
        workdir = args.workdir or Path(temp)
        workdir.mkdir(parents=True, exist_ok=True)
        start = time.perf_counter()
        print(f"Machine: {os.cpu_count()} CPUs, {platform.platform()}, Python {platform.python_version()}, "
              f"numpy {np.__version__}, scipy {scipy.__version__}; load average (1/5/15 min) at start: "
              f"{load_average()}.\n")
        lines, pour_rate = target_speed_quality(workdir)
        print("\n".join(lines), flush=True)
        if not args.skip_demo:
            print("\n".join(target_demo(workdir)), flush=True)
        print("\n".join(target_memory(workdir, args.size, pour_rate)), flush=True)
        print(f"Total benchmark wall time: {time.perf_counter() - start:.0f} s; load average at end: {load_average()}.")


if __name__ == "__main__":
    main()
