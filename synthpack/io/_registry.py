"""The input formats, one `Format` record each: the one list that detection, the path grammar,
`SUPPORTED_FORMATS`, the install messages and the command line's ``--tomogram`` help come from.

A new input format is one module of this package holding its reader (a function
``(path, role, name) -> (volume, voxel_size, unit)``, see `synthpack.io._base.Volume`) and
one `Format` line in `FORMATS`. Importing this module imports no reader and no storage
library: a reader's module is imported when the first file of its format is read.
"""

from __future__ import annotations

import importlib
import os
import re
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ..errors import SynthpackInputError
from ._base import PathLike, Volume, _is_zarr_store, _visible_files

__all__ = ["FORMATS", "Format", "SUPPORTED_FORMATS", "supported_formats", "tomogram_help"]


@dataclass(frozen=True)
class Format:
    """One input format: how a path is recognised, what reads it and how it is described.

    Attributes
    ----------
    name : str
        How errors name the format: ``"cannot read scan.h5 as HDF5: ..."``.
    reader : str
        ``"module:function"`` of the reader, the module relative to `synthpack.io`
        (``".hdf5:_read_hdf5"``) or absolute; imported on first use. The reader takes
        ``(path, role, name)`` and returns ``(volume, voxel_size, unit)``.
    suffixes : tuple of str
        A file whose name ends with one of these (any case) is of this format.
    folder_of : tuple of str
        A folder holding files with these suffixes is of this format (one file per slice
        or block); `holds` and `folder_needs` name its files in messages.
    store : callable, optional
        A folder for which ``store(path)`` is true is of this format (a Zarr store); it
        wins over `folder_of` formats.
    description : str, optional
        Its entry in `SUPPORTED_FORMATS`; None when another format's entry covers it.
    help : str, optional
        Its term in the ``--tomogram`` help; None when another format's term covers it.
    spec : str, optional
        What may follow a colon after the file name (``/entry/data``): the file's own
        part of its path; None when nothing may.
    requires : tuple of 3 str, optional
        ``(module, package to install, extra of synthpack holding it)`` of an optional
        reader package, e.g. ``("h5py", "h5py", "formats")``.
    holds, folder_needs : str
        For `folder_of` formats: its files (``"TIFF slices"``) and what a volume
        folder of it must hold (``"2D TIFF slices (.tif/.tiff)"``).
    """

    name: str
    reader: str
    suffixes: tuple[str, ...] = ()
    folder_of: tuple[str, ...] = ()
    store: Callable[[Path], bool] | None = None
    description: str | None = None
    help: str | None = None
    spec: str | None = None
    requires: tuple[str, str, str] | None = None
    holds: str = ""
    folder_needs: str = ""

    def matches(self, path: Path) -> bool:
        """True if `path` (an existing file or folder) is of this format (see the attributes)."""
        if path.is_dir():
            if self.store is not None:
                return self.store(path)
            return bool(self.folder_of) and any(f.suffix.lower() in self.folder_of for f in _visible_files(path))
        name = path.name.lower()
        return any(name.endswith(suffix) and len(name) > len(suffix) for suffix in self.suffixes)

    def load_reader(self) -> Callable[..., Volume]:
        """The reader function, its module imported now."""
        module, function = self.reader.split(":")
        return getattr(importlib.import_module(module, __package__), function)


#: The input formats, in the order they are listed and tried.
FORMATS: tuple[Format, ...] = (
    Format("TIFF", ".tiff:_read_tiff", suffixes=(".tif", ".tiff"),
           description="multi-page TIFF (.tif, .tiff)", help="TIFF stack"),
    Format("a folder of TIFF slices", ".tiff:_read_tiff_folder", folder_of=(".tif", ".tiff"),
           description="folder of 2D TIFF slices", help="folder of TIFF slices",
           holds="TIFF slices", folder_needs="2D TIFF slices (.tif/.tiff)"),
    Format("NumPy .npy", ".npy:_read_npy", suffixes=(".npy",), description="NumPy array (.npy)", help=".npy"),
    Format("a Zarr store", ".zarr_store:_read_zarr",
           store=lambda path: path.suffix.lower() == ".zarr" or _is_zarr_store(path),
           description="Zarr store (directory, e.g. .zarr)", help=".zarr"),
    Format("NetCDF", ".netcdf:_read_netcdf", suffixes=(".nc",),
           description="Mango NetCDF (.nc, or a folder of block*.nc files split along z)", help="NetCDF"),
    Format("a folder of NetCDF blocks", ".netcdf:_read_netcdf_folder", folder_of=(".nc",),
           holds="NetCDF blocks", folder_needs="NetCDF blocks (.nc)"),
    Format("HDF5", ".hdf5:_read_hdf5", suffixes=(".h5", ".hdf5", ".hdf", ".nxs"), spec="/entry/data",
           description="HDF5 (.h5, .hdf5, .hdf, .nxs; a dataset after a colon: scan.h5:/entry/data)",
           help="HDF5 (scan.h5, or scan.h5:/entry/data for one dataset)", requires=("h5py", "h5py", "formats")),
    Format("MetaImage", ".itk:_read_metaimage", suffixes=(".mhd", ".mha"), description="MetaImage (.mhd, .mha)",
           help="MetaImage", requires=("SimpleITK", "SimpleITK", "metaimage")),
    Format("NRRD", ".itk:_read_nrrd", suffixes=(".nrrd", ".nhdr"), description="NRRD (.nrrd, .nhdr)", help="NRRD",
           requires=("nrrd", "pynrrd", "formats")),
    Format("NIfTI", ".itk:_read_nifti", suffixes=(".nii", ".nii.gz"), description="NIfTI (.nii, .nii.gz)",
           help="NIfTI", requires=("nibabel", "nibabel", "formats")),
    Format("raw binary", ".raw:_read_raw", suffixes=(".raw", ".bin", ".vol"), spec="ZxYxX:DTYPE:BYTE_ORDER",
           description="raw binary with its layout after a colon (scan.raw:ZxYxX:uint16:little)",
           help="raw binary with its layout: scan.raw:ZxYxX:DTYPE:BYTE_ORDER, e.g. "
                "scan.raw:512x1024x1024:uint16:little"),
)


