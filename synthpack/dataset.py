"""PyTorch datasets of 2D slices of synthetic packs and of real scans (paper section 4.1).

`SyntheticParticlePackDataset` builds synthetic packs from a source (a built-in
sample scan, a labelled scan on disk or a particle library), caches them under a
root directory and serves their slices along one axis; `ScanSliceDataset` serves
the slices of a real labelled scan the same way, so that real and synthetic data
concatenate with `torch.utils.data.ConcatDataset`.

Item format (both datasets), following torchvision's detection conventions::

    image, target = dataset[i]
    image                   tv_tensors.Image, float32, shape (1, H, W)
    target["masks"]         tv_tensors.Mask, bool, shape (N, H, W), one per instance in the slice
                            (with dense_masks=False: target["instance_map"], Mask, int32,
                            (H, W), instance j as j + 1; expand_masks(target) gives "masks")
    target["boxes"]         tv_tensors.BoundingBoxes, float32, (N, 4), XYXY, canvas_size (H, W)
    target["labels"]        int64, (N,), class ids: all 1 (particle)
    target["instance_ids"]  int64, (N,), the instances' values in the label volume
    target["semantic"]      tv_tensors.Mask, uint8, (H, W): 1 = particle, 0 = pore, tube, outside
    target["pack"]          int, pack index (0 for a real scan)
    target["slice"]         int, slice index along `axis` in the volume

Slicing along axis 0 gives (H, W) = (Y, X), along axis 1 (Z, X), along axis 2
(Z, Y). Boxes are in pixel-edge coordinates: a mask covering columns 3..7 has
``x1 = 3, x2 = 8`` (torchvision.ops.masks_to_boxes gives the inclusive ``x2 = 7``),
so that flips and crops by torchvision v2 transforms keep boxes and masks
consistent. Instances are ordered by increasing instance id.

Split: the slices of each volume along `axis` are split with
`synthpack.split.split_slices` (the central 20% are ``"test"``, the rest
``"train"``), so no test slice has a near-identical neighbour in the training set.

Transform order in ``__getitem__``:

1. read the image and label slices (only those slices: from memory-mapped TIFF files,
   or only the chunks of a Zarr pack that the slice crosses);
2. apply the artefact transforms (`synthpack.artefacts`) to the float32 slice as a
   NumPy array, with a generator seeded by ``(seed, epoch, pack, axis, slice)``:
   fresh noise every epoch (see ``set_epoch``), the same noise for the same epoch
   in any process, with any number of DataLoader workers;
3. build the image tensor and target dict;
4. apply the other transforms as ``image, target = transform(image, target)``
   (torchvision v2 transforms and any callable of that form), in order.

DataLoader workers: datasets hold paths and small index arrays only; every
process opens the volumes (memory maps) on its first item and keeps them, so
nothing big is pickled and ``persistent_workers=True`` works. Inside a worker
the image, masks and semantic map are written straight into new shared memory,
which the DataLoader hands to the main process without a copy (only the pages
that hold pixels of an instance are touched). Use `collate_fn` for
detection-style batches (the number of instances varies per slice).
"""

from __future__ import annotations

import hashlib
import json
import logging
import math
import os
import shutil
from abc import ABC, abstractmethod
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import tifffile
import torch
from scipy import ndimage
from torch.utils.data import Dataset, get_worker_info
from torchvision import tv_tensors

from . import __version__
from ._atomic import atomic_file
from .artefacts import Compose as ArtefactCompose
from .artefacts import Transform as ArtefactTransform
from .config import PackConfig, load_config
from .errors import SynthpackInputError
from .generate import generate_packs, pack_name
from .pack import Pack, is_complete_pack, open_pack
from .samples import SAMPLE_NAMES
from .scan import Scan
from .split import SPLITS, split_slices

logger = logging.getLogger(__name__)

__all__ = [
    "SyntheticParticlePackDataset",
    "ScanSliceDataset",
    "instance_target",
    "expand_masks",
    "collate_fn",
    "collate_stacked",
]

#: Seed of the built-in sample scans used as a source.
SAMPLE_SEED = 0
_AXES = (0, 1, 2)

Item = tuple[tv_tensors.Image, dict[str, Any]]


