"""Chunk-by-chunk work on large volumes: the tiling of a volume into chunks, and a bounded thread map."""

from __future__ import annotations

import itertools
import os
from collections import deque
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import ThreadPoolExecutor
from typing import TypeVar

import numpy as np

from ..errors import SynthpackInputError

__all__ = ["bounded_map", "chunk_boxes", "thread_count"]

_Item = TypeVar("_Item")
_Result = TypeVar("_Result")


def chunk_boxes(shape: tuple[int, int, int], chunks: tuple[int, int, int]) -> Iterator[tuple[np.ndarray, np.ndarray]]:
    """Half-open ``(lo, hi)`` index boxes (int arrays of 3) tiling `shape` with blocks of `chunks`, z-major."""
    starts = [range(0, n, c) for n, c in zip(shape, chunks)]
    for z in starts[0]:
        for y in starts[1]:
            for x in starts[2]:
                lo = np.array([z, y, x])
                yield lo, np.minimum(lo + np.asarray(chunks), shape)


def thread_count(threads: int | None) -> int:
    """`threads`, or the number of CPU cores when None; at least 1.

    Raises
    ------
    SynthpackInputError
        If `threads` is below 1.
    """
    count = (os.cpu_count() or 1) if threads is None else int(threads)
    if count < 1:
        raise SynthpackInputError(f"the thread count must be at least 1, got {threads}")
    return count


def bounded_map(
    function: Callable[[_Item], _Result], items: Iterable[_Item], threads: int
) -> Iterator[tuple[_Item, _Result]]:
    """``(item, function(item))`` in the order of `items`, computed by `threads` threads.

    At most ``2 * threads`` results are held at a time, so memory stays bounded
    by a few items' work however many items there are (the consumer writes each
    result away before the next is computed). Worth it for NumPy/SciPy work that
    releases the GIL.
    """
    items = iter(items)
    with ThreadPoolExecutor(max_workers=threads) as pool:
        pending = deque((item, pool.submit(function, item)) for item in itertools.islice(items, 2 * threads))
        while pending:
            item, future = pending.popleft()
            result = future.result()
            for following in itertools.islice(items, 1):
                pending.append((following, pool.submit(function, following)))
            yield item, result
