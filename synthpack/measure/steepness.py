"""How steep a volume's edges are, read without its labels: the upper tail of its neighbour steps.

The PSF fit of `synthpack.measure.psf` reads the mean intensity profile across the
*label* boundaries. A real scan's labels (a watershed's) scatter about the true
boundary by a voxel or so, and the scatter broadens that profile as a wider PSF
would: fitted to it, a pack's edges come out softer than the scan's. On the sand
micro-CT of ``../shared/data`` the label-aligned fit asks for a 1.27 voxel PSF; the
logistic classifier of the realism report tells the pack from the scan least at
about 1.1 (AUC 0.95 against 0.98).

The steepest intensity steps between neighbouring voxels do not depend on labels.
`edge_steepness` takes the absolute differences between in-slice neighbours (along
both in-slice axes, both voxels in the region) and their quantiles at
`STEEPNESS_PROBABILITIES`, the upper tail from the 90th to the 99.9th percentile,
where the steps across edges lie: a sharper PSF makes them larger, noise adds to them
everywhere. `steepness_distance` compares two such tails, as the mean absolute
difference of the quantiles over the contrast (a Wasserstein distance of the tails).
Calibration blurs the clean pack so that its tail, with the noise it will get, is the
source's (`synthpack.artefacts.calibrate`). The tail counts edges per voxel as well as
their slope, so it presumes a pack with about the source's grain sizes and solid
fraction, which the pour gives.
"""

from __future__ import annotations

import numpy as np

__all__ = ["MIN_STEEPNESS_PAIRS", "STEEPNESS_PROBABILITIES", "edge_steepness", "neighbour_steps",
           "steepness_distance"]

#: The quantiles of the neighbour steps that make the steepness: the upper tail, where the edges' steps lie.
STEEPNESS_PROBABILITIES = np.linspace(0.9, 0.999, 50)
#: No steepness is measured from fewer neighbour pairs (its top quantile would rest on fewer than 20).
MIN_STEEPNESS_PAIRS = 20_000


def neighbour_steps(volume: np.ndarray, region: np.ndarray) -> np.ndarray:
    """Absolute intensity differences between in-slice neighbours that both lie in `region`.

    Parameters
    ----------
    volume : ndarray, shape (Z, Y, X)
        Intensities.
    region : ndarray of bool, same shape
        The voxels to read.

    Returns
    -------
    ndarray of float64, shape (N,)
        ``|v[z, y, x+1] - v[z, y, x]|`` and ``|v[z, y+1, x] - v[z, y, x]|`` of every such
        pair, intensity units.
    """
    volume = np.asarray(volume, dtype=np.float64)
    region = np.asarray(region, dtype=bool)
    along_x = np.abs(np.diff(volume, axis=2))[region[:, :, 1:] & region[:, :, :-1]]
    along_y = np.abs(np.diff(volume, axis=1))[region[:, 1:, :] & region[:, :-1, :]]
    return np.concatenate([along_x, along_y])


def edge_steepness(volume: np.ndarray, region: np.ndarray) -> np.ndarray | None:
    """The upper tail of `neighbour_steps`: its quantiles at `STEEPNESS_PROBABILITIES`.

    Parameters
    ----------
    volume : ndarray, shape (Z, Y, X)
        Intensities.
    region : ndarray of bool, same shape
        The voxels to read (a source's specimen, a pack's bulk region).

    Returns
    -------
    ndarray of float64, shape (len(STEEPNESS_PROBABILITIES),) or None
        Non-decreasing, intensity units; None with fewer than `MIN_STEEPNESS_PAIRS` pairs.
    """
    steps = neighbour_steps(volume, region)
    if steps.size < MIN_STEEPNESS_PAIRS:
        return None
    return np.quantile(steps, STEEPNESS_PROBABILITIES)


def steepness_distance(steepness: np.ndarray, reference: np.ndarray, contrast: float) -> float:
    """Mean absolute difference of two `edge_steepness` tails over the magnitude of the contrast.

    Parameters
    ----------
    steepness, reference : array-like of float, shape (len(STEEPNESS_PROBABILITIES),)
        Two tails, intensity units.
    contrast : float
        The grain-pore contrast, intensity units (either sign, not 0).

    Returns
    -------
    float
        Dimensionless: 0 for the same tail.
    """
    difference = np.asarray(steepness, dtype=np.float64) - np.asarray(reference, dtype=np.float64)
    return float(np.mean(np.abs(difference)) / abs(contrast))