def _zeros(shape: tuple[int, ...], dtype: torch.dtype, shared: bool) -> torch.Tensor:
    """A tensor of zeros; with `shared`, in new shared memory.

    A DataLoader worker hands a tensor to the main process through shared memory;
    a tensor already there goes without a copy (torch's ``default_collate`` does
    the same). New shared memory is a new file extended by ``ftruncate``, which
    reads as zeros, and ``np.zeros`` maps zero pages: either way only the pages
    written later cost anything.
    """
    if not shared:
        return torch.from_numpy(np.zeros(shape, dtype=torch.empty(0, dtype=dtype).numpy().dtype))
    storage = torch.UntypedStorage._new_shared(math.prod(shape) * dtype.itemsize)
    return torch.empty(0, dtype=dtype).set_(storage, 0, shape)


def _image(slice_: np.ndarray, shared: bool) -> tv_tensors.Image:
    """A (1, H, W) float32 image tensor holding a copy of `slice_`."""
    tensor = _zeros((1, *slice_.shape), torch.float32, shared)
    np.copyto(tensor.numpy()[0], slice_, casting="unsafe")
    return tv_tensors.Image(tensor)


def instance_target(labels: np.ndarray, *, shared: bool = False, dense_masks: bool = True) -> dict[str, Any]:
    """Detection target of one labelled slice.

    Parameters
    ----------
    labels : ndarray of int, shape (H, W)
        Instance labels, 0 = background.
    shared : bool
        Put masks and semantic map in shared memory (what a DataLoader worker
        sends without a copy).
    dense_masks : bool
        True: ``masks`` holds one (H, W) plane per instance. False: instead
        ``instance_map`` (Mask, int32, (H, W)) holds instance ``j`` as value
        ``j + 1``; it is N times smaller to send from a DataLoader worker, and
        :func:`expand_masks` makes the planes where they are needed (e.g. on the GPU).

    Returns
    -------
    dict
        ``masks`` (Mask, bool, (N, H, W)) or ``instance_map``, ``boxes``
        (BoundingBoxes, float32, (N, 4), XYXY pixel edges), ``labels`` (int64
        ones, (N,)), ``instance_ids`` (int64, (N,), increasing) and ``semantic``
        (Mask, uint8, (H, W)).
    """
    labels = np.asarray(labels)
    counts = np.bincount(labels.ravel())
    counts[0] = 0
    ids = np.flatnonzero(counts)
    # compact labels 1..N, so masks and boxes cost O(H*W) whatever the largest label is
    lookup = np.zeros(counts.size, dtype=np.int32)
    lookup[ids] = np.arange(1, ids.size + 1, dtype=np.int32)
    if dense_masks:
        compact = lookup[labels]
        masks = _zeros((ids.size, *labels.shape), torch.bool, shared)
        planes = masks.numpy()
    else:
        instance_map = _zeros(labels.shape, torch.int32, shared)
        compact = np.take(lookup, labels, out=instance_map.numpy(), mode="clip")  # in range: no check
    semantic = _zeros(labels.shape, torch.uint8, shared)
    np.greater(compact, 0, out=semantic.numpy().view(bool))
    boxes = np.zeros((ids.size, 4), dtype=np.float32)
    for j, (rows, cols) in enumerate(ndimage.find_objects(compact)):
        if dense_masks:
            np.equal(compact[rows, cols], j + 1, out=planes[j, rows, cols])
        boxes[j] = (cols.start, rows.start, cols.stop, rows.stop)
    return {
        ("masks" if dense_masks else "instance_map"): tv_tensors.Mask(masks if dense_masks else instance_map),
        "boxes": tv_tensors.BoundingBoxes(torch.from_numpy(boxes), format="XYXY", canvas_size=labels.shape),
        "labels": torch.ones(ids.size, dtype=torch.int64),
        "instance_ids": torch.from_numpy(ids.astype(np.int64)),
        "semantic": tv_tensors.Mask(semantic),
    }


def expand_masks(target: dict[str, Any]) -> dict[str, Any]:
    """Replace a compact ``instance_map`` (``dense_masks=False``) by the ``masks`` planes.

    Works on any device: ``masks[j] = instance_map == j + 1``, bool, (N, H, W).
    Returns a new dict; a target that already has ``masks`` is returned unchanged.
    """
    if "instance_map" not in target:
        return target
    expanded = {key: value for key, value in target.items() if key != "instance_map"}
    instance_map = target["instance_map"].as_subclass(torch.Tensor)
    values = torch.arange(1, len(target["labels"]) + 1, device=instance_map.device, dtype=instance_map.dtype)
    expanded["masks"] = tv_tensors.Mask(instance_map[None] == values[:, None, None])
    return expanded


