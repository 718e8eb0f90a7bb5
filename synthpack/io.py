"""Read and write CT volumes (TIFF, NPY, Zarr, NetCDF, HDF5, MetaImage, NRRD, NIfTI, raw) and 2D label images.

Volumes are NumPy arrays indexed ``(z, y, x)``. Readers return the voxel size
``(dz, dy, dx)`` and its length unit when the file records them; `read_scan`
turns a tomogram and its label volume into a validated `~synthpack.scan.Scan`.
`memmap_volume` memory-maps a volume file; `read_slice` reads one slice and
`read_box` one box of a memory map, a Zarr array or an array, so a slice or a
patch is read without the volume.
`write_label_image` and `read_label_image` store 2D instance label images
(PNG, TIFF, NPY), e.g. the truth and predictions of scored slices. `write_tiff`,
`write_zarr` and `write_nifti` (NIfTI-1, stored (x, y, z) as ITK and nnU-Net read it) write
volumes with their voxel size.
Writers are atomic: the data go to a temporary sibling first and are renamed
into place only once complete, so a failed write leaves nothing behind.
Their helpers, public for other writers: `atomic_file`, `atomic_directory`.

Supported inputs
----------------
- multi-page TIFF (``.tif``, ``.tiff``), voxel size from ImageJ metadata or
  the resolution tags;
- a folder of 2D TIFF slices, stacked in natural order (``slice_2.tif``
  before ``slice_10.tif``);
- NumPy ``.npy`` files;
- Zarr stores (a directory): a single array, or a group holding one array or
  arrays named ``tomogram`` / ``labels``; voxel size from the attributes
  ``voxel_size`` (z, y, x) and ``unit`` as written by `write_zarr`. An OME-Zarr
  image (NGFF 0.5 or 0.4, e.g. the ``pack.zarr`` of a Zarr pack): its
  full-resolution level, voxel size and unit from its ``multiscales`` scale and
  axes (`synthpack.ngff.full_resolution`); for the labels (or ``name="labels"``)
  its first label image under ``labels/``, or by `name` another image group in
  it (``"clean"``, ``"labels/instances"``);
- NetCDF files as written by the ANU CT lab's Mango tools (``.nc``), with the
  variable ``tomo`` (or ``tomo_float``) and/or ``labels``, or a folder of
  such files split along z (``block00000000.nc``, ``block00000001.nc``, ...).
  In Mango label volumes the dtype's maximum value (255 for uint8,
  2**31 - 1 for int32) marks voxels outside the round field of view; it is
  read as background (0);
- HDF5 files (``.h5``, ``.hdf5``, ``.hdf``, ``.nxs``; h5py), one dataset
  named after a colon (``scan.h5:/entry/data``) or the file's only 3D
  dataset. Voxel size from the first of these attributes found on the
  dataset or its parent groups: ``element_size_um`` (z, y, x in um, as the
  ImageJ HDF5 plugin and ilastik write it), ``voxel_size`` or ``spacing``
  (one value or z, y, x) with ``unit`` or ``units``;
- MetaImage (``.mhd``, ``.mha``; SimpleITK) and NRRD (``.nrrd``, ``.nhdr``;
  pynrrd), voxel size from their spacing, reversed from ITK's (x, y, z) to
  (z, y, x). The unit is NRRD's ``space units`` when recorded, else
  millimetres, the convention of ITK and 3D Slicer;
- NIfTI (``.nii``, ``.nii.gz``; nibabel), stored (x, y, z) and transposed
  to (z, y, x); voxel size from the header's pixdim (zooms), unit from
  ``xyzt_units`` (millimetres when it says unknown, as ITK reads it);
- raw binary (``.raw``, ``.bin``, ``.vol``) with its layout after a colon:
  ``scan.raw:ZxYxX:DTYPE:BYTE_ORDER``, e.g.
  ``scan.raw:512x1024x1024:uint16:little``: Z slices of Y rows of X voxels,
  X varying fastest, no header; the byte order (``little`` or ``big``) may
  be left out for 1-byte dtypes. It records no voxel size.

Orientation matrices (ITK direction cosines, NIfTI qform/sform) are
ignored: the array is read in the order it is stored.
HDF5, NRRD and NIfTI need the ``formats`` extra (``pip install
"synthpack[formats]"``: h5py, pynrrd, nibabel), MetaImage the ``metaimage``
extra (SimpleITK, large); without them these files give a one-line error
saying what to install.
"""

from __future__ import annotations

import importlib
import logging
import math
import os
import re
import struct
import sys
import tempfile
import warnings
from collections.abc import Callable, Iterable, Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import netCDF4
import numpy as np
import tifffile
import zarr
from PIL import Image

from .ngff import full_resolution, label_names
from ._atomic import Output, atomic_directory, atomic_file
from .errors import SynthpackInputError
from .scan import Scan, validate_tomogram, validate_voxel_size

logger = logging.getLogger(__name__)

__all__ = [
    "LABEL_IMAGE_SUFFIXES",
    "SUPPORTED_FORMATS",
    "atomic_directory",
    "atomic_file",
    "check_nifti_writer",
    "convert_voxel_size",
    "create_zarr_volume",
    "memmap_volume",
    "read_box",
    "read_label_image",
    "read_scan",
    "read_tomogram",
    "read_slice",
    "read_volume",
    "write_label_image",
    "write_nifti",
    "write_tiff",
    "write_zarr",
]

