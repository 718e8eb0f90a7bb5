"""Each grain's smooth surface: a smoothed signed distance of its mask, from which the render draws it (a render step).

A library grain is a voxel mask cut from the source scan. Resampled as it is with a
pose, its surface is a staircase: a slice that cuts it obliquely near its top or
bottom shows the terraces as teeth along the section's outline, where a real grain's
section is smooth. So the render draws every grain from a smooth surface instead,
made once per library grain in its own frame (`Surface.distance`):

1. ``d``: the signed distance of the mask (voxels, positive inside, ``+-1/2`` on
   either side of a face: `synthpack.measure.edges.signed_distance`);
2. ``g``: ``d`` convolved with a Gaussian of `sigma` voxels, which keeps a flat face
   where it is (a linear function is its own average) and rounds the terraces. Its
   slope is below 1 where the staircase's faces point different ways (they average),
   so it is stretched back to a distance: ``g / |grad g|`` (at most by 1 / `MIN_SLOPE`);
3. ``f = min((g - t) / |grad g|, d + 1/2)``: the iso-level ``t`` restores the grain's
   volume (smoothing a convex surface moves it inwards), as a render in any pose
   counts it: the voxels where the linearly interpolated ``f`` is positive, measured
   on 8 points per crop voxel (`_volume_level`). The cap keeps ``f <= 0`` at every
   voxel outside the mask, so the smooth surface never passes the centres of the
   mask's outer neighbours (a bound the render's boxes rely on, `Surface.reach`).

The render resamples ``f`` linearly with the pose; scaled to output voxels it is the
signed distance of each output voxel from the grain's smooth surface. The grain's
labels are where it is positive (a voxel two grains claim goes to the larger, the one
it is deeper in), and its partial-volume occupancy comes from the same distance
(`synthpack.render.partial_volume`). ``sigma = 0`` draws the voxel surface itself
(``f = d``). `Surface.distance` keeps what it made (`synthpack.render.crop_cache`)
for the next pack.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from ..measure.edges import signed_distance
from .crop_cache import PREPARED
from .partial_volume import PAD, PartialVolume

__all__ = ["SIGMA", "Surface"]

#: The default smoothing of the grains' surfaces, voxels (Gaussian standard deviation).
SIGMA = 0.5
#: The least slope of the smoothed distance that is stretched to 1 (near a thin grain's middle it is less).
MIN_SLOPE = 0.25


@dataclass(frozen=True)
class Surface:
    """How the grains' smooth surfaces are made (see the module docstring).

    Attributes
    ----------
    sigma : float
        Standard deviation of the Gaussian that smooths each mask's signed distance,
        voxels (>= 0; 0: the voxel surface).
    """

    sigma: float = SIGMA

    def distance(self, mask: np.ndarray) -> np.ndarray:
        """The smooth signed distance ``f`` of a grain's mask (see the module docstring), read-only.

        One made before in this process with the same surface (same bytes of `mask`)
        is returned from the cache (`~synthpack.render.crop_cache.PREPARED`).

        Parameters
        ----------
        mask : ndarray of bool, shape (nz, ny, nx)
            The grain's mask (not empty).

        Returns
        -------
        ndarray of float32, shape (nz + 2 PAD, ny + 2 PAD, nx + 2 PAD)
            Voxels, positive inside the smooth surface, padded by
            `~synthpack.render.partial_volume.PAD` (at most 0 outside the mask).
        """
        return PREPARED.prepared(self, (mask,), lambda: (self._distance(np.asarray(mask, dtype=bool)),))[0]

    def _distance(self, mask: np.ndarray) -> np.ndarray:
        """`distance` without the cache."""
        if self.sigma <= 0:
            return signed_distance(np.pad(mask, PAD))
        # the smoothing reads the signed distance 3 sigma beyond the crop's voxels near the surface
        # (2 voxels outside at most): the voxels beyond the padding repeat its outermost ones
        extra = max(0, int(np.ceil(3.0 * self.sigma)) + 2 - PAD)
        raw = signed_distance(np.pad(mask, PAD + extra)).astype(np.float64)
        smooth = ndimage.gaussian_filter(raw, self.sigma, mode="nearest")
        slope = np.sqrt(sum(np.square(g) for g in np.gradient(smooth)))
        window = (slice(extra, raw.shape[0] - extra), slice(extra, raw.shape[1] - extra),
                  slice(extra, raw.shape[2] - extra))
        cap = raw[window] + 0.5
        # distances from the smooth surface: the smoothed staircase's slope is below 1 (its faces' directions average)
        smooth, stretch = smooth[window], 1.0 / np.maximum(slope[window], MIN_SLOPE)
        level = _volume_level(smooth, stretch, cap, int(np.count_nonzero(mask)))
        return _field(smooth, stretch, cap, level).astype(np.float32)

    def reach(self, partial_volume: PartialVolume | None = None) -> float:
        """Crop voxels (per axis) beyond the mask within which the grain can label an output voxel or fill some of it.

        The `~synthpack.render.poses.pose_maps` boxes hold every output voxel this close to
        a mask voxel. An output voxel is labelled where its interpolated ``f > 0``, filled
        where ``f > shift - 1/2`` (unscaled): that needs a neighbouring crop voxel with
        ``f`` above ``L = min(0, shift - 1/2)``, so (with ``f <= d + 1/2``) within
        ``1 - L`` voxels of the mask's voxel centres: ``ceil(1 - L)`` crop voxels per axis.
        """
        lowest = 0.0 if partial_volume is None else min(0.0, partial_volume.shift - 0.5)
        return float(np.ceil(1.0 - lowest))


def _field(smooth: np.ndarray, stretch: np.ndarray, cap: np.ndarray, level: float) -> np.ndarray:
    """The smooth signed distance ``f = min((smooth - level) stretch, cap)`` (float64, voxels)."""
    return np.minimum((smooth - level) * stretch, cap)


#: Offsets (voxels) of the points that sample each voxel's volume: its 8 octant centres.
_OCTANTS = np.array(np.meshgrid(*[(-0.25, 0.25)] * 3, indexing="ij")).reshape(3, 8)


def _volume_level(smooth: np.ndarray, stretch: np.ndarray, cap: np.ndarray, voxels: int) -> float:
    """The level ``t`` at which the grain drawn from ``f`` (`_field`) holds `voxels` voxels, in any pose.

    A render's voxels sample the linearly interpolated ``f`` at points anywhere in the
    crop's voxels; so its volume is measured so: the fraction of the octant centres of
    each voxel where the interpolated ``f`` is positive, summed. Two secant steps from
    ``t = 0``, each by a volume's excess over the surface's area (the voxels within half a
    voxel of it, stretched): on the partial-volume volume ``sum clip(f + 1/2, 0, 1)`` (no
    interpolation), then on the octant volume (within 0.2 % of `voxels` on the sample and
    real-scan grains; the rotated grains' voxel counts are within 1 % of their masks').
    """
    level = 0.0
    for octants in (False, True):
        field = _field(smooth, stretch, cap, level)
        if octants:
            shell = np.abs(field) < _SHELL  # the voxels whose octants may lie on either side
            points = (np.argwhere(shell).T[:, :, None] + _OCTANTS[:, None, :]).reshape(3, -1)
            sampled = ndimage.map_coordinates(field, points, order=1)
            excess = np.count_nonzero(field >= _SHELL) + np.count_nonzero(sampled > 0) / 8.0 - voxels
        else:
            excess = float(np.clip(field + 0.5, 0.0, 1.0).sum()) - voxels
        slope = float(np.sum(stretch[np.abs(field) < 0.5]))  # voxels gained per unit fall of the level
        if slope > 0:
            level += excess / slope
    return level


#: The voxels (of ``f``) about the surface whose octant centres `_volume_level` samples: its octant
#: centres are 0.43 voxel from the voxel's, so one farther from the surface has them all on its side.
_SHELL = 0.75
