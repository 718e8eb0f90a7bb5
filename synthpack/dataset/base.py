"""The base class of the slice datasets: split, index, epoch, item assembly and ``repr``.

`EpochSeeded` (the epoch in shared memory) is shared with the patch dataset
(`synthpack.dataset.patches`), which also reads its volumes through a slice
dataset's `volume_shapes` and `open_volumes`.
"""

from __future__ import annotations

import os
from abc import ABC, abstractmethod
from collections.abc import Sequence
from typing import Any

import numpy as np
import torch
from torch.utils.data import Dataset

from ..errors import SynthpackInputError
from ..io import read_slice
from ..scan.split import split_slices
from .targets import Item, image_tensor, instance_target
from .transforms import SliceTransforms

__all__ = ["EpochSeeded", "SliceDataset", "check_axis", "check_seed"]

#: What a slice dataset serves: the paper's training or test slices (`synthpack.scan.split`,
#: without a validation part), or every slice.
_SPLIT_CHOICES = ("train", "test", "all")
_AXES = (0, 1, 2)


def check_seed(seed: Any, what: str) -> int:
    """`seed` as an int; raise unless it is a non-negative integer (`what` names it in the message)."""
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise SynthpackInputError(f"{what} must be a non-negative integer, got {seed!r}")
    return int(seed)


def check_axis(axis: Any) -> int:
    """`axis` as an int; raise unless it is 0, 1 or 2."""
    if isinstance(axis, bool) or axis not in _AXES:
        raise SynthpackInputError(f"axis must be 0, 1 or 2 (the slicing axis of the (Z, Y, X) volume), got {axis!r}")
    return int(axis)


class EpochSeeded:
    """The epoch that seeds a dataset's per-item random draws, shared with its DataLoader workers.

    Subclasses call `_init_epoch` in ``__init__``.
    """

    def _init_epoch(self) -> None:
        # in shared memory, so set_epoch reaches DataLoader workers that already run
        self._epoch = torch.zeros((), dtype=torch.int64).share_memory_()

    @property
    def epoch(self) -> int:
        """The epoch that seeds the random transforms (0 until `set_epoch`)."""
        return int(self._epoch)

    def set_epoch(self, epoch: int) -> None:
        """Set the epoch of the per-item seeds: call it before iterating a DataLoader.

        The value lives in shared memory, so persistent DataLoader workers see it.
        """
        self._epoch.fill_(check_seed(epoch, "epoch"))


class SliceDataset(Dataset, EpochSeeded, ABC):
    """Slices of a list of labelled volumes along one axis, split as in the paper.

    Subclasses call `_index` with the volume shapes once they are known and
    implement `_volumes` (the image and label volumes of volume `k`, opened in the
    calling process), `_ready` (make sure `_index` ran) and `_repr_lines`.
    """

    def __init__(self, split: str, axis: int, seed: int, transform: Any, dense_masks: bool = True) -> None:
        if split not in _SPLIT_CHOICES:
            raise SynthpackInputError(f"split must be 'train', 'test' or 'all', got {split!r}")
        self.split = split
        self.axis = check_axis(axis)
        self.seed = check_seed(seed, "seed")
        self.transform = transform
        self.dense_masks = bool(dense_masks)
        self._transforms = SliceTransforms(transform)
        self._init_epoch()
        self._volume_index: np.ndarray | None = None
        self._slice_index: np.ndarray | None = None
        self._n_slices: list[int] = []
        self._shapes: list[tuple[int, ...]] = []

    # -- indexing ------------------------------------------------------------------
    def _index(self, shapes: Sequence[tuple[int, ...]]) -> None:
        """Index the `split` slices along `axis` of volumes of `shapes`, volume by volume."""
        volumes, slices = [], []
        for k, shape in enumerate(shapes):
            chosen = split_slices(shape[self.axis], self.split)
            volumes.append(np.full(chosen.size, k, dtype=np.int64))
            slices.append(chosen)
        self._shapes = [tuple(int(n) for n in shape) for shape in shapes]
        self._n_slices = [shape[self.axis] for shape in self._shapes]
        self._volume_index = np.concatenate(volumes)
        self._slice_index = np.concatenate(slices)

    @abstractmethod
    def _ready(self) -> None:
        """Make sure `_index` ran (build or check what the dataset reads)."""

    @abstractmethod
    def _volumes(self, k: int) -> tuple[Any, Any]:
        """``(image volume, label volume)`` of volume `k`, opened in the calling process."""

    def volume_shapes(self) -> list[tuple[int, ...]]:
        """Shapes (Z, Y, X) of the dataset's volumes, in order (built or checked if needed)."""
        self._ready()
        return list(self._shapes)

    def open_volumes(self, k: int) -> tuple[Any, Any]:
        """``(image volume, label volume)`` of volume `k`: memory maps, Zarr arrays or shared arrays.

        Opened once per process and kept; slicing them reads only the voxels asked for.
        """
        self._ready()
        return self._volumes(k)

    def slices(self, k: int = 0) -> np.ndarray:
        """Slice indices (int64, sorted) of volume `k` in this dataset."""
        self._ready()
        return self._slice_index[self._volume_index == k]  # type: ignore[index]

    def __len__(self) -> int:
        self._ready()
        return int(self._slice_index.size)  # type: ignore[union-attr]

    def _locate(self, index: int) -> tuple[int, int]:
        """``(volume, slice)`` of item `index` (negative indices count from the end)."""
        self._ready()
        n = self._slice_index.size  # type: ignore[union-attr]
        if not -n <= index < n:
            raise IndexError(f"index {index} is out of range for a dataset of {n} slices")
        return int(self._volume_index[index]), int(self._slice_index[index])  # type: ignore[index]

    def __getitem__(self, index: int) -> Item:
        k, s = self._locate(index)
        images, labels = self._volumes(k)
        image = self._transforms.apply_artefacts(read_slice(images, self.axis, s), self.seed, self.epoch, k,
                                                 self.axis, s)
        target = instance_target(read_slice(labels, self.axis, s), dense_masks=self.dense_masks)
        target["pack"], target["slice"] = k, s
        return self._transforms(image_tensor(image), target)

    # -- processes -------------------------------------------------------------------
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
    def describe_source(self) -> str:
        """One line naming where the volumes come from (for ``repr`` and patch items)."""

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
