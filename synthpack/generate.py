"""From a particle library to synthetic packs on disk: pour, reconstruct, post-process, write."""

from __future__ import annotations

import dataclasses
import importlib.metadata
import logging
import os
import platform
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from tqdm.auto import tqdm

from . import __version__
from .config import PackConfig, ReconstructConfig
from .errors import SynthpackInputError
from .library import ParticleLibrary
from .pack import is_complete_pack, write_pack
from .physics import Placements, Tube, pour
from .physics.engine import Material
from .reconstruct import Grid, Phases, pose_maps, reconstruct

if TYPE_CHECKING:
    from .realism.calibrate import Calibration

logger = logging.getLogger(__name__)

__all__ = ["SyntheticPack", "build_pack", "generate_packs", "pack_phases", "pack_seed", "pack_name"]

#: Wall intensity as a fraction of the way from pore to grain intensity (a plastic tube).
_WALL_FRACTION = 0.4


def pack_seed(run_seed: int, index: int) -> int:
    """Seed of pack `index` of a run: a pure function of the run seed and the index."""
    return int(np.random.SeedSequence([int(run_seed), int(index)]).generate_state(1, np.uint32)[0])


def pack_name(index: int) -> str:
    """Directory name of pack `index`: ``pack_0000``, ``pack_0001``, ..."""
    return f"pack_{index:04d}"


@dataclass
class SyntheticPack:
    """One synthetic pack in memory.

    Attributes
    ----------
    tomogram : ndarray of float32, shape (Z, Y, X)
        Post-processed tomogram.
    clean : ndarray of float32, shape (Z, Y, X)
        Tomogram before post-processing.
    labels : ndarray of int32, shape (Z, Y, X)
        Placement ``i`` has label ``i + 1``; 0 is pore, tube or outside.
    placements : Placements
        The pour.
    grid : Grid
        Where the volumes sit in the world frame.
    manifest : dict
        Config, seed, counts, contested voxels, artefacts applied, timings.
    """

    tomogram: np.ndarray
    clean: np.ndarray
    labels: np.ndarray
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


def _postprocessing(config: PackConfig, phases: dict[str, float], clean: np.ndarray, labels: np.ndarray):
    from .artefacts import Compose, default_postprocessing, estimate_noise, from_config, noise_to_add

    choice = config.postprocess
    if choice == "default":
        return default_postprocessing(contrast=phases["grain_mean"] - phases["pore_mean"])
    if choice == "match_source":
        return Compose([noise_to_add(phases["noise_std"], estimate_noise(clean, labels)["std"])])
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


def build_pack(
    library: ParticleLibrary, config: PackConfig, seed: int, *, progress: bool = True
) -> SyntheticPack:
    """Pour, reconstruct and post-process one pack in memory.

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
    """
    targets = None
    if config.postprocess == "calibrated":
        from .realism.calibrate import targets_from_phases

        targets = targets_from_phases(library.phases)  # fails before the pour if the library lacks them
    timings: dict[str, float] = {}
    start = time.perf_counter()
    pour_config = config.pour
    scale = pour_config.scale if isinstance(pour_config.scale, (int, float)) else tuple(pour_config.scale)
    placements = pour(
        library, pour_config.n_particles, pour_config.batch_size, engine=pour_config.engine,
        seed=seed, container=_tube(library, config), scale=scale,
        material=Material(friction=pour_config.friction, restitution=pour_config.restitution),
        progress=progress,
    )
    timings["pour"] = time.perf_counter() - start

    start = time.perf_counter()
    tube = placements.tube
    rec = config.reconstruct
    grid = Grid.covering(tube.outer_radius, -tube.base_thickness, placements.checks.fill_height,
                         library.voxel_size, margin=rec.margin)
    maps = pose_maps([p.mask for p in library], placements.indices,
                     placements.rotation_matrices(), placements.positions, placements.scales, grid)
    clean, labels, contested = reconstruct(
        [(p.tomogram, p.mask) for p in library], maps, grid, pack_phases(library, rec),
        tube=(tube.inner_radius, tube.outer_radius, -tube.base_thickness),
        order=rec.order, seed=seed, chunks=tuple(rec.chunks),
    )
    timings["reconstruct"] = time.perf_counter() - start

    start = time.perf_counter()
    calibration = None
    if targets is not None:
        calibration = _calibration(clean, labels, grid, placements, targets)
        postprocessing = calibration.pipeline()
    else:
        postprocessing = _postprocessing(config, library.phases, clean, labels)
    tomogram, applied = postprocessing.apply(clean, np.random.SeedSequence([seed, 1]))
    timings["postprocess"] = time.perf_counter() - start

    present = np.unique(labels)
    n_present = int(np.count_nonzero(present))
    if n_present < len(placements):
        logger.warning("%d of %d placed grains have no voxel in the volume",
                       len(placements) - n_present, len(placements))
    manifest = dict(
        seed=seed, config=config.to_dict(), library_source=library.source,
        n_particles=len(placements), n_labels=n_present, contested_voxels=contested,
        shape=list(labels.shape), grid_origin=list(grid.origin),
        pour_checks=dataclasses.asdict(placements.checks),
        postprocessing=applied, timings=timings,
    )
    if calibration is not None:
        manifest["calibration"] = calibration.to_dict()
    return SyntheticPack(tomogram, clean, labels, placements, grid, manifest)


def _versions() -> dict[str, str]:
    versions = {"synthpack": __version__, "python": platform.python_version()}
    for name in ("numpy", "scipy", "scikit-image", "trimesh", "pybullet", "tifffile", "zarr"):
        try:
            versions[name] = importlib.metadata.version(name)
        except importlib.metadata.PackageNotFoundError:
            continue
    return versions


def generate_packs(
    library: ParticleLibrary,
    out: str | os.PathLike,
    n_packs: int = 1,
    config: PackConfig | None = None,
    *,
    format: str = "tiff",
    source: str = "",
    progress: bool = True,
) -> list[Path]:
    """Build `n_packs` packs into ``out/pack_0000``, ... (complete packs are skipped).

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
        Volume format of the packs.
    source : str
        Description of the source scan, for the manifests.
    progress : bool
        Show progress bars.

    Returns
    -------
    list of Path
        The pack directories, in order.
    """
    if not isinstance(n_packs, int) or n_packs < 1:
        raise SynthpackInputError(f"n_packs must be a positive integer, got {n_packs!r}")
    config = config or PackConfig()
    out = Path(out)
    paths = []
    for index in tqdm(range(n_packs), desc="packs", unit="pack", disable=not progress or n_packs == 1):
        path = out / pack_name(index)
        paths.append(path)
        if is_complete_pack(path):
            logger.info("%s is complete: skipped", path)
            continue
        seed = pack_seed(config.seed, index)
        pack = build_pack(library, config, seed, progress=progress)
        start = time.perf_counter()
        manifest = dict(pack.manifest, pack_index=index, run_seed=config.seed,
                        source=source or library.source, versions=_versions())
        write_pack(path, {"tomogram": pack.tomogram, "clean": pack.clean, "labels": pack.labels},
                   pack.placements, manifest, voxel_size=library.voxel_size, unit=library.unit,
                   format=format)
        logger.info("wrote %s (%d grains, %s voxels, write %.1f s)", path, len(pack.placements),
                    "x".join(map(str, pack.labels.shape)), time.perf_counter() - start)
    return paths