def collate_fn(batch: Sequence[Item]) -> tuple[list[tv_tensors.Image], list[dict[str, Any]]]:
    """DataLoader collate for detection batches: ``[(image, target), ...] -> (images, targets)``.

    Images and targets stay lists (instances per slice vary), as torchvision's
    detection models expect.
    """
    return [image for image, _ in batch], [target for _, target in batch]


def _stack(tensors: Sequence[torch.Tensor]) -> torch.Tensor:
    """``torch.stack`` of same-shape tensors, in a DataLoader worker straight into new shared memory.

    A tensor the worker returns in shared memory crosses to the main process
    without another copy (what torch's ``default_collate`` does too).
    """
    first = tensors[0]
    out = _zeros((len(tensors), *first.shape), first.dtype, get_worker_info() is not None)
    return torch.stack([tensor.as_subclass(torch.Tensor) for tensor in tensors], out=out)


def collate_stacked(batch: Sequence[Item]) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
    """DataLoader collate for compact targets (``dense_masks=False``): five tensors per batch.

    Every slice of the batch must have the same (H, W). Per-instance values are
    concatenated with their batch index (the layout ultralytics uses for its own
    batches), so a batch crosses from a worker to the main process as a handful
    of tensors instead of several per item: each tensor costs new shared memory.

    Returns
    -------
    images : Tensor, float32, (B, 1, H, W)
    targets : dict
        ``instance_map`` (B, H, W) int32 (the semantic mask is ``instance_map > 0``);
        ``boxes`` (M, 4) float32 XYXY for the M instances of the batch;
        ``instances`` (M, 3) int64 columns ``batch_index, label, instance_id``;
        ``index`` (B, 2) int64 columns ``pack, slice``.
    """
    targets = [target for _, target in batch]
    if any("instance_map" not in target for target in targets):
        raise SynthpackInputError("collate_stacked needs dense_masks=False datasets; use collate_fn otherwise")
    shapes = {tuple(image.shape) for image, _ in batch}
    if len(shapes) != 1:
        raise SynthpackInputError(
            f"collate_stacked needs slices of one shape, got {sorted(shapes)}: use collate_fn for mixed sizes"
        )
    counts = torch.tensor([len(target["labels"]) for target in targets])
    instances = torch.stack([
        torch.repeat_interleave(torch.arange(len(batch)), counts),
        torch.cat([t["labels"] for t in targets]),
        torch.cat([t["instance_ids"] for t in targets]),
    ], dim=1)
    return _stack([image for image, _ in batch]), {
        "instance_map": _stack([t["instance_map"] for t in targets]),
        "boxes": torch.cat([t["boxes"].as_subclass(torch.Tensor) for t in targets]),
        "instances": instances,
        "index": torch.tensor([[t["pack"], t["slice"]] for t in targets], dtype=torch.int64),
    }


def _split_transforms(transform: Any) -> tuple[list, list]:
    """Artefact transforms and ``(image, target)`` callables of `transform`, in order."""
    if transform is None:
        return [], []
    entries = list(transform) if isinstance(transform, (list, tuple)) else [transform]
    artefacts: list = []
    callables: list = []
    for entry in entries:
        if isinstance(entry, (ArtefactTransform, ArtefactCompose)):
            if callables:
                raise SynthpackInputError(
                    f"artefact transform {entry!r} comes after an (image, target) transform: artefacts "
                    "act on the raw slice, so list them first, e.g. transform=[GaussianNoise(std=0.05), "
                    "v2.RandomHorizontalFlip()]"
                )
            artefacts.append(entry)
        elif callable(entry):
            callables.append(entry)
        else:
            raise SynthpackInputError(
                f"transform {entry!r} is neither a synthpack.artefacts transform nor a callable "
                "image, target = transform(image, target): pass one of those, or a list of them"
            )
    return artefacts, callables


def _check_axis(axis: Any) -> int:
    if isinstance(axis, bool) or axis not in _AXES:
        raise SynthpackInputError(f"axis must be 0, 1 or 2 (the slicing axis of the (Z, Y, X) volume), got {axis!r}")
    return int(axis)


def _check_seed(seed: Any, what: str) -> int:
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise SynthpackInputError(f"{what} must be a non-negative integer, got {seed!r}")
    return int(seed)


