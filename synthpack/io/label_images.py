"""2D instance label images (PNG, TIFF, NPY): the truth and predictions of scored slices.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import tifffile
from PIL import Image

from .atomic import atomic_file
from ..errors import SynthpackInputError
from .tiff import _TIFF_SUFFIXES, _open_tiff


#: File types `read_label_image` reads.
LABEL_IMAGE_SUFFIXES = (".png", ".tif", ".tiff", ".npy")


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