PathLike = str | os.PathLike
VoxelSize = tuple[float, float, float]
# What a reader returns: the array, and the voxel size and unit if recorded.
Volume = tuple[np.ndarray, VoxelSize | None, str | None]
Metadata = tuple[VoxelSize | None, str | None]
# A volume read lazily: ndarray, numpy.memmap or zarr.Array, indexed (z, y, x).
ArrayLike = Any

SUPPORTED_FORMATS = (
    "multi-page TIFF (.tif, .tiff)",
    "folder of 2D TIFF slices",
    "NumPy array (.npy)",
    "Zarr store (directory, e.g. .zarr)",
    "Mango NetCDF (.nc, or a folder of block*.nc files split along z)",
    "HDF5 (.h5, .hdf5, .hdf, .nxs; a dataset after a colon: scan.h5:/entry/data)",
    "MetaImage (.mhd, .mha)",
    "NRRD (.nrrd, .nhdr)",
    "NIfTI (.nii, .nii.gz)",
    "raw binary with its layout after a colon (scan.raw:ZxYxX:uint16:little)",
)

_TIFF_SUFFIXES = (".tif", ".tiff")
#: File types `read_label_image` reads.
LABEL_IMAGE_SUFFIXES = (".png", ".tif", ".tiff", ".npy")
_ZARR_MARKERS = ("zarr.json", ".zarray", ".zgroup")
_NAMES = {
    "tomogram": ("tomogram", "tomo", "tomo_float"),
    "labels": ("labels",),
}
_NETCDF_VARIABLES = _NAMES["tomogram"][1:] + _NAMES["labels"]

# Length of one unit in micrometres, to convert between known length units.
_MICROMETRES = {"nm": 1e-3, "um": 1.0, "mm": 1e3, "cm": 1e4, "m": 1e6}
_UNIT_ALIASES = {
    "µm": "um", "μm": "um", "\\u00b5m": "um", "micron": "um", "microns": "um",
    "micrometer": "um", "micrometre": "um", "micrometers": "um", "micrometres": "um",
    "millimeter": "mm", "millimetre": "mm", "millimeters": "mm", "millimetres": "mm",
    "nanometer": "nm", "nanometre": "nm", "centimeter": "cm", "centimetre": "cm",
    "meter": "m", "metre": "m", "pixel": "px", "pixels": "px", "voxel": "px", "": "px",
}
# TIFF ResolutionUnit values that are lengths, in micrometres (INCH is left
# out on purpose: an inch resolution is a display DPI, not a voxel size).
_TIFF_RESOLUTION_UNITS = {
    tifffile.RESUNIT.CENTIMETER: 1e4,
    tifffile.RESUNIT.MILLIMETER: 1e3,
    tifffile.RESUNIT.MICROMETER: 1.0,
}
# A path, then after a colon the dataset of an HDF5 file (scan.h5:/entry/data)
# or the layout of a raw file (scan.raw:64x128x256:uint16:little).
_PATH_SPEC = re.compile(r"^(?P<file>.+?\.(?:h5|hdf5|hdf|nxs|raw|bin|vol)):(?P<spec>.*)$", re.IGNORECASE)
_RAW_DTYPES = ("uint8", "int8", "uint16", "int16", "uint32", "int32", "uint64", "int64", "float32", "float64")
_RAW_BYTE_ORDERS = {"little": "<", "big": ">"}
_RAW_LAYOUT = ("FILE.raw:ZxYxX:DTYPE:BYTE_ORDER, e.g. scan.raw:512x1024x1024:uint16:little (Z slices of Y "
               "rows of X voxels, X varying fastest; DTYPE one of " + ", ".join(_RAW_DTYPES)
               + "; BYTE_ORDER little or big, optional for 1-byte dtypes)")
# The attributes an HDF5 dataset or its parent groups record its voxel size in, z first.
_HDF5_SIZE_ATTRIBUTES = ("element_size_um", "voxel_size", "spacing")
# Length unit of ITK-family spacings that record none (MetaImage, NRRD without
# "space units", NIfTI with unknown xyzt_units): ITK's and 3D Slicer's millimetres.
_ITK_UNIT = "mm"
# Optional reader packages: module -> (package to install, extra of synthpack holding it).
_OPTIONAL = {
    "h5py": ("h5py", "formats"),
    "nrrd": ("pynrrd", "formats"),
    "nibabel": ("nibabel", "formats"),
    "SimpleITK": ("SimpleITK", "metaimage"),
}
# NIfTI's spatial units (xyzt_units) of synthpack's canonical length units; write_nifti writes others as "unknown".
_NIFTI_UNITS = {"m": "meter", "mm": "mm", "um": "micron"}
# Above this many bytes write_tiff writes BigTIFF (same margin as tifffile).
_BIGTIFF_BYTES = 2**32 - 2**25


# --------------------------------------------------------------------------- #
# Public API
# --------------------------------------------------------------------------- #


