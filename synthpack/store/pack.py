"""A synthetic pack on disk: volumes, placements and manifest, written atomically.

Layout of one pack directory (names scripts and the dataset rely on)::

    tomogram.tif     post-processed tomogram (float32, ImageJ stack with voxel size)
    clean.tif        the same before post-processing
    labels.tif       instance labels (uint16 when they fit, else the pack is Zarr)
    placements.json  the pour: library index, pose, scale and batch of every grain
    manifest.json    config, seeds, source, versions, timings, counts, and the size and
                     SHA-256 of every other file (``files``); written last

With ``format="zarr"`` (also called ``"ome-zarr"``) the three volumes are one
OME-Zarr store (NGFF 0.5, on Zarr v3) instead of the TIFF files::

    pack.zarr/                      the tomogram, a multiscales image: levels 0 (full resolution), 1, ...
        labels/instances/           the instance labels, a label image of the same levels
        clean/                      the noise-free volume, an image of level 0 only

with the voxel size and unit as each level's coordinate transformations, readable by
ome-zarr-py, napari and Fiji; `synthpack.store.zarr_pack` describes it. Packs from before
OME-Zarr, with plain arrays ``tomogram``, ``clean`` and ``labels`` in ``pack.zarr``,
are still read.

A pack is complete when its manifest says so and every file it lists has the recorded
size (:func:`is_complete_pack`, cheap: a rerun rebuilds a pack whose file was cut
short). :func:`open_pack` with ``verify=True`` also recomputes the checksums and checks
that the labels fit the placements, for readers that read the volumes anyway.

The directory is built under a temporary name and renamed when complete, so an
interrupted run leaves no directory that looks complete. `stage_pack` gives the
temporary directory: volumes held in memory are written whole, and a Zarr pack's
volumes can be filled chunk by chunk (volumes larger than memory), before the
pack is published (its downsampled levels are then built block by block).
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import shutil
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import zarr

from .._shared.chunks import bounded_map, thread_count
from .._shared.strict_json import dumps as strict_json
from ..io.atomic import Output, atomic_directory
from .formats import PACK_FORMATS, pack_format
from ..errors import SynthpackInputError
from ..io import create_zarr_volume, memmap_volume, write_tiff
from .zarr_pack import (STORE_NAME, LevelledVolume, create_levelled_volume, open_volumes,
                        volume_paths, write_levels, write_volume)

__all__ = ["PACK_VOLUMES", "PACK_FORMATS", "pack_format", "Pack", "StagedPack", "find_packs", "stage_pack",
           "is_complete_pack", "open_pack", "verify_pack"]

#: Volume names of a pack, as TIFF files (``<name>.tif``) or the images of its OME-Zarr store.
PACK_VOLUMES = ("tomogram", "clean", "labels")
# Intermediate arrays of a Zarr pack being built (e.g. ``scratch``), removed by finish.
_SCRATCH = "scratch.zarr"
#: A pack folder: an earlier pack (``manifest.json``) is replaced, anything else is refused.
PACK_OUTPUT = Output("pack", marker="manifest.json")
#: The output folder of a run: synthpack's own when it holds packs (complete or staged) of an earlier run.
PACKS_OUTPUT = Output("folder of packs", is_ours=lambda path: any(path.glob("pack_*")) or any(path.glob(".pack_*")))


@dataclass
class Pack:
    """An opened pack: volumes are read lazily (memory-mapped TIFF or Zarr arrays).

    Attributes
    ----------
    path : Path
        The pack directory.
    tomogram, clean, labels : array-like, shape (Z, Y, X)
        Slicing reads only what is asked for.
    manifest : dict
        The pack's ``manifest.json``.
    """

    path: Path
    tomogram: Any
    clean: Any
    labels: Any
    manifest: dict

    @property
    def voxel_size(self) -> tuple[float, float, float]:
        """``(dz, dy, dx)`` in :attr:`unit`."""
        return tuple(self.manifest["voxel_size"])  # type: ignore[return-value]

    @property
    def unit(self) -> str:
        """Length unit of the voxel size."""
        return self.manifest["unit"]

    @property
    def shape(self) -> tuple[int, int, int]:
        """Volume shape ``(Z, Y, X)``."""
        return tuple(self.labels.shape)  # type: ignore[return-value]


class StagedPack:
    """A pack being written in a temporary directory; see :func:`stage_pack`.

    Attributes
    ----------
    path : Path
        The temporary directory (renamed to the pack directory once complete).
    format : {"tiff", "zarr"}
        Volume format.
    """

    def __init__(self, path: Path, format: str, voxel_size: tuple[float, float, float], unit: str) -> None:
        self.path = path
        self.format = format
        self.voxel_size = tuple(float(v) for v in voxel_size)
        self.unit = unit
        self.finished = False
        self.levels: int | None = None
        self._levelled: dict[str, LevelledVolume] = {}  # the volumes whose level 1 is written with them

    def zarr_array(self, name: str, shape: tuple[int, int, int], dtype: np.dtype | type,
                   chunks: tuple[int, int, int]) -> zarr.Array | LevelledVolume:
        """A new, empty array `name` of the pack's Zarr store, to fill in blocks of `chunks`.

        Each block of `chunks` is one shard file, stored as compressed chunks of
        one slice ``(1, Y, X)`` of the block: a block is written at once, and a
        slice along z is read without decoding its neighbours (the dataset's
        and the export's default slicing). A pack volume (``tomogram``, ``clean``,
        ``labels``) is the full-resolution level of its image in the OME-Zarr store;
        other arrays (e.g. a ``scratch`` volume for intermediate results) go to a
        separate store, removed when the levels are built (:meth:`write_levels`). The
        tomogram and the labels come as a `~synthpack.store.zarr_pack.LevelledVolume` where
        they will have levels: their level 1 is written with their blocks.
        """
        if self.format != "zarr":
            raise SynthpackInputError(f"a {self.format} pack has no Zarr store: write its volumes with write_volumes")
        shards = tuple(int(c) for c in chunks)
        layout = dict(chunks=(1, *shards[1:]), shards=shards)
        if name in PACK_VOLUMES:
            array = create_levelled_volume(self.path / STORE_NAME, name, shape, dtype, self.voxel_size, self.unit,
                                           **layout)
            if isinstance(array, LevelledVolume):
                self._levelled[name] = array
            return array
        scratch = self.path / _SCRATCH
        if not scratch.exists():
            zarr.open_group(str(scratch), mode="w")
        return create_zarr_volume(scratch / name, shape, dtype, self.voxel_size, self.unit, **layout)

    def write_volumes(self, volumes: dict[str, np.ndarray]) -> None:
        """Write the in-memory volumes ``{"tomogram", "clean", "labels"}`` in the pack's format."""
        missing = [name for name in PACK_VOLUMES if name not in volumes]
        if missing:
            raise SynthpackInputError(f"a pack needs the volumes {', '.join(missing)}")
        for name in PACK_VOLUMES:
            if self.format == "tiff":
                write_tiff(self.path / f"{name}.tif", volumes[name], self.voxel_size, self.unit,
                           labels=name == "labels")
            else:
                write_volume(self.path / STORE_NAME, name, volumes[name], self.voxel_size, self.unit)

    def write_levels(self, threads: int | None = None) -> None:
        """Build the downsampled levels and write the OME-Zarr metadata of a Zarr pack whose volumes are written.

        Nothing for a TIFF pack. :meth:`finish` calls it if it was not called
        (call it first to time it, or to give it `threads`); see
        `synthpack.store.zarr_pack.write_levels`.
        """
        if self.format == "zarr" and self.levels is None:
            shutil.rmtree(self.path / _SCRATCH, ignore_errors=True)
            self.levels = write_levels(self.path / STORE_NAME, self.voxel_size, self.unit, threads=threads,
                                       level_one=[name for name, array in self._levelled.items() if array.level_one])

    def finish(self, placements, manifest: dict) -> None:
        """Write ``placements.json`` and, last, ``manifest.json`` (``complete: true``).

        Parameters
        ----------
        placements : synthpack.physics.Placements
            The pour.
        manifest : dict
            JSON-able; ``format``, ``voxel_size``, ``unit`` and ``complete`` are added.
        """
        self.write_levels()
        placements.save(self.path / "placements.json")
        full = dict(manifest, format=self.format, voxel_size=list(self.voxel_size), unit=self.unit,
                    files=_file_records(self.path), complete=True)
        (self.path / "manifest.json").write_text(strict_json(full, indent=1))
        self.finished = True


