"""The `Scan`: a tomogram, its instance labels and the voxel size, validated.

Volumes are NumPy arrays indexed ``(z, y, x)``: axis 0 is the slice axis (the
scanner's rotation axis, the tube axis and the direction of gravity in a pour).
"""

from __future__ import annotations

import logging
import warnings
from collections.abc import Iterator
from dataclasses import dataclass, field

import numpy as np

from ..errors import SynthpackInputError

logger = logging.getLogger(__name__)

__all__ = ["Scan", "validate_voxel_size", "validate_labels", "validate_tomogram", "compact_labels"]

#: Label values up to this are used as they are, however sparse: the tables indexed by
#: label value (`scipy.ndimage.find_objects`, `numpy.bincount`) then take a few MB at most.
DIRECT_LABEL_LIMIT = 2**20

#: Voxels per slab when sparse labels are renumbered slab by slab.
_SLAB_VOXELS = 2**22


@dataclass
class Scan:
    """A CT scan of a particle pack with one label per particle.

    Parameters
    ----------
    tomogram : ndarray, shape (Z, Y, X)
        Reconstructed intensities (any real dtype; kept as read).
    labels : ndarray of int, shape (Z, Y, X)
        Instance labels: 0 is background (pores, air, outside the field of view),
        each particle has its own positive integer.
    voxel_size : tuple of 3 float
        Voxel edge lengths ``(dz, dy, dx)`` in `unit`.
    unit : str
        Length unit of `voxel_size`, e.g. ``"um"`` or ``"mm"``.
    source : str
        Where the scan came from (paths or sample name), for manifests.

    Attributes
    ----------
    label_values : ndarray of int, shape (N + 1,), or None
        Set when the labels given were sparse (see :func:`compact_labels`): `labels`
        then holds ``0..N`` and ``label_values[k]`` is the value label ``k`` had in
        the volume given. None when the labels are used as given.
    """

    tomogram: np.ndarray
    labels: np.ndarray
    voxel_size: tuple[float, float, float] = (1.0, 1.0, 1.0)
    unit: str = "um"
    source: str = ""
    metadata: dict = field(default_factory=dict)
    label_values: np.ndarray | None = field(default=None, init=False, repr=False)

    def __post_init__(self) -> None:
        self.voxel_size = validate_voxel_size(self.voxel_size)
        self.tomogram = validate_tomogram(self.tomogram)
        self.labels, self.label_values = compact_labels(validate_labels(self.labels))
        if self.tomogram.shape != self.labels.shape:
            raise SynthpackInputError(
                f"tomogram shape {self.tomogram.shape} and labels shape "
                f"{self.labels.shape} differ: the label mask must be the segmentation "
                "of this very tomogram, voxel for voxel (check that both files are "
                "from the same scan and neither was cropped or binned)"
            )

    @property
    def shape(self) -> tuple[int, int, int]:
        """Volume shape ``(Z, Y, X)`` in voxels."""
        return tuple(self.labels.shape)  # type: ignore[return-value]

    @property
    def n_particles(self) -> int:
        """Number of distinct positive labels."""
        return int(np.count_nonzero(np.bincount(self.labels.ravel())[1:]))

    def original_label(self, label: int) -> int:
        """The value that `label` (a label of `labels`) has in the label volume as given."""
        return int(label if self.label_values is None else self.label_values[label])

    def __repr__(self) -> str:
        return (
            f"Scan(shape={self.shape}, tomogram dtype={self.tomogram.dtype}, "
            f"labels dtype={self.labels.dtype}, voxel_size={self.voxel_size} {self.unit}, "
            f"source={self.source!r})"
        )


#: Voxel edge lengths synthpack accepts, in any unit: volumes (edge^3) and masses stay well inside float range.
VOXEL_SIZE_RANGE = (1e-30, 1e30)


def validate_voxel_size(voxel_size: float | tuple[float, ...]) -> tuple[float, float, float]:
    """Return `voxel_size` as a ``(dz, dy, dx)`` tuple of positive floats.

    A single number means an isotropic voxel.
    """
    try:
        values = np.atleast_1d(np.asarray(voxel_size, dtype=float))
    except (TypeError, ValueError):
        values = np.empty((0, 0))
    if values.ndim != 1 or values.size not in (1, 3):
        raise SynthpackInputError(
            f"voxel size {voxel_size!r} is not understood: give one positive number "
            "(isotropic) or three, in (z, y, x) order"
        )
    if values.size == 1:
        values = np.repeat(values, 3)
    shown = "(" + ", ".join(f"{float(v):g}" for v in values) + ")"  # plain numbers, not np.float64(...)
    if not np.all(np.isfinite(values)) or np.any(values <= 0):
        raise SynthpackInputError(
            f"voxel size {shown} must be positive and finite: give the edge "
            "length of one voxel, e.g. --voxel-size 10 for 10 um voxels"
        )
    low, high = VOXEL_SIZE_RANGE
    if np.any(values < low) or np.any(values > high):
        raise SynthpackInputError(
            f"voxel size {shown} is outside {low:g}-{high:g}: volumes and masses would under- or "
            "overflow; give it in a unit that makes it a plain number, e.g. --voxel-size 10 --unit um"
        )
    return tuple(float(v) for v in values)  # type: ignore[return-value]


def _require_3d(volume: np.ndarray, what: str) -> np.ndarray:
    volume = np.asarray(volume)
    if volume.ndim != 3:
        raise SynthpackInputError(
            f"the {what} has {volume.ndim} dimension(s) (shape {volume.shape}) but a 3D "
            "volume (z, y, x) is needed: pass the whole stack, not a single slice"
        )
    if min(volume.shape) < 2:
        raise SynthpackInputError(
            f"the {what} has shape {volume.shape}: every axis needs at least 2 voxels"
        )
    return volume


