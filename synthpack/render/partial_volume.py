"""Partial volume: how much of each voxel a grain fills, and the grain intensities that go with it (a render step).

A scanner's voxel on a grain boundary holds some grain and some pore, and shows
the mixture. The render draws it so: each grain has an *occupancy* per output
voxel, the fraction of the voxel it fills, from the signed distance ``s`` (output
voxels, positive inside) of its smooth surface resampled with its pose
(`synthpack.render.surface`: the same distance whose sign gives the labels),

    occupancy = clip(s - shift + 1/2, 0, 1),

a ramp one voxel wide centred on the iso-surface ``s = shift``: the grain's
intensity edge sits `shift` voxels inside its label boundary (< 0: outside), the
offset measured in the source scan (`~synthpack.source.SourceStatistics.edge_shift`).
Grains are composited over the background by their occupancies, ``out = (1 - O)
background + sum_i o_i g_i`` with ``O = sum_i o_i`` (where grains overlap, ``O >
1``, the values are normalised, ``out = sum_i o_i g_i / O``).

A grain's intensities ``g_i`` come from its clean crop, cut from the real scan, whose
outermost voxels are already the scanner's blurred mixture of grain and pore.
Used as they are, that rim would be blurred twice (by the scan, then by the pack's
point-spread function). So the crop is prepared once: every voxel within `rim`
voxels of the grain's surface, and every voxel outside it, takes the value of the
nearest voxel deeper than `rim` (the grain's interior texture, extrapolated outwards);
a grain too thin to have such voxels uses its deepest ones. The preparation is in
the grain's own frame, before any pose, so a run prepares each library grain once:
`PartialVolume.prepare` keeps what it made (`synthpack.render.crop_cache`) for the next pack.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy import ndimage

from ..source.statistics import SourceStatistics
from .crop_cache import PREPARED

__all__ = ["FAR", "PAD", "PartialVolume", "RIM_QUANTILE"]

#: Voxels of padding around each prepared crop (intensities and smooth surface), so the ramp
#: and a shift of up to ``PAD - 2`` voxels outwards stay inside it.
PAD = 3
#: The rim default: where the source's edge is within ``Phi(-RIM_QUANTILE)`` (5 %) of the grain level.
RIM_QUANTILE = 1.645
#: Signed distance (voxels) to read beyond a prepared crop: far outside.
FAR = -float(PAD + 1)


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

    def record(self) -> dict[str, float]:
        """For the pack manifest: ``{"shift": ..., "rim": ...}``, voxels."""
        return {"shift": self.shift, "rim": self.rim}

    def prepare(self, tomogram: np.ndarray, distance: np.ndarray) -> np.ndarray:
        """A grain's intensities prepared for the render (see the module docstring), read-only.

        Intensities prepared before in this process with the same partial volume (same
        bytes of `tomogram` and `distance`) are returned from the cache
        (`~synthpack.render.crop_cache.PREPARED`).

        Parameters
        ----------
        tomogram : ndarray of float32, shape (nz, ny, nx)
            The grain's clean crop.
        distance : ndarray of float32, shape (nz + 2 PAD, ny + 2 PAD, nx + 2 PAD)
            The signed distance of its surface (voxels, positive inside, padded by `PAD`:
            `~synthpack.render.surface.Surface.distance`), positive somewhere.

        Returns
        -------
        ndarray of float32, same shape as `distance`
            The crop padded by `PAD`, its rim and its outside replaced by the interior.
        """
        return PREPARED.prepared(self, (tomogram, distance), lambda: (self._prepare(tomogram, distance),))[0]

    def _prepare(self, tomogram: np.ndarray, distance: np.ndarray) -> np.ndarray:
        """`prepare` without the cache."""
        interior = distance > self.rim
        if not interior.any():
            interior = distance >= distance.max()
        nearest = ndimage.distance_transform_edt(~interior, return_distances=False, return_indices=True)
        return np.pad(tomogram.astype(np.float32, copy=False), PAD, mode="edge")[tuple(nearest)]

    def threshold(self, scale: float | np.ndarray) -> float | np.ndarray:
        """The signed distance of a crop (crop voxels) at and below which a grain drawn `scale` output voxels per
        crop voxel has no occupancy: ``(shift - 1/2) / scale`` (`occupancy` of ``distance * scale``)."""
        return (self.shift - 0.5) / np.asarray(scale, dtype=np.float64)

    @property
    def level(self) -> np.float32:
        """``shift - 1/2`` in float32: the signed distance (output voxels) at which the occupancy starts to rise."""
        return np.float32(self.shift - 0.5)

    def occupancy(self, distance: Any) -> Any:
        """Occupancy ``clip(distance - level, 0, 1)`` of voxels at signed `distance` (voxels), `level` ``shift - 1/2``.

        `distance` is a float32 NumPy array or torch tensor (the NumPy and the torch render
        share this formula, the compiled one `synthpack.render.kernel` computes it so); the
        occupancy is one of the same type and dtype, computed in float32.
        """
        return (distance - float(self.level)).clip(0.0, 1.0)