@contextlib.contextmanager
def stage_pack(
    directory: str | os.PathLike, *, voxel_size: tuple[float, float, float], unit: str, format: str = "tiff"
) -> Iterator[StagedPack]:
    """Write a pack directory atomically: fill the yielded :class:`StagedPack`, then call its ``finish``.

    The pack appears at `directory` (replacing an existing one) only when the
    block ends after ``finish``; on an exception nothing is left behind.

    Examples
    --------
    >>> with stage_pack("packs/pack_0000", voxel_size=(1, 1, 1), unit="um", format="zarr") as staged:
    ...     labels = staged.zarr_array("labels", shape, np.int32, chunks)   # fill chunk by chunk
    ...     staged.finish(placements, manifest)
    """
    format = pack_format(format)
    with atomic_directory(directory, PACK_OUTPUT) as staging:
        staged = StagedPack(staging, format, voxel_size, unit)
        yield staged
        if not staged.finished:
            raise RuntimeError(f"the pack {directory} was staged but never finished: call finish()")


def _read_manifest(directory: Path) -> dict | None:
    try:
        manifest = json.loads((directory / "manifest.json").read_text())
    except (OSError, ValueError):
        return None
    return manifest if isinstance(manifest, dict) and manifest.get("complete") is True else None


def _sha256(path: Path) -> str:
    with open(path, "rb") as handle:
        return hashlib.file_digest(handle, "sha256").hexdigest()