def read_scan(
    tomogram: PathLike | np.ndarray,
    labels: PathLike | np.ndarray,
    voxel_size: float | tuple[float, float, float] | None = None,
    unit: str | None = None,
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

    Returns
    -------
    Scan
        Tomogram (dtype as read), labels (integer), voxel size and unit.

    Notes
    -----
    The voxel size comes from, in order: the `voxel_size` argument, the
    tomogram's metadata, the labels' metadata. Without any of them the voxel
    size is 1.0 in unit ``"px"`` (voxel units) and a warning is logged.
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
    if origin == "default":
        _warn_no_voxel_size(tomo_source)
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
    return array, size, size_unit


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


def write_tiff(
    path: PathLike,
    volume: np.ndarray,
    voxel_size: float | tuple[float, float, float],
    unit: str = "um",
    *,
    labels: bool = False,
) -> Path:
    """Write a volume as an ImageJ hyperstack that Fiji opens with its voxel size.

    Parameters
    ----------
    path : str or Path
        Output file (``.tif``); parent folders are created. An existing file
        is replaced atomically.
    volume : ndarray, shape (Z, Y, X)
        The volume. ImageJ stores uint8, uint16 and float32 only, so other
        dtypes are converted: bool -> uint8; integers whose values all lie in
        0..65535 -> uint16 (lossless); other integers and floats -> float32
        (intensities only).
    voxel_size : float or tuple of 3 float
        Voxel edge lengths ``(dz, dy, dx)`` in `unit`.
    unit : str
        Length unit; ``"um"`` is written as ImageJ's ``"micron"`` so Fiji
        shows µm.
    labels : bool
        True for a label volume: labels outside 0..65535 or non-integer
        values raise instead of being converted to float32.

    Returns
    -------
    Path
        The file written. Volumes over 4 GB are written as BigTIFF.

    Raises
    ------
    SynthpackInputError
        If the volume is not 3D, does not fit the rule above (labels outside
        0..65535 or not integral, values beyond float32, non-numeric data),
        or `path` is a folder.
    """
    path = Path(path)
    size = validate_voxel_size(voxel_size)
    data = _imagej_compatible(_require_volume(volume), labels)
    if path.is_dir():
        raise SynthpackInputError(
            f"cannot write the TIFF file {path}: a folder of that name exists; "
            "give a file name ending in .tif"
        )
    dz, dy, dx = size
    bigtiff = data.nbytes > _BIGTIFF_BYTES
    with atomic_file(path) as tmp, warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=".*nonconformant BigTIFF ImageJ")
        tifffile.imwrite(
            tmp,
            data,
            imagej=True,
            bigtiff=bigtiff,
            resolution=(1.0 / dx, 1.0 / dy),
            metadata={"spacing": dz, "unit": _imagej_unit(unit), "axes": "ZYX"},
        )
    logger.info("wrote %s: %s %s, voxel %s %s", path, data.shape, data.dtype, size, unit)
    return path


def check_nifti_writer() -> None:
    """Raise the one-line install message unless nibabel, which `write_nifti` needs, is installed."""
    _optional("nibabel", "NIfTI files", "writing")


