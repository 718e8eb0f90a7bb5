"""`ParticleLibrary`: the meshed particles of a scan, built once and reused by every pack."""

from __future__ import annotations

import csv
import json
import logging
import os
from collections.abc import Iterator, Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh

from .._shared.strict_json import dumps as strict_json
from .._shared.arrays import without_cupping
from ..io.atomic import Output, atomic_directory
from .._shared.console import progress_bar
from .._shared.schema import in_range, positive, setting
from .._shared.budget import LABEL_BYTES_PER_VOXEL, check_volume
from ..errors import SynthpackInputError
from .meshing import DECIMATION_FACTORS, mesh_from_mask
from .particles import Particle, ParticleCrop, extract_particles
from .sampling import cut_axes, window_weights
from ..scan.core import Scan
from ..source.statistics import SourceStatistics, measure_source

logger = logging.getLogger(__name__)

__all__ = ["ParticleLibrary", "LibraryConfig"]


@dataclass(frozen=True)
class LibraryConfig:
    """Particle extraction and meshing settings (paper 3.1-3.2), with their defaults.

    Below 50 voxels a marching-cubes surface is little more than a voxel blob;
    500 faces hold a grain's hull and contacts while thousands of grains still
    simulate quickly; 2.65 g/cm^3 is the density of quartz.
    """

    min_voxels: int = setting(50, positive, "drop particles smaller than this many voxels")
    include_border: bool = setting(False, None, "keep particles cut by the scan border")
    density: float = setting(2.65, positive, "grain density for masses (paper eq. 1)")
    target_faces: int = setting(500, in_range(8, float("inf")), "faces per mesh after decimation")


_FORMAT = "synthpack-particle-library"
#: A library folder; an earlier one (``library.json``) is replaced, anything else is refused.
LIBRARY_OUTPUT = Output("particle library", marker="library.json")
#: Raised whenever what a library holds on disk changes; a library of another version must be rebuilt.
_FORMAT_VERSION = 10
_REBUILD = "rebuild it with `synthpack library build`"
_TABLE_COLUMNS = (
    "index", "label", "z0", "y0", "x0", "z1", "y1", "x1", "voxel_count",
    "equivalent_diameter", "touches_border", "volume", "mass", "faces",
)


def _mesh_arrays(args: tuple[np.ndarray, tuple[float, float, float], int | None]):
    mask, voxel_size, target_faces = args
    mesh = mesh_from_mask(mask, voxel_size, target_faces=target_faces)
    return mesh.vertices, mesh.faces


def _log_undecimated(faces: Sequence[int], target_faces: int | None) -> None:
    """Log once how many meshes (of `faces` faces each) decimation could not bring to `target_faces`."""
    if target_faces is None:
        return
    kept = [n for n in faces if n > max(DECIMATION_FACTORS) * target_faces]
    if kept:
        counts = f"{min(kept)}-{max(kept)}" if len(kept) > 1 else str(kept[0])
        logger.info("%d of %d meshes left at %s faces: decimation to ~%d kept breaking their surface",
                    len(kept), len(faces), counts, target_faces)


def _check_exclude(shape: tuple[int, ...], exclude: tuple[int, int], axis: int) -> tuple[int, int]:
    """`exclude` as ints, checked to be a non-empty range of slices along `axis` that leaves some."""
    if axis not in (0, 1, 2):
        raise SynthpackInputError(f"axis must be 0, 1 or 2, got {axis!r}")
    start, stop = (int(v) for v in exclude)
    n = shape[axis]
    if not 0 <= start < stop <= n or stop - start == n:
        raise SynthpackInputError(
            f"exclude_slices {exclude} must be a non-empty range start < stop inside the {n} slices along "
            f"axis {axis} that leaves some slices, e.g. synthpack.scan.split.central_block({n})"
        )
    return start, stop