def validate_tomogram(tomogram: np.ndarray) -> np.ndarray:
    """Check that `tomogram` is a finite, real 3D volume and return it.

    Raises
    ------
    SynthpackInputError
        If it is not 3D, not real-valued, or holds NaN or infinite values.
    """
    tomogram = _require_3d(tomogram, "tomogram")
    if not (np.issubdtype(tomogram.dtype, np.number) and not np.iscomplexobj(tomogram)):
        raise SynthpackInputError(
            f"the tomogram has dtype {tomogram.dtype}; it must hold real numbers"
        )
    if np.issubdtype(tomogram.dtype, np.floating):
        bad = int(np.count_nonzero(~np.isfinite(tomogram)))
        if bad:
            raise SynthpackInputError(
                f"the tomogram holds {bad} NaN or infinite voxel(s): replace them (e.g. "
                "with the background value) before building packs from it"
            )
    return tomogram


def validate_labels(labels: np.ndarray) -> np.ndarray:
    """Check that `labels` is a usable instance-label volume and return it as integers.

    A float volume whose values are all whole numbers is converted with a warning;
    one with fractional values is an error (it is probably a probability map or an
    interpolated mask, not labels).

    Raises
    ------
    SynthpackInputError
        If it is not 3D, has fractional or negative values, or holds no particle.
    """
    labels = _require_3d(labels, "label volume")
    if labels.dtype == bool:
        labels = labels.astype(np.uint8)
    if np.issubdtype(labels.dtype, np.floating):
        if not np.all(np.isfinite(labels)):
            raise SynthpackInputError(
                "the label volume holds NaN or infinite values: labels must be whole "
                "numbers (0 = background, 1..N = particles)"
            )
        if np.any(labels != np.round(labels)):
            raise SynthpackInputError(
                "the label volume holds fractional values: it looks like a probability "
                "map or an interpolated mask, not instance labels. Export the labels as "
                "an integer image (0 = background, 1..N = particles)"
            )
        warnings.warn(
            f"label volume stored as {labels.dtype} with whole-number values; "
            "converting to integers (save labels as an integer type to avoid this)",
            UserWarning,
            stacklevel=3,
        )
        labels = labels.astype(np.int64)
    elif not np.issubdtype(labels.dtype, np.integer):
        raise SynthpackInputError(
            f"the label volume has dtype {labels.dtype}; it must hold integers "
            "(0 = background, 1..N = particles)"
        )
    if np.issubdtype(labels.dtype, np.signedinteger):
        lowest = labels.min()
        if lowest < 0:
            raise SynthpackInputError(
                f"the label volume holds negative labels (lowest {int(lowest)}): use 0 "
                "for background and positive integers for particles"
            )
    if not labels.any():
        raise SynthpackInputError(
            "the label volume holds no particle (every voxel is 0): check that you "
            "passed the label mask, not an empty or background-only image"
        )
    return labels


def _slabs(shape: tuple[int, ...]) -> Iterator[slice]:
    """Slices along axis 0 of about `_SLAB_VOXELS` voxels each."""
    step = max(1, _SLAB_VOXELS // max(1, int(np.prod(shape[1:]))))
    return (slice(start, start + step) for start in range(0, shape[0], step))


def compact_labels(labels: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
    """Renumber sparse instance labels ``1..N``, keeping their original values.

    Tables indexed by label value grow with the largest label, not with the
    number of particles: a single label 4,000,000,000 would need tens of GB. So
    when the largest label exceeds both `DIRECT_LABEL_LIMIT` and twice the
    number of distinct labels, the labels are renumbered in increasing order of
    value, slab by slab (peak memory: the renumbered volume, in the smallest
    unsigned dtype that holds ``N``, plus one slab). Otherwise `labels` is
    returned as it is: dense labels cost one pass for the maximum and no copy.

    Parameters
    ----------
    labels : (Z, Y, X) ndarray of non-negative int
        Validated instance labels (see :func:`validate_labels`), 0 = background.

    Returns
    -------
    labels : (Z, Y, X) ndarray of unsigned int
        `labels` itself, or its renumbered copy holding ``0..N``.
    values : ndarray, shape (N + 1,), or None
        ``values[k]`` is the original value of renumbered label ``k``
        (``values[0] == 0``); None when `labels` is returned as it is.

    Examples
    --------
    >>> labels = np.zeros((2, 2, 2), np.uint32)
    >>> labels[0, 0, 0], labels[1, 1, 1] = 70_000, 4_000_000_000
    >>> compact, values = compact_labels(labels)
    >>> compact[0, 0, 0], compact[1, 1, 1], values.tolist()
    (np.uint8(1), np.uint8(2), [0, 70000, 4000000000])
    """
    top = int(labels.max())
    if top <= DIRECT_LABEL_LIMIT:
        return labels, None
    pieces = [np.unique(labels[s]) for s in _slabs(labels.shape)]
    values = np.unique(np.concatenate([np.zeros(1, labels.dtype), *pieces]))
    if top <= 2 * (len(values) - 1):
        return labels, None
    logger.info("labels renumbered 1..%d: their values reach %d", len(values) - 1, top)
    compact = np.empty(labels.shape, dtype=np.min_scalar_type(len(values) - 1))
    for s in _slabs(labels.shape):
        compact[s] = np.searchsorted(values, labels[s])
    return compact, values
