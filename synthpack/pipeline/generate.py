"""From a particle library to synthetic packs on disk: pour, reconstruct, post-process, write."""

from __future__ import annotations

import dataclasses
import functools
import importlib.metadata
import logging
import os
import platform
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .. import __version__
from ..io.atomic import check_output
from .._shared.seeds import derived_seed, record as random_streams
from ..artefacts.band_map import apply_band_map
from ..artefacts.blockwise import apply_blockwise, device_for
from .._shared.budget import check_pack_grid
from .config import OVERLAP_MIN_GRAINS, PackConfig
from ..library.deform import PackGrains, pack_grains
from ..errors import PackBuildError, SynthpackInputError
from ..library.core import ParticleLibrary
from ..store.pack import PACKS_OUTPUT, is_complete_pack, pack_format, stage_pack
from ..render.partial_volume import PartialVolume
from ..physics import LockedGrains, Placements, Tube, check_pour_size, pour
from ..physics.placements import rotation_matrices
from ..physics.container import CROP_WALL_MARGIN, crop_box, crop_extent
from ..physics.plan import parse_scale
from ..physics.registry import get_engine
from ..artefacts.recipes import Postprocessing, check_postprocess, resolve_postprocessing
from ..render import Background, Grid, pose_maps, reconstruct, resolve_kernel
from ..render.streamed import LockedRender
from ..render.torch_render import TorchRenderer, resolve_device
from .._shared.chunks import thread_count
from .pour_process import can_start_pour_process, pour_in_process
from .runner import run_packs
from .view import resolve_pack, warn_tube

logger = logging.getLogger(__name__)

__all__ = ["SyntheticPack", "build_pack", "generate_pack", "generate_packs", "pack_seed", "pack_name"]

#: ``allocate(name, shape, dtype, chunks) -> array``: where `build_pack` writes a volume.
Allocate = Callable[[str, tuple[int, int, int], Any, tuple[int, int, int]], Any]


def pack_seed(run_seed: int, index: int) -> int:
    """Seed of pack `index` of a run: from the run seed's ``"pack"`` stream (`synthpack._shared.seeds`)."""
    return derived_seed(run_seed, "pack", index)


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


