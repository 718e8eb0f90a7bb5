"""Reading: `read_scan`, `read_tomogram` and `read_volume`, with the reader that `._registry` picks for a path."""

from __future__ import annotations

import logging
import os
from pathlib import Path

import numpy as np

from ..errors import SynthpackInputError
from .._shared.text import voxel_size as voxel_size_text
from ..scan.core import Scan, validate_tomogram
from ._base import Metadata, PathLike, Volume, VoxelSize, _reading
from ._registry import _reader_for, _split_spec
from .units import _resolve_voxel_size

logger = logging.getLogger(__name__)


def read_scan(
    tomogram: PathLike | np.ndarray,
    labels: PathLike | np.ndarray,
    voxel_size: float | tuple[float, float, float] | None = None,
    unit: str | None = None,
    *,
    need_voxel_size: bool = True,
) -> Scan:
    """Read a tomogram and its instance labels into a validated `Scan`.

    Parameters
    ----------
    tomogram : path or ndarray, shape (Z, Y, X)
        Reconstructed intensities, or the file / folder / Zarr store holding
        them (see the module docstring for the formats). In a Zarr group, a
        NetCDF or an HDF5 file holding several volumes, the array named
        ``tomogram``, ``tomo`` or ``tomo_float`` is read. A path may name an
        HDF5 dataset (``scan.h5:/entry/data``) or give the layout of a raw
        file (``scan.raw:ZxYxX:DTYPE:BYTE_ORDER``) after a colon.
    labels : path or ndarray of int, shape (Z, Y, X)
        Instance labels (0 = background, 1..N = particles), or where they are.
        In a Zarr group, NetCDF or HDF5 file the array named ``labels`` is
        read; it may be the same path as `tomogram`.
    voxel_size : float or tuple of 3 float, optional
        Voxel edge lengths ``(dz, dy, dx)`` (one number: isotropic). Overrides
        the voxel size in the file metadata (the difference is logged at INFO).
    unit : str, optional
        Length unit of the voxel size, e.g. ``"um"`` or ``"mm"``. Given alone,
        the metadata voxel size is converted to it (for nm, um, mm, cm, m).
    need_voxel_size : bool
        False for a caller that works in voxels (a 2D slice export): files that record
        no voxel size are read in pixels without the warning.

    Returns
    -------
    Scan
        Tomogram (dtype as read), labels (integer), voxel size and unit.

    Notes
    -----
    The voxel size comes from, in order: the `voxel_size` argument, the
    tomogram's metadata, the labels' metadata. Without any of them the voxel
    size is 1.0 in unit ``"px"`` (voxel units) and a warning is logged (unless
    `need_voxel_size` is False).
    With `voxel_size` but no `unit`, the unit is that of the metadata, else
    ``"um"``.

    Raises
    ------
    SynthpackInputError
        If a file is missing, unreadable or of an unknown format, or the
        volumes fail the checks of `Scan` (not 3D, shapes differ, labels not
        integral, negative or empty, tomogram not finite).
    """
    tomo_array, tomo_meta, tomo_source = _load(tomogram, "tomogram")
    label_array, label_meta, label_source = _load(labels, "labels")
    size, size_unit, origin = _resolve_voxel_size(voxel_size, unit, tomo_meta, label_meta)
    try:
        scan = Scan(
            tomo_array,
            label_array,
            voxel_size=size,
            unit=size_unit,
            source=f"tomogram={tomo_source}; labels={label_source}",
            metadata={
                "tomogram": tomo_source,
                "labels": label_source,
                "voxel_size_from": origin,
            },
        )
    except SynthpackInputError as exc:
        raise SynthpackInputError(
            f"{exc} [tomogram: {tomo_source}; labels: {label_source}]"
        ) from exc
    if origin == "default" and need_voxel_size:
        _warn_no_voxel_size(tomo_source)
    else:
        _log_read(f"{tomo_source} and {label_source}", scan.tomogram, size, size_unit, origin,
                  assumed=unit is None and tomo_meta[1] is None and label_meta[1] is None)
    return scan


def read_tomogram(
    tomogram: PathLike | np.ndarray,
    voxel_size: float | tuple[float, float, float] | None = None,
    unit: str | None = None,
) -> tuple[np.ndarray, VoxelSize, str]:
    """Read a tomogram alone (no labels), validated, with its voxel size.

    Parameters
    ----------
    tomogram : path or ndarray, shape (Z, Y, X)
        As for `read_scan`: any format `read_volume` reads.
    voxel_size : float or tuple of 3 float, optional
        Voxel edge lengths ``(dz, dy, dx)``; overrides the file metadata.
    unit : str, optional
        Length unit of the voxel size (see `read_scan`).

    Returns
    -------
    tomogram : ndarray, shape (Z, Y, X)
        Finite real intensities, dtype as read.
    voxel_size : tuple of 3 float
        ``(dz, dy, dx)``, chosen as `read_scan` chooses it (1.0 px with a warning when
        neither the argument nor the metadata gives one).
    unit : str
        Length unit of `voxel_size`.

    Raises
    ------
    SynthpackInputError
        If the file is missing, unreadable or of an unknown format, or the volume is
        not a finite real 3D volume.
    """
    array, meta, source = _load(tomogram, "tomogram")
    size, size_unit, origin = _resolve_voxel_size(voxel_size, unit, meta, (None, None))
    try:
        array = validate_tomogram(array)
    except SynthpackInputError as exc:
        raise SynthpackInputError(f"{exc} [tomogram: {source}]") from exc
    if origin == "default":
        _warn_no_voxel_size(source)
    else:
        _log_read(source, array, size, size_unit, origin, assumed=unit is None and meta[1] is None)
    return array, size, size_unit


