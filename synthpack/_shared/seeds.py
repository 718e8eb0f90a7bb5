"""Named random streams: every random draw in synthpack comes from one seed's stream for one purpose.

A stream is a child of the seed's `numpy.random.SeedSequence`, spawned for its purpose:
``stream(seed, "plan")`` is ``SeedSequence(seed).spawn(...)[PURPOSES.index("plan")]``, and further
keys spawn below it (``stream(seed, "pack", 3)`` is the fourth child of the ``"pack"`` child).
Streams of different purposes are independent however the seeds are chosen, so no two stages
ever draw the same numbers (NumPy's guarantee for spawned sequences), and adding a draw to
one stage leaves every other stage's numbers as they were.

`PURPOSES` is append-only: a purpose's position is part of every output drawn from it, so
renaming is free but reordering or removing one changes bytes (and the pack format's version).
A pack's manifest records its seed and the spawn key of each stream (`record`, under
``random_streams``), as TorchIO records its transforms' draws, so that any draw can be
redone alone.
"""

from __future__ import annotations

import numpy as np

#: Every purpose a stream is drawn for, in spawn order (append only; see the module's note).
PURPOSES: tuple[str, ...] = (
    "pack",               # the seed of pack k of a run (key: k)
    "plan",               # the pour plan: grains, scales, orientations, drop positions
    "compaction",         # the packing controller's draws
    "checks",             # the pour checks' sample points
    "grains",             # the pack's deformed grains: sources and one seed per grain
    "pore_texture",       # the pore phase's texture
    "artefacts",          # the seed a pack's post-processing pipeline is applied with
    "recipe",             # the ``randomised`` recipe's draw of an image formation
    "transform_params",   # a pipeline step's p test and parameters (key: step)
    "transform_volume",   # a step's per-volume draws, alike in every block (key: step)
    "transform_blocks",   # a step's per-block noise (keys: step, the block's first voxel)
    "patch_origins",      # a patch dataset's patch corners (keys: epoch, item, draw)
    "augment",            # a dataset's artefact transforms (keys: epoch, item, and its slice or corner)
    "plots",              # subsamples drawn for figures
    "calibration_guard",  # the calibration guard's trial of the fitted steps (key: the step's kind)
    "shells",             # which grains of a spaced pour collide without a spacing shell
    "calibration_fit",    # the noise the calibration's PSF fit measures the edges' steepness with
)


def stream(seed: int, purpose: str, *key: int) -> np.random.SeedSequence:
    """The stream of `seed` for `purpose`, spawned further by `key`.

    Parameters
    ----------
    seed : int
        A non-negative integer seed (a run's, a pack's, a dataset's).
    purpose : str
        One of `PURPOSES`.
    *key : int
        Further spawn indices below the purpose (a pack index, a step, a block corner).

    Returns
    -------
    numpy.random.SeedSequence
        ``SeedSequence(seed, spawn_key=(PURPOSES.index(purpose), *key))``.
    """
    if purpose not in PURPOSES:
        raise ValueError(f"unknown random stream {purpose!r}; the streams are {', '.join(PURPOSES)}")
    return np.random.SeedSequence(int(seed), spawn_key=(PURPOSES.index(purpose), *(int(k) for k in key)))


def generator(seed: int, purpose: str, *key: int) -> np.random.Generator:
    """A `numpy.random.Generator` on ``stream(seed, purpose, *key)``."""
    return np.random.default_rng(stream(seed, purpose, *key))


def derived_seed(seed: int, purpose: str, *key: int) -> int:
    """A 32-bit integer seed drawn from ``stream(seed, purpose, *key)``, for an API that takes an int."""
    return int(stream(seed, purpose, *key).generate_state(1, np.uint32)[0])


def record() -> dict[str, list[int]]:
    """The manifest's record of the streams: each purpose's spawn key below the recorded seed."""
    return {purpose: [index] for index, purpose in enumerate(PURPOSES)}
