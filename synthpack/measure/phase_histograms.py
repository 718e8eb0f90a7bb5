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
"""

from __future__ import annotations

import numpy as np

from .spectrum import phase_interiors

__all__ = ["EDGE_BAND", "HISTOGRAM_QUANTILES", "MIN_HISTOGRAM_VOXELS", "phase_masks", "phase_quantiles",
           "quantile_distance"]

#: Quantiles per histogram.
HISTOGRAM_QUANTILES = 200
#: The edge voxels lie within this many voxels of the grain-pore boundary.
EDGE_BAND = 1.0
#: A phase needs at least this many voxels for its histogram.
MIN_HISTOGRAM_VOXELS = 200


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
