"""What the torch block steps share: the device a step runs on, and what it keeps there for a volume.

A transform's torch step, `~synthpack.artefacts.Transform._transform_block_torch`, is
defined in the transform's own module beside its NumPy step; it gets a `DeviceVolume`
to move arrays to the device and to keep what it computes once per volume (noise
tiles, a slice's ring pattern or cupping factor). This module imports torch; the
transform modules name it in type hints only (and import torch inside their torch
steps), and `synthpack.artefacts.blockwise` imports it only when asked for a device.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Hashable
from typing import Any

import numpy as np
import torch

__all__ = ["DeviceVolume"]


class DeviceVolume:
    """One transform's torch device for one volume: arrays moved there, and what is made once per volume.

    `apply_blockwise` gives each step of a pass its own, shared by the blocks of that
    pass (which may run in several threads at once).

    Parameters
    ----------
    device : str or torch.device
        E.g. ``"cuda"``, or ``"cpu"`` (the same arithmetic, for tests).
    """

    def __init__(self, device: str | torch.device) -> None:
        self.device = torch.device(device)
        self._kept: dict[Hashable, Any] = {}
        self._lock = threading.Lock()

    def put(self, array: np.ndarray) -> torch.Tensor:
        """`array` as a tensor on the device (a read-only array is copied first: torch wants writable memory)."""
        return torch.as_tensor(array if array.flags.writeable else array.copy(), device=self.device)

    @staticmethod
    def get(tensor: torch.Tensor) -> np.ndarray:
        """`tensor` back on the CPU, as a NumPy array of its dtype."""
        return tensor.cpu().numpy()

    def once(self, key: Hashable, make: Callable[[], Any]) -> Any:
        """``make()``, computed on the first call with `key` and kept for the volume's other blocks."""
        with self._lock:
            if key not in self._kept:
                self._kept[key] = make()
            return self._kept[key]
