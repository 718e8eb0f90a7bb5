"""HDF5 (h5py): one dataset, named after a colon or the file's only 3D dataset, with its voxel size.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from ..errors import SynthpackInputError
from ._base import Metadata, Volume, _choose
from ._registry import _optional
from .units import _attribute_voxel_size


# The attributes an HDF5 dataset or its parent groups record its voxel size in, z first.
_HDF5_SIZE_ATTRIBUTES = ("element_size_um", "voxel_size", "spacing")


def _read_hdf5(path: Path, role: str | None, name: str | None) -> Volume:
    h5py = _optional("h5py", "HDF5 files")
    with h5py.File(path, "r") as file:
        dataset = file[_hdf5_dataset(file, role, name, path, h5py.Dataset)]
        volume = dataset[()]
        size, unit = _hdf5_voxel_size(dataset, path)
    return volume, size, unit


def _hdf5_dataset(file: Any, role: str | None, name: str | None, path: Path, dataset_type: type) -> str:
    """Path of the dataset to read: `name`, else the file's only 3D dataset or the one named for `role`."""
    volumes: list[str] = []
    file.visititems(lambda key, node: volumes.append(key)
                    if isinstance(node, dataset_type) and node.ndim == 3 else None)
    if name is not None:
        if isinstance(file.get(name), dataset_type):
            return name
        raise SynthpackInputError(
            f"{path} has no dataset {name!r}; 3D datasets present: {sorted(volumes) or 'none'}"
        )
    if not volumes:
        raise SynthpackInputError(
            f"{path} holds no 3D dataset: give the HDF5 file holding the volume, or its dataset "
            f"after a colon ({path}:/path/to/dataset)"
        )
    return _choose(sorted(volumes), role, None, path, "3D dataset",
                   pick=f"give the one you want after a colon ({path}:/path/to/dataset)")


def _hdf5_voxel_size(dataset: Any, path: Path) -> Metadata:
    """Voxel size from the first `_HDF5_SIZE_ATTRIBUTES` entry found on `dataset` or a parent group."""
    node = dataset
    while True:
        found = [key for key in _HDF5_SIZE_ATTRIBUTES if key in node.attrs]
        if found:
            value = np.asarray(node.attrs[found[0]]).tolist()
            unit = "um" if found[0] == "element_size_um" else node.attrs.get("unit", node.attrs.get("units"))
            if isinstance(unit, bytes):
                unit = unit.decode()
            return _attribute_voxel_size(value, unit, path)
        if node.name == "/":
            return None, None
        node = node.parent

