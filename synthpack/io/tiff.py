"""TIFF: multi-page stacks and folders of 2D slices (voxel size from ImageJ metadata or the
resolution tags), refusing truncated files; `write_tiff` writes ImageJ hyperstacks.
"""

from __future__ import annotations

import logging
import struct
import warnings
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import tifffile

from .atomic import atomic_file
from .._shared.budget import check_read
from ..errors import SynthpackInputError
from ..scan.core import validate_voxel_size
from ._base import Metadata, PathLike, Volume, _natural_sorted, _reading, _require_volume, _visible_files
from .units import _normalise_unit

logger = logging.getLogger(__name__)


_TIFF_SUFFIXES = (".tif", ".tiff")

# TIFF ResolutionUnit values that are lengths, in micrometres (INCH is left
# out on purpose: an inch resolution is a display DPI, not a voxel size).
_TIFF_RESOLUTION_UNITS = {
    tifffile.RESUNIT.CENTIMETER: 1e4,
    tifffile.RESUNIT.MILLIMETER: 1e3,
    tifffile.RESUNIT.MICROMETER: 1.0,
}

# Above this many bytes write_tiff writes BigTIFF (same margin as tifffile).
_BIGTIFF_BYTES = 2**32 - 2**25


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
    logger.debug("wrote %s: %s %s, voxel %s %s", path, data.shape, data.dtype, size, unit)
    return path


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
        check_read(tif.series[0].shape, tif.series[0].dtype, path)
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
    check_read((len(files), *shape), dtype, path)
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