def _log_read(source: str, tomogram: np.ndarray, size: VoxelSize, unit: str, origin: str, assumed: bool) -> None:
    """Log what was read, once: its shape, dtype and the voxel size it is taken in, and where that came from.

    `assumed`: no unit was given or recorded, so a given voxel size is taken in `unit` (um).
    """
    where = {"argument": "given", "default": "none recorded, none needed"}.get(origin, f"from the {origin}")
    if origin == "argument" and assumed:
        where += f"; no unit given or recorded: {unit} assumed, give --unit"
    logger.info("read %s: %s %s, voxel size %s (%s)", source, "x".join(map(str, tomogram.shape)), tomogram.dtype,
                voxel_size_text(size, unit), where)


def _warn_no_voxel_size(source: str) -> None:
    logger.warning(
        "no voxel size was given and the input records none: using 1.0 px (voxel "
        "units). Pass --voxel-size (one value, or dz dy dx) and --unit on the "
        "command line, or voxel_size=... and unit=... to read_scan, to work in "
        "physical units [tomogram: %s]", source,
    )


def read_volume(path: PathLike, name: str | None = None) -> Volume:
    """Read one volume and the voxel size its file records.

    Parameters
    ----------
    path : str or Path
        A ``.tif``/``.tiff`` stack, a folder of 2D TIFF slices, a ``.npy``
        file, a Zarr store, a Mango NetCDF ``.nc`` file or a folder of NetCDF
        blocks, an HDF5, MetaImage, NRRD or NIfTI file, or a raw file with its
        layout after a colon, ``scan.raw:ZxYxX:DTYPE:BYTE_ORDER`` (see the
        module docstring). An HDF5 path may name its dataset after a colon,
        ``scan.h5:/entry/data``.
    name : str, optional
        The array to read from a Zarr group (in an OME-Zarr image: ``"labels"``,
        a label image ``"labels/<name>"`` or another image group in it), the
        variable to read from a NetCDF file, or the dataset to read from an HDF5
        file (the same as after a colon). Needed only when the file holds
        several candidates.

    Returns
    -------
    volume : ndarray
        The data as stored (any dtype; raw data in native byte order), usually
        shape (Z, Y, X) (NIfTI transposed from its (x, y, z) to it). NetCDF
        ``labels`` have their field-of-view marker (the dtype maximum) set to 0.
    voxel_size : tuple of 3 float or None
        ``(dz, dy, dx)`` from the file metadata, or None if it records none.
    unit : str or None
        Length unit of `voxel_size` (``"um"``, ``"mm"``, ...), or None.

    Raises
    ------
    SynthpackInputError
        If the path does not exist, its format is not supported, it cannot be
        read, or the package that reads it is not installed.
    """
    return _read(path, role=None, name=name)


def _load(source: PathLike | np.ndarray, role: str) -> tuple[np.ndarray, Metadata, str]:
    """Return ``(array, (voxel_size, unit), description)`` for one input of read_scan."""
    if isinstance(source, np.ndarray):
        return source, (None, None), f"<{source.dtype} array {source.shape}>"
    if isinstance(source, (str, os.PathLike)):
        volume, size, unit = _read(source, role=role, name=None)
        return volume, (size, unit), str(source)
    raise SynthpackInputError(
        f"the {role} must be a file path or a NumPy array, not {type(source).__name__}"
    )


def _read(path: PathLike, role: str | None, name: str | None) -> Volume:
    if not str(path).strip():
        raise SynthpackInputError("an empty path was given: pass the file or folder to read")
    path, spec = _split_spec(path)
    if spec is not None:
        if name is not None and name != spec:
            raise SynthpackInputError(f"{path} has {spec!r} after its colon and name={name!r}: give one of them")
        name = spec
    if not path.exists():
        raise SynthpackInputError(
            f"{path} does not exist: check the path (it is resolved from "
            f"{Path.cwd()} when relative)"
        )
    reader, description = _reader_for(path)
    with _reading(path, description):
        volume, size, unit = reader(path, role, name)
    logger.debug("read %s: %s %s, voxel size recorded %s", path, volume.shape, volume.dtype,
                 "none" if size is None else voxel_size_text(size, unit or "(no unit)"))
    return volume, size, unit