def _check_size(library: ParticleLibrary, config: PackConfig, format: str) -> None:
    """Refuse up front a pack whose pour or whose volumes cannot fit this machine (`synthpack._shared.budget`).

    The grid is bounded by the tube (its full height, the fill being lower), as `_render` lays it out
    (an interior crop lies inside it).
    """
    config, view = resolve_pack(library, config)
    tube = config.pour.tube(library, interior=view == "interior")
    check_pour_size(library, config.pour, tube)
    grid = Grid.covering(tube.outer_radius, -tube.base_thickness, tube.height, library.voxel_size,
                         margin=config.reconstruct.margin)
    check_pack_grid(grid.shape, format)


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
    ``config.run.chunks``) from one volume to the next, so with Zarr
    arrays from `allocate` no whole volume is ever held in memory. The volumes
    depend only on `library`, `config` and `seed`: not on `threads`, nor on where
    they are stored.

    Parameters
    ----------
    library : ParticleLibrary
        The grains, and the statistics of their source scan.
    config : PackConfig
        Pour, reconstruction and post-processing settings. The post-processing is
        resolved by `synthpack.artefacts.recipes.resolve_postprocessing`; with
        ``postprocess: calibrated`` (the default) the blur and noise are fitted to
        the source scan and the fit is recorded in the manifest under
        ``calibration``. The mode applied is recorded under ``postprocess_mode``.
    seed : int
        Seed of this pack (pour, pore texture and artefacts).
    progress : bool
        Show progress bars.
    threads : int, optional
        Threads for the chunks; default ``config.run.threads`` (default: the CPUs this process may use).
    allocate : callable, optional
        ``allocate(name, shape, dtype, chunks) -> array`` gives the arrays to fill:
        ``"clean"`` (float32), ``"labels"`` (int32), ``"tomogram"`` (float32) and,
        for post-processing pipelines with several blur-type steps, ``"scratch"``
        (float32), e.g. Zarr arrays (`synthpack.store.pack.StagedPack.zarr_array`).
        Default: NumPy arrays.
    """
    check_postprocess(config.postprocess, library.statistics)  # fail or warn before the pour, not after it
    requested, (config, view) = config, resolve_pack(library, config)
    segmented = config.reconstruct.segmented_labels_of(library.statistics)
    device = resolve_device(config.run.device, config.reconstruct.order)
    allocate = allocate or _numpy_volume
    chunks = tuple(config.run.chunks)
    threads = config.run.threads if threads is None else threads
    timings: dict[str, float] = {}
    grains = None
    if config.grains.deform.strength > 0:
        with _timed(timings, "deform"):
            grains = pack_grains(library, config.pour.n_particles, config.grains.deform, seed)
    if _overlaps(library, config, view, device, threads):
        placements, render = _pour_rendering(library, config, seed, progress, grains, chunks, threads, allocate,
                                             timings)
    else:
        with _timed(timings, "pour"):
            placements = _pour(library, config, seed, progress, grains, view)
        with _timed(timings, "reconstruct"):
            render = _render(library, placements, config, view, seed, chunks, threads, allocate, grains, device)
    timings["pour_engine"] = placements.checks.seconds  # the engine run alone (not saved with the placements)
    labels_record, present = None, render.present
    if segmented is not None:
        with _timed(timings, "labels"):
            labels_record = segmented.redraw(render.labels, chunks[0], len(placements))
        present = labels_record.pop("present")
    with _timed(timings, "postprocess"):
        postprocessing = resolve_postprocessing(
            config.postprocess, library.statistics, clean=render.clean, labels=render.labels,
            grid=render.grid, packing_region=None if render.crop is not None else placements.checks.packing_region,
            pore_texture=render.background.texture_density(), seed=seed, n_grains=len(placements),
        )
        # any render order post-processes on the device, if every transform has a torch version
        postprocess_device = device_for(postprocessing.pipeline, resolve_device(config.run.device))
        tomogram, applied = _postprocess(postprocessing, render, seed, threads, allocate, chunks, postprocess_device,
                                         placements.tube.inner_radius)
    grid = render.grid
    manifest = dict(
        seed=seed, random_streams=random_streams(), config=requested.to_dict(), library_source=library.source,
        n_particles=len(placements),
        n_labels=_grains_present(present, every=render.crop is None and segmented is None),
        segmented_labels=labels_record,
        contested_voxels=render.contested, shape=list(grid.shape), grid_origin=list(grid.origin),
        pour_checks=placements.checks.to_dict(), pore_texture=render.background.texture_record(seed),
        view=_view_record("tube" if render.crop is None else "interior", config.reconstruct.view, placements,
                          render.crop),
        wall=None if render.wall is None else render.background.wall_record(render.wall),
        partial_volume=render.partial_volume.record() if render.partial_volume else None,
        postprocessing=applied, timings=timings, **postprocessing.record,
        devices=dict(render=device or "cpu", render_kernel=render.kernel,  # "cpu": NumPy
                     postprocess=postprocess_device or "cpu"),
        overlap=render.overlap,
    )
    return SyntheticPack(tomogram, render.clean, render.labels, placements, grid, manifest)


@contextmanager
def _timed(timings: dict[str, float], step: str) -> Iterator[None]:
    """Record the wall time of the ``with`` block as ``timings[step]``, seconds."""
    start = time.perf_counter()
    yield
    timings[step] = time.perf_counter() - start


@dataclass(frozen=True)
class _Render:
    """What the render made: clean volume and labels on their grid, the background drawn, contested voxels,
    the partial volume (None: whole voxels), the wall's inner and outer radius (physical units; None: no wall
    in view), the interior crop's world corners ``(lo, hi)`` (physical units; None: the tube), the kernel
    that drew the grains on the CPU (``"numba"`` or ``"scipy"``, `synthpack.render.kernel`; None on a torch device),
    the labels in view (`_LabelWrites.present`) and, for a render while pouring, the manifest's ``overlap``."""

    grid: Grid
    clean: Any
    labels: Any
    background: Background
    contested: int
    partial_volume: PartialVolume | None
    wall: tuple[float, float] | None
    crop: tuple[np.ndarray, np.ndarray] | None
    kernel: str | None
    present: np.ndarray
    overlap: dict | None = None


