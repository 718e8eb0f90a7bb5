"""Mango NetCDF: ``.nc`` files and folders of ``block*.nc`` files split along z.
"""

from __future__ import annotations

import logging
from pathlib import Path

import netCDF4
import numpy as np

from ..errors import SynthpackInputError
from ._base import Metadata, Volume, _NAMES, _choose, _natural_sorted, _reading, _visible_files
from .units import _attribute_voxel_size

logger = logging.getLogger(__name__)


_NETCDF_VARIABLES = _NAMES["tomogram"][1:] + _NAMES["labels"]


def _read_netcdf(path: Path, role: str | None, name: str | None) -> Volume:
    with netCDF4.Dataset(path, mode="r") as dataset:
        variable = dataset.variables[_netcdf_variable(dataset, role, name, path)]
        variable.set_auto_mask(False)
        volume = np.asarray(variable[...])
        size, unit = _mango_voxel_size(dataset, path)
        var_name = variable.name
    return _mask_field_of_view(volume, var_name, path), size, unit


def _read_netcdf_folder(path: Path, role: str | None, name: str | None) -> Volume:
    files = _natural_sorted(f for f in _visible_files(path) if f.suffix.lower() == ".nc")
    with _reading(files[0], "NetCDF"), netCDF4.Dataset(files[0], mode="r") as first:
        var_name = _netcdf_variable(first, role, name, files[0])
        size, unit = _mango_voxel_size(first, files[0])
    layouts = [_netcdf_layout(file, var_name, path) for file in files]
    first_shape, dtype = layouts[0]
    for file, (shape, block_dtype) in zip(files, layouts):
        if len(shape) != 3 or shape[1:] != first_shape[1:] or block_dtype != dtype:
            raise SynthpackInputError(
                f"block {file.name} holds {var_name!r} of shape {shape} and dtype "
                f"{block_dtype}, which does not stack along z with {files[0].name} "
                f"(shape {first_shape}, dtype {dtype}): all blocks of {path} must be 3D "
                "(z, y, x) with the same (y, x) size and dtype"
            )
    volume = np.empty((sum(shape[0] for shape, _ in layouts), *first_shape[1:]), dtype)
    z = 0
    for file, (shape, _) in zip(files, layouts):
        with _reading(file, "NetCDF"), netCDF4.Dataset(file, mode="r") as dataset:
            variable = dataset.variables[var_name]
            variable.set_auto_mask(False)
            volume[z : z + shape[0]] = variable[...]
        z += shape[0]
    return _mask_field_of_view(volume, var_name, path), size, unit


def _netcdf_layout(file: Path, var_name: str, folder: Path) -> tuple[tuple, np.dtype]:
    """Shape and dtype (as read) of `var_name` in one NetCDF block, without its data."""
    with _reading(file, "NetCDF"), netCDF4.Dataset(file, mode="r") as dataset:
        if var_name not in dataset.variables:
            raise SynthpackInputError(
                f"block {file} has no variable {var_name!r} (variables present: "
                f"{sorted(dataset.variables)}): all blocks in {folder} must hold "
                "the same volume"
            )
        variable = dataset.variables[var_name]
        return tuple(variable.shape), _netcdf_dtype(variable)


def _netcdf_dtype(variable: netCDF4.Variable) -> np.dtype:
    """The dtype netCDF4 returns, honouring the ``_Unsigned`` convention of NetCDF-3."""
    dtype = np.dtype(variable.dtype)
    unsigned = str(getattr(variable, "_Unsigned", "false")).lower() == "true"
    if unsigned and dtype.kind == "i":
        return np.dtype(f"u{dtype.itemsize}")
    return dtype


def _netcdf_variable(
    dataset: netCDF4.Dataset, role: str | None, name: str | None, path: Path
) -> str:
    """Name of the variable to read: `name`, else the tomogram/labels variable."""
    present = sorted(dataset.variables)
    if name is not None:
        candidates = present
    else:
        candidates = [v for v in present if v in _NETCDF_VARIABLES]
        if not candidates:
            raise SynthpackInputError(
                f"{path} has no 'tomo' or 'labels' variable (variables present: "
                f"{present or 'none'}): pass a Mango tomogram or label file, or use "
                "read_volume(path, name=...) to pick a variable"
            )
    return _choose(candidates, role, name, path, "variable")


def _mango_voxel_size(dataset: netCDF4.Dataset, path: Path) -> Metadata:
    """Voxel size from Mango's global attributes ``voxel_size_xyz`` and ``voxel_unit``."""
    attrs = dataset.ncattrs()
    if "voxel_size_xyz" not in attrs or "voxel_unit" not in attrs:
        return None, None
    xyz = np.atleast_1d(dataset.getncattr("voxel_size_xyz"))
    return _attribute_voxel_size(xyz[::-1].tolist(), dataset.getncattr("voxel_unit"), path)


def _mask_field_of_view(volume: np.ndarray, var_name: str, path: Path) -> np.ndarray:
    """Set Mango's outside-the-field-of-view marker (the dtype maximum) in labels to 0."""
    if var_name not in _NAMES["labels"] or volume.dtype.kind not in "iu":
        return volume
    outside = volume == np.iinfo(volume.dtype).max
    count = int(np.count_nonzero(outside))
    if count:
        volume[outside] = 0
        logger.info("%s: %d voxel(s) outside the field of view (value %d) set to 0",
                    path, count, np.iinfo(volume.dtype).max)
    return volume

