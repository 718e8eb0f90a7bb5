"""What the readers and writers of `synthpack.io` share: the types, the choice of a store's array, the
turning of a reader library's exception into a one-line error, and folder listings.
"""

from __future__ import annotations

import os
import re
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import SynthpackInputError


PathLike = str | os.PathLike

VoxelSize = tuple[float, float, float]

# What a reader returns: the array, and the voxel size and unit if recorded.
Volume = tuple[np.ndarray, VoxelSize | None, str | None]

Metadata = tuple[VoxelSize | None, str | None]

# A volume read lazily: ndarray, numpy.memmap or zarr.Array, indexed (z, y, x).
ArrayLike = Any

_ZARR_MARKERS = ("zarr.json", ".zarray", ".zgroup")

_NAMES = {
    "tomogram": ("tomogram", "tomo", "tomo_float"),
    "labels": ("labels",),
}


@contextmanager
def _reading(path: Path, description: str) -> Iterator[None]:
    """Turn a reader library's exception into a SynthpackInputError naming the file."""
    try:
        yield
    except (SynthpackInputError, MemoryError):
        raise
    except Exception as exc:
        reason = " ".join(str(exc).split())  # one line, also for multi-line messages (ITK's)
        raise SynthpackInputError(
            f"cannot read {path} as {description}: {reason}. Check that the file is "
            "complete and really is in this format (copy or export it again)"
        ) from exc


def _choose(
    available: list[str], role: str | None, name: str | None, path: Path, kind: str,
    pick: str = "read the one you want with read_volume(path, name=...)",
) -> str:
    """Pick one of the arrays/variables of a store for `role` or by `name`.

    An explicit `name` must exist. Otherwise the first conventional name for
    the role wins (``tomogram``/``tomo``/``tomo_float``, ``labels``); failing
    that, a lone array is taken unless its name says it is the other role.
    """
    if name is not None:
        if name in available:
            return name
        raise SynthpackInputError(
            f"{path} has no {kind} named {name!r}; {kind}s present: {available or 'none'}"
        )
    for wanted in _NAMES.get(role, ()):
        if wanted in available:
            return wanted
    other_roles = [n for r, names in _NAMES.items() if role and r != role for n in names]
    if len(available) == 1 and available[0] not in other_roles:
        return available[0]
    looking_for = f"the {role} " if role else ""
    raise SynthpackInputError(
        f"cannot tell which {kind} of {path} holds {looking_for}volume; {kind}s "
        f"present: {available or 'none'}. Name them 'tomogram' and 'labels', or {pick}"
    )


def _require_volume(volume: np.ndarray) -> np.ndarray:
    volume = np.asarray(volume)
    if volume.ndim != 3 or volume.size == 0:
        raise SynthpackInputError(
            f"cannot write an array of shape {volume.shape}: a non-empty 3D volume "
            "(z, y, x) is needed"
        )
    return volume


def _is_empty_dir(path: Path) -> bool:
    return path.is_dir() and not any(path.iterdir())


def _visible_files(folder: Path) -> list[Path]:
    """Files of `folder`, without hidden ones (e.g. macOS ``._slice.tif``)."""
    return [f for f in folder.iterdir() if f.is_file() and not f.name.startswith(".")]


def _natural_sorted(files: Iterable[Path]) -> list[Path]:
    """`files` sorted by name with digit runs compared as numbers (2 before 10)."""
    def key(file: Path) -> list:
        return [int(part) if part.isdigit() else part.lower()
                for part in re.split(r"(\d+)", file.name)]
    return sorted(files, key=key)


def _is_zarr_store(path: Path) -> bool:
    return path.is_dir() and any((path / marker).is_file() for marker in _ZARR_MARKERS)
