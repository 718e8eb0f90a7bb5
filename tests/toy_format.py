"""A toy input format, registered only by tests/test_io_registry.py to prove the extension point.

A ``.toy`` file is text: the line ``shape Z Y X``, optionally the line ``voxel DZ DY DX UNIT``,
then the Z * Y * X integer values, x varying fastest. Its reader is all a new format needs
beside its `~synthpack.io._registry.Format` line.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from synthpack.errors import SynthpackInputError


def read_toy(path: Path, role: str | None, name: str | None) -> tuple[np.ndarray, tuple | None, str | None]:
    """Read a ``.toy`` file: ``(volume (Z, Y, X) int64, (dz, dy, dx) or None, unit or None)``."""
    lines = path.read_text().splitlines()
    if not lines or not lines[0].startswith("shape "):
        raise SynthpackInputError(f"{path} is not a toy file: its first line must be 'shape Z Y X'")
    shape = tuple(int(n) for n in lines[0].split()[1:])
    size, unit, values = None, None, lines[1:]
    if values and values[0].startswith("voxel "):
        *numbers, unit = values[0].split()[1:]
        size, values = tuple(float(v) for v in numbers), values[1:]
    return np.array(" ".join(values).split(), dtype=np.int64).reshape(shape), size, unit
