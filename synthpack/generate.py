"""From a particle library to synthetic packs on disk: pour, reconstruct, post-process, write."""

from __future__ import annotations

import dataclasses
import functools
import importlib.metadata
import logging
import math
import os
import platform
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from . import __version__
from ._chunks import bounded_map, chunk_boxes, thread_count
from .config import PackConfig, ReconstructConfig
from .errors import PackBuildError, SynthpackInputError
from .library import ParticleLibrary
from .pack import is_complete_pack, stage_pack
from .physics import Placements, Tube, pour
from .physics.engine import Material
from .reconstruct import Grid, Phases, pose_maps, reconstruct
from .runner import run_packs

if TYPE_CHECKING:
    from .realism.calibrate import Calibration

logger = logging.getLogger(__name__)

__all__ = [
    "SyntheticPack", "build_pack", "generate_pack", "generate_packs", "pack_phases", "pack_seed", "pack_name",
]

#: Wall intensity as a fraction of the way from pore to grain intensity (a plastic tube).
_WALL_FRACTION = 0.4
#: ``match_source`` measures the clean pack's noise on at most about this many central voxels.
_NOISE_SAMPLE_VOXELS = 1 << 24

#: ``allocate(name, shape, dtype, chunks) -> array``: where `build_pack` writes a volume.
Allocate = Callable[[str, tuple[int, int, int], Any, tuple[int, int, int]], Any]


def pack_seed(run_seed: int, index: int) -> int:
    """Seed of pack `index` of a run: a pure function of the run seed and the index."""
    return _derived_seed(run_seed, index)


def pack_name(index: int) -> str:
    """Directory name of pack `index`: ``pack_0000``, ``pack_0001``, ..."""
    return f"pack_{index:04d}"


@dataclass
class SyntheticPack:
    """One synthetic pack in memory.

    Attributes
    ----------
    tomogram : array of float32, shape (Z, Y, X)
        Post-processed tomogram (NumPy, or the Zarr array `build_pack` was given).
    clean : array of float32, shape (Z, Y, X)
        Tomogram before post-processing.
    labels : array of int32, shape (Z, Y, X)
        Placement ``i`` has label ``i + 1``; 0 is pore, tube or outside.
    placements : Placements
        The pour.
    grid : Grid
        Where the volumes sit in the world frame.
    manifest : dict
        Config, seed, counts, contested voxels, artefacts applied, timings.
    """

    tomogram: Any
    clean: Any
    labels: Any
    placements: Placements
    grid: Grid
    manifest: dict = field(default_factory=dict)


def _tube(library: ParticleLibrary, config: PackConfig) -> Tube:
    pour_config = config.pour
    return Tube.for_library(
        library, pour_config.n_particles, scale=float(max(np.atleast_1d(pour_config.scale))),
        inner_radius=pour_config.tube_radius, height=pour_config.tube_height,
    )


def pack_phases(library: ParticleLibrary, config: ReconstructConfig) -> Phases:
    """Pore and tube-wall intensities of a pack, from the library's source-scan statistics.

    The wall defaults to 40% of the way from pore to grain intensity (a plastic tube)
    unless ``config.wall_intensity`` sets it; ``config.wall = False`` draws none.
    """
    phases = library.phases
    wall = config.wall_intensity if config.wall_intensity is not None else (
        phases["pore_mean"] + _WALL_FRACTION * (phases["grain_mean"] - phases["pore_mean"]))
    return Phases(phases["pore_mean"], phases["pore_std"], wall if config.wall else None)


def _postprocessing(config: PackConfig, phases: dict[str, float], clean, labels):
    from .artefacts import Compose, default_postprocessing, estimate_noise, from_config, noise_to_add

    choice = config.postprocess
    if choice == "default":
        return default_postprocessing(contrast=phases["grain_mean"] - phases["pore_mean"])
    if choice == "match_source":
        window = _central_slab(labels.shape)
        return Compose([noise_to_add(phases["noise_std"], estimate_noise(clean[window], labels[window])["std"])])
    if choice in ("none", []):
        return Compose([])
    return from_config(list(choice))