class _SliceDataset(Dataset, ABC):
    """Slices of a list of labelled volumes along one axis, split as in the paper.

    Subclasses call `_index` with the volume shapes once they are known and
    implement `_volumes` (the image and label volumes of volume `k`, opened in the
    calling process) and `_ready` (make sure `_index` ran).
    """

    def __init__(self, split: str, axis: int, seed: int, transform: Any, dense_masks: bool = True) -> None:
        if split not in SPLITS:
            raise SynthpackInputError(f"split must be 'train', 'test' or 'all', got {split!r}")
        self.split = split
        self.axis = _check_axis(axis)
        self.seed = _check_seed(seed, "seed")
        self.transform = transform
        self.dense_masks = bool(dense_masks)
        self._artefacts, self._callables = _split_transforms(transform)
        # in shared memory, so set_epoch reaches DataLoader workers that already run
        self._epoch = torch.zeros((), dtype=torch.int64).share_memory_()
        self._volume_index: np.ndarray | None = None
        self._slice_index: np.ndarray | None = None
        self._n_slices: list[int] = []

    # -- epoch ---------------------------------------------------------------------
    @property
    def epoch(self) -> int:
        """The epoch that seeds the artefact transforms (0 until `set_epoch`)."""
        return int(self._epoch)

    def set_epoch(self, epoch: int) -> None:
        """Set the epoch of the artefact transforms' seeds: call it before iterating a DataLoader.

        The value lives in shared memory, so persistent DataLoader workers see it.
        """
        self._epoch.fill_(_check_seed(epoch, "epoch"))

    # -- indexing ------------------------------------------------------------------
    def _index(self, shapes: Sequence[tuple[int, ...]]) -> None:
        volumes, slices = [], []
        for k, shape in enumerate(shapes):
            chosen = split_slices(shape[self.axis], self.split)
            volumes.append(np.full(chosen.size, k, dtype=np.int64))
            slices.append(chosen)
        self._n_slices = [shape[self.axis] for shape in shapes]
        self._volume_index = np.concatenate(volumes)
        self._slice_index = np.concatenate(slices)

    @abstractmethod
    def _ready(self) -> None:
        """Make sure `_index` ran (build or check what the dataset reads)."""

    @abstractmethod
    def _volumes(self, k: int) -> tuple[Any, Any]:
        """``(image volume, label volume)`` of volume `k`, opened in the calling process."""

    def slices(self, k: int = 0) -> np.ndarray:
        """Slice indices (int64, sorted) of volume `k` in this dataset."""
        self._ready()
        return self._slice_index[self._volume_index == k]  # type: ignore[index]

    def __len__(self) -> int:
        self._ready()
        return int(self._slice_index.size)  # type: ignore[union-attr]

    def __getitem__(self, index: int) -> Item:
        self._ready()
        n = self._slice_index.size  # type: ignore[union-attr]
        if not -n <= index < n:
            raise IndexError(f"index {index} is out of range for a dataset of {n} slices")
        k, s = int(self._volume_index[index]), int(self._slice_index[index])  # type: ignore[index]
        image_volume, label_volume = self._volumes(k)
        where = (slice(None),) * self.axis + (s,)
        image = np.asarray(image_volume[where])
        if self._artefacts:
            rng = np.random.default_rng(np.random.SeedSequence([self.seed, self.epoch, k, self.axis, s]))
            for artefact in self._artefacts:
                image = artefact(image, rng)
        # dense masks go to the main process fastest from shared memory; compact targets
        # are batched by `collate_stacked`, which makes a few large tensors per batch
        shared = self.dense_masks and get_worker_info() is not None
        target = instance_target(np.asarray(label_volume[where]), shared=shared, dense_masks=self.dense_masks)
        target["pack"], target["slice"] = k, s
        sample: Item = (_image(image, shared), target)
        for transform in self._callables:
            sample = transform(*sample)
        return sample

    def __getstate__(self) -> dict:
        state = dict(self.__dict__)
        state["_opened"], state["_opened_pid"] = {}, None  # memory maps stay in their process
        return state

    def _opened_cache(self) -> dict:
        """Per-process cache of opened volumes (dropped in a new process)."""
        if self.__dict__.get("_opened_pid") != os.getpid():
            self._opened, self._opened_pid = {}, os.getpid()
        return self._opened

    # -- repr ------------------------------------------------------------------------
    @abstractmethod
    def _repr_lines(self) -> list[str]:
        """The dataset-specific lines of ``repr``."""

    def __repr__(self) -> str:
        body = self._repr_lines()
        if self._slice_index is not None:
            body.insert(0, f"Number of datapoints: {self._slice_index.size}")
        body += [f"Split: {self.split}", f"Axis: {self.axis}", f"Seed: {self.seed}"]
        if self.transform is not None:
            body += ["Transform:", *("    " + line for line in repr(self.transform).splitlines())]
        return "\n".join([f"Dataset {type(self).__name__}", *("    " + line for line in body)])


