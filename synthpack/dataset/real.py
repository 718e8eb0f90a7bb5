"""`ScanSliceDataset`: slices of a real labelled scan, memory-mapped or held once in shared memory."""

from __future__ import annotations

import logging
import os
from pathlib import Path
from typing import Any

import numpy as np
import torch

from ..errors import SynthpackInputError
from ..io import memmap_volume, read_scan
from ..scan.samples import SAMPLE_NAMES, sample_scan
from ..scan.core import Scan
from .base import SliceDataset
from .source import SAMPLE_SEED

logger = logging.getLogger(__name__)

__all__ = ["ScanSliceDataset"]


class _Volume:
    """A volume readable in any process: a memory-mapped file, or an array in shared memory.

    Parameters
    ----------
    path : Path, optional
        An NPY file or uncompressed TIFF stack, memory-mapped in each process.
    array : ndarray, shape (Z, Y, X), optional
        Copied once into shared memory, which DataLoader workers read without a copy.
    """

    def __init__(self, path: Path | None = None, array: np.ndarray | None = None) -> None:
        self.path = path
        self.tensor = None if array is None else torch.from_numpy(np.ascontiguousarray(array)).share_memory_()
        self.shape = tuple(self.open().shape)

    def open(self) -> np.ndarray:
        """The array (a memory map for a file; a view of the shared tensor)."""
        return self.tensor.numpy() if self.tensor is not None else memmap_volume(self.path)  # type: ignore[arg-type]


def _memmappable(path: Path, role: str) -> bool:
    """True when `path` is an NPY file or an uncompressed TIFF stack of a usable dtype for `role`."""
    if not (path.is_file() and path.suffix.lower() in (".npy", ".tif", ".tiff")):
        return False
    try:
        volume = memmap_volume(path)
    except SynthpackInputError as error:
        logger.info("%s cannot be memory-mapped (%s): it is read into memory", path, error)
        return False
    return volume.dtype.kind in ("iu" if role == "labels" else "iuf")


def _shared_volumes(scan: Scan) -> tuple[_Volume, _Volume]:
    """The scan's volumes in shared memory: float32 tomogram, int32 (int64 if needed) labels."""
    labels = scan.labels
    wide = labels.size and labels.max() >= 2**31
    return (_Volume(array=scan.tomogram.astype(np.float32, copy=False)),
            _Volume(array=labels.astype(np.int64 if wide else np.int32, copy=False)))


class ScanSliceDataset(SliceDataset):
    """Slices of a real labelled scan, with the same split and item format as the synthetic packs.

    Parameters
    ----------
    scan : Scan, str or path-like
        A `~synthpack.scan.core.Scan`, a built-in sample name (``"large"``,
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

    def describe_source(self) -> str:
        return self.description

    def _repr_lines(self) -> list[str]:
        return [f"Scan: {self.description}", f"Shape: {self.shape}"]