def _without_cupping(scan: Scan, statistics: SourceStatistics) -> Scan:
    """`scan` with its measured cupping divided out (mean level kept); `scan` itself where it shows none."""
    if statistics.cupping_strength is None:
        return scan
    flat = without_cupping(scan.tomogram, statistics.cupping_strength, statistics.scan_axis)
    logger.info("crops cut with the scan's cupping (strength %.3f) divided out", statistics.cupping_strength)
    return Scan(flat, scan.labels, voxel_size=scan.voxel_size, unit=scan.unit, source=scan.source)


class ParticleLibrary(Sequence[Particle]):
    """The particles of one scan with their crops and meshes (paper sections 3.1-3.2).

    Build it with :meth:`from_scan`, save it with :meth:`save` and load it back
    with :meth:`load`. It is a sequence of :class:`~synthpack.library.particles.Particle`.

    Parameters
    ----------
    particles : list of Particle
        The meshed particles.
    voxel_size : tuple of 3 float
        ``(dz, dy, dx)`` of the source scan, in `unit`.
    unit : str
        Length unit.
    density : float
        Grain density used for the particles' masses.
    statistics : SourceStatistics
        What was measured of the source scan (its pore level is the value outside
        each particle's mask in its clean crop).
    source_shape : tuple of 3 int
        Shape ``(Z, Y, X)`` of the source scan.
    source : str
        Description of the source scan.
    settings : dict
        The extraction and meshing settings used to build it.
    """

    def __init__(
        self,
        particles: list[Particle],
        *,
        voxel_size: tuple[float, float, float],
        unit: str,
        density: float,
        statistics: SourceStatistics,
        source_shape: tuple[int, int, int],
        source: str = "",
        settings: dict | None = None,
    ) -> None:
        self.particles = list(particles)
        self.voxel_size = tuple(float(v) for v in voxel_size)
        self.unit = unit
        self.density = float(density)
        self.statistics = statistics
        self.source_shape = tuple(int(n) for n in source_shape)
        self.source = source
        self.settings = dict(settings or {})

    # -- construction -------------------------------------------------------------
    @classmethod
    def from_scan(
        cls,
        scan: Scan,
        *,
        min_voxels: int = LibraryConfig.min_voxels,
        include_border: bool = LibraryConfig.include_border,
        density: float = LibraryConfig.density,
        target_faces: int | None = LibraryConfig.target_faces,
        workers: int | None = None,
        progress: bool = True,
        exclude_slices: tuple[int, int] | None = None,
        axis: int = 0,
    ) -> ParticleLibrary:
        """Extract and mesh every particle of `scan`.

        Parameters
        ----------
        scan : Scan
            Tomogram, labels and voxel size.
        min_voxels, include_border, density, target_faces
            Extraction and meshing settings; their meaning and defaults are those
            of :class:`LibraryConfig` (``target_faces=None`` keeps the full meshes).
        workers : int, optional
            Processes used for meshing; default: all cores. 1 meshes in-process.
        progress : bool
            Show a progress bar.
        exclude_slices : (start, stop), optional
            Slices ``start <= i < stop`` along `axis` that must not reach the
            library, e.g. the test block of the paper's split
            (`synthpack.scan.split.central_block`): particles with any voxel in them are
            dropped, and the intensity statistics come from the other slices only.
            Where the scan shows cupping (`SourceStatistics.cupping_strength`), the
            crops are cut from the scan with its cupping divided out (keeping the
            mean level), so a grain does not carry the darkening of where it lay; the
            calibrated post-processing puts the cupping back where the pack has it.
        axis : {0, 1, 2}
            Axis of `exclude_slices`.

        Returns
        -------
        ParticleLibrary
        """
        if not density > 0:
            raise SynthpackInputError(f"density must be positive, got {density}")
        check_volume(scan.shape, LABEL_BYTES_PER_VOXEL, "building the library", "crop the scan first")
        workers = (os.cpu_count() or 1) if workers is None else int(workers)
        if workers < 1:
            raise SynthpackInputError(f"workers must be at least 1, got {workers}")
        if exclude_slices is not None:
            exclude_slices = _check_exclude(scan.shape, exclude_slices, axis)
        statistics = measure_source(scan, exclude_slices, axis)
        crops = extract_particles(
            _without_cupping(scan, statistics), min_voxels=min_voxels, include_border=include_border,
            background=statistics.pore_mean,
        )
        if exclude_slices is not None:
            start, stop = exclude_slices
            kept = [c for c in crops if c.bbox[axis + 3] <= start or c.bbox[axis] >= stop]
            logger.info("%d of %d particles reach slices %d-%d along axis %d: dropped",
                        len(crops) - len(kept), len(crops), start, stop - 1, axis)
            crops = kept
        jobs = [(c.mask, c.voxel_size, target_faces) for c in crops]
        bar = dict(total=len(jobs), desc="meshing", unit="particle", disable=not progress)
        if workers == 1:
            arrays = [_mesh_arrays(job) for job in progress_bar(jobs, **bar)]
        else:
            chunk = max(1, len(jobs) // (8 * workers))
            with ProcessPoolExecutor(max_workers=workers) as pool:
                arrays = list(progress_bar(pool.map(_mesh_arrays, jobs, chunksize=chunk), **bar))
        _log_undecimated([len(f) for _, f in arrays], target_faces)
        particles = [
            _meshed(crop, trimesh.Trimesh(v, f, process=False), density)
            for crop, (v, f) in zip(crops, arrays)
        ]
        settings = dict(min_voxels=min_voxels, include_border=include_border,
                        target_faces=target_faces, cut_axes=list(cut_axes(scan.labels)))
        if exclude_slices is not None:
            settings.update(exclude_slices=[int(v) for v in exclude_slices], exclude_axis=axis)
        return cls(
            particles, voxel_size=scan.voxel_size, unit=scan.unit, density=density,
            statistics=statistics, source_shape=scan.shape, source=scan.source, settings=settings,
        )

    # -- sequence protocol ----------------------------------------------------------
    def __len__(self) -> int:
        return len(self.particles)

    def __getitem__(self, index):  # type: ignore[override]
        if isinstance(index, slice):
            return self.with_particles(self.particles[index])
        return self.particles[index]

    def __iter__(self) -> Iterator[Particle]:
        return iter(self.particles)

    def __repr__(self) -> str:
        d = self.equivalent_diameters
        return (
            f"ParticleLibrary({len(self)} particles, d_eq {d.min():.4g}-{d.max():.4g} "
            f"{self.unit}, voxel_size={self.voxel_size}, source={self.source!r})"
        )

    # -- sieving (paper section 3: particles are sifted by size) --------------------
    @property
    def equivalent_diameters(self) -> np.ndarray:
        """Equivalent-sphere diameters, shape (N,), in physical units."""
        return np.array([p.equivalent_diameter for p in self.particles], dtype=float)

    @property
    def draw_weights(self) -> np.ndarray:
        """How often a pour draws each grain, shape (N,), float64, summing to 1.

        The inverse of the chance that a grain of its size lay whole in the source's
        field of view (`synthpack.library.sampling`), so that a pack's grains have the
        sizes of all the scan's grains, not only of those the field of view left whole.
        Even for a library that keeps the cut grains (``include_border``) and for one
        saved before synthpack 0.9 (whose settings do not say which axes cut grains).
        """
        cut = self.settings.get("cut_axes")
        if cut is None or self.settings.get("include_border"):
            return np.full(len(self), 1.0 / len(self))
        gap = self.settings.get("exclude_slices")
        return window_weights([p.bbox for p in self.particles], self.source_shape, cut,
                              None if gap is None else (int(gap[0]), int(gap[1])), int(self.settings.get("exclude_axis", 0)))

    def sieve(self, d_min: float = 0.0, d_max: float = np.inf) -> ParticleLibrary:
        """The particles with ``d_min <= equivalent diameter < d_max`` (physical units)."""
        if d_min >= d_max:
            raise SynthpackInputError(f"sieve needs d_min < d_max, got {d_min} and {d_max}")
        keep = [p for p in self.particles if d_min <= p.equivalent_diameter < d_max]
        if not keep:
            raise SynthpackInputError(
                f"no particle with equivalent diameter in [{d_min}, {d_max}) {self.unit}; "
                f"this library spans {self.equivalent_diameters.min():.4g}-"
                f"{self.equivalent_diameters.max():.4g} {self.unit}"
            )
        return self.with_particles(keep)

    def size_distribution(self, edges: Sequence[float] | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Particle counts per equivalent-diameter class.

        Parameters
        ----------
        edges : sequence of float, optional
            Class edges in physical units; default: 8 classes over the range.

        Returns
        -------
        counts : ndarray of int, shape (K,)
        edges : ndarray of float, shape (K + 1,)
        """
        counts, edges = np.histogram(self.equivalent_diameters, bins=8 if edges is None else edges)
        return counts, edges

    def summary(self) -> str:
        """A short human-readable description: count and size distribution."""
        d = self.equivalent_diameters
        counts, edges = self.size_distribution()
        lines = [
            f"{len(self)} particles from {self.source or 'an unnamed scan'} "
            f"(voxel size {self.voxel_size} {self.unit}, density {self.density})",
            f"equivalent diameter [{self.unit}]: min {d.min():.4g}, median {np.median(d):.4g}, "
            f"max {d.max():.4g}",
            f"{'class [' + self.unit + ']':>24}  count",
        ]
        for lo, hi, n in zip(edges[:-1], edges[1:], counts):
            lines.append(f"{lo:>11.4g} - {hi:<10.4g}  {n:5d}  {'#' * int(round(40 * n / counts.max()))}")
        return "\n".join(lines)

    def with_particles(self, particles: Sequence[Particle]) -> ParticleLibrary:
        """A library of `particles` with this one's voxel size, unit, density, statistics, source and settings
        (a subset, or grains made from these, e.g. by `synthpack.library.deform`)."""
        return ParticleLibrary(
            list(particles), voxel_size=self.voxel_size, unit=self.unit, density=self.density,
            statistics=self.statistics, source_shape=self.source_shape, source=self.source,
            settings=self.settings,
        )

    # -- persistence ------------------------------------------------------------------
    def save(self, directory: str | os.PathLike, *, overwrite: bool = False) -> Path:
        """Write the library to `directory`, atomically.

        An earlier library there is replaced. A folder holding anything else is
        refused (:class:`~synthpack.errors.SynthpackInputError`) unless `overwrite`,
        which writes the library's files into it and keeps its other files.

        Layout: ``library.json`` (metadata, the source statistics under
        ``phases`` and the per-particle table),
        ``particles.csv`` (the same table for spreadsheets), ``crops.npz``
        (``tomogram_<i>`` float32 and ``mask_<i>`` bool arrays) and ``meshes.npz``
        (``vertices_<i>`` and ``faces_<i>``).
        """
        rows = [self._row(i, p) for i, p in enumerate(self.particles)]
        meta = dict(
            format=_FORMAT, version=_FORMAT_VERSION, voxel_size=self.voxel_size,
            unit=self.unit, density=self.density, phases=self.statistics.to_dict(),
            source_shape=self.source_shape, source=self.source, settings=self.settings,
            particles=rows,
        )
        with atomic_directory(directory, LIBRARY_OUTPUT, overwrite=overwrite) as staging:
            (staging / "library.json").write_text(strict_json(meta, indent=1))
            with open(staging / "particles.csv", "w", newline="") as handle:
                writer = csv.DictWriter(handle, fieldnames=_TABLE_COLUMNS)
                writer.writeheader()
                writer.writerows(rows)
            np.savez_compressed(staging / "crops.npz", **{
                key: value for i, p in enumerate(self.particles)
                for key, value in ((f"tomogram_{i}", p.tomogram), (f"mask_{i}", p.mask))
            })
            np.savez(staging / "meshes.npz", **{
                key: value for i, p in enumerate(self.particles)
                for key, value in ((f"vertices_{i}", p.mesh.vertices), (f"faces_{i}", p.mesh.faces))
            })
        logger.info("saved %d particles to %s", len(self), directory)
        return Path(directory)

    @staticmethod
    def _row(index: int, p: Particle) -> dict:
        z0, y0, x0, z1, y1, x1 = p.bbox
        return dict(
            index=index, label=p.label, z0=z0, y0=y0, x0=x0, z1=z1, y1=y1, x1=x1,
            voxel_count=p.voxel_count, equivalent_diameter=p.equivalent_diameter,
            touches_border=p.touches_border, volume=p.volume, mass=p.mass, faces=len(p.mesh.faces),
        )

    @classmethod
    def load(cls, directory: str | os.PathLike) -> ParticleLibrary:
        """Load a library written by :meth:`save`.

        Raises
        ------
        SynthpackInputError
            If the directory is missing, incomplete or corrupt, or holds a library
            of another format version (from an older or newer synthpack).
        """
        directory = Path(directory)
        missing = [n for n in ("library.json", "crops.npz", "meshes.npz") if not (directory / n).is_file()]
        if not directory.is_dir() or missing:
            what = "does not exist" if not directory.is_dir() else f"lacks {', '.join(missing)}"
            raise SynthpackInputError(f"particle library {directory} {what}: {_REBUILD}")
        try:
            meta = json.loads((directory / "library.json").read_text())
            if meta.get("format") != _FORMAT:
                raise ValueError("not a synthpack particle library")
        except Exception as error:  # any parse error means a corrupt library
            raise _corrupt(directory, error) from error
        if meta.get("version") != _FORMAT_VERSION:
            raise SynthpackInputError(
                f"particle library {directory} has format version {meta.get('version')!r}, but this "
                f"synthpack reads version {_FORMAT_VERSION}: {_REBUILD}"
            )
        try:
            voxel_size = tuple(meta["voxel_size"])
            particles = []
            with np.load(directory / "crops.npz") as crops, np.load(directory / "meshes.npz") as meshes:
                for row in meta["particles"]:
                    i = row["index"]
                    bbox = (row["z0"], row["y0"], row["x0"], row["z1"], row["y1"], row["x1"])
                    mesh = trimesh.Trimesh(meshes[f"vertices_{i}"], meshes[f"faces_{i}"], process=False)
                    particles.append(Particle(
                        row["label"], bbox, crops[f"tomogram_{i}"], crops[f"mask_{i}"],
                        voxel_size, bool(row["touches_border"]), mesh, meta["density"],
                    ))
            return cls(
                particles, voxel_size=voxel_size, unit=meta["unit"], density=meta["density"],
                statistics=SourceStatistics.from_dict(meta["phases"]), source_shape=tuple(meta["source_shape"]),
                source=meta.get("source", ""), settings=meta.get("settings", {}),
            )
        except Exception as error:  # any key, shape or zip error means a corrupt library
            raise _corrupt(directory, error) from error


def _corrupt(directory: Path, error: Exception) -> SynthpackInputError:
    return SynthpackInputError(
        f"particle library {directory} is corrupt or from an older synthpack "
        f"({type(error).__name__}: {error}): {_REBUILD}"
    )


def _meshed(crop: ParticleCrop, mesh: trimesh.Trimesh, density: float) -> Particle:
    return Particle(
        crop.label, crop.bbox, crop.tomogram, crop.mask, crop.voxel_size,
        crop.touches_border, mesh, density,
    )