# --------------------------------------------------------------------------- #
# Synthetic packs
# --------------------------------------------------------------------------- #


@dataclass(frozen=True)
class _Source:
    """Where the grains come from: a built-in sample, a labelled scan on disk, or a library."""

    kind: str  # "sample", "scan" or "library"
    name: str = ""
    paths: tuple[Path, ...] = ()

    @classmethod
    def parse(cls, source: Any) -> _Source:
        if isinstance(source, str) and source in SAMPLE_NAMES:
            return cls("sample", name=source)
        if isinstance(source, (tuple, list)) and len(source) == 2:
            paths = tuple(Path(p).expanduser().resolve() for p in source)
            missing = [str(p) for p in paths if not p.exists()]
            if missing:
                raise SynthpackInputError(f"source scan file(s) {', '.join(missing)} do not exist")
            return cls("scan", paths=paths)
        if isinstance(source, (str, os.PathLike)):
            path = Path(source).expanduser().resolve()
            if (path / "library.json").is_file():
                return cls("library", paths=(path,))
            raise SynthpackInputError(
                f"source {str(source)!r} is neither a sample name ({', '.join(SAMPLE_NAMES)}) nor a "
                "particle library directory (with library.json): give one of those, or a "
                "(tomogram_path, labels_path) pair"
            )
        raise SynthpackInputError(
            f"source {source!r} is not understood: give a sample name ({', '.join(SAMPLE_NAMES)}), "
            "a (tomogram_path, labels_path) pair or a particle library directory"
        )

    def identity(self) -> dict:
        """What the cache key depends on: sample name and seed, file sizes and times, or library content."""
        if self.kind == "sample":
            return {"sample": self.name, "seed": SAMPLE_SEED}
        if self.kind == "scan":
            return {"scan": [_file_identity(path) for path in self.paths]}
        return {"library_json_sha256": hashlib.sha256((self.paths[0] / "library.json").read_bytes()).hexdigest()}

    def describe(self) -> str:
        if self.kind == "sample":
            return f"sample:{self.name}"
        if self.kind == "scan":
            return f"tomogram={self.paths[0]}; labels={self.paths[1]}"
        return f"library:{self.paths[0]}"


def _file_identity(path: Path) -> list:
    """``[path, [[relative file, size, mtime_ns], ...]]`` of a file or of every file of a folder."""
    files = sorted(p for p in path.rglob("*") if p.is_file()) if path.is_dir() else [path]
    return [str(path), [[str(f.relative_to(path)) if path.is_dir() else f.name, f.stat().st_size,
                         f.stat().st_mtime_ns] for f in files]]


def _digest(data: dict) -> str:
    return hashlib.sha256(json.dumps(data, sort_keys=True).encode()).hexdigest()[:16]


def _as_config(config: PackConfig | dict | str | os.PathLike | None) -> PackConfig:
    if config is None or isinstance(config, PackConfig):
        return config or PackConfig()
    if isinstance(config, dict):
        return PackConfig.from_dict(config)
    if isinstance(config, (str, os.PathLike)):
        return load_config(config)
    raise SynthpackInputError(f"config must be a PackConfig, a dict or a YAML file path, got {type(config).__name__}")


def _usable_pack_shape(path: Path, config: dict) -> tuple[int, int, int] | None:
    """Shape of the cached pack at `path`, or None when it is missing, incomplete, corrupt or stale."""
    if not path.exists():
        return None
    problem = None
    if not is_complete_pack(path):
        problem = "incomplete"
    else:
        try:
            pack = open_pack(path)
        except SynthpackInputError as error:
            problem = str(error)
        else:
            if pack.shape != tuple(pack.manifest.get("shape", ())):
                problem = f"volumes of shape {pack.shape}, manifest says {pack.manifest.get('shape')}"
            elif pack.manifest.get("config") != config:
                problem = "built with another config"
            elif pack.labels.dtype.kind not in "iu":
                problem = f"labels of dtype {pack.labels.dtype}"
    if problem is not None:
        logger.warning("cached pack %s is unusable (%s): it will be rebuilt", path, problem)
        return None
    return pack.shape


