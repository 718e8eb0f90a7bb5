"""The Zarr store of a pack, ``pack.zarr``: an OME-Zarr image (NGFF 0.5) with its instance labels.

Layout::

    pack.zarr/                the tomogram: an NGFF multiscales image (ome.multiscales)
        0/                    full resolution (float32)
        1/ 2/ ...             each level half the previous one along every axis (mean of 2x2x2 voxels)
        labels/               ome.labels = ["instances"]
            instances/        the instance labels: a multiscales image with image-label metadata
                0/            full resolution (int32)
                1/ 2/ ...     every second voxel of the previous level (no mixing of labels)
        clean/                the noise-free volume: a multiscales image of level 0 only
            0/

Each level's ``coordinateTransformations`` give its voxel size (``scale``); the mean
levels of the tomogram also record the half-voxel offset of their voxel centres
(``translation``), so the levels and the labels overlay exactly in a viewer. Levels
are added while the smallest axis keeps at least :data:`MIN_LEVEL_SIZE` voxels, so a
small pack has level 0 only. ``clean`` is a second image next to the labels: NGFF
readers (ome-zarr-py, napari, Fiji's OME-Zarr readers) open the tomogram and its
labels and ignore it; open ``pack.zarr/clean`` to view it. Every array keeps the
codecs, chunking and ``voxel_size``/``unit``/``axes`` attributes of
`synthpack.io.write_zarr`, so any level reads as a plain Zarr volume too.

Full-resolution volumes are written first (whole, or chunk by chunk for packs
larger than memory; a tomogram or labels written chunk by chunk through a
`LevelledVolume` gets its level 1 as its chunks are written); :func:`write_levels` then
builds each level from the previous one block by block, so memory stays bounded by a
few blocks.

Packs written before synthpack used OME-Zarr hold plain arrays ``tomogram``,
``clean`` and ``labels`` at the top of the store; :func:`volume_paths` and
:func:`open_volumes` still read them.
"""

from __future__ import annotations

import logging
import shutil
from collections.abc import Callable, Collection
from pathlib import Path

import numpy as np
import zarr

from .._shared.chunks import bounded_map, chunk_boxes, thread_count
from ..io import create_zarr_volume, write_zarr
from ..io.ngff import image_attributes, labels_attributes

__all__ = ["STORE_NAME", "VOLUME_PATHS", "MIN_LEVEL_SIZE", "LevelledVolume", "volume_paths", "create_volume",
           "create_levelled_volume", "write_volume", "write_levels", "open_volumes", "level_shapes"]

logger = logging.getLogger(__name__)

#: Name of the store in the pack directory.
STORE_NAME = "pack.zarr"
#: Name of the label image under ``labels/``.
LABEL_IMAGE = "instances"
#: Where each volume's full-resolution array is in the store.
VOLUME_PATHS = {"tomogram": "0", "clean": "clean/0", "labels": f"labels/{LABEL_IMAGE}/0"}
#: A downsampled level is added only while its smallest axis keeps at least this many voxels.
MIN_LEVEL_SIZE = 64
# z slices of a level built at a time within one block: bounds the memory of a block's source.
_SLAB = 8


def volume_paths(store: Path) -> dict[str, Path]:
    """The full-resolution array of each volume (``tomogram``, ``clean``, ``labels``) in `store`.

    For a store of the earlier plain layout, its top-level arrays of these names.
    """
    legacy = (store / "tomogram" / "zarr.json").is_file()
    return {name: store / (name if legacy else path) for name, path in VOLUME_PATHS.items()}


def open_volumes(store: Path) -> dict[str, zarr.Array]:
    """The full-resolution arrays of `store` by volume name, opened read-only (slicing reads lazily)."""
    return {name: zarr.open_array(str(path), mode="r") for name, path in volume_paths(store).items()}