class _LabelWrites:
    """The label volume the render writes, chunk by chunk, noting the labels each chunk holds.

    ``present[k]``: label ``k`` has a voxel in a chunk written (bool, one per label
    ``0..n_placed``; a chunk written again counts as written last). Counted as the chunks are
    written, so the count of the grains in view reads no volume back (a 1,355-million-voxel
    pack's labels take about 10 s to decode).
    """

    def __init__(self, array: Any, n_placed: int) -> None:
        self.array = array
        self._labels = n_placed + 1
        self._present: dict[tuple[int | None, ...], np.ndarray] = {}  # chunk corner -> labels it holds

    def __setitem__(self, window: tuple[slice, ...], block: np.ndarray) -> None:
        self.array[window] = block
        present = np.zeros(self._labels, dtype=bool)
        for part in block:  # a slice at a time, a count of every label (4x faster than np.unique's sort)
            present[np.flatnonzero(np.bincount(part.ravel(), minlength=self._labels))] = True
        self._present[tuple(s.start for s in window)] = present

    @property
    def present(self) -> np.ndarray:
        if not self._present:
            return np.zeros(self._labels, dtype=bool)
        return np.any(np.stack(list(self._present.values())), axis=0)


def _trimmed(array: Any, shape: tuple[int, int, int]) -> Any:
    """`array` (made deeper than needed, `_pour_rendering`) cut to `shape` along z: a view of a NumPy array, a
    Zarr array (or `~synthpack.store.zarr_pack.LevelledVolume`) resized in place."""
    if isinstance(array, np.ndarray):
        return array[:shape[0]]
    array.resize(shape)
    return array


def _pour(
    library: ParticleLibrary, config: PackConfig, seed: int, progress: bool, grains: PackGrains | None, view: str,
    on_lock: Callable[[LockedGrains], None] | None = None,
) -> Placements:
    """The pour (paper 3.3) of ``config.pour`` with `seed`, into the tube of `view`.

    With `grains`, placement ``k`` pours ``grains.particles[k]`` (a deformed grain, in its
    own frame); the placements name its library grain (``indices``) and record how it
    was made (``grains``). The tube is the library's either way. For an interior crop, the
    tube is wide enough for one and the pour measures its bulk where the crop lies: the crop's
    footprint (`_crop_lateral`), `~synthpack.physics.container.CROP_WALL_MARGIN` or more from the wall.
    `on_lock` is `~synthpack.physics.pour`'s (its grains are ``grains.particles``' with `grains`).
    """
    interior = view == "interior"
    tube = config.pour.tube(library, interior=interior)
    wall_margin = CROP_WALL_MARGIN if interior else 1.0
    crop = _crop_lateral(library, config) if interior else None
    if grains is None:
        return pour(library, config.pour, seed, container=tube, progress=progress, wall_margin=wall_margin,
                    crop=crop, on_lock=on_lock)
    placements = pour(grains.particles, config.pour, seed, container=tube, wall_margin=wall_margin, crop=crop,
                      indices=np.arange(len(grains.particles)), progress=progress, on_lock=on_lock)
    return dataclasses.replace(placements, indices=grains.sources, grains=grains.record)


