"""Size and memory budget: refuse a job up front when it cannot fit this machine.

Every estimate is checked before any work starts and before any output is written; a job
over budget raises `SynthpackInputError` with the figure and what to change. The constants
below are the one place of these figures, each with where it comes from.
"""

from __future__ import annotations

import math

import numpy as np
import psutil

from ..errors import SynthpackInputError

#: Peak bytes per voxel of `synthpack label` and `synthpack library build` on a volume held
#: in memory (README, "the whole volume is held in memory (about 30 bytes per voxel at the peak)").
LABEL_BYTES_PER_VOXEL = 30

#: Peak bytes per voxel of building a TIFF pack in memory: the clean, labels and tomogram
#: volumes (float32, int32, float32 = 12 B) times the 1.21x net peak of reconstruction
#: (docs/benchmarks.md, 512^3 grid), rounded up.
PACK_BYTES_PER_VOXEL = 15

#: Bytes per cell of the burial height map of a pour (`physics.burial`): about six float64
#: arrays of the tube's cross-section in simulation units (coordinates, heights, padded minima).
BURIAL_BYTES_PER_CELL = 48

#: Pour seconds per grain, a lower bound: 0.109 s/grain for the 10,000-grain pour of
#: docs/benchmarks.md (bench_scale.py); larger pours are slower per grain, not faster.
POUR_SECONDS_PER_GRAIN = 0.109

#: The longest pour accepted, hours; more grains than this allows are refused.
MAX_POUR_HOURS = 24.0

#: Grains refused above (MAX_POUR_HOURS at POUR_SECONDS_PER_GRAIN): 792,660.
MAX_POUR_GRAINS = int(MAX_POUR_HOURS * 3600 / POUR_SECONDS_PER_GRAIN)

_GIB = 2**30


def available_bytes() -> int:
    """Memory this machine can give now, bytes (`psutil.virtual_memory().available`)."""
    return int(psutil.virtual_memory().available)


def check_bytes(needed: float, what: str, change: str) -> None:
    """Raise `SynthpackInputError` if `needed` bytes exceed the memory available now.

    Parameters
    ----------
    needed : float
        Estimated peak bytes of the job.
    what : str
        The job and its size, e.g. ``"reading big.raw (2560x4096x4096 uint8)"``.
    change : str
        What the user can change to fit, e.g. ``"crop the volume"``.
    """
    free = available_bytes()
    if needed > free:
        raise SynthpackInputError(
            f"{what} needs about {_size(needed)} of memory but {_size(free)} is available: {change}."
        )


def _size(n_bytes: float) -> str:
    """`n_bytes` in GiB, TiB or PiB, one decimal: ``"40.0 GiB"``."""
    for unit in ("GiB", "TiB"):
        if n_bytes < 1024 * _GIB:
            break
        n_bytes /= 1024
    else:
        unit = "PiB"
    return f"{n_bytes / _GIB:,.1f} {unit}"


def check_volume(shape: tuple[int, ...], bytes_per_voxel: float, what: str, change: str) -> None:
    """`check_bytes` for a volume of `shape` at `bytes_per_voxel`; `what` gets the shape appended."""
    voxels = math.prod(int(n) for n in shape)
    check_bytes(voxels * bytes_per_voxel, f"{what} ({'x'.join(map(str, shape))} = {voxels:,} voxels)", change)


def check_read(shape: tuple[int, ...], dtype: np.dtype, source: object) -> None:
    """Refuse reading a volume of `shape` and `dtype` that does not fit in memory (before allocating)."""
    check_volume(shape, np.dtype(dtype).itemsize, f"reading {source}",
                 "crop or downsample the volume first, or use a machine with more memory")


def check_pour(n_particles: int, tube_radius: float) -> None:
    """Refuse a pour of more than `MAX_POUR_GRAINS` grains, or whose tube cross-section does not fit.

    Parameters
    ----------
    n_particles : int
        Grains to pour.
    tube_radius : float
        Inner radius of the tube in simulation units (about one grain diameter).
    """
    if n_particles > MAX_POUR_GRAINS:
        hours = n_particles * POUR_SECONDS_PER_GRAIN / 3600
        raise SynthpackInputError(
            f"pouring {n_particles:,} grains would take about {hours:,.0f} h or more "
            f"({POUR_SECONDS_PER_GRAIN} s/grain); at most {MAX_POUR_GRAINS:,} grains "
            f"({MAX_POUR_HOURS:g} h) are accepted: lower pour.n_particles (--n-particles)."
        )
    cells = (2.0 * math.ceil(tube_radius)) ** 2
    check_bytes(cells * BURIAL_BYTES_PER_CELL,
                f"pouring into a tube {tube_radius:,.3g} grain diameters in radius",
                "give a smaller pour.tube_radius (--tube-radius) or pour.scale")



def check_pack_grid(shape: tuple[int, int, int], fmt: str) -> None:
    """Refuse a TIFF pack whose grid `shape` (Z, Y, X voxels) does not fit in memory.

    A Zarr pack is built chunk by chunk, a few chunks in memory at a time, so it is not checked.
    """
    if fmt != "zarr":
        check_volume(shape, PACK_BYTES_PER_VOXEL, "building the pack",
                     "give a smaller pour.tube_radius, pour.tube_height or pour.scale, fewer grains, "
                     "or --format zarr")
