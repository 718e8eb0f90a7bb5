"""The ITK family: MetaImage (SimpleITK), NRRD (pynrrd) and NIfTI (nibabel) read; `write_nifti` writes NIfTI-1.
"""

from __future__ import annotations

import logging
import os
import re
import sys
import tempfile
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from .atomic import atomic_file
from ..errors import SynthpackInputError
from ..scan.core import validate_voxel_size
from ._base import Metadata, PathLike, Volume, _require_volume
from ._registry import _optional
from .units import _attribute_voxel_size, _normalise_unit

logger = logging.getLogger(__name__)


# Length unit of ITK-family spacings that record none (MetaImage, NRRD without
# "space units", NIfTI with unknown xyzt_units): ITK's and 3D Slicer's millimetres.
_ITK_UNIT = "mm"

# NIfTI's spatial units (xyzt_units) of synthpack's canonical length units; write_nifti writes others as "unknown".
_NIFTI_UNITS = {"m": "meter", "mm": "mm", "um": "micron"}


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
    logger.debug("wrote %s: %s %s, voxel %s %s", path, data.shape, data.dtype, size, unit)
    return path


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