def _overlaps(library: ParticleLibrary, config: PackConfig, view: str, device: str | None,
              threads: int | None) -> bool:
    """Whether the pack is rendered while it is poured (`_pour_rendering`): ``run.overlap`` (from
    `OVERLAP_MIN_GRAINS` grains for ``auto``), the tube in view (an interior crop's grid waits for the
    pour's bulk), on the CPU with two threads or more, and a pore texture whose period the pack's height
    cannot change (`~synthpack.render.pore_texture.PoreTextureConfig.period`)."""
    wanted = config.run.overlap == "on" or (config.run.overlap == "auto"
                                            and config.pour.n_particles >= OVERLAP_MIN_GRAINS)
    if not (wanted and view == "tube" and device is None and thread_count(threads) > 1 and can_start_pour_process()):
        return False
    tube = config.pour.tube(library, interior=False)
    background = Background.from_source(library.statistics, config.reconstruct)
    low, high = (_tube_grid(background, library, config, tube, top)[1].shape for top in (0.0, tube.height))
    return background.texture.period(low) == background.texture.period(high)


def _tube_grid(background: Background, library: ParticleLibrary, config: PackConfig, tube: Tube,
               top: float) -> tuple[tuple[float, float], Grid]:
    """The wall's inner and outer radius (physical units) and the grid that shows the tube up to height `top`."""
    wall = background.wall_radii(tube.inner_radius, tube.outer_radius, min(library.voxel_size[1:]))
    grid = Grid.covering(max(wall[1], tube.outer_radius), -tube.base_thickness, top, library.voxel_size,
                         margin=config.reconstruct.margin)
    return wall, grid


@dataclass(frozen=True)
class _Early:
    """The chunks rendered while pouring (`_pour_rendering`): their render and the volumes they went into."""

    render: LockedRender
    clean: Any
    labels: _LabelWrites


def _pour_rendering(
    library: ParticleLibrary, config: PackConfig, seed: int, progress: bool, grains: PackGrains | None,
    chunks: tuple[int, int, int], threads: int | None, allocate: Allocate, timings: dict[str, float],
) -> tuple[Placements, _Render]:
    """The pour in a second process (`synthpack.pipeline.pour_process`) and the render of the tube meanwhile.

    The chunks the locked batches bury are rendered as the pour goes on, on the threads the pour
    leaves (`~synthpack.render.streamed.LockedRender`); the volumes are made as deep as the tube and
    cut to the pack's grid after the pour, when `_render` draws the rest. The same voxels as a render
    after the pour. ``timings``: ``pour`` (its wall time), ``render_while_pouring`` (thread seconds of the
    chunks rendered meanwhile) and ``reconstruct`` (the render after the pour).
    """
    pack = config.reconstruct
    tube = config.pour.tube(library, interior=False)
    background = Background.from_source(library.statistics, pack)
    wall, deepest = _tube_grid(background, library, config, tube, tube.height)
    particles = library if grains is None else grains.particles
    n_placed = config.pour.n_particles
    early_labels = _LabelWrites(allocate("labels", deepest.shape, np.int32, chunks), n_placed)
    early_clean = allocate("clean", deepest.shape, np.float32, chunks)
    partial_volume = pack.partial_volume_of(library.statistics)
    with LockedRender(
        [(p.tomogram, p.mask) for p in particles], deepest, dataclasses.replace(background, extent=deepest.shape),
        (early_clean, early_labels), n_placed=n_placed, tube=(wall[0], wall[1], -tube.base_thickness),
        order=pack.order, seed=seed, chunks=chunks, partial_volume=partial_volume, surface=pack.surface,
        kernel=pack.kernel, reach=pack.surface.reach(partial_volume), workers=thread_count(threads) - 1,
    ) as early:
        def locked(batch: LockedGrains) -> None:
            early.add(batch.batch, batch.members, batch.indices, rotation_matrices(batch.quaternions),
                      batch.positions, batch.scales)

        with _timed(timings, "pour"):
            placements = pour_in_process(
                _pour, locked, library=_without_intensities(library), config=config, seed=seed, progress=progress,
                grains=None if grains is None else dataclasses.replace(
                    grains, particles=_without_intensities(grains.particles)),
                view="tube")
        timings["render_while_pouring"] = early.seconds
        with _timed(timings, "reconstruct"):
            render = _render(library, placements, config, "tube", seed, chunks, threads, allocate, grains, None,
                             _Early(early, early_clean, early_labels))
    return placements, render