def _calibration(
    clean: np.ndarray, labels: np.ndarray, grid: Grid, placements: Placements, targets: dict[str, float]
) -> Calibration:
    """Blur and noise fitted in the pack's bulk region to the source's edge width and noise level."""
    from .realism.calibrate import calibrate
    from .realism.region import bulk_region

    region = bulk_region(labels.shape, grid.origin, grid.voxel_size, placements.checks.packing_region)
    return calibrate(clean, labels, region, **targets)


def _central_slab(shape: tuple[int, ...], max_voxels: int = _NOISE_SAMPLE_VOXELS) -> tuple[slice, ...]:
    """The central slices of a volume of `shape` holding at most about `max_voxels` voxels (at least one slice)."""
    n = min(shape[0], max(1, max_voxels // math.prod(shape[1:])))
    start = (shape[0] - n) // 2
    return (slice(start, start + n), slice(None), slice(None))


def _labels_present(labels, n_labels: int, chunks: tuple[int, int, int], threads: int | None) -> np.ndarray:
    """Which of the labels ``0..n_labels`` occur in `labels`, read chunk by chunk: bool, (n_labels + 1,)."""
    present = np.zeros(n_labels + 1, dtype=bool)

    def found(box: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
        lo, hi = box
        return np.unique(labels[tuple(slice(a, b) for a, b in zip(lo, hi))])

    for _, values in bounded_map(found, chunk_boxes(tuple(labels.shape), chunks), thread_count(threads)):
        present[values] = True
    return present


def _derived_seed(seed: int, stream: int) -> int:
    """A 32-bit seed for stream `stream` of `seed` (pack `stream` of a run, or a pack's post-processing)."""
    return int(np.random.SeedSequence([int(seed), int(stream)]).generate_state(1, np.uint32)[0])


def _numpy_volume(name: str, shape: tuple[int, int, int], dtype, chunks: tuple[int, int, int]) -> np.ndarray:
    return np.empty(shape, dtype=dtype)


def build_pack(
    library: ParticleLibrary,
    config: PackConfig,
    seed: int,
    *,
    progress: bool = True,
    threads: int | None = None,
    allocate: Allocate | None = None,
) -> SyntheticPack:
    """Pour, reconstruct and post-process one pack.

    Reconstruction and post-processing go chunk by chunk (chunks
    ``config.reconstruct.chunks``) from one volume to the next, so with Zarr
    arrays from `allocate` no whole volume is ever held in memory. The volumes
    depend only on `library`, `config` and `seed`: not on `threads`, nor on where
    they are stored.

    Parameters
    ----------
    library : ParticleLibrary
        The grains.
    config : PackConfig
        Pour, reconstruction and post-processing settings. With ``postprocess:
        calibrated`` the blur and noise are fitted to the source scan
        (`synthpack.realism.calibrate`) and the fit is recorded in the manifest
        under ``calibration``.
    seed : int
        Seed of this pack (pour and artefacts).
    progress : bool
        Show progress bars.
    threads : int, optional
        Threads for the chunks; default: the number of CPU cores.
    allocate : callable, optional
        ``allocate(name, shape, dtype, chunks) -> array`` gives the arrays to fill:
        ``"clean"`` (float32), ``"labels"`` (int32), ``"tomogram"`` (float32) and,
        for post-processing pipelines with several blur-type steps, ``"scratch"``
        (float32), e.g. Zarr arrays (`synthpack.pack.StagedPack.zarr_array`).
        Default: NumPy arrays.
    """
    targets = None
    if config.postprocess == "calibrated":
        from .realism.calibrate import targets_from_phases

        targets = targets_from_phases(library.phases)  # fails before the pour if the library lacks them
    from .artefacts.blockwise import apply_blockwise

    allocate = allocate or _numpy_volume
    timings: dict[str, float] = {}
    start = time.perf_counter()
    pour_config = config.pour
    scale = pour_config.scale if isinstance(pour_config.scale, (int, float)) else tuple(pour_config.scale)
    placements = pour(
        library, pour_config.n_particles, pour_config.batch_size, engine=pour_config.engine,
        seed=seed, container=_tube(library, config), scale=scale,
        material=Material(friction=pour_config.friction, restitution=pour_config.restitution),
        progress=progress, engine_options=pour_config.engine_options,
    )
    timings["pour"] = time.perf_counter() - start

    start = time.perf_counter()
    tube = placements.tube
    rec = config.reconstruct
    chunks = tuple(rec.chunks)
    grid = Grid.covering(tube.outer_radius, -tube.base_thickness, placements.checks.fill_height,
                         library.voxel_size, margin=rec.margin)
    maps = pose_maps([p.mask for p in library], placements.indices,
                     placements.rotation_matrices(), placements.positions, placements.scales, grid)
    clean, labels, contested = reconstruct(
        [(p.tomogram, p.mask) for p in library], maps, grid, pack_phases(library, rec),
        tube=(tube.inner_radius, tube.outer_radius, -tube.base_thickness),
        order=rec.order, seed=seed, chunks=chunks, workers=threads,
        out=(allocate("clean", grid.shape, np.float32, chunks), allocate("labels", grid.shape, np.int32, chunks)),
    )
    timings["reconstruct"] = time.perf_counter() - start

    start = time.perf_counter()
    calibration = None
    if targets is not None:
        calibration = _calibration(clean, labels, grid, placements, targets)
        postprocessing = calibration.pipeline()
    else:
        postprocessing = _postprocessing(config, library.phases, clean, labels)
    tomogram = allocate("tomogram", grid.shape, np.float32, chunks)
    applied = apply_blockwise(
        postprocessing, clean, tomogram, _derived_seed(seed, 1), chunks, threads=threads,
        scratch=lambda: allocate("scratch", grid.shape, np.float32, chunks),
    )
    timings["postprocess"] = time.perf_counter() - start

    n_present = int(np.count_nonzero(_labels_present(labels, len(placements), chunks, threads)[1:]))
    if n_present < len(placements):
        logger.warning("%d of %d placed grains have no voxel in the volume",
                       len(placements) - n_present, len(placements))
    manifest = dict(
        seed=seed, config=config.to_dict(), library_source=library.source,
        n_particles=len(placements), n_labels=n_present, contested_voxels=contested,
        shape=list(grid.shape), grid_origin=list(grid.origin),
        pour_checks=dataclasses.asdict(placements.checks),
        postprocessing=applied, timings=timings,
    )
    if calibration is not None:
        manifest["calibration"] = calibration.to_dict()
    return SyntheticPack(tomogram, clean, labels, placements, grid, manifest)


def _versions() -> dict[str, str]:
    versions = {"synthpack": __version__, "python": platform.python_version()}
    for name in ("numpy", "scipy", "scikit-image", "trimesh", "pybullet", "tifffile", "zarr", "dask", "distributed"):
        try:
            versions[name] = importlib.metadata.version(name)
        except importlib.metadata.PackageNotFoundError:
            continue
    return versions


def generate_pack(
    library: ParticleLibrary,
    index: int,
    config: PackConfig,
    out: str | os.PathLike,
    *,
    format: str = "tiff",
    source: str = "",
    threads: int | None = None,
    progress: bool = False,
) -> Path:
    """Build pack `index` of a run into ``out/pack_NNNN``, atomically: the unit of work of a Dask task.

    Its seed is :func:`pack_seed` ``(config.seed, index)``, so the pack is the same
    whichever process, machine or thread count builds it. A Zarr pack is written
    chunk by chunk (memory does not grow with the volume); a TIFF pack is built
    in memory, then written.

    Parameters
    ----------
    library : ParticleLibrary
        The grains.
    index : int
        Pack index in the run.
    config : PackConfig
        The run's config.
    out : path-like
        Output directory of the run.
    format : {"tiff", "zarr"}
        Volume format.
    source : str
        Description of the source scan, for the manifest.
    threads : int, optional
        Threads for the chunks of this pack; default: the number of CPU cores.
    progress : bool
        Show the pour's progress bar.

    Returns
    -------
    Path
        The pack directory.
    """
    path = Path(out) / pack_name(index)
    seed = pack_seed(config.seed, index)
    with stage_pack(path, voxel_size=library.voxel_size, unit=library.unit, format=format) as staged:
        pack = build_pack(library, config, seed, progress=progress, threads=threads,
                          allocate=staged.zarr_array if format == "zarr" else None)
        start = time.perf_counter()
        if format == "tiff":
            staged.write_volumes({"tomogram": pack.tomogram, "clean": pack.clean, "labels": pack.labels})
        manifest = dict(pack.manifest, pack_index=index, run_seed=config.seed,
                        source=source or library.source, versions=_versions())
        manifest["timings"]["write"] = time.perf_counter() - start
        staged.finish(pack.placements, manifest)
    logger.info("wrote %s (%d grains, %s voxels)", path, len(pack.placements),
                "x".join(map(str, pack.grid.shape)))
    return path


def generate_packs(
    library: ParticleLibrary,
    out: str | os.PathLike,
    n_packs: int = 1,
    config: PackConfig | None = None,
    *,
    format: str = "tiff",
    source: str = "",
    progress: bool = True,
    workers: int | None = None,
    scheduler: str | None = None,
) -> list[Path]:
    """Build `n_packs` packs into ``out/pack_0000``, ... as Dask tasks (complete packs are skipped).

    Parameters
    ----------
    library : ParticleLibrary
        The grains.
    out : path-like
        Output directory.
    n_packs : int
        Number of packs; pack ``k`` uses seed :func:`pack_seed` ``(config.seed, k)``.
    config : PackConfig, optional
        Defaults to ``PackConfig()``.
    format : {"tiff", "zarr"}
        Volume format of the packs. Zarr packs are written chunk by chunk, for
        volumes larger than memory.
    source : str
        Description of the source scan, for the manifests.
    progress : bool
        Show a progress bar over packs.
    workers, scheduler
        Where the packs are built; see :func:`synthpack.runner.run_packs`.
        Default: a local Dask cluster sized to the machine, or this process
        when one pack is missing.

    Returns
    -------
    list of Path
        The pack directories, in order.

    Raises
    ------
    PackBuildError
        If some packs failed (after all the others were built): it lists each
        failed pack with its error. Calling again builds only the missing packs.
    """
    if isinstance(n_packs, bool) or not isinstance(n_packs, int) or n_packs < 1:
        raise SynthpackInputError(f"n_packs must be a positive integer, got {n_packs!r}")
    if format not in ("tiff", "zarr"):
        raise SynthpackInputError(f"pack format must be tiff or zarr, got {format!r}")
    config = config or PackConfig()
    out = Path(out)
    paths = [out / pack_name(index) for index in range(n_packs)]
    missing = [index for index, path in enumerate(paths) if not is_complete_pack(path)]
    if len(missing) < n_packs:
        logger.info("%d of %d packs in %s are complete: skipped", n_packs - len(missing), n_packs, out)
    build = functools.partial(generate_pack, config=config, out=out, format=format,
                              source=source or library.source)
    failures = run_packs(build, missing, library, n_packs=n_packs, workers=workers, scheduler=scheduler,
                         progress=progress)
    if failures:
        raise PackBuildError({pack_name(i): error for i, error in failures.items()}, out, n_packs)
    return paths
