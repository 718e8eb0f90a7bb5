"""Full-band intensity histograms of the grain, pore and edge voxels, held as quantiles, and their distance.

A phase's histogram is kept as its quantile function at `HISTOGRAM_QUANTILES`
evenly spaced probabilities ``(i + 0.5) / HISTOGRAM_QUANTILES``: every scale of
variation is in it (noise, texture, cupping, blotches), where the noise level and
the noise power spectrum see only some. The Wasserstein-1 distance of two
distributions is the mean absolute difference of their quantile functions, so
`quantile_distance` of two such tables is it (to the resolution of the table). The
phases are those of the realism report (`synthpack.realism.appearance`):

* **grains**: voxels at least `~synthpack.measure.edges.INTERIOR` voxels inside a grain;
* **pores**: voxels at least as far inside the pore space;
* **edges**: the voxels within `EDGE_BAND` voxel of the boundary, on either side.

`band_quantiles` keeps the same table for shells of voxels by their signed distance
from the boundary (`band_of`: band ``-k`` the pore voxels with ``k - 1 < -d <= k``,
``+k`` the grain voxels likewise, the last band on each side open), so a phase whose
intensity depends on how far a voxel lies from the other (a cement paste brighter next
to its aggregates, a blur tail into narrow pores) is described band by band.
"""

from __future__ import annotations

import numpy as np

from .pore_bands import BANDS
from .spectrum import phase_interiors

__all__ = ["BAND_KEYS", "EDGE_BAND", "HISTOGRAM_QUANTILES", "MIN_HISTOGRAM_VOXELS", "band_of", "band_quantiles",
           "phase_masks", "phase_quantiles", "quantile_distance"]

#: Quantiles per histogram.
HISTOGRAM_QUANTILES = 200
#: The edge voxels lie within this many voxels of the grain-pore boundary.
EDGE_BAND = 1.0
#: A phase needs at least this many voxels for its histogram.
MIN_HISTOGRAM_VOXELS = 200
#: The signed bands of `band_of`, pore side first: ``-BANDS .. -1, 1 .. BANDS``.
BAND_KEYS = tuple(range(-BANDS, 0)) + tuple(range(1, BANDS + 1))


def phase_masks(distance: np.ndarray, region: np.ndarray) -> dict[str, np.ndarray]:
    """Boolean masks of the grain interior, pore interior and edge voxels in `region`.

    Parameters
    ----------
    distance : ndarray of float32, shape (Z, Y, X)
        From `~synthpack.measure.edges.signed_distance`.
    region : ndarray of bool, same shape

    Returns
    -------
    dict
        ``"grains"``, ``"pores"``, ``"edges"``: ndarray of bool, same shape.
    """
    return {**phase_interiors(distance, region), "edges": region & (np.abs(distance) <= EDGE_BAND)}


def phase_quantiles(tomogram: np.ndarray, masks: dict[str, np.ndarray]) -> dict[str, np.ndarray | None]:
    """The intensity quantiles of each phase of `masks`.

    Parameters
    ----------
    tomogram : ndarray, shape (Z, Y, X)
        Intensities.
    masks : dict of str to ndarray of bool, same shape
        E.g. `phase_masks`.

    Returns
    -------
    dict
        Per phase: ndarray of float64, shape (HISTOGRAM_QUANTILES,), intensity units,
        increasing; None where the phase has fewer than `MIN_HISTOGRAM_VOXELS` voxels.
    """
    probabilities = (np.arange(HISTOGRAM_QUANTILES) + 0.5) / HISTOGRAM_QUANTILES
    image = np.asarray(tomogram)
    return {phase: np.quantile(image[mask].astype(np.float64), probabilities)
            if np.count_nonzero(mask) >= MIN_HISTOGRAM_VOXELS else None for phase, mask in masks.items()}


def quantile_distance(quantiles: np.ndarray, reference: np.ndarray) -> float:
    """Wasserstein-1 distance of two histograms given by `phase_quantiles`: ``mean |q - r|``, intensity units."""
    return float(np.mean(np.abs(np.asarray(quantiles, dtype=np.float64) - np.asarray(reference, dtype=np.float64))))


def band_of(distance: np.ndarray) -> np.ndarray:
    """The signed band of each voxel: ``sign(d) * min(ceil(|d|), BANDS)`` (`BAND_KEYS`).

    Parameters
    ----------
    distance : ndarray of float32
        From `~synthpack.measure.edges.signed_distance` (never 0: ``+-0.5`` next to the boundary).

    Returns
    -------
    ndarray of int64, same shape
        ``-BANDS .. -1`` in the pore, ``1 .. BANDS`` in the grains.
    """
    band = np.minimum(np.ceil(np.abs(distance)), BANDS).astype(np.int64)
    return np.where(distance > 0, band, -band)


def band_quantiles(tomogram: np.ndarray, distance: np.ndarray, region: np.ndarray) -> dict[int, np.ndarray | None]:
    """The intensity quantiles of the voxels of `region` in each band of distance from the boundary.

    Parameters
    ----------
    tomogram : ndarray, shape (Z, Y, X)
        Intensities.
    distance : ndarray of float32, same shape
        From `~synthpack.measure.edges.signed_distance`.
    region : ndarray of bool, same shape
        Voxels to use.

    Returns
    -------
    dict of int to ndarray or None
        Per band of `BAND_KEYS`: as `phase_quantiles` (None where the band has fewer than
        `MIN_HISTOGRAM_VOXELS` voxels in `region`).
    """
    bands = band_of(distance[region])
    values = np.asarray(tomogram)[region]
    return phase_quantiles(values, {band: bands == band for band in BAND_KEYS})