def _file_records(directory: Path) -> dict[str, dict[str, Any]]:
    """Size (bytes) and SHA-256 of every file under `directory` but the manifest, by relative POSIX path.

    The files are hashed on every core (hashlib lets go of the GIL while it hashes): a Zarr
    pack of 1,355 million voxels holds about 9 GB of shards.
    """
    files = sorted(p for p in directory.rglob("*") if p.is_file() and p.name != "manifest.json")
    return {p.relative_to(directory).as_posix(): {"bytes": p.stat().st_size, "sha256": digest}
            for p, digest in bounded_map(_sha256, files, thread_count(None))}


def _size_problem(directory: Path, manifest: dict) -> str | None:
    """What is missing or of the wrong size among the files the manifest lists, or None."""
    for name, record in manifest.get("files", {}).items():
        path = directory / name
        if not path.is_file():
            return f"{name} is missing"
        if path.stat().st_size != record["bytes"]:
            return f"{name} has {path.stat().st_size} bytes, {record['bytes']} were written"
    return None


def _volume_paths(directory: Path, manifest: dict) -> list[Path]:
    if manifest.get("format") == "zarr":
        paths = volume_paths(directory / STORE_NAME)
        return [paths[name] for name in PACK_VOLUMES]
    return [directory / f"{name}.tif" for name in PACK_VOLUMES]


def is_complete_pack(directory: str | os.PathLike) -> bool:
    """True when `directory` holds a complete pack: its manifest, and every file it lists at its recorded size."""
    directory = Path(directory)
    manifest = _read_manifest(directory)
    if manifest is None or not (directory / "placements.json").is_file():
        return False
    if not all(path.exists() for path in _volume_paths(directory, manifest)):
        return False
    return _size_problem(directory, manifest) is None


