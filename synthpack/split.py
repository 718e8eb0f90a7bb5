"""The paper's train/test split of a volume's slices (section 4.1).

The central 20% of the slices along the slicing axis are the test set and the
rest are training slices, so that no test slice has a near-identical neighbour
in the training set.

Rounding: ``n_test = round(0.2 * n)`` with Python's round-half-to-even, at least
1 when ``n >= 2``; the test block starts at ``(n - n_test) // 2``, so for an odd
remainder the extra training slice is at the end. Train and test never share a
slice.
"""

from __future__ import annotations

import numpy as np

from .errors import SynthpackInputError

__all__ = ["SPLITS", "TEST_FRACTION", "split_slices", "central_block"]

SPLITS = ("train", "test", "all")
TEST_FRACTION = 0.2


def central_block(n_slices: int, fraction: float = TEST_FRACTION) -> tuple[int, int]:
    """Half-open ``(start, stop)`` of the central test block of `n_slices` slices."""
    if n_slices < 2:
        raise SynthpackInputError(f"a volume needs at least 2 slices to split, got {n_slices}")
    if not 0 < fraction < 1:
        raise SynthpackInputError(f"the test fraction must be in (0, 1), got {fraction}")
    n_test = max(1, round(fraction * n_slices))
    start = (n_slices - n_test) // 2
    return start, start + n_test


def split_slices(n_slices: int, split: str, fraction: float = TEST_FRACTION) -> np.ndarray:
    """Slice indices of `split` (``"train"``, ``"test"`` or ``"all"``), sorted, int64."""
    if split not in SPLITS:
        raise SynthpackInputError(f"split must be one of {', '.join(SPLITS)}, got {split!r}")
    start, stop = central_block(n_slices, fraction)
    every = np.arange(n_slices, dtype=np.int64)
    if split == "all":
        return every
    in_test = (every >= start) & (every < stop)
    return every[in_test] if split == "test" else every[~in_test]
