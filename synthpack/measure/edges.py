"""Grain-pore boundaries: signed distance, the mean intensity profile across them, its width.

The boundary between grains (``labels > 0``) and pore (``labels == 0``) lies
half-way between a grain voxel and a pore voxel. The *signed distance* of a voxel
is its distance (voxels) from that boundary: positive in grains, negative in pore,
``+-0.5`` for the voxels on either side of a face. The *edge profile* is the mean
intensity of the voxels at each signed distance within `REACH` voxels of the
boundary; scaled so that the pore interior is 0 and the grain interior is 1, its
*10-90 width* is the distance over which it rises from 0.1 to 0.9 (about
``2.56 sigma`` for an edge blurred by a Gaussian of ``sigma`` voxels, more for
a scan with partial-volume voxels on top), and its *half-height position* is the
signed distance at which it crosses 0.5: 0 when the edge is centred on the label
boundary, positive when it sits inside the grains. Both read the profile scaled by
the signed step ``grain_level - pore_level``, so they hold for grains darker than
the pores too. Grain-grain contacts are not edges.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from ..errors import SynthpackInputError

__all__ = ["EdgeProfile", "INTERIOR", "PSF_REACH", "REACH", "edge_profile", "edge_width", "half_height",
           "interior_depth", "signed_distance", "volume_edge_width"]

#: Voxels within this distance of the boundary make up the edge profile.
REACH = 4.0
#: Voxels at least this far from the boundary are the grain and pore interiors.
INTERIOR = 2.5
#: How far (in its sigmas) a Gaussian PSF carries one phase into the other: beyond it less than 0.14 %
#: of the contrast is left, below the noise of any scan.
PSF_REACH = 3.0
#: A distance needs this many voxels to be a point of the profile.
_MIN_COUNT = 20


def signed_distance(labels: np.ndarray) -> np.ndarray:
    """Signed distance (voxels) of every voxel from the grain-pore boundary.

    Parameters
    ----------
    labels : ndarray of int, shape (Z, Y, X) or (H, W)
        0 = pore, > 0 = grain.

    Returns
    -------
    ndarray of float32, same shape
        Positive in grains, negative in pore; ``+-0.5`` next to the boundary.

    Raises
    ------
    SynthpackInputError
        If there is no grain or no pore voxel (no boundary).
    """
    grain = np.asarray(labels) > 0
    if grain.all() or not grain.any():
        raise SynthpackInputError("the labels hold no grain-pore boundary (all grain or all pore): "
                                  "pass a labelled volume with both phases")
    squared = np.where(grain, _squared_distance(grain), _squared_distance(~grain))
    distance = np.sqrt(squared, dtype=np.float64)
    return np.where(grain, distance - 0.5, 0.5 - distance).astype(np.float32)


def interior_depth(edge_sigma: float | None) -> float:
    """Voxels from the boundary beyond which a scan's edges no longer reach: ``max(INTERIOR, PSF_REACH * edge_sigma)``.

    Parameters
    ----------
    edge_sigma : float or None
        The scan's fitted edge width (Gaussian sigma, voxels; `~synthpack.measure.psf.fit_edge_spread`);
        None: not measured (`INTERIOR`).
    """
    return INTERIOR if edge_sigma is None else max(INTERIOR, PSF_REACH * float(edge_sigma))


def _squared_distance(region: np.ndarray) -> np.ndarray:
    """Squared Euclidean distance (voxels^2, int32) of every voxel of `region` to the nearest voxel outside it.

    The same numbers as ``ndimage.distance_transform_edt(region) ** 2`` (its float64
    sums of squared whole numbers are exact), from the feature transform alone: whole
    numbers and one array per axis at a time, where SciPy's distances take three float64 arrays.
    """
    nearest = ndimage.distance_transform_edt(region, return_distances=False, return_indices=True)
    squared = np.zeros(region.shape, dtype=np.int32)
    for axis, index in enumerate(nearest):
        step = index - np.arange(region.shape[axis], dtype=index.dtype).reshape(
            (-1,) + (1,) * (region.ndim - axis - 1))
        squared += step * step
    return squared


@dataclass
class EdgeProfile:
    """Mean intensity against signed distance from the grain-pore boundary.

    Attributes
    ----------
    distance : ndarray of float64, shape (K,)
        Signed distances (voxels), increasing, within `REACH` of the boundary.
    intensity : ndarray of float64, shape (K,)
        Mean intensity at each distance.
    pore_level, grain_level : float
        Median intensity of the pore and grain interiors (at least `INTERIOR` voxels deep);
        they differ, in either order.
    count : ndarray of int64, shape (K,)
        Voxels averaged at each distance (the weights of a least-squares fit to the profile).
    """

    distance: np.ndarray
    intensity: np.ndarray
    pore_level: float
    grain_level: float
    count: np.ndarray

    @property
    def contrast(self) -> float:
        """The signed step across the edge, ``grain_level - pore_level``, intensity units (< 0: darker grains)."""
        return self.grain_level - self.pore_level

    @property
    def normalised(self) -> np.ndarray:
        """The profile scaled to 0 in the pore interior and 1 in the grain interior, shape (K,), for either sign."""
        return (self.intensity - self.pore_level) / self.contrast


def edge_profile(tomogram: np.ndarray, distance: np.ndarray, region: np.ndarray | None = None) -> EdgeProfile:
    """The mean intensity profile across the grain-pore boundaries in `region`.

    Parameters
    ----------
    tomogram : ndarray, shape (Z, Y, X)
        Intensities.
    distance : ndarray of float32, same shape
        From `signed_distance`.
    region : ndarray of bool, same shape, optional
        Voxels to use (default all).

    Returns
    -------
    EdgeProfile

    Raises
    ------
    SynthpackInputError
        If the region has no grain or pore interior, or grains and pores of the same level (no edge).
    """
    region = np.ones(distance.shape, dtype=bool) if region is None else region
    d = distance[region]
    values = np.asarray(tomogram)[region].astype(np.float64)
    grain, pore = values[d >= INTERIOR], values[d <= -INTERIOR]
    if grain.size < _MIN_COUNT or pore.size < _MIN_COUNT:
        raise SynthpackInputError(
            f"too few grain ({grain.size}) or pore ({pore.size}) voxels lie {INTERIOR} voxels from an edge "
            "to measure the edge profile: measure a bigger volume"
        )
    near = np.abs(d) <= REACH
    keys, inverse, counts = np.unique(np.round(d[near], 3), return_inverse=True, return_counts=True)
    means = np.bincount(inverse, weights=values[near]) / counts
    keep = counts >= _MIN_COUNT
    pore_level, grain_level = float(np.median(pore)), float(np.median(grain))
    if grain_level == pore_level:
        raise SynthpackInputError(
            f"grains and pores have the same level ({grain_level:.4g}): there is no edge to measure; "
            "check that the labels belong to this tomogram"
        )
    return EdgeProfile(keys[keep].astype(np.float64), means[keep], pore_level, grain_level,
                       counts[keep].astype(np.int64))


def _crossing(distance: np.ndarray, profile: np.ndarray, level: float) -> float:
    """Distance at which the (running-maximum) profile first reaches `level`, linearly interpolated."""
    rising = np.maximum.accumulate(profile)
    i = int(np.searchsorted(rising, level))
    if i == 0:
        return float(distance[0])
    if i == len(rising):
        return float(distance[-1])
    low, high = rising[i - 1], rising[i]
    t = 0.0 if high == low else (level - low) / (high - low)
    return float(distance[i - 1] + t * (distance[i] - distance[i - 1]))


def edge_width(profile: EdgeProfile) -> float:
    """10-90 % rise distance (voxels) of a normalised edge profile.

    Parameters
    ----------
    profile : EdgeProfile

    Returns
    -------
    float
        ``d(0.9) - d(0.1)`` in voxels, from linear interpolation between the
        profile's points (a perfectly sharp voxel edge gives 0.8).
    """
    normalised = profile.normalised
    return _crossing(profile.distance, normalised, 0.9) - _crossing(profile.distance, normalised, 0.1)


def half_height(profile: EdgeProfile) -> float:
    """Half-height position (voxels) of a normalised edge profile.

    Parameters
    ----------
    profile : EdgeProfile

    Returns
    -------
    float
        The signed distance from the label boundary at which the normalised profile
        (running maximum) first reaches 0.5, linearly interpolated between its points:
        0 for an edge centred on the boundary, ``+s`` for one shifted ``s`` voxels into
        the grains, ``-s`` into the pores. Grains darker or brighter than pores alike.
    """
    return _crossing(profile.distance, profile.normalised, 0.5)


def volume_edge_width(tomogram: np.ndarray, labels: np.ndarray, region: np.ndarray | None = None) -> float:
    """10-90 edge width (voxels) of the grain-pore boundaries of a labelled volume.

    `edge_width` of `edge_profile` with the `signed_distance` of `labels`; see them
    for the parameters and the errors.
    """
    return edge_width(edge_profile(tomogram, signed_distance(labels), region))