def _without_intensities(library: ParticleLibrary) -> ParticleLibrary:
    """`library` with its particles' intensity crops emptied: what the pour's process is sent (a pour reads the
    meshes, masks and masses, never the intensities, which are most of a library's bytes)."""
    empty = np.zeros((0, 0, 0), dtype=np.float32)
    return library.with_particles([dataclasses.replace(particle, tomogram=empty) for particle in library])


def _crop_lateral(library: ParticleLibrary, config: PackConfig) -> tuple[float, float]:
    """The ``(Y, X)`` extent an interior crop aims at (`~synthpack.physics.container.crop_extent`), physical units."""
    extent = crop_extent(library, parse_scale(config.pour.scale)[1])
    return float(extent[1]), float(extent[2])


def _render(
    library: ParticleLibrary, placements: Placements, pack: PackConfig, view: str, seed: int,
    chunks: tuple[int, int, int], threads: int | None, allocate: Allocate, grains: PackGrains | None,
    device: str | None, early: _Early | None = None,
) -> _Render:
    """Clean tomogram and labels of the placed grains (paper 3.4), chunk by chunk into `allocate`'s arrays.

    Placement ``k``'s grain is ``library[placements.indices[k]]``, or ``grains.particles[k]`` with `grains`.
    On the torch `device` (`synthpack.render.torch_render`), or with NumPy where it is None. The grid
    covers the tube and its wall (`view` ``"tube"``), or only the interior crop
    (`~synthpack.physics.container.crop_box`), with no wall. A pour whose bulk holds no crop is
    refused for ``reconstruct.view: interior`` and shown as the tube, with a warning, for ``auto``.
    With `early` (the tube only), the chunks rendered while pouring that the placements reach as they
    were drawn are kept, its volumes cut to the grid, and only the other chunks drawn.
    """
    config = pack.reconstruct
    particles, placed = (library, placements.indices) if grains is None else (
        grains.particles, np.arange(len(placements)))
    tube = placements.tube
    background = Background.from_source(library.statistics, config)
    wall, crop = None, None
    if view == "interior":
        crop = crop_box(placements.checks.packing_region, _crop_lateral(library, pack))
        if crop is None:
            why = (f"the pour's bulk ({placements.checks.fill_height:g} high in a tube of radius "
                   f"{tube.inner_radius:g}) holds no interior crop: pour more grains (pour.n_particles), "
                   "or show the tube (reconstruct.view: tube)")
            if pack.reconstruct.view != "auto":
                raise SynthpackInputError(why)
            warn_tube(why, "the pour's bulk is too low for an interior crop (-v says why)")  # auto: the tube after all
    if crop is not None:
        grid = Grid.box(*crop, library.voxel_size)
    else:
        wall, grid = _tube_grid(background, library, pack, tube, placements.checks.fill_height)
    background = dataclasses.replace(background, extent=grid.shape)  # the pore texture's period covers the pack
    partial_volume = config.partial_volume_of(library.statistics)
    maps = pose_maps([p.mask for p in particles], placed,
                     placements.rotation_matrices(), placements.positions, placements.scales, grid,
                     reach=config.surface.reach(partial_volume))
    renderer = None if device is None else TorchRenderer(device)
    kernel = None if renderer is not None else resolve_kernel(config.kernel)
    done, early_contested, overlap = (), 0, None
    if early is None:
        labels = _LabelWrites(allocate("labels", grid.shape, np.int32, chunks), len(placements))
        clean = allocate("clean", grid.shape, np.float32, chunks)
    else:
        done, early_contested, redrawn = early.render.finish(maps, grid.shape)
        labels, clean = early.labels, _trimmed(early.clean, grid.shape)
        labels.array = _trimmed(labels.array, grid.shape)
        overlap = {"chunks_while_pouring": len(done) + redrawn, "drawn_again": redrawn,
                   "thread_seconds_while_pouring": round(early.render.seconds, 3)}
        logger.info("rendered %d of the pack's chunks while pouring; %d of them drawn again", len(done) + redrawn,
                    redrawn)
    clean, _, contested = reconstruct(
        [(p.tomogram, p.mask) for p in particles], maps, grid, background,
        tube=None if wall is None else (wall[0], wall[1], -tube.base_thickness),
        order=config.order, seed=seed, chunks=chunks, workers=threads if renderer is None else 1,
        out=(clean, labels), partial_volume=partial_volume, renderer=renderer, surface=config.surface,
        kernel=config.kernel, done=done,
    )
    if renderer is not None:
        logger.info("rendered on %s: %d voxels within float rounding of a grain's surface", device,
                    renderer.near_threshold)
    return _Render(grid, clean, labels.array, background, contested + early_contested, partial_volume, wall, crop,
                   kernel, labels.present, overlap)