def create_volume(
    store: Path, name: str, shape: tuple[int, int, int], dtype: np.dtype | type,
    voxel_size: tuple[float, float, float], unit: str, *,
    chunks: tuple[int, int, int] | None = None, shards: tuple[int, int, int] | None = None,
) -> zarr.Array:
    """A new, empty full-resolution array of volume `name` in `store`, to fill chunk by chunk.

    Parameters
    ----------
    store : Path
        The pack's store (created if missing).
    name : {"tomogram", "clean", "labels"}
        The volume.
    shape : tuple of 3 int
        ``(Z, Y, X)``.
    dtype : numpy dtype
        float32 for images, an integer type for the labels.
    voxel_size : tuple of 3 float
        ``(dz, dy, dx)`` in `unit`.
    unit : str
        Length unit.
    chunks, shards : tuple of 3 int, optional
        See `synthpack.io.create_zarr_volume`.
    """
    path = store / VOLUME_PATHS[name]
    _make_groups(store, path.parent)
    return create_zarr_volume(path, shape, dtype, voxel_size, unit, chunks=chunks, shards=shards)


def write_volume(store: Path, name: str, volume: np.ndarray, voxel_size: tuple[float, float, float],
                 unit: str) -> None:
    """Write the in-memory full-resolution volume `name` (``tomogram``, ``clean``, ``labels``) into `store`."""
    path = store / VOLUME_PATHS[name]
    _make_groups(store, path.parent)
    write_zarr(path.parent, volume, voxel_size, unit, name=path.name)


