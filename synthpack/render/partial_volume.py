"""Partial volume: how much of each voxel a grain fills, and the grain crops that go with it (a render step).

A scanner's voxel on a grain boundary holds some grain and some pore, and shows
the mixture. The render draws it so: each grain has an *occupancy* per output
voxel, the fraction of the voxel it fills, from the signed distance ``s`` (voxels,
positive inside) of its mask resampled with its pose,

    occupancy = clip(s - shift + 1/2, 0, 1),

a ramp one voxel wide centred on the iso-surface ``s = shift``: the grain's
intensity edge sits `shift` voxels inside its label boundary (< 0: outside), the
offset measured in the source scan (`~synthpack.source.SourceStatistics.edge_shift`).
Grains are composited over the background by their occupancies, ``out = (1 - O)
background + sum_i o_i g_i`` with ``O = sum_i o_i`` (where grains overlap, ``O >
1``, the values are normalised, ``out = sum_i o_i g_i / O``). Labels do not use the
occupancy: they stay the resampled mask's > 0.5 rule.

A grain's intensities ``g_i`` come from its clean crop, cut from the real scan, whose
outermost voxels are already the scanner's blurred mixture of grain and pore.
Used as they are, that rim would be blurred twice (by the scan, then by the pack's
point-spread function). So the crop is prepared once: every voxel of its mask
within `rim` voxels of the boundary, and every voxel outside it, takes the value
of the nearest voxel deeper than `rim` (the grain's interior texture, extrapolated
outwards); a grain too thin to have such voxels uses its deepest ones. The
preparation is in the grain's own frame, before any pose, so a run prepares each
library grain once: `PartialVolume.prepare` keeps what it made (up to
`CACHE_BYTES`, found again by the crop's content) for the next pack.
"""

from __future__ import annotations

import hashlib
import threading
from collections import OrderedDict
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np
from scipy import ndimage

from ..measure.edges import signed_distance
from ..source.statistics import SourceStatistics

__all__ = ["CACHE_BYTES", "FAR", "PAD", "PartialVolume", "PreparedCrop", "RIM_QUANTILE"]

#: Voxels of padding around each prepared crop, so the ramp and a shift of up to
#: ``PAD - 1`` voxels outwards stay inside it.
PAD = 3
#: The rim default: where the source's edge is within ``Phi(-RIM_QUANTILE)`` (5 %) of the grain level.
RIM_QUANTILE = 1.645
#: Signed distance (voxels) to read beyond a prepared crop: far outside.
FAR = -float(PAD + 1)
#: Bytes of prepared crops kept for later renders in this process (the least recently used go first).
CACHE_BYTES = 1 << 28


class PreparedCrop(NamedTuple):
    """One grain's crop prepared for the partial-volume render, all float32 and padded by `PAD`.

    Attributes
    ----------
    intensity : ndarray, shape (nz + 2 PAD, ny + 2 PAD, nx + 2 PAD)
        The crop with its rim and its outside replaced by the interior (see the module docstring).
    distance : ndarray, same shape
        Signed distance of every voxel from the mask's boundary, voxels, positive inside
        (``+-0.5`` for the voxels on either side of a face).
    """

    intensity: np.ndarray
    distance: np.ndarray