def write_nifti(
    path: PathLike,
    volume: np.ndarray,
    voxel_size: float | tuple[float, float, float],
    unit: str = "um",
    *,
    origin: tuple[float, float, float] = (0.0, 0.0, 0.0),
) -> Path:
    """Write a volume as a NIfTI-1 file that nibabel, ITK (SimpleITK, 3D Slicer) and nnU-Net read with its voxel size.

    Parameters
    ----------
    path : str or Path
        Output file, ``.nii`` or ``.nii.gz`` (gzip, nibabel's level 1);
        parent folders are created. An existing file is replaced atomically.
    volume : ndarray, shape (Z, Y, X)
        The volume, written in its dtype (bool as uint8).
    voxel_size : float or tuple of 3 float
        Voxel edge lengths ``(dz, dy, dx)`` in `unit`.
    unit : str
        Length unit. NIfTI records only metres, millimetres and micrometres
        (``xyzt_units``); another unit is written as "unknown", which ITK and
        `read_volume` read as millimetres.
    origin : tuple of 3 float
        Position ``(z, y, x)`` of the first voxel's centre in `unit` (the
        affine's translation), e.g. where a crop starts in its whole scan.

    Returns
    -------
    Path
        The file written.

    Notes
    -----
    NIfTI stores its first axis fastest, so the array is stored as
    ``volume.T``, shape (X, Y, Z), with zooms ``(dx, dy, dz)`` and the affine
    ``diag(dx, dy, dz, 1)`` plus the translation ``origin[::-1]``, as both its
    qform and sform (code 1, scanner). So `read_volume` gives back `volume`
    and ``voxel_size``, and ITK's ``GetArrayFromImage`` gives the (Z, Y, X)
    array with ``GetSpacing() == (dx, dy, dz)``: nnU-Net's spacing, which
    reverses ITK's, is ``(dz, dy, dx)``.
    """
    path = Path(path)
    if not path.name.endswith((".nii", ".nii.gz")):
        raise SynthpackInputError(f"cannot write the NIfTI file {path}: give a file name ending in .nii or .nii.gz")
    nibabel = _optional("nibabel", "NIfTI files", "writing")
    size = validate_voxel_size(voxel_size)
    data = _require_volume(volume)
    data = data.astype(np.uint8) if data.dtype == bool else data
    affine = np.diag([*size[::-1], 1.0])
    affine[:3, 3] = np.asarray(origin, dtype=float)[::-1]
    image = nibabel.Nifti1Image(data.T, affine)
    image.set_qform(affine, code=1)
    image.set_sform(affine, code=1)
    image.header.set_xyzt_units(xyz=_NIFTI_UNITS.get(_normalise_unit(unit), "unknown"))
    with atomic_file(path) as tmp:
        # nibabel picks gzip from the name, so the temporary name keeps the suffix
        staged = tmp.with_name(tmp.name + (".nii.gz" if path.name.endswith(".gz") else ".nii"))
        try:
            nibabel.save(image, staged)
            os.replace(staged, tmp)
        finally:
            staged.unlink(missing_ok=True)
    logger.info("wrote %s: %s %s, voxel %s %s", path, data.shape, data.dtype, size, unit)
    return path


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
    logger.info("wrote %s%s: %s %s, voxel %s %s", path, f"/{name}" if name else "",
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


# --------------------------------------------------------------------------- #
# Slices of volumes
# --------------------------------------------------------------------------- #


def memmap_volume(path: PathLike) -> np.ndarray:
    """Memory-map a volume file read-only, so that slicing it reads only the slices asked for.

    Parameters
    ----------
    path : str or Path
        A NumPy ``.npy`` file or an uncompressed, contiguous TIFF stack
        (``.tif``/``.tiff``, as `write_tiff` writes).

    Returns
    -------
    numpy.memmap, usually shape (Z, Y, X)
        The data as stored (any dtype), read-only. A memory map belongs to the
        process that made it: open it again in each process (e.g. in each
        DataLoader worker) instead of pickling it.

    Raises
    ------
    SynthpackInputError
        If the file is missing, of another type, compressed, tiled or truncated
        (read it with `read_volume` instead).
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in (".npy", *_TIFF_SUFFIXES):
        raise SynthpackInputError(
            f"{path} cannot be memory-mapped: only .npy files and uncompressed TIFF stacks can; "
            "read it with read_volume instead"
        )
    with _reading(path, "a memory-mappable NPY or uncompressed TIFF file"):
        return np.load(path, mmap_mode="r") if suffix == ".npy" else tifffile.memmap(path, mode="r")


def read_slice(volume: ArrayLike, axis: int, index: int) -> np.ndarray:
    """One 2D slice of a 3D volume, read alone.

    Parameters
    ----------
    volume : array-like, shape (Z, Y, X)
        A NumPy array, a memory map (`memmap_volume`) or a Zarr array: only the
        slice is read (from a Zarr array, only the chunks it crosses).
    axis : {0, 1, 2}
        Slicing axis.
    index : int
        Slice index along `axis`.

    Returns
    -------
    ndarray, dtype of `volume`
        Shape (Y, X) for axis 0, (Z, X) for axis 1, (Z, Y) for axis 2; a view
        when `volume` is a NumPy array or memory map.
    """
    return np.asarray(volume[(slice(None),) * axis + (index,)])


def read_box(volume: ArrayLike, origin: Sequence[int], size: Sequence[int]) -> np.ndarray:
    """One box of a 3D volume, read alone.

    Parameters
    ----------
    volume : array-like, shape (Z, Y, X)
        A NumPy array, a memory map (`memmap_volume`) or a Zarr array: only the
        box is read (from a memory map, only the pages it crosses; from a Zarr
        array, only the chunks it crosses).
    origin : sequence of 3 int
        First voxel ``(z, y, x)`` of the box, inside the volume.
    size : sequence of 3 int
        Extent ``(d, h, w)`` of the box in voxels; the box must lie inside the volume.

    Returns
    -------
    ndarray, dtype of `volume`, shape `size`
        A view when `volume` is a NumPy array or memory map.
    """
    box = tuple(slice(int(start), int(start) + int(extent)) for start, extent in zip(origin, size))
    out = np.asarray(volume[box])
    if out.shape != tuple(int(n) for n in size):
        raise ValueError(f"box at {tuple(origin)} of size {tuple(size)} is not inside a volume of shape {volume.shape}")
    return out


# --------------------------------------------------------------------------- #
# Label images (2D instance labels of slices)
# --------------------------------------------------------------------------- #


def write_label_image(stem: str | os.PathLike, labels: np.ndarray) -> Path:
    """Write a 2D label image that `read_label_image` reads back exactly.

    Parameters
    ----------
    stem : path-like
        Path without extension: ``.png`` (16-bit grey) is added when every id
        fits in 16 bits, else ``.tif`` (uint32).
    labels : ndarray of int, shape (H, W)
        0 = background, one positive id per instance.

    Returns
    -------
    Path
        The file written.
    """
    stem = Path(stem)
    png = labels.max(initial=0) <= np.iinfo(np.uint16).max
    path = stem.with_suffix(".png" if png else ".tif")
    with atomic_file(path) as tmp:
        if png:
            Image.fromarray(labels.astype(np.uint16)).save(tmp, format="PNG")
        else:
            tifffile.imwrite(tmp, labels.astype(np.uint32))
    return path


def read_label_image(path: str | os.PathLike) -> np.ndarray:
    """Read a label image: PNG (8/16/32-bit grey or palette), TIFF (2D or 3D stack) or NPY.

    Returns
    -------
    ndarray of int, shape (H, W) or (Z, Y, X)

    Raises
    ------
    SynthpackInputError
        If the file is unreadable, a colour image, not integral or not 2D/3D.
    """
    path = Path(path)
    try:
        if path.suffix.lower() == ".png":
            with Image.open(path) as image:
                if image.mode not in ("1", "L", "P", "I", "I;16", "I;16B", "I;16L"):
                    raise SynthpackInputError(
                        f"{path} is a {image.mode} image: label images must be single-channel "
                        "(grey or palette), one integer id per instance"
                    )
                array = np.array(image)
        elif path.suffix.lower() in _TIFF_SUFFIXES:
            with _open_tiff(path) as tif:
                array = tif.asarray()
        elif path.suffix.lower() == ".npy":
            array = np.load(path, allow_pickle=False)
        else:
            raise SynthpackInputError(f"{path}: unknown label image type; use one of {', '.join(LABEL_IMAGE_SUFFIXES)}")
    except SynthpackInputError:
        raise
    except Exception as error:
        raise SynthpackInputError(f"cannot read label image {path} ({error}): check the file") from error
    if array.ndim not in (2, 3):
        raise SynthpackInputError(f"{path} has shape {array.shape}: label images must be 2D (H, W) or 3D (Z, Y, X)")
    if array.dtype == bool:
        return array.astype(np.uint8)
    if not np.issubdtype(array.dtype, np.integer):
        if not np.all(np.isfinite(array)) or np.any(array != np.round(array)):
            raise SynthpackInputError(f"{path} holds fractional values: label images must hold integer ids")
        array = array.astype(np.int64)
    if array.size and array.min() < 0:
        raise SynthpackInputError(f"{path} holds negative values: use 0 for background and 1..N for instances")
    return array


# --------------------------------------------------------------------------- #
# Reading
# --------------------------------------------------------------------------- #


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
    logger.info("read %s: %s %s, voxel size %s %s", path, volume.shape, volume.dtype,
                size, unit)
    return volume, size, unit


def _reader_for(path: Path) -> tuple[Callable[..., Volume], str]:
    """Return ``(reader, format description)`` for `path`, or raise."""
    if path.is_dir():
        if path.suffix.lower() == ".zarr" or _is_zarr_store(path):
            return _read_zarr, "a Zarr store"
        files = _visible_files(path)
        tiffs = [f for f in files if f.suffix.lower() in _TIFF_SUFFIXES]
        blocks = [f for f in files if f.suffix.lower() == ".nc"]
        if tiffs and blocks:
            raise SynthpackInputError(
                f"the folder {path} holds both TIFF slices and NetCDF blocks: keep one "
                "volume per folder"
            )
        if tiffs:
            return _read_tiff_folder, "a folder of TIFF slices"
        if blocks:
            return _read_netcdf_folder, "a folder of NetCDF blocks"
        what = "is empty" if not files else "holds no TIFF slices or NetCDF blocks"
        raise SynthpackInputError(
            f"the folder {path} {what}: a volume folder must hold 2D TIFF slices "
            f"(.tif/.tiff) or NetCDF blocks (.nc), or be a Zarr store. "
            f"Supported formats: {'; '.join(SUPPORTED_FORMATS)}"
        )
    hdf5, raw, itk = (_read_hdf5, "HDF5"), (_read_raw, "raw binary"), (_read_metaimage, "MetaImage")
    nrrd, nifti = (_read_nrrd, "NRRD"), (_read_nifti, "NIfTI")
    readers = {
        ".tif": (_read_tiff, "TIFF"),
        ".tiff": (_read_tiff, "TIFF"),
        ".npy": (_read_npy, "NumPy .npy"),
        ".nc": (_read_netcdf, "NetCDF"),
        ".h5": hdf5, ".hdf5": hdf5, ".hdf": hdf5, ".nxs": hdf5,
        ".mhd": itk, ".mha": itk,
        ".nrrd": nrrd, ".nhdr": nrrd,
        ".nii": nifti, ".nii.gz": nifti,
        ".raw": raw, ".bin": raw, ".vol": raw,
    }
    suffix = ".nii.gz" if path.name.lower().endswith(".nii.gz") else path.suffix.lower()
    if suffix not in readers:
        raise SynthpackInputError(
            f"{path} is not a supported volume file (extension {path.suffix!r}). "
            f"Supported formats: {'; '.join(SUPPORTED_FORMATS)}. Convert it to one "
            "of these (e.g. save as TIFF stack from Fiji)"
        )
    return readers[suffix]


def _split_spec(path: PathLike) -> tuple[Path, str | None]:
    """`path` without what follows the colon after an HDF5 or raw file name, and that (None if nothing).

    A file whose name really contains the colon is taken whole.
    """
    text = os.fspath(path)
    match = _PATH_SPEC.match(text)
    if match is None or Path(text).exists():
        return Path(text), None
    return Path(match["file"]), match["spec"] or None


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


def _read_npy(path: Path, role: str | None, name: str | None) -> Volume:
    return np.load(path, allow_pickle=False), None, None


@contextmanager
def _open_tiff(path: Path) -> Iterator[tifffile.TiffFile]:
    """Open `path` with tifffile, refusing a file that looks truncated (see `_check_tiff_complete`).

    tifffile reports a damaged file by logging errors and reading what it can.
    Its log messages are held back while the file is open: dropped when an error
    is raised (its message says what is wrong), logged as warnings otherwise.
    """
    messages: list[str] = []

    def hold(record: logging.LogRecord) -> bool:
        messages.append(record.getMessage())
        return False

    tifffile_logger = logging.getLogger("tifffile")
    tifffile_logger.addFilter(hold)
    try:
        with tifffile.TiffFile(path) as tif:
            _check_tiff_complete(tif, path)
            yield tif
    finally:
        tifffile_logger.removeFilter(hold)
    for message in messages:
        logger.warning("%s: %s", path, message)


def _check_tiff_complete(tif: tifffile.TiffFile, path: Path) -> None:
    """Raise if `tif` refers to bytes past its end: a copy or export cut short.

    A truncated TIFF often still opens, and tifffile reads the pages it finds:
    a stack cut in half would come back as fewer slices, or a single one. Two
    references can point past the end: the link from the last page found to the
    next one, and the image data of the first series.
    """
    size = tif.filehandle.size
    found = len(tif.pages)  # follows the whole chain of pages
    end = _next_page_link(tif)
    if end <= size and tif.series:
        end = max(end, _data_end(tif.series[0]))
    if end <= size:
        return
    announced = _announced_images(tif)
    pages = f"{announced} images announced, {found} found; " if announced and announced > found else ""
    raise SynthpackInputError(
        f"{path} looks truncated (incomplete): {pages}the file is {size:,} bytes but refers to data up "
        f"to byte {end:,}. Re-export or copy the file again"
    )


def _announced_images(tif: tifffile.TiffFile) -> int | None:
    """The number of 2D images that the ImageJ or tifffile metadata of `tif` announce, if any."""
    if tif.imagej_metadata:
        return int(tif.imagej_metadata.get("images", 1))
    if tif.shaped_metadata and tif.pages.first.size:
        return int(np.prod(tif.shaped_metadata[0]["shape"])) // tif.pages.first.size
    return None


def _next_page_link(tif: tifffile.TiffFile) -> int:
    """Where the last page found says the next page is (0: it is the last), or where that link would end."""
    position = tif.pages.next_page_offset
    if position is None:
        return 0
    tif.filehandle.seek(position)
    raw = tif.filehandle.read(tif.tiff.offsetsize)
    if len(raw) < tif.tiff.offsetsize:
        return position + tif.tiff.offsetsize
    return int(struct.unpack(tif.tiff.offsetformat, raw)[0])


def _data_end(series: tifffile.TiffPageSeries) -> int:
    """The byte after the last image data of `series` in its file."""
    if series.dataoffset is not None:
        return int(series.dataoffset) + int(series.nbytes)
    return max((int(offset) + int(count) for page in series.pages if page is not None
                for offset, count in zip(page.dataoffsets, page.databytecounts)), default=0)


def _read_tiff(path: Path, role: str | None, name: str | None) -> Volume:
    with _open_tiff(path) as tif:
        if len(tif.series) > 1:
            logger.warning("%s holds %d image series of shapes %s; reading the first only",
                           path, len(tif.series), [s.shape for s in tif.series])
        volume = tif.asarray()
        size, unit = _tiff_voxel_size(tif, stack=True)
    return volume, size, unit


def _read_tiff_folder(path: Path, role: str | None, name: str | None) -> Volume:
    files = _natural_sorted(
        f for f in _visible_files(path) if f.suffix.lower() in _TIFF_SUFFIXES
    )
    with _reading(files[0], "TIFF"), _open_tiff(files[0]) as tif:
        shape, dtype = tif.series[0].shape, tif.series[0].dtype
        size, unit = _tiff_voxel_size(tif, stack=False)
    if len(shape) != 2:
        raise SynthpackInputError(
            f"{files[0]} holds an image of shape {shape}, but a folder of slices must "
            "hold one 2D grayscale image per file"
        )
    volume = np.empty((len(files), *shape), dtype=dtype)
    for k, file in enumerate(files):
        with _reading(file, "TIFF"), _open_tiff(file) as tif:
            series = tif.series[0]
            if series.shape != shape or series.dtype != dtype:
                raise SynthpackInputError(
                    f"slice {file.name} has shape {series.shape} and dtype {series.dtype} "
                    f"but {files[0].name} has shape {shape} and dtype {dtype}: every "
                    f"slice in {path} must have the same shape and dtype (remove stray "
                    "files or re-export the stack)"
                )
            volume[k] = series.asarray()
    return volume, size, unit


def _tiff_voxel_size(tif: tifffile.TiffFile, stack: bool) -> Metadata:
    """Voxel size ``(dz, dy, dx)`` and unit from ImageJ metadata or resolution tags.

    The slice spacing of an ImageJ stack is its ``spacing`` entry (1.0 when
    absent, as in ImageJ). A single slice, or a non-ImageJ file, records no
    spacing: the voxel is then assumed cubic (dz = dx).
    """
    page = tif.pages[0]
    xres = _tag_ratio(page, "XResolution")
    yres = _tag_ratio(page, "YResolution")
    imagej = tif.imagej_metadata
    if imagej:
        unit = _normalise_unit(str(imagej.get("unit", "")))
        if unit == "px":
            return None, None
        dx = 1.0 / xres if xres else 1.0
        dy = 1.0 / yres if yres else dx
        default_dz = 1.0 if stack else dx
        return (float(imagej.get("spacing", default_dz)), dy, dx), unit
    scale = _TIFF_RESOLUTION_UNITS.get(page.resolutionunit)
    if scale is None or not xres or not yres:
        return None, None
    dx, dy = scale / xres, scale / yres
    return (dx, dy, dx), "um"


def _tag_ratio(page: tifffile.TiffPage, tag: str) -> float | None:
    """A RATIONAL tag as a float, or None when absent or degenerate."""
    value = page.tags.valueof(tag)
    if value is None:
        return None
    numerator, denominator = value
    return numerator / denominator if numerator > 0 and denominator > 0 else None


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


def _attribute_voxel_size(voxel_size: object, unit: object, path: Path) -> Metadata:
    """Validated voxel size and unit from store attributes, or (None, None)."""
    if voxel_size is None or unit is None:
        return None, None
    try:
        size = validate_voxel_size(voxel_size)
    except SynthpackInputError as exc:
        try:  # plain numbers, not np.float32(...)
            voxel_size = np.asarray(voxel_size, dtype=float).tolist()
        except (TypeError, ValueError):
            pass
        raise SynthpackInputError(
            f"{path} records an invalid voxel size {voxel_size!r}: fix its metadata "
            "or pass the voxel size explicitly"
        ) from exc
    unit = _normalise_unit(str(unit))
    return (None, None) if unit == "px" else (size, unit)


def _optional(module: str, what: str, doing: str = "reading") -> Any:
    """Import the optional package `module` that reads (or, `doing`, writes) `what`, or say how to install it."""
    try:
        return importlib.import_module(module)
    except ImportError as exc:
        package, extra = _OPTIONAL[module]
        raise SynthpackInputError(
            f"{doing} {what} needs the Python package {package}, which is not installed: "
            f'pip install "synthpack[{extra}]" (or pip install {package})'
        ) from exc


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


def _read_metaimage(path: Path, role: str | None, name: str | None) -> Volume:
    sitk = _optional("SimpleITK", "MetaImage files")
    try:
        with _native_stderr_held(path):
            image = sitk.ReadImage(str(path), imageIO="MetaImageIO")
    except RuntimeError as exc:  # ITK's reason without its source file, object address and errno text
        reason = re.sub(r"^.*ITK ERROR: \w+\(0x[0-9a-f]+\): |\s*Reason: [^.]*\.?$", "", " ".join(str(exc).split()))
        raise RuntimeError(reason.rstrip(".")) from exc
    volume = sitk.GetArrayFromImage(image)  # (z, y, x) for a 3D image
    return volume, *_itk_voxel_size(image.GetSpacing(), None, path)


@contextmanager
def _native_stderr_held(path: Path) -> Iterator[None]:
    """Hold back what native code (ITK's MetaIO) prints on the process's stderr while reading `path`.

    Like tifffile's log messages in `_open_tiff`: dropped when an error is raised
    (its message says what is wrong), logged as warnings otherwise. Nothing else
    should write to stderr meanwhile: file descriptor 2 is redirected.
    """
    sys.stderr.flush()
    saved = os.dup(2)
    with tempfile.TemporaryFile() as held:
        os.dup2(held.fileno(), 2)
        try:
            yield
        finally:
            os.dup2(saved, 2)
            os.close(saved)
        held.seek(0)
        for line in held.read().decode(errors="replace").splitlines():
            if line.strip():
                logger.warning("%s: %s", path, line.strip())


def _read_nrrd(path: Path, role: str | None, name: str | None) -> Volume:
    nrrd = _optional("nrrd", "NRRD files")
    volume, header = nrrd.read(str(path), index_order="C")  # (z, y, x): file axes reversed
    if "space directions" in header:
        directions = [np.asarray(row, dtype=float) for row in header["space directions"]]
        spacing = [float(np.linalg.norm(row)) for row in directions if np.all(np.isfinite(row))]
    else:
        spacing = [float(v) for v in header.get("spacings", ()) if np.isfinite(v)]
    units = set(header.get("space units", ()))
    return volume, *_itk_voxel_size(spacing, units.pop() if len(units) == 1 else None, path)


def _itk_voxel_size(spacing: Iterable[float], unit: str | None, path: Path) -> Metadata:
    """``(dz, dy, dx)`` from an ITK-order ``(dx, dy, dz)`` spacing; without a unit, `_ITK_UNIT`."""
    spacing = tuple(spacing)
    if len(spacing) != 3:
        return None, None
    if unit is None:
        logger.info("%s records no length unit: its spacing is taken in %s, as ITK and 3D Slicer do",
                    path, _ITK_UNIT)
    return _attribute_voxel_size(spacing[::-1], unit or _ITK_UNIT, path)


def _read_nifti(path: Path, role: str | None, name: str | None) -> Volume:
    nibabel = _optional("nibabel", "NIfTI files")
    image = nibabel.load(path, mmap=False)
    data = np.asarray(image.dataobj)
    while data.ndim > 3 and data.shape[-1] == 1:  # (x, y, z, 1): a volume saved with a time axis
        data = data[..., 0]
    volume = np.ascontiguousarray(data.T)  # stored (x, y, z): now (z, y, x)
    unit = image.header.get_xyzt_units()[0]
    zooms = image.header.get_zooms()[:3] if volume.ndim == 3 else ()
    return volume, *_itk_voxel_size(zooms, None if unit == "unknown" else unit, path)


def _read_raw(path: Path, role: str | None, name: str | None) -> Volume:
    """Read a headerless binary volume whose layout `name` gives (see `_raw_layout`)."""
    shape, dtype = _raw_layout(name, path)
    expected = math.prod(shape) * dtype.itemsize
    size = path.stat().st_size
    if size != expected:
        raise SynthpackInputError(
            f"{path} is {size:,} bytes but {'x'.join(map(str, shape))} voxels of {dtype.name} take "
            f"{expected:,}: check the shape and dtype after the colon ({_RAW_LAYOUT})"
        )
    volume = np.fromfile(path, dtype=dtype).reshape(shape)
    return volume.astype(dtype.newbyteorder("="), copy=False), None, None


def _raw_layout(spec: str | None, path: Path) -> tuple[tuple[int, int, int], np.dtype]:
    """Shape ``(Z, Y, X)`` and dtype (with its byte order) of a raw file from ``ZxYxX:DTYPE[:BYTE_ORDER]``."""
    parts = [] if spec is None else spec.lower().split(":")
    shape_text, dtype_name, order = (parts + ["", "", ""])[:3]
    dims = shape_text.split("x")
    if spec is None:
        problem = "its layout is missing after a colon"
    elif len(parts) > 3:
        problem = f"layout {spec!r} has more than three parts"
    elif len(dims) != 3 or not all(d.isdigit() and int(d) > 0 for d in dims):
        problem = f"shape {shape_text!r} is not three positive integers ZxYxX"
    elif dtype_name not in _RAW_DTYPES:
        problem = f"dtype {dtype_name!r} is not supported"
    elif order and order not in _RAW_BYTE_ORDERS:
        problem = f"byte order {order!r} is not little or big"
    elif not order and np.dtype(dtype_name).itemsize > 1:
        problem = f"the byte order of {dtype_name} is missing"
    else:
        shape = (int(dims[0]), int(dims[1]), int(dims[2]))
        return shape, np.dtype(dtype_name).newbyteorder(_RAW_BYTE_ORDERS.get(order, "="))
    raise SynthpackInputError(f"cannot read the raw file {path}: {problem}; give {_RAW_LAYOUT}")


# --------------------------------------------------------------------------- #
# Voxel size and units
# --------------------------------------------------------------------------- #


def _normalise_unit(unit: str) -> str:
    """Canonical spelling of a length unit: ``"um"`` for micron/µm, ``"px"`` for none."""
    key = unit.strip()
    return _UNIT_ALIASES.get(key.lower(), _UNIT_ALIASES.get(key, key))


def convert_voxel_size(size: VoxelSize, unit: str, to: str) -> VoxelSize | None:
    """Voxel size `size` from `unit` into `to`, or None if either is not a known length unit (nm, um, mm, cm, m)."""
    if unit not in _MICROMETRES or to not in _MICROMETRES:
        return None
    factor = _MICROMETRES[unit] / _MICROMETRES[to]
    return tuple(v * factor for v in size)  # type: ignore[return-value]


def _resolve_voxel_size(
    voxel_size: float | tuple[float, ...] | None,
    unit: str | None,
    tomo_meta: Metadata,
    label_meta: Metadata,
) -> tuple[VoxelSize, str, str]:
    """Choose ``(voxel_size, unit, where it came from)`` for read_scan (see its Notes)."""
    unit = None if unit is None else _normalise_unit(unit)
    meta_size, meta_unit = tomo_meta if tomo_meta[0] is not None else label_meta
    origin = "tomogram metadata" if tomo_meta[0] is not None else "labels metadata"
    if tomo_meta[0] is not None and label_meta[0] is not None and (
        tomo_meta[1] != label_meta[1] or not np.allclose(tomo_meta[0], label_meta[0])
    ):
        logger.info("voxel size in the tomogram metadata (%s %s) and the labels metadata "
                    "(%s %s) differ; using the tomogram's", *tomo_meta, *label_meta)
    if voxel_size is not None:
        size = validate_voxel_size(voxel_size)
        unit = unit or meta_unit or "um"
        if meta_size is not None and (unit != meta_unit or not np.allclose(size, meta_size)):
            logger.info("voxel size %s %s given explicitly overrides %s %s from the %s",
                        size, unit, meta_size, meta_unit, origin)
        return size, unit, "argument"
    if meta_size is not None:
        if unit is None or unit == meta_unit:
            return meta_size, meta_unit, origin
        converted = convert_voxel_size(meta_size, meta_unit, unit)
        if converted is not None:
            return converted, unit, origin
        logger.info("unit %r given explicitly overrides %r from the %s (no conversion "
                    "between them is known)", unit, meta_unit, origin)
        return meta_size, unit, origin
    if unit is not None:
        logger.info("unit %r ignored: no voxel size was given or recorded", unit)
    return (1.0, 1.0, 1.0), "px", "default"


# --------------------------------------------------------------------------- #
# Writing
# --------------------------------------------------------------------------- #


def _require_volume(volume: np.ndarray) -> np.ndarray:
    volume = np.asarray(volume)
    if volume.ndim != 3 or volume.size == 0:
        raise SynthpackInputError(
            f"cannot write an array of shape {volume.shape}: a non-empty 3D volume "
            "(z, y, x) is needed"
        )
    return volume


def _imagej_compatible(volume: np.ndarray, labels: bool) -> np.ndarray:
    """`volume` as uint8, uint16 or float32, converted by the rule given in write_tiff."""
    dtype = volume.dtype
    if dtype == bool:
        return volume.astype(np.uint8)
    if dtype in (np.uint8, np.uint16):
        return volume
    if np.issubdtype(dtype, np.integer):
        low, high = volume.min(), volume.max()
        if low >= 0 and high <= np.iinfo(np.uint16).max:
            return volume.astype(np.uint16)
        if labels:
            raise SynthpackInputError(
                f"the label volume holds values from {low} to {high}, outside 0..65535, "
                "the range an ImageJ TIFF holds exactly: write it with write_zarr "
                "instead (or relabel the particles 1..N first)"
            )
        return volume.astype(np.float32)
    if labels:
        raise SynthpackInputError(
            f"cannot write a label volume of dtype {dtype} as TIFF: labels must be "
            "integers (0 = background, 1..N = particles)"
        )
    if not np.issubdtype(dtype, np.floating):
        raise SynthpackInputError(
            f"cannot write a volume of dtype {dtype} as TIFF: it must hold real numbers"
        )
    if dtype.itemsize > 4 and np.nanmax(np.abs(volume)) > np.finfo(np.float32).max:
        raise SynthpackInputError(
            "the volume holds values beyond the float32 range, the widest type ImageJ "
            "stores: rescale it, or write it with write_zarr"
        )
    return volume.astype(np.float32, copy=False)


def _imagej_unit(unit: str) -> str:
    """Unit for ImageJ: ``"micron"`` for µm (Fiji shows µm), ``"pixel"`` for none."""
    return {"um": "micron", "px": "pixel"}.get(_normalise_unit(unit), unit)


# --------------------------------------------------------------------------- #
# Paths
# --------------------------------------------------------------------------- #


def _is_zarr_store(path: Path) -> bool:
    return path.is_dir() and any((path / marker).is_file() for marker in _ZARR_MARKERS)


def _is_zarr_group(path: Path) -> bool:
    with _reading(path, "a Zarr store"):
        return isinstance(zarr.open(str(path), mode="r"), zarr.Group)


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
