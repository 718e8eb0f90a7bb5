"""The pore phase against the distance to the nearest grain: its level and spread, band by band.

A pore phase need not look the same everywhere: a cement paste is brighter and less
variable next to its aggregates (an interfacial transition zone) and holds unlabelled
fine aggregate far from them; a scan's blur and scatter carry the grains' level some
voxels into a narrow pore. The bands are shells of the pore space by the voxels'
signed distance from the grain-pore boundary (`~synthpack.measure.edges.signed_distance`):
band ``k`` (``k = 1 .. BANDS - 1``) holds the pore voxels with ``k - 1 < |d| <= k``
(band 1: the voxels that share a face or an edge with a grain), the last band everything
farther. In each band, the median intensity and the interquartile range (IQR). The
realism report sets a pack's bands beside its source's, so a pore phase drawn the same
everywhere shows against one that is not.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._shared.strict_json import plain

__all__ = ["BANDS", "MIN_BAND_VOXELS", "PoreBands", "pore_bands"]

#: Bands of one voxel from the boundary, the last one open (beyond ``BANDS - 1`` voxels).
BANDS = 5
#: A band with fewer voxels has no figures (NaN).
MIN_BAND_VOXELS = 50


@dataclass(frozen=True)
class PoreBands:
    """Level and spread of the pore phase in bands of distance from the nearest grain.

    Attributes
    ----------
    median : ndarray of float64, shape (BANDS,)
        Median intensity of each band (NaN where it has fewer than `MIN_BAND_VOXELS`).
    iqr : ndarray of float64, shape (BANDS,)
        Interquartile range of each band, intensity units (NaN likewise).
    voxels : ndarray of int64, shape (BANDS,)
        Voxels in each band.
    """

    median: np.ndarray
    iqr: np.ndarray
    voxels: np.ndarray

    def to_dict(self) -> dict:
        """JSON-able lists (None for NaN; `~synthpack._shared.strict_json.plain`)."""
        return plain({"median": self.median, "iqr": self.iqr, "voxels": self.voxels})


def pore_bands(tomogram: np.ndarray, distance: np.ndarray, region: np.ndarray) -> PoreBands:
    """The median and IQR of the pore voxels of `region` in each band of distance from the boundary.

    Parameters
    ----------
    tomogram : ndarray, shape (Z, Y, X)
        Intensities.
    distance : ndarray of float32, same shape
        From `~synthpack.measure.edges.signed_distance` (negative in the pore).
    region : ndarray of bool, same shape
        Voxels to use.

    Returns
    -------
    PoreBands
    """
    inside = region & (distance < 0)
    band = np.minimum(np.ceil(-distance[inside]).astype(np.int64), BANDS) - 1
    values = np.asarray(tomogram)[inside].astype(np.float64)
    median, iqr = np.full(BANDS, np.nan), np.full(BANDS, np.nan)
    voxels = np.bincount(band, minlength=BANDS).astype(np.int64)
    for k in np.flatnonzero(voxels >= MIN_BAND_VOXELS):
        low, middle, high = np.percentile(values[band == k], [25, 50, 75])
        median[k], iqr[k] = middle, high - low
    return PoreBands(median, iqr, voxels)
