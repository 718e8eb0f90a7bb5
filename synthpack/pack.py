"""A synthetic pack on disk: volumes, placements and manifest, written atomically.

Layout of one pack directory (names scripts and the dataset rely on)::

    tomogram.tif     post-processed tomogram (float32, ImageJ stack with voxel size)
    clean.tif        the same before post-processing
    labels.tif       instance labels (uint16 when they fit, else the pack is Zarr)
    placements.json  the pour: library index, pose, scale and batch of every grain
    manifest.json    config, seeds, source, versions, timings, counts; written last

With ``format="zarr"`` the three volumes are arrays of one store ``pack.zarr``
under the same names (``tomogram``, ``clean``, ``labels``).

The directory is built under a temporary name and renamed when complete, so an
interrupted run leaves no directory that looks complete. `write_pack` writes
volumes held in memory; `stage_pack` lets a Zarr pack's volumes be filled chunk
by chunk (volumes larger than memory) before the pack is published.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import zarr

from ._atomic import atomic_directory
from .errors import SynthpackInputError
from .io import create_zarr_volume, memmap_volume, write_tiff, write_zarr

__all__ = ["PACK_VOLUMES", "Pack", "StagedPack", "find_packs", "stage_pack", "write_pack", "is_complete_pack",
           "open_pack"]

#: Volume names of a pack, as TIFF files (``<name>.tif``) or Zarr arrays.
PACK_VOLUMES = ("tomogram", "clean", "labels")
_FORMATS = ("tiff", "zarr")


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

    def zarr_array(self, name: str, shape: tuple[int, int, int], dtype: np.dtype | type,
                   chunks: tuple[int, int, int]) -> zarr.Array:
        """A new, empty array `name` of the pack's Zarr store, to fill in blocks of `chunks`.

        Each block of `chunks` is one shard file, stored as compressed chunks of
        one slice ``(1, Y, X)`` of the block: a block is written at once, and a
        slice along z is read without decoding its neighbours (the dataset's
        and the export's default slicing). Arrays other than the pack volumes
        (e.g. a ``scratch`` volume for intermediate results) are removed by
        :meth:`finish`.
        """
        if self.format != "zarr":
            raise SynthpackInputError(f"a {self.format} pack has no Zarr store: write its volumes with write_volumes")
        store = self.path / "pack.zarr"
        if not store.exists():
            zarr.open_group(str(store), mode="w")
        shards = tuple(int(c) for c in chunks)
        return create_zarr_volume(store / name, shape, dtype, self.voxel_size, self.unit,
                                  chunks=(1, *shards[1:]), shards=shards)

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
                write_zarr(self.path / "pack.zarr", volumes[name], self.voxel_size, self.unit, name=name)

    def finish(self, placements, manifest: dict) -> None:
        """Write ``placements.json`` and, last, ``manifest.json`` (``complete: true``).

        Parameters
        ----------
        placements : synthpack.physics.Placements
            The pour.
        manifest : dict
            JSON-able; ``format``, ``voxel_size``, ``unit`` and ``complete`` are added.
        """
        store = self.path / "pack.zarr"
        if store.is_dir():
            for extra in sorted(p for p in store.iterdir() if p.is_dir() and p.name not in PACK_VOLUMES):
                shutil.rmtree(extra)
        placements.save(self.path / "placements.json")
        full = dict(manifest, format=self.format, voxel_size=list(self.voxel_size), unit=self.unit, complete=True)
        (self.path / "manifest.json").write_text(json.dumps(full, indent=1, default=_json_default))
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
    if format not in _FORMATS:
        raise SynthpackInputError(f"pack format must be one of {', '.join(_FORMATS)}, got {format!r}")
    with atomic_directory(directory) as staging:
        staged = StagedPack(staging, format, voxel_size, unit)
        yield staged
        if not staged.finished:
            raise RuntimeError(f"the pack {directory} was staged but never finished: call finish()")


def write_pack(
    directory: str | os.PathLike,
    volumes: dict[str, np.ndarray],
    placements,
    manifest: dict,
    *,
    voxel_size: tuple[float, float, float],
    unit: str,
    format: str = "tiff",
) -> Path:
    """Write one pack directory atomically from in-memory volumes.

    Parameters
    ----------
    directory : path-like
        The pack directory (replaced if it exists).
    volumes : dict
        ``{"tomogram": float32, "clean": float32, "labels": int}`` arrays of one shape.
    placements : synthpack.physics.Placements
        Saved as ``placements.json``.
    manifest : dict
        JSON-able; ``format``, ``voxel_size``, ``unit`` and ``complete`` are added.
    voxel_size, unit
        Voxel size ``(dz, dy, dx)`` and its unit.
    format : {"tiff", "zarr"}
        Volume format.
    """
    with stage_pack(directory, voxel_size=voxel_size, unit=unit, format=format) as staged:
        staged.write_volumes(volumes)
        staged.finish(placements, manifest)
    return Path(directory)


def _json_default(value: Any) -> Any:
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, Path):
        return str(value)
    raise TypeError(f"not JSON-serialisable: {type(value).__name__}")


def _read_manifest(directory: Path) -> dict | None:
    try:
        manifest = json.loads((directory / "manifest.json").read_text())
    except (OSError, ValueError):
        return None
    return manifest if isinstance(manifest, dict) and manifest.get("complete") is True else None


def _volume_paths(directory: Path, manifest: dict) -> list[Path]:
    if manifest.get("format") == "zarr":
        return [directory / "pack.zarr" / name for name in PACK_VOLUMES]
    return [directory / f"{name}.tif" for name in PACK_VOLUMES]


def is_complete_pack(directory: str | os.PathLike) -> bool:
    """True when `directory` holds a complete pack (manifest and every file present)."""
    directory = Path(directory)
    manifest = _read_manifest(directory)
    if manifest is None or not (directory / "placements.json").is_file():
        return False
    return all(path.exists() for path in _volume_paths(directory, manifest))


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


def open_pack(directory: str | os.PathLike) -> Pack:
    """Open a pack for lazy slice access.

    Raises
    ------
    SynthpackInputError
        If the directory is missing, incomplete or corrupt.
    """
    directory = Path(directory)
    manifest = _read_manifest(directory)
    if manifest is None or not is_complete_pack(directory):
        raise SynthpackInputError(
            f"{directory} is not a complete synthpack pack (manifest.json missing, unreadable "
            "or incomplete): generate it again with `synthpack generate`"
        )
    try:
        if manifest["format"] == "zarr":
            store = zarr.open_group(str(directory / "pack.zarr"), mode="r")
            arrays = [store[name] for name in PACK_VOLUMES]
        else:
            arrays = [memmap_volume(path) for path in _volume_paths(directory, manifest)]
    except Exception as error:
        raise SynthpackInputError(f"pack {directory} is corrupt ({error}): generate it again") from error
    shapes = {tuple(a.shape) for a in arrays}
    if len(shapes) != 1 or len(next(iter(shapes))) != 3:
        raise SynthpackInputError(f"pack {directory} is corrupt: volumes of shapes {sorted(shapes)}")
    return Pack(directory, *arrays, manifest=manifest)