def level_shapes(shape: tuple[int, int, int], min_size: int = MIN_LEVEL_SIZE) -> list[tuple[int, int, int]]:
    """Shapes of the levels of a volume of `shape`: each next one halves every axis (rounding up).

    Levels are added while the smallest axis of the new level keeps at least `min_size` voxels.
    """
    shapes = [tuple(int(n) for n in shape)]
    while min(half := tuple((n + 1) // 2 for n in shapes[-1])) >= min_size:
        shapes.append(half)
    return shapes  # type: ignore[return-value]


class LevelledVolume:
    """A full-resolution volume (`create_volume`) written block by block, with its level 1 made as it is written.

    Each block written at even offsets (and of even size, but at the volume's end) is
    also reduced into level 1 as `write_levels` would (the tomogram's 2x2x2 means, the
    labels' every second voxel), so `write_levels` builds the further levels from level 1
    and need not read level 0 back (a 1,355-million-voxel pack's tomogram and labels took
    most of its 36 s of levels). Reading, and anything else, goes to level 0. A block
    written off that grid leaves level 1 to be rebuilt (`level_one` False); a block written
    again (the band map's) is reduced again. A volume made before its depth is known
    (the render while the pour goes on) is made deep enough and then `resize`-d.

    Parameters
    ----------
    full : zarr.Array
        Level 0.
    half : zarr.Array
        Level 1, of ``ceil(shape / 2)``, stored at `half_path`.
    reduce : callable
        ``reduce(block) -> block`` of half the size (rounded up).
    half_path : Path
        Where `half` is stored.
    min_size : int
        See :func:`level_shapes`.
    """

    def __init__(self, full: zarr.Array, half: zarr.Array, reduce: Callable[[np.ndarray], np.ndarray],
                 half_path: Path, min_size: int = MIN_LEVEL_SIZE) -> None:
        self.full, self.half, self._reduce = full, half, reduce
        self._half_path, self._min_size = half_path, min_size
        self.level_one = True

    def resize(self, shape: tuple[int, int, int]) -> None:
        """Cut level 0 to `shape` and level 1 to match; the blocks written within `shape` keep their values.

        Where `create_levelled_volume` would lay level 1 out otherwise for `shape` (none, or other
        shards), it is dropped and left to `write_levels` to build from level 0 (`level_one` False).
        """
        self.full.resize(tuple(int(n) for n in shape))
        shapes = level_shapes(self.full.shape, self._min_size)
        if len(shapes) > 1 and self.half.shards == _half_shards(self.full.shards, shapes[1]):
            self.half.resize(shapes[1])
            return
        self.level_one = False
        shutil.rmtree(self._half_path, ignore_errors=True)

    def __getattr__(self, name: str):
        return getattr(self.full, name)

    def __getitem__(self, key):
        return self.full[key]

    def __setitem__(self, key: tuple[slice, ...], block: np.ndarray) -> None:
        self.full[key] = block
        box = [s.indices(n)[:2] for s, n in zip(key, self.full.shape)] if isinstance(key, tuple) else None
        if box is None or len(box) != 3 or any(a % 2 or (b % 2 and b != n) for (a, b), n in zip(box, self.full.shape)):
            self.level_one = False
            return
        if self.level_one:
            self.half[tuple(slice(a // 2, (b + 1) // 2) for a, b in box)] = self._reduce(np.asarray(block))


def create_levelled_volume(
    store: Path, name: str, shape: tuple[int, int, int], dtype: np.dtype | type,
    voxel_size: tuple[float, float, float], unit: str, *,
    chunks: tuple[int, int, int], shards: tuple[int, int, int], min_size: int = MIN_LEVEL_SIZE,
) -> zarr.Array | LevelledVolume:
    """`create_volume` of the ``tomogram`` or ``labels``, as a `LevelledVolume` where it will have a level 1.

    That is where `level_shapes` gives it one and its `shards` are even along every
    axis; level 1's shards are half of them (each block of level 0's shards writes one
    whole shard of level 1), its chunks single slices of a shard. Otherwise the plain array.
    """
    full = create_volume(store, name, shape, dtype, voxel_size, unit, chunks=chunks, shards=shards)
    shapes = level_shapes(shape, min_size)
    if name not in _REDUCE or len(shapes) < 2 or any(n % 2 for n in shards):
        return full
    half_shards = _half_shards(shards, shapes[1])
    half_path = (store / VOLUME_PATHS[name]).parent / "1"
    half = create_zarr_volume(half_path, shapes[1], dtype, tuple(v * 2 for v in voxel_size), unit,
                              chunks=(1, *half_shards[1:]), shards=half_shards)
    return LevelledVolume(full, half, _REDUCE[name], half_path, min_size)


def _half_shards(shards: tuple[int, ...], half_shape: tuple[int, ...]) -> tuple[int, ...]:
    """Level 1's shards: half of level 0's (each block of level 0's shards writes one whole shard), within its shape."""
    return tuple(min(n // 2, m) for n, m in zip(shards, half_shape))


def write_levels(store: Path, voxel_size: tuple[float, float, float], unit: str, *,
                 min_size: int = MIN_LEVEL_SIZE, threads: int | None = None,
                 level_one: Collection[str] = ()) -> int:
    """Write the downsampled levels and the OME-Zarr metadata of a store whose full-resolution volumes are written.

    Level ``k + 1`` of the tomogram is the mean of each 2x2x2 block of level ``k``
    (edge voxels repeated where an axis is odd), that of the labels every second
    voxel of level ``k``; each is written block by block (the blocks of level 0's
    shards, or chunks), so memory stays bounded by a few blocks.

    Parameters
    ----------
    store : Path
        The pack's store, holding the full-resolution volumes (`create_volume` or `write_volume`).
    voxel_size : tuple of 3 float
        Voxel size of level 0, ``(dz, dy, dx)`` in `unit`.
    unit : str
        Length unit.
    min_size : int
        See :func:`level_shapes`.
    threads : int, optional
        Threads for the blocks; default: the number of CPU cores.
    level_one : collection of str
        The volumes whose level 1 is written already (`LevelledVolume.level_one`): their
        levels are built from it.

    Returns
    -------
    int
        The number of levels, level 0 included.
    """
    workers = thread_count(threads)
    shapes = level_shapes(zarr.open_array(str(store / VOLUME_PATHS["tomogram"]), mode="r").shape, min_size)
    for name, reduce in _REDUCE.items():  # the same shape (open_pack checks)
        image = (store / VOLUME_PATHS[name]).parent
        first = 2 if name in level_one and len(shapes) > 1 else 1
        level = zarr.open_array(str(image / str(first - 1)), mode="r")
        for index, shape in enumerate(shapes[first:], first):
            shutil.rmtree(image / str(index), ignore_errors=True)  # a level 1 left stale by a `LevelledVolume`
            level = _write_level(level, image / str(index), shape, reduce,
                                 [v * 2**index for v in voxel_size], unit, workers)
    sizes = [[v * 2**k for v in voxel_size] for k in range(len(shapes))]
    offsets = [[v * (2**k - 1) / 2 for v in voxel_size] for k in range(len(shapes))]
    zarr.open_group(str(store), mode="r+").attrs["ome"] = image_attributes(
        "tomogram", sizes, unit, translations=offsets, method="mean")
    zarr.open_group(str(store / "labels"), mode="r+").attrs["ome"] = labels_attributes([LABEL_IMAGE])
    zarr.open_group(str(store / "labels" / LABEL_IMAGE), mode="r+").attrs["ome"] = image_attributes(
        LABEL_IMAGE, sizes, unit, method="nearest", label_source="../../")
    zarr.open_group(str(store / "clean"), mode="r+").attrs["ome"] = image_attributes("clean", sizes[:1], unit)
    logger.info("%s: %d level(s) %s", store, len(shapes), shapes)
    return len(shapes)


def _make_groups(store: Path, group: Path) -> None:
    """Make `group` (`store` or a folder in it) and the folders between them Zarr groups, where they are not yet."""
    for path in [*(store / parent for parent in reversed(group.relative_to(store).parents)), group]:
        if not (path / "zarr.json").is_file():
            zarr.open_group(str(path), mode="a")


def _write_level(source: zarr.Array, path: Path, shape: tuple[int, int, int],
                 reduce: Callable[[np.ndarray], np.ndarray], voxel_size: list[float], unit: str,
                 threads: int) -> zarr.Array:
    """Level `path` of `shape` made from `source` (the previous level) by `reduce`, block by block."""
    block = tuple(min(b, n) for b, n in zip(source.shards or source.chunks, shape))
    chunks = tuple(c if b % c == 0 else b for c, b in zip(source.chunks, block))  # chunks tile a shard
    target = create_zarr_volume(path, shape, source.dtype, tuple(voxel_size), unit, chunks=chunks,
                                shards=block if source.shards else None)

    def build(box: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
        lo, hi = box
        out = np.empty(tuple(hi - lo), dtype=source.dtype)
        for z in range(lo[0], hi[0], _SLAB):
            top = min(z + _SLAB, hi[0])
            part = source[2 * z:2 * top, 2 * lo[1]:2 * hi[1], 2 * lo[2]:2 * hi[2]]
            out[z - lo[0]:top - lo[0]] = reduce(part)
        return out

    for (lo, hi), values in bounded_map(build, chunk_boxes(shape, block), threads):
        target[lo[0]:hi[0], lo[1]:hi[1], lo[2]:hi[2]] = values
    return target


def _mean_2x(block: np.ndarray) -> np.ndarray:
    """Mean of each 2x2x2 block of voxels, float32; an odd axis has its last voxel repeated.

    The pairs are added in a fixed order, axis by axis, so a voxel's mean is the same bytes
    whichever block it is computed in (`LevelledVolume`'s blocks or `write_levels`').
    """
    odd = [(0, n % 2) for n in block.shape]
    padded = np.pad(block, odd, mode="edge") if any(b for _, b in odd) else block  # a copy only where needed
    padded = padded.astype(np.float32, copy=False)
    z, y, x = (n // 2 for n in padded.shape)
    pairs = padded.reshape(z, 2, y, 2, x, 2)
    total = pairs[:, 0] + pairs[:, 1]
    total = total[:, :, 0] + total[:, :, 1]
    total = total[..., 0] + total[..., 1]
    return total * np.float32(0.125)


def _every_second(block: np.ndarray) -> np.ndarray:
    """Every second voxel along each axis, starting at the first (labels stay labels)."""
    return block[::2, ::2, ::2]


#: How each volume with levels makes its next level from the previous one (``clean`` has level 0 only).
_REDUCE: dict[str, Callable[[np.ndarray], np.ndarray]] = {"tomogram": _mean_2x, "labels": _every_second}