class SyntheticParticlePackDataset(_SliceDataset):
    """Slices of synthetic particle packs, built on demand and cached on disk.

    Parameters
    ----------
    root : path-like
        Cache directory. Packs go to ``root/packs-<key>/pack_0000, ...`` and a
        library built from a scan to ``root/library-<key>/library``; each
        ``<key>`` folder has a ``key.json`` recording what its key covers.
    source : str, (path, path) or path-like
        ``"large"`` or ``"small"`` (a built-in sample scan, seed 0), a
        ``(tomogram_path, labels_path)`` pair of a labelled scan (read with
        `synthpack.io.read_scan`), or a particle library directory (written by
        `ParticleLibrary.save`; then the config's ``library`` section is unused).
        A string equal to a sample name means the sample; pass a Path for a
        library folder of that name.
    n_packs : int
        Number of packs; pack ``k`` is the same whatever `n_packs` is, so
        raising it builds only the new packs.
    split : {"train", "test", "all"}
        ``"test"``: the central 20% of each pack's slices along `axis`;
        ``"train"``: the rest.
    axis : {0, 1, 2}
        Slicing axis of the (Z, Y, X) packs; 0 = along the tube.
    seed : int, optional
        Run seed of the packs (replaces ``config.seed``; default: ``config.seed``)
        and base seed of the artefact transforms.
    config : PackConfig, dict or path-like, optional
        Pack configuration (a YAML file path is read with `load_config`);
        default ``PackConfig()``.
    transform : callable, artefact transform or list of them, optional
        See the module docstring for the order: artefact transforms act on the
        NumPy slice with per-item, per-epoch seeds; other callables are called as
        ``image, target = transform(image, target)``.
    postprocess : bool
        True: the post-processed tomogram (noise, blur as configured); False: the
        clean tomogram before post-processing (the paper's "without
        post-processing" arm). Both come from the same cached packs.
    build : bool
        Build (or check) the packs now instead of on first use.
    progress : bool
        Show progress bars while building.
    dense_masks : bool
        True: ``target["masks"]`` (N, H, W). False: the compact
        ``target["instance_map"]`` (H, W) instead, N times cheaper to send from
        DataLoader workers; :func:`expand_masks` turns it into ``masks``.
    format : {"tiff", "zarr"}
        Format of the cached packs. Zarr packs are built chunk by chunk, for
        volumes larger than memory, and an item reads only the Zarr chunks its
        slice crosses; the voxels are the same in both formats.

    Notes
    -----
    When packs are built: on `build` (or ``build=True``) or on the first
    ``len()`` / item access in the main process, which is before any DataLoader
    worker asks for an item (a DataLoader calls ``len()`` in the main process
    before it hands out indices). DataLoader workers never build: they only read
    the cache, and raise if it is missing (call ``dataset.build()`` first when
    you use a sampler that never calls ``len()``). Two separate programs building
    the same cache at once do not corrupt it (packs are written atomically) but
    may both do the work.

    The cache key is a hash of the full config (seed included), the source's
    identity (sample name and seed; the scan files' paths, sizes and modification
    times; or the hash of the library's ``library.json``), the pack format and
    the synthpack version, so a changed config or source never returns stale
    packs. A cached pack that is incomplete, corrupt (a TIFF that no longer
    memory-maps, e.g. truncated), of the wrong shape or of another config is
    rebuilt, never returned.
    """

    def __init__(
        self,
        root: str | os.PathLike,
        source: str | os.PathLike | tuple,
        n_packs: int = 1,
        split: str = "train",
        axis: int = 0,
        seed: int | None = None,
        config: PackConfig | dict | str | os.PathLike | None = None,
        transform: Any = None,
        postprocess: bool = True,
        *,
        build: bool = False,
        progress: bool = False,
        dense_masks: bool = True,
        format: str = "tiff",
    ) -> None:
        if isinstance(n_packs, bool) or not isinstance(n_packs, int) or n_packs < 1:
            raise SynthpackInputError(f"n_packs must be a positive integer, got {n_packs!r}")
        if format not in ("tiff", "zarr"):
            raise SynthpackInputError(f"format must be 'tiff' or 'zarr', got {format!r}")
        config = _as_config(config)
        if seed is not None:
            config = config.replace(seed=_check_seed(seed, "seed"))
        super().__init__(split, axis, config.seed, transform, dense_masks)
        self.root = Path(root).expanduser()
        self.source = _Source.parse(source)
        self.n_packs = n_packs
        self.config = config
        self.postprocess = bool(postprocess)
        self.progress = progress
        identity = self.source.identity()
        self._library_key = {"source": identity, "library": config.to_dict()["library"], "synthpack": __version__}
        self.format = format
        self._pack_key = {"source": identity, "config": config.to_dict(), "format": format, "synthpack": __version__}
        self.cache_dir = self.root / f"packs-{_digest(self._pack_key)}"
        self._pack_paths: list[Path] | None = None
        if build:
            self.build()

    @property
    def pack_paths(self) -> list[Path]:
        """The pack directories, ``cache_dir/pack_0000``, ... (built if needed)."""
        self._ready()
        return list(self._pack_paths)  # type: ignore[arg-type]

    def build(self) -> SyntheticParticlePackDataset:
        """Build the missing or unusable packs now (as Dask tasks, see `generate_packs`); return the dataset."""
        self._ready()
        return self

    def _ready(self) -> None:
        if self._pack_paths is not None:
            return
        config = json.loads(json.dumps(self.config.to_dict()))  # as the manifest stores it
        paths = [self.cache_dir / pack_name(k) for k in range(self.n_packs)]
        shapes = [_usable_pack_shape(path, config) for path in paths]
        if any(shape is None for shape in shapes):
            if get_worker_info() is not None:
                raise SynthpackInputError(
                    f"the packs in {self.cache_dir} are not built, and DataLoader workers never build "
                    "them: call dataset.build() (or len(dataset)) before iterating the DataLoader"
                )
            for path, shape in zip(paths, shapes):
                if shape is None and path.exists():
                    shutil.rmtree(path)
            generate_packs(self._library(), self.cache_dir, self.n_packs, self.config, format=self.format,
                           source=self.source.describe(), progress=self.progress)
            _write_key(self.cache_dir, self._pack_key)
            shapes = [_usable_pack_shape(path, config) for path in paths]
            if any(shape is None for shape in shapes):
                raise SynthpackInputError(f"packs in {self.cache_dir} were built but cannot be read back: "
                                          "check the disk (space, permissions) and try again")
        self._index(shapes)  # type: ignore[arg-type]
        self._pack_paths = paths

    def _library(self):
        from .library import ParticleLibrary

        if self.source.kind == "library":
            return ParticleLibrary.load(self.source.paths[0])
        directory = self.root / f"library-{_digest(self._library_key)}"
        if (directory / "library").exists():
            try:
                return ParticleLibrary.load(directory / "library")
            except SynthpackInputError as error:
                logger.warning("cached library is unusable (%s): it will be rebuilt", error)
        if self.source.kind == "sample":
            from .samples import sample_scan

            scan = sample_scan(self.source.name, seed=SAMPLE_SEED)
        else:
            from .io import read_scan

            scan = read_scan(*self.source.paths)
        logger.info("building the particle library of %s into %s", self.source.describe(), directory)
        library = ParticleLibrary.from_scan(scan, **vars(self.config.library), progress=self.progress)
        library.save(directory / "library")
        _write_key(directory, self._library_key)
        return library

    def _volumes(self, k: int) -> tuple[Any, Any]:
        opened = self._opened_cache()
        if k not in opened:
            opened[k] = open_pack(self._pack_paths[k])  # type: ignore[index]
        pack: Pack = opened[k]
        return (pack.tomogram if self.postprocess else pack.clean), pack.labels

    def _repr_lines(self) -> list[str]:
        lines = [f"Root location: {self.root}", f"Source: {self.source.describe()}", f"Packs: {self.n_packs}"]
        if self._pack_paths is None:
            lines.insert(0, "Number of datapoints: not known yet (packs are built or checked on first use)")
        else:
            lines.append(f"Slices per pack along axis {self.axis}: {self._n_slices}")
        return [*lines, f"Cache: {self.cache_dir}", f"Format: {self.format}", f"Postprocess: {self.postprocess}"]


