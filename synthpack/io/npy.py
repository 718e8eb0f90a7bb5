"""NumPy ``.npy`` volumes.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .._shared.budget import check_read
from ._base import Volume


def _read_npy(path: Path, role: str | None, name: str | None) -> Volume:
    volume = np.load(path, mmap_mode="r", allow_pickle=False)
    check_read(volume.shape, volume.dtype, path)
    return np.array(volume), None, None

