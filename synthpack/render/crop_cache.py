"""What the render prepares from each library grain once, kept for the next render in this process.

A render prepares each library grain it places in the grain's own frame (its smooth
surface, `synthpack.render.surface`; its partial-volume intensities,
`synthpack.render.partial_volume`), before any pose. `PREPARED` keeps what was made, up
to `CACHE_BYTES`, under a key made of who prepared it and the `digest` of the grain's
arrays, so the next pack of a run finds it prepared.
"""

from __future__ import annotations

import hashlib
import threading
from collections import OrderedDict
from collections.abc import Callable

import numpy as np

__all__ = ["CACHE_BYTES", "PREPARED", "CropCache", "digest"]

#: Bytes of prepared crops kept for later renders in this process (the least recently used go first).
CACHE_BYTES = 1 << 28


def digest(*arrays: np.ndarray) -> bytes:
    """A digest of the dtypes, shapes and bytes of `arrays` (a cache key)."""
    hashed = hashlib.blake2b(digest_size=20)
    for array in arrays:
        array = np.ascontiguousarray(array)
        hashed.update(f"{array.dtype.str}{array.shape}".encode())
        hashed.update(array.view(np.uint8).reshape(-1) if array.size else b"")
    return hashed.digest()


class CropCache:
    """Tuples of arrays by key, the least recently used dropped beyond `limit` bytes; safe across threads.

    Parameters
    ----------
    limit : int
        Bytes.
    """

    def __init__(self, limit: int) -> None:
        self.limit = limit
        self._entries: OrderedDict[tuple, tuple[np.ndarray, ...]] = OrderedDict()
        self._bytes = 0
        self._lock = threading.Lock()

    def get(self, key: tuple) -> tuple[np.ndarray, ...] | None:
        """The arrays stored under `key` (now the most recently used), or None."""
        with self._lock:
            prepared = self._entries.get(key)
            if prepared is not None:
                self._entries.move_to_end(key)
            return prepared

    def put(self, key: tuple, prepared: tuple[np.ndarray, ...]) -> None:
        """Store `prepared` under `key`, then drop the least recently used beyond the limit."""
        with self._lock:
            if key in self._entries:
                return
            self._entries[key] = prepared
            self._bytes += sum(array.nbytes for array in prepared)
            while self._bytes > self.limit and self._entries:
                _, dropped = self._entries.popitem(last=False)
                self._bytes -= sum(array.nbytes for array in dropped)

    def prepared(self, owner: object, arrays: tuple[np.ndarray, ...],
                 make: Callable[[], tuple[np.ndarray, ...]]) -> tuple[np.ndarray, ...]:
        """What `owner` (a hashable preparer) makes of `arrays`: from the cache, else ``make()``, made read-only and kept."""
        key = (owner, digest(*arrays))
        prepared = self.get(key)
        if prepared is None:
            prepared = make()
            for array in prepared:
                array.flags.writeable = False
            self.put(key, prepared)
        return prepared


#: The render's cache, shared by its preparers.
PREPARED = CropCache(CACHE_BYTES)
