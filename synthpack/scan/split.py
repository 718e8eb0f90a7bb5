"""The paper's split of a volume's slices (section 4.1): train, val and test.

The central 20% of the slices along the slicing axis are the test set, so that
no test slice has a near-identical neighbour in the training set; the rest are
training slices. The paper has no validation set; where one is needed (the
YOLO export), the validation slices are the training slices nearest the test
block on both sides: the central ``20% + val_fraction`` block minus the test
block. So val touches train only at its two outer ends, and it also separates
the remaining training slices from the test slices.

Rounding: a central block of ``fraction`` of ``n`` slices holds
``round(fraction * n)`` slices (Python's round-half-to-even), at least 1 when
``n >= 2``, and starts at ``(n - size) // 2``, so for an odd remainder the extra
slice is at the end. The splits never share a slice.
"""

from __future__ import annotations

import numpy as np

from ..errors import SynthpackInputError

__all__ = [
    "SPLITS",
    "TEST_FRACTION",
    "VAL_FRACTION",
    "central_block",
    "check_val_fraction",
    "slice_splits",
    "split_slices",
]

#: The parts of a volume's slices, in this order.
SPLITS = ("train", "val", "test")
#: Fraction of the slices in the central test block.
TEST_FRACTION = 0.2
#: Default fraction of the slices for validation, next to the test block.
VAL_FRACTION = 0.1


def central_block(n_slices: int, fraction: float = TEST_FRACTION) -> tuple[int, int]:
    """Half-open ``(start, stop)`` of the central block of `fraction` of `n_slices` slices.

    Parameters
    ----------
    n_slices : int
        Slices along the slicing axis, at least 2.
    fraction : float
        In (0, 1); the default is the paper's test block.

    Returns
    -------
    (int, int)
        Slice indices ``start < stop``.
    """
    if n_slices < 2:
        raise SynthpackInputError(f"a volume needs at least 2 slices to split, got {n_slices}")
    if not 0 < fraction < 1:
        raise SynthpackInputError(f"the central block fraction must be in (0, 1), got {fraction}")
    n_test = max(1, round(fraction * n_slices))
    start = (n_slices - n_test) // 2
    return start, start + n_test


def check_val_fraction(val_fraction: float) -> float:
    """`val_fraction` as a float; raise unless it is in ``[0, 1 - TEST_FRACTION)``."""
    if isinstance(val_fraction, bool) or not isinstance(val_fraction, (int, float, np.integer, np.floating)) \
            or not 0 <= val_fraction < 1 - TEST_FRACTION:
        raise SynthpackInputError(f"val_fraction must be in [0, {1 - TEST_FRACTION:g}), got {val_fraction!r}")
    return float(val_fraction)


def slice_splits(n_slices: int, val_fraction: float = VAL_FRACTION) -> dict[str, np.ndarray]:
    """Slice indices of train, val and test for a volume of `n_slices` slices.

    Parameters
    ----------
    n_slices : int
        Slices along the slicing axis, at least 2.
    val_fraction : float
        In ``[0, 1 - TEST_FRACTION)``. 0 gives the paper's split: no val slices,
        every slice outside the test block is a training slice.

    Returns
    -------
    dict
        ``{"train", "val", "test"}`` -> sorted int64 indices; they partition
        ``range(n_slices)``.
    """
    val_fraction = check_val_fraction(val_fraction)
    start, stop = central_block(n_slices)
    wide_start, wide_stop = central_block(n_slices, TEST_FRACTION + val_fraction) if val_fraction else (start, stop)
    every = np.arange(n_slices, dtype=np.int64)
    test = (every >= start) & (every < stop)
    val = (every >= wide_start) & (every < wide_stop) & ~test
    return {"train": every[~test & ~val], "val": every[val], "test": every[test]}


def split_slices(n_slices: int, split: str, val_fraction: float = 0.0) -> np.ndarray:
    """Slice indices of one split of a volume of `n_slices` slices, or of every slice.

    Parameters
    ----------
    n_slices : int
        Slices along the slicing axis, at least 2.
    split : {"train", "val", "test", "all"}
        A part of `slice_splits`, or ``"all"``.
    val_fraction : float
        As in `slice_splits`; the default 0 is the paper's split (``"train"`` is
        every slice outside the test block, ``"val"`` is empty).

    Returns
    -------
    ndarray of int64
        Sorted slice indices.
    """
    if split not in (*SPLITS, "all"):
        raise SynthpackInputError(f"split must be one of {', '.join(SPLITS)}, all; got {split!r}")
    parts = slice_splits(n_slices, val_fraction)
    return np.arange(n_slices, dtype=np.int64) if split == "all" else parts[split]