def _view_record(view: str, requested: str, placements: Placements, crop: tuple[np.ndarray, np.ndarray] | None) -> dict:
    """The manifest's ``view``: what the pack shows (`view`, from ``reconstruct.view`` `requested`), the
    container poured into and the interior crop's world corners (``lo``, ``hi``, ``(z, y, x)``, physical units)."""
    return {"view": view, "requested": requested, "container": placements.tube.to_dict(),
            "crop": None if crop is None else {"lo": [float(v) for v in crop[0]], "hi": [float(v) for v in crop[1]]}}


def _postprocess(
    postprocessing: Postprocessing, render: _Render, seed: int, threads: int | None, allocate: Allocate,
    chunks: tuple[int, int, int], device: str | None, tube_radius: float,
) -> tuple[Any, list[dict]]:
    """The post-processed tomogram, chunk by chunk into `allocate`'s array, and the record of what was applied.

    On the torch `device` (`synthpack.artefacts.torch_blocks`) where the pipeline allows, or with NumPy;
    then the band map, where there is one, with NumPy, inside the tube of `tube_radius` (physical
    units) or, for an interior crop, everywhere.
    """
    shape = render.grid.shape
    tomogram = allocate("tomogram", shape, np.float32, chunks)
    applied = apply_blockwise(
        postprocessing.pipeline, render.clean, tomogram, derived_seed(seed, "artefacts"), chunks, threads=threads,
        scratch=lambda: allocate("scratch", shape, np.float32, chunks), device=device,
    )
    band_map = postprocessing.band_map
    if band_map is not None:
        rounding = postprocessing.band_map_rounding
        apply_band_map(band_map, tomogram, render.labels, chunks, threads=threads,
                       inside=None if render.wall is None else _in_tube(render.grid, tube_radius), rounding=rounding)
        applied.append({"name": "band_map", "bands": list(band_map.bands),
                        "grey_levels": None if rounding is None else [rounding.step, rounding.offset]})
    return tomogram, applied