def supported_formats() -> tuple[str, ...]:
    """The formats' descriptions, for messages: `SUPPORTED_FORMATS` of the formats registered now."""
    return tuple(f.description for f in FORMATS if f.description is not None)


#: What `read_volume` reads, one description per format, for messages and documentation.
SUPPORTED_FORMATS = supported_formats()


def tomogram_help() -> str:
    """The command line's help of ``--tomogram``: the formats' `Format.help` terms."""
    terms = [f.help for f in FORMATS if f.help is not None]
    return f"tomogram: {', '.join(terms[:-1])}, or {terms[-1]}"


def _reader_for(path: Path) -> tuple[Callable[..., Volume], str]:
    """Return ``(reader, format name)`` for `path`, or raise."""
    if path.is_dir():
        stores = [f for f in FORMATS if f.store is not None]
        folders = [f for f in FORMATS if f.folder_of]
        found = [f for f in stores if f.matches(path)] or [f for f in folders if f.matches(path)]
        if len(found) > 1:
            raise SynthpackInputError(
                f"the folder {path} holds both {' and '.join(f.holds for f in found)}: keep one "
                "volume per folder"
            )
        if found:
            return found[0].load_reader(), found[0].name
        what = "is empty" if not _visible_files(path) else f"holds no {' or '.join(f.holds for f in folders)}"
        raise SynthpackInputError(
            f"the folder {path} {what}: a volume folder must hold {' or '.join(f.folder_needs for f in folders)}, "
            f"or be {' or '.join(f.name for f in stores)}. "
            f"Supported formats: {'; '.join(supported_formats())}"
        )
    found = [f for f in FORMATS if f.suffixes and f.matches(path)]
    if not found:
        raise SynthpackInputError(
            f"{path} is not a supported volume file (extension {path.suffix!r}). "
            f"Supported formats: {'; '.join(supported_formats())}. Convert it to one "
            "of these (e.g. save as TIFF stack from Fiji)"
        )
    return found[0].load_reader(), found[0].name


def _path_spec() -> re.Pattern[str]:
    """A path, then after a colon what `Format.spec` says: the dataset of an HDF5 file
    (scan.h5:/entry/data) or the layout of a raw file (scan.raw:64x128x256:uint16:little)."""
    suffixes = "|".join(re.escape(s.lstrip(".")) for f in FORMATS if f.spec is not None for s in f.suffixes)
    return re.compile(rf"^(?P<file>.+?\.(?:{suffixes})):(?P<spec>.*)$", re.IGNORECASE)


def _split_spec(path: PathLike) -> tuple[Path, str | None]:
    """`path` without what follows the colon after an HDF5 or raw file name, and that (None if nothing).

    A file whose name really contains the colon is taken whole.
    """
    text = os.fspath(path)
    match = _path_spec().match(text)
    if match is None or Path(text).exists():
        return Path(text), None
    return Path(match["file"]), match["spec"] or None


def _optional(module: str, what: str, doing: str = "reading") -> Any:
    """Import the optional package `module` that reads (or, `doing`, writes) `what`, or say how to install it."""
    try:
        return importlib.import_module(module)
    except ImportError as exc:
        package, extra = next(f.requires[1:] for f in FORMATS if f.requires and f.requires[0] == module)
        raise SynthpackInputError(
            f"{doing} {what} needs the Python package {package}, which is not installed: "
            f'pip install "synthpack[{extra}]" (or pip install {package})'
        ) from exc
