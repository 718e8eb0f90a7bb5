"""Zarr stores: single arrays, groups and OME-Zarr images read; `write_zarr` and
`create_zarr_volume` write volumes with their voxel size.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import zarr

from .atomic import Output, atomic_directory
from ..errors import SynthpackInputError
from .ngff import full_resolution, label_names
from ..scan.core import validate_voxel_size
from ._base import PathLike, Volume, VoxelSize, _choose, _is_empty_dir, _is_zarr_store, _reading, _require_volume
from .units import _attribute_voxel_size

logger = logging.getLogger(__name__)


#: A Zarr store (or an array in a group): an earlier store is replaced, anything else is refused.
_ZARR_OUTPUT = Output("Zarr store", is_ours=lambda path: _is_zarr_store(path))


def write_zarr(
    path: PathLike,
    volume: np.ndarray,
    voxel_size: float | tuple[float, float, float],
    unit: str = "um",
    chunks: tuple[int, int, int] | None = None,
    name: str | None = None,
) -> Path:
    """Write a volume to a Zarr store with its voxel size and unit as attributes.

    Parameters
    ----------
    path : str or Path
        The store (a directory, conventionally ending in ``.zarr``).
    volume : ndarray, shape (Z, Y, X)
        The volume, any numeric dtype (kept as is: use Zarr for labels beyond
        65535, which TIFF cannot hold).
    voxel_size : float or tuple of 3 float
        Voxel edge lengths ``(dz, dy, dx)`` in `unit`, stored as the array
        attribute ``voxel_size`` (a list, z first); `unit` as ``unit``.
    unit : str
        Length unit, e.g. ``"um"``.
    chunks : tuple of 3 int, optional
        Chunk shape in voxels; Zarr chooses one if omitted.
    name : str, optional
        Without a name the store is a single array and an existing store at
        `path` is replaced. With a name the store is a group and the array is
        added to it (replacing only an array of the same name), so a tomogram
        and its labels can share one store.

    Returns
    -------
    Path
        The store written.

    Raises
    ------
    SynthpackInputError
        If the volume is not 3D, `chunks` is invalid, or `path` exists and is
        not a Zarr store (it is never deleted).
    """
    path = Path(path)
    size = validate_voxel_size(voxel_size)
    data = _require_volume(volume)
    if chunks is not None and (
        len(chunks) != 3 or not all(isinstance(c, (int, np.integer)) and c > 0 for c in chunks)
    ):
        raise SynthpackInputError(
            f"chunks {chunks!r} must be three positive integers (z, y, x) or None"
        )
    if name is not None and (not name or "/" in name or name.startswith(".")):
        raise SynthpackInputError(
            f"array name {name!r} is not usable: give a plain name such as 'labels'"
        )
    if path.exists() and not _is_zarr_store(path) and not _is_empty_dir(path):
        raise SynthpackInputError(
            f"cannot write the Zarr store {path}: something that is not a Zarr store "
            "is already there; choose another path or remove it"
        )

    def create(store: Path) -> None:
        zarr.create_array(store=str(store), data=data, **_zarr_layout(size, unit, chunks, data.dtype))

    if name is None:
        with atomic_directory(path, _ZARR_OUTPUT) as tmp:
            create(tmp)
    elif not _is_zarr_store(path):
        with atomic_directory(path, _ZARR_OUTPUT) as tmp:
            zarr.open_group(str(tmp), mode="w")
            create(tmp / name)
    elif _is_zarr_group(path):
        with atomic_directory(path / name, _ZARR_OUTPUT) as tmp:
            create(tmp)
    else:
        raise SynthpackInputError(
            f"cannot add array {name!r} to {path}: it is a single Zarr array, not a "
            "group; write without a name, or choose another path"
        )
    logger.debug("wrote %s%s: %s %s, voxel %s %s", path, f"/{name}" if name else "",
                 data.shape, data.dtype, size, unit)
    return path


def create_zarr_volume(
    store: PathLike,
    shape: tuple[int, int, int],
    dtype: np.dtype | type,
    voxel_size: tuple[float, float, float],
    unit: str,
    chunks: tuple[int, int, int] | None = None,
    shards: tuple[int, int, int] | None = None,
) -> zarr.Array:
    """Create an empty Zarr volume at `store` (a new directory) to be filled chunk by chunk.

    It carries the attributes `write_zarr` writes (``voxel_size`` z first,
    ``unit``, ``axes``) and the dimension names ``z, y, x``, so `read_volume`
    reads it like any written volume. Voxels never written read as 0.

    Parameters
    ----------
    store : str or Path
        Directory of the new array (inside a group directory, a member of it).
    shape : tuple of 3 int
        ``(Z, Y, X)``.
    dtype : numpy dtype
        Element type.
    voxel_size : tuple of 3 float
        ``(dz, dy, dx)`` in `unit` (already validated).
    unit : str
        Length unit.
    chunks : tuple of 3 int, optional
        Chunk shape (the unit of compression and of reading); Zarr chooses one
        if omitted.
    shards : tuple of 3 int, optional
        Shard shape, a multiple of `chunks`: each shard is one file holding its
        chunks (fewer files; write whole shards at once). None: one file per chunk.
    """
    return zarr.create_array(store=str(store), shape=tuple(int(n) for n in shape), dtype=dtype,
                             shards=None if shards is None else tuple(int(n) for n in shards),
                             **_zarr_layout(voxel_size, unit, chunks, dtype))


def _zarr_compressor(dtype: np.dtype | type) -> zarr.abc.codec.BytesBytesCodec:
    """The compressor of every volume synthpack writes to Zarr, chosen for write speed.

    Floating-point volumes (tomograms): Blosc LZ4 at level 1 on byte-shuffled values;
    integer volumes (labels): Zstandard at level 1. On a 50-million-voxel pack (tomogram,
    clean, labels; docs/benchmarks.md) they write about 2.5x as fast as Zarr's default
    (Zstandard at its default level), for a compression ratio of 1.9 instead of 2.1.
    """
    if np.issubdtype(np.dtype(dtype), np.floating):
        return zarr.codecs.BloscCodec(cname="lz4", clevel=1, shuffle="shuffle")
    return zarr.codecs.ZstdCodec(level=1)


def _zarr_layout(voxel_size: VoxelSize, unit: str, chunks: tuple[int, int, int] | None,
                 dtype: np.dtype | type) -> dict:
    """Chunks, compressor, dimension names and attributes of every volume synthpack writes to Zarr."""
    return dict(
        chunks="auto" if chunks is None else tuple(int(c) for c in chunks),
        compressors=[_zarr_compressor(dtype)],
        dimension_names=("z", "y", "x"),
        attributes={"voxel_size": list(voxel_size), "unit": unit, "axes": ["z", "y", "x"]},
    )


def _read_zarr(path: Path, role: str | None, name: str | None) -> Volume:
    node = zarr.open(str(path), mode="r")
    if isinstance(node, zarr.Group) and full_resolution(node.attrs) is not None:
        return _read_ome_zarr(node, role, name, path)
    group_attrs: dict = {}
    if isinstance(node, zarr.Group):
        arrays = dict(node.arrays())
        group_attrs = dict(node.attrs)
        node = arrays[_choose(sorted(arrays), role, name, path, "array")]
    attrs = {**group_attrs, **dict(node.attrs)}
    size, unit = _attribute_voxel_size(attrs.get("voxel_size"), attrs.get("unit"), path)
    return node[...], size, unit


def _read_ome_zarr(image: zarr.Group, role: str | None, name: str | None, path: Path) -> Volume:
    """Level 0 of an OME-Zarr image: the image itself (`name` ``"."``), a label image (``labels/<name>``; the
    first for the labels role or `name` ``"labels"``) or another image group in it (`name`, e.g. ``clean``)."""
    labels = image.get("labels")
    label_images = [f"labels/{n}" for n in label_names(labels.attrs)] if isinstance(labels, zarr.Group) else []
    images = {".": image, **{key: image[key] for key in label_images}}
    images.update({key: group for key, group in image.groups()
                   if key != "labels" and full_resolution(group.attrs) is not None})
    if (name is None and role == "labels" or name == "labels") and label_images:
        name = label_images[0]
    chosen = images[_choose(sorted(images), None, name or ".", path, "image")]
    level, size, unit = full_resolution(chosen.attrs)  # type: ignore[misc]
    array = chosen[level]
    if size is None:
        size, unit = array.attrs.get("voxel_size"), array.attrs.get("unit")
    return array[...], *_attribute_voxel_size(size, unit or "px", path)


def _is_zarr_group(path: Path) -> bool:
    with _reading(path, "a Zarr store"):
        return isinstance(zarr.open(str(path), mode="r"), zarr.Group)

