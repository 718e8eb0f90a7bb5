"""`PatchDataset`: 3D patches of packs and real scans, split along one axis, as MONAI / TorchIO items.

Item format (a dict, as MONAI's dictionary transforms and TorchIO's subjects take)::

    item = dataset[i]
    item["image"]    float32 tensor, (1, D, H, W): the tomogram in the patch
    item["label"]    int64 tensor, (1, D, H, W): instance labels (0 = not a grain);
                     PAD_LABEL (-1) where the patch is padding, not volume
    item["source"]   str, where the volumes come from (`SliceDataset.describe_source`)
    item["volume"]   int, the volume (pack) index
    item["origin"]   int64 tensor, (3,): the patch's first voxel (z, y, x) in the volume
    item["extent"]   int64 tensor, (3,): voxels of volume in the patch along (z, y, x);
                     ``(D, H, W)`` unless the patch is padded

The patch box is in the volume's own (Z, Y, X) frame whatever `axis` is: `axis`
only says along which axis the split runs. The default DataLoader collate stacks
items into ``image`` / ``label`` batches of shape (B, 1, D, H, W).

Split: the slices of each volume along `axis` are split with
`synthpack.scan.split.split_slices` exactly as the slice datasets do (the paper's
central 20% are ``"test"``; ``"val"``, when `val_fraction` > 0, the blocks next to
it). A split's slices form one or two contiguous blocks along `axis`, and every
patch lies wholly inside one block, so no voxel of another split is ever in a
patch: no test voxel in a training patch.

Thin blocks and small volumes: a block thinner than the patch (the test block
holds 20% of the slices, each val block half of `val_fraction`), or a volume
smaller than the patch along another axis, gets patches that start at the block's
(or volume's) first voxel and hold all of it; the rest of the patch, at the high
end of that axis, is padding: image `PAD_VALUE` (0.0), label `PAD_LABEL` (-1).
So every item has the full patch size and batches stack; ``item["extent"]`` and
``label >= 0`` say which voxels are real. Leave the padding out of a loss (e.g.
the semantic target ``torch.where(label < 0, -1, (label > 0).long())`` with
``CrossEntropyLoss(ignore_index=-1)``), or choose a patch no deeper than the block.

Sampling:

- ``"random"``: `patches_per_volume` patches per volume per epoch. Patch ``j``
  of volume ``k`` has its origin drawn from a generator seeded by
  ``(seed, epoch, k, j)``, uniformly over every origin whose box lies inside one
  block of the split (and inside the volume), so an index gives the same patch in
  any process and epoch ``e`` gives the same patches in every run; `set_epoch`
  draws new ones.
- ``"grid"``: tiles covering every block of the split, neighbours sharing
  `overlap` voxels; the last tile of a row is moved back to end at the block's
  (or volume's) end, so it may overlap its neighbour more. Order: volume, block,
  z, y, x.

Transforms: artefact transforms (`synthpack.artefacts`, 3D-capable) act on the
patch's voxels of volume (before padding) as a float32 NumPy array, with a
generator seeded by ``(seed, epoch, volume, z, y, x)`` of the origin; other
callables follow in order as ``item = transform(item)`` (MONAI dictionary
transforms such as ``RandFlipd(keys=["image", "label"])``). Radial artefacts
(rings, cupping) and ``CTSimulation`` centre on the patch, not on the scanner's
axis: put those in the packs' post-processing instead.

Reading: a patch reads only its box (`synthpack.io.read_box`) from the memory-mapped
TIFF packs, the Zarr packs' chunks it crosses, or a scan held in shared memory,
through the slice dataset's `open_volumes`; the volumes are opened once per process.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from typing import Any

import numpy as np
import torch
from torch.utils.data import Dataset

from .._shared.seeds import generator
from ..errors import SynthpackInputError
from ..io import read_box
from ..scan.core import Scan
from ..scan.split import check_val_fraction, split_slices
from .base import EpochSeeded, SliceDataset, check_axis, check_seed
from .real import ScanSliceDataset
from .transforms import SliceTransforms

__all__ = ["PAD_LABEL", "PAD_VALUE", "PatchDataset"]

#: Label of padding voxels (outside the volume or the patch's split block).
PAD_LABEL = -1
#: Image value of padding voxels.
PAD_VALUE = 0.0

_SAMPLINGS = ("random", "grid")
_SPLITS = ("train", "val", "test", "all")


class PatchDataset(Dataset, EpochSeeded):
    """3D patches of the volumes of a slice dataset or a real scan, split along `axis` as in the paper.

    Parameters
    ----------
    volumes : SliceDataset, Scan, str or (path, path)
        Where the volumes come from: a `SyntheticParticlePackDataset` (its packs,
        built into its cache on first use; its ``postprocess`` and ``format``
        apply) or a `ScanSliceDataset`, of which only the volumes are used (not
        its split, axis or seed; it must have no transform: give that here); or
        what `ScanSliceDataset` takes alone: a `~synthpack.scan.core.Scan`, a built-in
        sample name (``"large"``, ``"small"``: the sample scan itself), or a
        ``(tomogram_path, labels_path)`` pair.
    patch_size : sequence of 3 int
        ``(D, H, W)``: the patch's extent along the volumes' (Z, Y, X), in voxels.
    sampling : {"random", "grid"}
        Random patches (`patches_per_volume` per volume per epoch) or a grid of
        tiles covering the split.
    patches_per_volume : int
        Random patches per volume per epoch (``"random"`` only).
    overlap : int or sequence of 3 int
        Voxels shared by neighbouring grid tiles along (Z, Y, X), each in
        ``[0, patch size)`` (``"grid"`` only).
    split : {"train", "val", "test", "all"}
        The part of each volume's slices along `axis` (`synthpack.scan.split.split_slices`).
    axis : {0, 1, 2}
        The axis the split runs along; 0 = along the tube.
    val_fraction : float
        Fraction of the slices in the val blocks, in ``[0, 0.8)``; the default 0
        is the paper's split, in which ``"train"`` is every slice outside the test
        block (as in the slice datasets) and ``"val"`` is empty.
    seed : int
        Base seed of the random origins and the artefact transforms.
    transform : callable, artefact transform or list of them, optional
        Artefact transforms first (on the patch's float32 voxels), then callables
        ``item = transform(item)``; see `synthpack.dataset.patches`.

    Notes
    -----
    Packs are built (or checked) on the first ``len()`` or item in the main
    process, as in `SyntheticParticlePackDataset`; DataLoader workers only read.
    """

    def __init__(
        self,
        volumes: SliceDataset | Scan | str | Sequence,
        patch_size: Sequence[int],
        sampling: str = "random",
        patches_per_volume: int = 16,
        overlap: int | Sequence[int] = 0,
        split: str = "train",
        axis: int = 0,
        val_fraction: float = 0.0,
        seed: int = 0,
        transform: Any = None,
    ) -> None:
        self.patch_size = _three_ints(patch_size, "patch_size", minimum=1)
        if sampling not in _SAMPLINGS:
            raise SynthpackInputError(f"sampling must be 'random' or 'grid', got {sampling!r}")
        if isinstance(patches_per_volume, bool) or not isinstance(patches_per_volume, int) or patches_per_volume < 1:
            raise SynthpackInputError(f"patches_per_volume must be a positive integer, got {patches_per_volume!r}")
        self.overlap = _three_ints((overlap,) * 3 if isinstance(overlap, (int, np.integer)) else overlap,
                                   "overlap", minimum=0)
        if any(o >= p for o, p in zip(self.overlap, self.patch_size)):
            raise SynthpackInputError(
                f"overlap {self.overlap} must be smaller than patch_size {self.patch_size} along every axis"
            )
        if split not in _SPLITS:
            raise SynthpackInputError(f"split must be one of {', '.join(_SPLITS)}; got {split!r}")
        val_fraction = check_val_fraction(val_fraction)
        if split == "val" and not val_fraction:
            raise SynthpackInputError("split='val' needs val_fraction > 0 (the paper's split has no val slices)")
        self.sampling = sampling
        self.patches_per_volume = patches_per_volume
        self.split = split
        self.axis = check_axis(axis)
        self.val_fraction = val_fraction
        self.seed = check_seed(seed, "seed")
        self.transform = transform
        self._transforms = SliceTransforms(transform, form="item = transform(item)")
        self.volumes = _slice_dataset(volumes)
        self._init_epoch()
        self._shapes: list[tuple[int, ...]] | None = None
        self._blocks: list[np.ndarray] = []  # per volume: (R, 2) int64 [start, stop) along axis
        self._grid: np.ndarray | None = None  # (M, 4) int64: volume, z, y, x

    # -- index -------------------------------------------------------------------------
    def _ready(self) -> None:
        """Index the split's blocks (and the grid) once the volumes' shapes are known."""
        if self._shapes is not None:
            return
        shapes = self.volumes.volume_shapes()
        blocks = []
        for k, shape in enumerate(shapes):
            runs = _runs(split_slices(shape[self.axis], self.split, self.val_fraction))
            if not len(runs):
                raise SynthpackInputError(
                    f"volume {k} of shape {shape} has no {self.split!r} slices along axis {self.axis} "
                    f"with val_fraction={self.val_fraction:g}: raise val_fraction or use another split"
                )
            blocks.append(runs)
        self._blocks = blocks
        if self.sampling == "grid":
            self._grid = np.concatenate([self._volume_grid(k, shape) for k, shape in enumerate(shapes)])
        self._shapes = shapes

    def _volume_grid(self, k: int, shape: tuple[int, ...]) -> np.ndarray:
        """Grid origins (M, 4) int64 ``(k, z, y, x)`` tiling the split's blocks of volume `k`."""
        rows = []
        for start, stop in self._blocks[k]:
            bounds = [(0, n) for n in shape]
            bounds[self.axis] = (start, stop)
            starts = [_tile_starts(a, b, p, o) for (a, b), p, o in zip(bounds, self.patch_size, self.overlap)]
            origins = np.stack(np.meshgrid(*starts, indexing="ij"), axis=-1).reshape(-1, 3)
            rows.append(np.column_stack([np.full(len(origins), k), origins]))
        return np.concatenate(rows).astype(np.int64)

    def __len__(self) -> int:
        self._ready()
        if self._grid is not None:
            return len(self._grid)
        return len(self._shapes) * self.patches_per_volume  # type: ignore[arg-type]

    def _locate(self, index: int) -> tuple[int, np.ndarray]:
        """``(volume, origin)`` of item `index`; origin int64 (3,) ``(z, y, x)``."""
        n = len(self)
        if not -n <= index < n:
            raise IndexError(f"index {index} is out of range for a dataset of {n} patches")
        index %= n
        if self._grid is not None:
            return int(self._grid[index, 0]), self._grid[index, 1:].copy()
        k, j = divmod(index, self.patches_per_volume)
        rng = generator(self.seed, "patch_origins", self.epoch, k, j)
        shape, blocks, size = self._shapes[k], self._blocks[k], self.patch_size  # type: ignore[index]
        origin = np.zeros(3, dtype=np.int64)
        for axis in range(3):
            if axis == self.axis:  # uniform over the origins inside one block, all blocks together
                positions = np.maximum(blocks[:, 1] - blocks[:, 0] - size[axis] + 1, 1)
                draw = int(rng.integers(positions.sum()))
                block = int(np.searchsorted(np.cumsum(positions), draw, side="right"))
                origin[axis] = blocks[block, 0] + draw - (positions[:block].sum())
            else:
                origin[axis] = rng.integers(max(shape[axis] - size[axis], 0) + 1)
        return k, origin

    def _extent(self, k: int, origin: np.ndarray) -> np.ndarray:
        """Voxels of volume in the patch at `origin` of volume `k`, int64 (3,): the rest is padding."""
        stops = np.array(self._shapes[k], dtype=np.int64)  # type: ignore[index]
        blocks = self._blocks[k]
        block = int(np.searchsorted(blocks[:, 0], origin[self.axis], side="right")) - 1
        stops[self.axis] = blocks[block, 1]
        return np.minimum(np.array(self.patch_size), stops - origin)

    # -- items -------------------------------------------------------------------------
    def __getitem__(self, index: int) -> dict[str, Any]:
        k, origin = self._locate(index)
        extent = self._extent(k, origin)
        images, labels = self.volumes.open_volumes(k)
        image = read_box(images, origin, extent).astype(np.float32)
        image = self._transforms.apply_artefacts(image, self.seed, self.epoch, k, *origin)
        label = read_box(labels, origin, extent).astype(np.int64)
        item: dict[str, Any] = {
            "image": torch.from_numpy(_pad(image, self.patch_size, PAD_VALUE))[None],
            "label": torch.from_numpy(_pad(label, self.patch_size, PAD_LABEL))[None],
            "source": self.volumes.describe_source(),
            "volume": k,
            "origin": torch.from_numpy(origin),
            "extent": torch.from_numpy(extent),
        }
        for transform in self._transforms.callables:
            item = transform(item)
        return item

    def blocks(self, k: int = 0) -> np.ndarray:
        """The split's blocks along `axis` in volume `k`: int64 (R, 2), half-open ``[start, stop)``."""
        self._ready()
        return self._blocks[k].copy()

    def __repr__(self) -> str:
        body = [f"Volumes: {self.volumes.describe_source()}"]
        if self._shapes is not None:
            body += [f"Number of datapoints: {len(self)}", f"Shapes: {self._shapes}"]
        body += [f"Patch size: {self.patch_size}", f"Sampling: {self.sampling}"]
        body.append(f"Patches per volume: {self.patches_per_volume}" if self.sampling == "random"
                    else f"Overlap: {self.overlap}")
        body += [f"Split: {self.split}", f"Axis: {self.axis}", f"Val fraction: {self.val_fraction:g}",
                 f"Seed: {self.seed}"]
        if self.transform is not None:
            body += ["Transform:", *("    " + line for line in repr(self.transform).splitlines())]
        return "\n".join([f"Dataset {type(self).__name__}", *("    " + line for line in body)])


def _slice_dataset(volumes: Any) -> SliceDataset:
    """`volumes` as a slice dataset whose volumes the patches read."""
    if isinstance(volumes, SliceDataset):
        if volumes.transform is not None:
            raise SynthpackInputError(
                "the slice dataset given as volumes has a transform, which patches do not use: "
                "give the transform to PatchDataset instead"
            )
        return volumes
    if isinstance(volumes, (tuple, list)) and len(volumes) == 2:
        return ScanSliceDataset(volumes[0], labels=volumes[1], split="all")
    if isinstance(volumes, (Scan, str, os.PathLike)):
        return ScanSliceDataset(volumes, split="all")
    raise SynthpackInputError(
        f"volumes {volumes!r} is not understood: give a SyntheticParticlePackDataset or ScanSliceDataset, "
        "a Scan, a sample name or a (tomogram_path, labels_path) pair"
    )


def _three_ints(values: Any, what: str, minimum: int) -> tuple[int, int, int]:
    """`values` as three ints >= `minimum` (along Z, Y, X); raise otherwise."""
    if (isinstance(values, (str, bytes)) or not isinstance(values, Sequence) or len(values) != 3
            or any(isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < minimum for v in values)):
        raise SynthpackInputError(f"{what} must be three integers >= {minimum} along (Z, Y, X), got {values!r}")
    return tuple(int(v) for v in values)  # type: ignore[return-value]


def _runs(indices: np.ndarray) -> np.ndarray:
    """Contiguous runs of sorted slice `indices` as (R, 2) int64 half-open ``[start, stop)``."""
    if not indices.size:
        return np.zeros((0, 2), dtype=np.int64)
    breaks = np.flatnonzero(np.diff(indices) != 1) + 1
    starts = indices[np.concatenate([[0], breaks])]
    stops = indices[np.concatenate([breaks - 1, [indices.size - 1]])] + 1
    return np.column_stack([starts, stops]).astype(np.int64)


def _tile_starts(start: int, stop: int, size: int, overlap: int) -> np.ndarray:
    """Starts of tiles of `size` covering ``[start, stop)``, `overlap` apart; the last ends at `stop`.

    A range no longer than `size` gets one tile at `start` (padded beyond `stop`).
    """
    if stop - start <= size:
        return np.array([start], dtype=np.int64)
    return np.append(np.arange(start, stop - size, size - overlap), stop - size).astype(np.int64)


def _pad(array: np.ndarray, size: Sequence[int], value: float) -> np.ndarray:
    """`array` padded at the high end of each axis to `size` with `value` (as is when it fits)."""
    missing = [(0, n - m) for n, m in zip(size, array.shape)]
    if not any(after for _, after in missing):
        return np.ascontiguousarray(array)
    return np.pad(array, missing, constant_values=value)