def _write_key(directory: Path, key: dict) -> None:
    directory.mkdir(parents=True, exist_ok=True)
    with atomic_file(directory / "key.json") as tmp:
        tmp.write_text(json.dumps(key, indent=1, sort_keys=True))


# --------------------------------------------------------------------------- #
# Real scans
# --------------------------------------------------------------------------- #


class _Volume:
    """A volume readable in any process: a memory-mapped file, or an array in shared memory."""

    def __init__(self, path: Path | None = None, array: np.ndarray | None = None) -> None:
        self.path = path
        self.tensor = None if array is None else torch.from_numpy(np.ascontiguousarray(array)).share_memory_()
        self.shape = tuple(self.open().shape)

    def open(self) -> np.ndarray:
        """The array (a memory map for a file; a view of the shared tensor)."""
        return self.tensor.numpy() if self.tensor is not None else _memmap(self.path)  # type: ignore[arg-type]


def _memmap(path: Path) -> np.ndarray:
    return np.load(path, mmap_mode="r") if path.suffix.lower() == ".npy" else tifffile.memmap(path, mode="r")


def _memmappable(path: Path, role: str) -> bool:
    """True when `path` is an NPY file or an uncompressed TIFF stack of a usable dtype."""
    if not (path.is_file() and path.suffix.lower() in (".npy", ".tif", ".tiff")):
        return False
    try:
        volume = _memmap(path)
    except (ValueError, OSError) as error:
        logger.info("%s cannot be memory-mapped (%s): it is read into memory", path, error)
        return False
    return volume.dtype.kind in ("iu" if role == "labels" else "iuf")