def verify_pack(pack: Pack) -> None:
    """Check an opened pack's files against their recorded checksums, and its labels against its placements.

    Raises
    ------
    SynthpackInputError
        If a file changed since the pack was written, or the labels hold values
        no placement has (a label volume that is not this pack's).
    """
    for name, record in pack.manifest.get("files", {}).items():
        if _sha256(pack.path / name) != record["sha256"]:
            raise SynthpackInputError(
                f"pack {pack.path} is corrupt: {name} changed since it was written (checksum differs); "
                "delete the pack folder and run `synthpack generate` again to rebuild it"
            )
    n_particles = int(pack.manifest.get("n_particles", 0))
    for index in np.linspace(0, pack.shape[0] - 1, 5).astype(int):
        highest = int(np.max(pack.labels[int(index)]))
        if highest > n_particles:
            raise SynthpackInputError(
                f"pack {pack.path} is corrupt: slice {index} of its labels holds label {highest}, but the pack "
                f"has {n_particles} grains; delete the pack folder and run `synthpack generate` again"
            )


def find_packs(path: str | os.PathLike) -> list[Path]:
    """The complete packs at `path`: the pack itself, or the packs in a folder of packs.

    Parameters
    ----------
    path : path-like
        A pack directory, or a directory holding pack directories (``pack_0000``, ...).

    Returns
    -------
    list of Path
        Pack directories, sorted by name.

    Raises
    ------
    SynthpackInputError
        If `path` does not exist, holds an incomplete ``pack_*`` directory, or holds no pack.
    """
    path = Path(path)
    if is_complete_pack(path):
        return [path]
    if not path.is_dir():
        raise SynthpackInputError(f"pack folder {path} does not exist: give pack folders made by `synthpack generate`")
    candidates = sorted(p for p in path.iterdir() if p.is_dir() and not p.name.startswith("."))
    packs = [p for p in candidates if is_complete_pack(p)]
    broken = [p.name for p in candidates if p.name.startswith("pack_") and not is_complete_pack(p)]
    if broken:
        raise SynthpackInputError(
            f"{path} holds incomplete pack(s) {', '.join(broken)}: run `synthpack generate` again to finish them"
        )
    if not packs:
        raise SynthpackInputError(
            f"{path} is neither a pack nor a folder of packs: give folders made by `synthpack generate`"
        )
    return packs


def open_pack(directory: str | os.PathLike, *, verify: bool = False) -> Pack:
    """Open a pack for lazy slice access.

    Parameters
    ----------
    directory : path-like
        The pack directory.
    verify : bool
        Also check every file's checksum and the labels against the placements
        (:func:`verify_pack`): reads the whole pack once.

    Raises
    ------
    SynthpackInputError
        If the directory is missing, incomplete or corrupt.
    """
    directory = Path(directory)
    manifest = _read_manifest(directory)
    if manifest is None or not is_complete_pack(directory):
        problem = None if manifest is None else _size_problem(directory, manifest)
        raise SynthpackInputError(
            f"{directory} is not a complete synthpack pack ({problem or 'manifest.json missing, unreadable or incomplete'})"
            ": run the same `synthpack generate` again to rebuild it"
        )
    try:
        if manifest["format"] == "zarr":
            volumes = open_volumes(directory / STORE_NAME)
            arrays = [volumes[name] for name in PACK_VOLUMES]
        else:
            arrays = [memmap_volume(path) for path in _volume_paths(directory, manifest)]
    except Exception as error:
        raise SynthpackInputError(f"pack {directory} is corrupt ({error}): generate it again") from error
    shapes = {tuple(a.shape) for a in arrays}
    if len(shapes) != 1 or len(next(iter(shapes))) != 3:
        raise SynthpackInputError(f"pack {directory} is corrupt: volumes of shapes {sorted(shapes)}")
    pack = Pack(directory, *arrays, manifest=manifest)
    if verify:
        verify_pack(pack)
    return pack
