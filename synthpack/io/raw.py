"""Raw binary volumes: no header, the layout ``ZxYxX:DTYPE:BYTE_ORDER`` given after a colon.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from .._shared.budget import check_read
from ..errors import SynthpackInputError
from ._base import Volume


_RAW_DTYPES = ("uint8", "int8", "uint16", "int16", "uint32", "int32", "uint64", "int64", "float32", "float64")

_RAW_BYTE_ORDERS = {"little": "<", "big": ">"}

_RAW_LAYOUT = ("FILE.raw:ZxYxX:DTYPE:BYTE_ORDER, e.g. scan.raw:512x1024x1024:uint16:little (Z slices of Y "
               "rows of X voxels, X varying fastest; DTYPE one of " + ", ".join(_RAW_DTYPES)
               + "; BYTE_ORDER little or big, optional for 1-byte dtypes)")


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
    check_read(shape, dtype, path)
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

