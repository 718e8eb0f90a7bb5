"""The shape of the pore phase's intensity histogram: its quantiles, and a map that gives a Gaussian field that shape.

The pore spectrum (`~synthpack.measure.pore_spectrum`) is a second-order
description: a Gaussian texture drawn from it has the right variance and
correlations, but Gaussian values. A real pore phase need not be Gaussian: a
cement paste, with sand grains and voids in it, has a heavy-tailed histogram (its
robust spread is three quarters of its standard deviation). This module measures
that shape and maps a Gaussian field onto it.

**Measurement.** The pore interior's intensities ``I`` are standardized, ``s = (I -
median) / std``, and their quantiles taken at the `QUANTILE_SCORES`: the
probabilities ``Phi(z_k)`` of Gaussian scores ``z_k`` evenly spaced from ``-3`` to
``3`` (so the tails are as finely resolved as the middle; the middle score is 0,
the median, whose quantile is 0).

**Mapping.** A zero-mean Gaussian field of standard deviation ``sigma`` is mapped
voxel by voxel through ``t -> sigma Q(t / sigma)``, where ``Q`` interpolates the
quantiles linearly between the scores and extrapolates the end segments beyond
``+-3``: the Gaussian CDF followed by the source's quantile function. The result
has the source's histogram shape at the field's scale and median 0; the map is
monotonic, so the field's rank structure, and so approximately its spectrum, are
kept (a strongly non-Gaussian shape moves some power to higher frequencies).
"""

from __future__ import annotations

import logging

import numpy as np
from scipy import special

__all__ = ["MIN_QUANTILE_VOXELS", "QUANTILE_SCORES", "map_to_quantiles", "measure_pore_quantiles"]

logger = logging.getLogger(__name__)

#: Gaussian scores at whose probabilities ``Phi(z)`` the quantiles are taken (65, from -3 to 3; the middle is 0).
QUANTILE_SCORES = np.linspace(-3.0, 3.0, 65)
#: No quantiles are measured from fewer interior voxels.
MIN_QUANTILE_VOXELS = 2000


def measure_pore_quantiles(tomogram: np.ndarray, mask: np.ndarray) -> np.ndarray | None:
    """Quantiles of the standardized intensities ``(I - median) / std`` of `tomogram` inside `mask`.

    Parameters
    ----------
    tomogram : ndarray, shape (Z, Y, X)
        Intensities.
    mask : ndarray of bool, same shape
        The voxels to measure (the pore interior of the specimen).

    Returns
    -------
    ndarray of float64, shape (len(QUANTILE_SCORES),) or None
        Non-decreasing, dimensionless (standard deviations from the median), 0 at
        the middle score. None when `mask` holds fewer than `MIN_QUANTILE_VOXELS`
        voxels or their intensities are all equal.
    """
    values = np.asarray(tomogram)[np.asarray(mask, dtype=bool)].astype(np.float64)
    if values.size < MIN_QUANTILE_VOXELS:
        logger.debug("pore histogram: %d interior voxels (%d needed): not measured", values.size,
                     MIN_QUANTILE_VOXELS)
        return None
    spread = values.std()
    if not spread > 0:
        return None
    median = np.median(values)
    return np.quantile((values - median) / spread, special.ndtr(QUANTILE_SCORES))


def map_to_quantiles(field: np.ndarray, sigma: float, quantiles: np.ndarray) -> np.ndarray:
    """Map a zero-mean Gaussian `field` of standard deviation `sigma` onto the histogram shape of `quantiles`.

    Parameters
    ----------
    field : ndarray of float
        Gaussian values (any shape).
    sigma : float
        Its standard deviation (> 0), the same units as the field.
    quantiles : array of float, shape (len(QUANTILE_SCORES),)
        From `measure_pore_quantiles`.

    Returns
    -------
    ndarray of float64, shape of `field`
        ``sigma Q(field / sigma)`` (see the module docstring).
    """
    quantiles = np.asarray(quantiles, dtype=np.float64)
    score = np.asarray(field, dtype=np.float64) / sigma
    mapped = np.interp(score, QUANTILE_SCORES, quantiles)
    step = QUANTILE_SCORES[1] - QUANTILE_SCORES[0]
    low, high = score < QUANTILE_SCORES[0], score > QUANTILE_SCORES[-1]
    mapped[low] += (score[low] - QUANTILE_SCORES[0]) * (quantiles[1] - quantiles[0]) / step
    mapped[high] += (score[high] - QUANTILE_SCORES[-1]) * (quantiles[-1] - quantiles[-2]) / step
    return mapped * sigma