@dataclass(frozen=True)
class PartialVolume:
    """The partial-volume render's two numbers (see the module docstring).

    Attributes
    ----------
    shift : float
        Iso-surface of the occupancy relative to the label boundary, voxels (> 0: inside the grain).
    rim : float
        Depth of the crop's blurred rim that is replaced by its interior, voxels (>= 0).
    """

    shift: float = 0.0
    rim: float = 1.0

    @classmethod
    def from_source(
        cls, statistics: SourceStatistics, shift: float | None = None, rim: float | None = None,
    ) -> PartialVolume:
        """The partial volume of a source scan: the one place its defaults are derived.

        Parameters
        ----------
        statistics : SourceStatistics
        shift : float, optional
            Default: the source's ``edge_shift`` (0 when it was not measured).
        rim : float, optional
            Default: ``edge_shift + RIM_QUANTILE edge_sigma``, the depth at which the
            source's edge is within 5 % of the grain level (at least 0.5; 1 when the
            source's edge was not measured).
        """
        measured = statistics.edge_shift is not None and statistics.edge_sigma is not None
        if shift is None:
            shift = float(statistics.edge_shift) if measured else 0.0
        if rim is None:
            rim = max(0.5, float(statistics.edge_shift) + RIM_QUANTILE * float(statistics.edge_sigma)) \
                if measured else 1.0
        return cls(float(shift), float(rim))

    @property
    def reach(self) -> float:
        """Crop voxels (per axis) beyond the mask that the occupancy may reach: ``1 + ceil(max(0, -shift))``.

        With ``shift >= 0`` an output voxel whose 8 interpolation neighbours are all
        outside the mask reads a signed distance ``<= -1/2``, so occupancy 0.
        """
        return 1.0 + float(np.ceil(max(0.0, -self.shift)))

    def record(self) -> dict[str, float]:
        """For the pack manifest: ``{"shift": ..., "rim": ...}``, voxels."""
        return {"shift": self.shift, "rim": self.rim}

    def prepare(self, tomogram: np.ndarray, mask: np.ndarray) -> PreparedCrop:
        """A grain's crop prepared for the render (see `PreparedCrop`), read-only.

        A crop prepared before in this process with the same partial volume (same
        bytes of `tomogram` and `mask`) is returned from the cache (see `CACHE_BYTES`).

        Parameters
        ----------
        tomogram : ndarray of float32, shape (nz, ny, nx)
            The grain's clean crop.
        mask : ndarray of bool, same shape
            Its mask (not empty).
        """
        key = (self, _digest(tomogram, mask))
        prepared = _PREPARED.get(key)
        if prepared is None:
            prepared = self._prepare(tomogram, mask)
            for array in prepared:
                array.flags.writeable = False
            _PREPARED.put(key, prepared)
        return prepared

    def _prepare(self, tomogram: np.ndarray, mask: np.ndarray) -> PreparedCrop:
        """`prepare` without the cache."""
        padded = np.pad(mask, PAD)
        distance = signed_distance(padded)
        interior = distance > self.rim
        if not interior.any():
            interior = distance >= distance.max()
        nearest = ndimage.distance_transform_edt(~interior, return_distances=False, return_indices=True)
        intensity = np.pad(tomogram.astype(np.float32, copy=False), PAD, mode="edge")[tuple(nearest)]
        return PreparedCrop(intensity, distance)

    def threshold(self, scale: float | np.ndarray) -> float | np.ndarray:
        """The signed distance of a crop (crop voxels) at and below which a grain drawn `scale` output voxels per
        crop voxel has no occupancy: ``(shift - 1/2) / scale`` (`occupancy` of ``distance * scale``)."""
        return (self.shift - 0.5) / np.asarray(scale, dtype=np.float64)

    def occupancy(self, distance: Any) -> Any:
        """Occupancy ``clip(distance - shift + 1/2, 0, 1)`` of voxels at signed `distance` (voxels).

        `distance` is a float32 NumPy array or torch tensor (the NumPy and the torch render
        share this formula); the occupancy is one of the same type and dtype, computed in float32.
        """
        return (distance - float(np.float32(self.shift - 0.5))).clip(0.0, 1.0)


def _digest(*arrays: np.ndarray) -> bytes:
    """A digest of the dtypes, shapes and bytes of `arrays` (the cache's key)."""
    digest = hashlib.blake2b(digest_size=20)
    for array in arrays:
        array = np.ascontiguousarray(array)
        digest.update(f"{array.dtype.str}{array.shape}".encode())
        digest.update(array.view(np.uint8).reshape(-1) if array.size else b"")
    return digest.digest()


class _Cache:
    """Prepared crops by key, the least recently used dropped beyond `limit` bytes; safe across threads."""

    def __init__(self, limit: int) -> None:
        self.limit = limit
        self._entries: OrderedDict[tuple, PreparedCrop] = OrderedDict()
        self._bytes = 0
        self._lock = threading.Lock()

    def get(self, key: tuple) -> PreparedCrop | None:
        """The crop stored under `key` (now the most recently used), or None."""
        with self._lock:
            prepared = self._entries.get(key)
            if prepared is not None:
                self._entries.move_to_end(key)
            return prepared

    def put(self, key: tuple, prepared: PreparedCrop) -> None:
        """Store `prepared` under `key`, then drop the least recently used beyond the limit."""
        with self._lock:
            if key in self._entries:
                return
            self._entries[key] = prepared
            self._bytes += sum(array.nbytes for array in prepared)
            while self._bytes > self.limit and self._entries:
                _, dropped = self._entries.popitem(last=False)
                self._bytes -= sum(array.nbytes for array in dropped)


_PREPARED = _Cache(CACHE_BYTES)