def _shared_volumes(scan: Scan) -> tuple[_Volume, _Volume]:
    """The scan's volumes in shared memory: float32 tomogram, int32 (int64 if needed) labels."""
    labels = scan.labels
    wide = labels.size and labels.max() >= 2**31
    return (_Volume(array=scan.tomogram.astype(np.float32, copy=False)),
            _Volume(array=labels.astype(np.int64 if wide else np.int32, copy=False)))


class ScanSliceDataset(_SliceDataset):
    """Slices of a real labelled scan, with the same split and item format as the synthetic packs.

    Parameters
    ----------
    scan : Scan, str or path-like
        A `~synthpack.scan.Scan`, a built-in sample name (``"large"``,
        ``"small"``, seed 0) or the tomogram's path (then `labels` is its label
        volume's path). Uncompressed TIFF stacks and NPY files are memory-mapped
        in each process; other formats (and Scans) are held once in shared
        memory, which DataLoader workers use without a copy.
    labels : path-like, optional
        Label volume path, when `scan` is a path.
    split : {"train", "test", "all"}
        As in `SyntheticParticlePackDataset`: central 20% of the slices = test.
    axis : {0, 1, 2}
        Slicing axis.
    seed : int
        Base seed of artefact transforms.
    transform : callable, artefact transform or list of them, optional
        As in `SyntheticParticlePackDataset`.
    dense_masks : bool
        As in `SyntheticParticlePackDataset`.

    Notes
    -----
    Every item has ``target["pack"] == 0``.
    """

    def __init__(
        self,
        scan: Scan | str | os.PathLike,
        labels: str | os.PathLike | None = None,
        split: str = "train",
        axis: int = 0,
        seed: int = 0,
        transform: Any = None,
        *,
        dense_masks: bool = True,
    ) -> None:
        super().__init__(split, axis, seed, transform, dense_masks)
        if isinstance(scan, str) and labels is None and scan in SAMPLE_NAMES:
            from .samples import sample_scan

            self.description = f"sample:{scan}"
            volumes = _shared_volumes(sample_scan(scan, seed=SAMPLE_SEED))
        elif isinstance(scan, Scan) and labels is None:
            self.description = scan.source or "Scan"
            volumes = _shared_volumes(scan)
        elif isinstance(scan, (str, os.PathLike)) and labels is not None:
            paths = [Path(p).expanduser().resolve() for p in (scan, labels)]
            self.description = f"tomogram={paths[0]}; labels={paths[1]}"
            if all(_memmappable(path, role) for path, role in zip(paths, ("tomogram", "labels"))):
                volumes = (_Volume(path=paths[0]), _Volume(path=paths[1]))
            else:
                from .io import read_scan

                volumes = _shared_volumes(read_scan(*paths))
        else:
            raise SynthpackInputError(
                f"scan {scan!r} with labels={labels!r} is not understood: give a Scan or a sample name "
                f"({', '.join(SAMPLE_NAMES)}) alone, or a tomogram path together with labels=<label volume path>"
            )
        shapes = {volume.shape for volume in volumes}
        if len(shapes) != 1 or len(volumes[0].shape) != 3:
            raise SynthpackInputError(
                f"tomogram and labels must be 3D volumes of one shape, got {[v.shape for v in volumes]}: "
                "give the label volume of this very tomogram"
            )
        self._scan_volumes = volumes
        self._index([volumes[0].shape])

    @property
    def shape(self) -> tuple[int, int, int]:
        """Shape ``(Z, Y, X)`` of the scan."""
        return self._scan_volumes[0].shape  # type: ignore[return-value]

    def _ready(self) -> None:
        """Nothing to build: the index is made in ``__init__``."""

    def _volumes(self, k: int) -> tuple[Any, Any]:
        opened = self._opened_cache()
        if k not in opened:
            opened[k] = tuple(volume.open() for volume in self._scan_volumes)
        return opened[k]

    def _repr_lines(self) -> list[str]:
        return [f"Scan: {self.description}", f"Shape: {self.shape}"]