def _in_tube(grid: Grid, radius: float) -> Callable[[np.ndarray, np.ndarray], np.ndarray]:
    """``inside(lo, hi)``: the voxels of the chunk ``[lo, hi)`` of `grid` inside the tube (within `radius` of the
    world z axis, above its floor at z = 0): the specimen a band map applies to, not the wall or the air."""
    def inside(lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
        z, y, x = (grid.origin[a] + grid.voxel_size[a] * np.arange(lo[a], hi[a]) for a in range(3))
        return (z >= 0)[:, None, None] & (np.hypot(y[:, None], x[None, :]) < radius)[None]
    return inside


def _grains_present(present: np.ndarray, *, every: bool = True) -> int:
    """How many grain labels are `present` (`_LabelWrites.present`; label 0 is the pores); warns if not all
    where `every` grain should be in view (not in an interior crop)."""
    n_placed, n_present = len(present) - 1, int(np.count_nonzero(present[1:]))
    if n_present < n_placed and every:
        logger.warning("%d of %d placed grains have no voxel in the volume", n_placed - n_present, n_placed)
    return n_present


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
    whichever process or thread count builds it, byte for byte on one machine (another
    CPU may differ in the last bits of its floats, and a pour then diverges). A Zarr pack is written
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
    format : {"tiff", "zarr", "ome-zarr"}
        Volume format (`synthpack.store.pack.PACK_FORMATS`); Zarr packs are OME-Zarr stores.
    source : str
        Description of the source scan, for the manifest.
    threads : int, optional
        Threads for the chunks of this pack; default ``config.run.threads``.
    progress : bool
        Show the pour's progress bar.

    Returns
    -------
    Path
        The pack directory.
    """
    path = Path(out) / pack_name(index)
    seed = pack_seed(config.seed, index)
    threads = config.run.threads if threads is None else threads
    with stage_pack(path, voxel_size=library.voxel_size, unit=library.unit, format=format) as staged:
        pack = build_pack(library, config, seed, progress=progress, threads=threads,
                          allocate=staged.zarr_array if staged.format == "zarr" else None)
        start = time.perf_counter()
        if staged.format == "tiff":
            staged.write_volumes({"tomogram": pack.tomogram, "clean": pack.clean, "labels": pack.labels})
        staged.write_levels(threads)
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
    overwrite: bool = False,
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
    format : {"tiff", "zarr", "ome-zarr"}
        Volume format of the packs (`synthpack.store.pack.PACK_FORMATS`). Zarr packs
        (``"ome-zarr"`` is another name) are OME-Zarr stores written chunk by
        chunk, for volumes larger than memory, with downsampled levels for viewing.
    source : str
        Description of the source scan, for the manifests.
    progress : bool
        Show a progress bar over packs.
    workers, scheduler
        Where the packs are built; see :func:`synthpack.pipeline.runner.run_packs`.
        Default: a local Dask cluster sized to the machine, or this process
        when one pack is missing.
    overwrite : bool
        Write the packs into an `out` folder that holds something other than
        packs (its files are kept).

    Returns
    -------
    list of Path
        The pack directories, in order.

    Raises
    ------
    PackBuildError
        If some packs failed (after all the others were built): it lists each
        failed pack with its error. Calling again builds only the missing packs.
    SynthpackInputError
        Before any work: for an output path that cannot be used, an unknown
        post-processing, or an engine or ``run.device`` that cannot run here
        (checked when the packs are built on this machine). After the other packs were built: when every
        failed pack failed on its input (a `~synthpack.errors.PackInputError`,
        which is both a `PackBuildError` and a `SynthpackInputError`).
    """
    if isinstance(n_packs, bool) or not isinstance(n_packs, int) or n_packs < 1:
        raise SynthpackInputError(f"n_packs must be a positive integer, got {n_packs!r}")
    format = pack_format(format)
    config = config or PackConfig()
    _check_size(library, config, format)
    out = check_output(out, PACKS_OUTPUT, overwrite=overwrite)
    check_postprocess(config.postprocess, library.statistics)
    if scheduler is None:  # a remote cluster's workers may have what this machine lacks
        get_engine(config.pour.engine).check_available()
        resolve_device(config.run.device, config.reconstruct.order)
    paths = [out / pack_name(index) for index in range(n_packs)]
    missing = [index for index, path in enumerate(paths) if not is_complete_pack(path)]
    if len(missing) < n_packs:
        logger.info("%d of %d packs in %s are complete: skipped", n_packs - len(missing), n_packs, out)
    build = functools.partial(generate_pack, config=config, out=out, format=format,
                              source=source or library.source)
    failures = run_packs(build, missing, library, n_packs=n_packs, workers=workers, scheduler=scheduler,
                         progress=progress)
    if failures:
        raise PackBuildError.of({pack_name(i): error for i, error in failures.items()}, out, n_packs)
    return paths
