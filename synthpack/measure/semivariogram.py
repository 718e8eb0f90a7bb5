"""The fine texture of grain and pore interiors: their in-slice semivariogram at short lags.

A scan's phase interiors are not flat plus noise: grains hold mineral texture and pores
fines and blur, correlated over a voxel or two. The noise estimates
(`synthpack.measure.noise_estimate`, `synthpack.measure.spectrum`) take second
differences so as to count no structure, and so do not see this texture; a pack that
lacks it looks smoother to any eye or classifier. The semivariogram measures it:

    gamma(k) = 1/2 mean((I(v + k e) - I(v))^2),   k = 1 .. `LAGS` voxels,

over in-slice axis pairs (``e`` along y and along x, averaged) whose two voxels both lie
in the phase's interior (`~synthpack.measure.spectrum.phase_interiors`, eroded by the
edges' reach), intensity units squared. It is the variance of the texture and noise
together at each scale up to `LAGS` voxels, so the short lags hold no edge and no
structure coarser than a few voxels. Independent fields add their semivariograms, which
is how `synthpack.artefacts.calibrate` fills a pack's deficit.
"""

from __future__ import annotations

import numpy as np

from .spectrum import phase_interiors

__all__ = ["LAGS", "MIN_PAIRS", "phase_semivariograms", "semivariogram"]

#: Lags measured, voxels: 1, 2, ..., LAGS.
LAGS = 4
#: A phase needs at least this many voxel pairs at the longest lag.
MIN_PAIRS = 2000


def semivariogram(volume: np.ndarray, mask: np.ndarray, lags: int = LAGS) -> np.ndarray | None:
    """The in-slice semivariogram of `volume` over voxel pairs both in `mask`.

    Parameters
    ----------
    volume : ndarray, shape (Z, Y, X)
        Intensities.
    mask : ndarray of bool, same shape
        The voxels measured.
    lags : int
        Lags ``1 .. lags`` voxels, along y and x.

    Returns
    -------
    ndarray of float64, shape (lags,) or None
        ``gamma(k)``, intensity units squared; None where fewer than `MIN_PAIRS` pairs
        lie in `mask` at the longest lag.
    """
    gamma = np.empty(lags)
    for k in range(1, lags + 1):
        total, pairs = 0.0, 0
        for axis in (1, 2):
            head = [slice(None)] * 3
            tail = [slice(None)] * 3
            head[axis], tail[axis] = slice(k, None), slice(None, -k)
            both = mask[tuple(head)] & mask[tuple(tail)]
            n = int(np.count_nonzero(both))
            if n:
                step = volume[tuple(head)][both].astype(np.float64) - volume[tuple(tail)][both]
                total += float(step @ step)
                pairs += n
        if pairs < MIN_PAIRS:
            return None
        gamma[k - 1] = total / (2 * pairs)
    return gamma


def phase_semivariograms(
    volume: np.ndarray, distance: np.ndarray, region: np.ndarray | None, depth: float, lags: int = LAGS,
) -> dict[str, np.ndarray | None]:
    """`semivariogram` of the grain and of the pore interior.

    Parameters
    ----------
    volume : ndarray, shape (Z, Y, X)
    distance : ndarray of float32, same shape
        From `~synthpack.measure.edges.signed_distance` of the labels.
    region : ndarray of bool, same shape, or None
        Voxels to measure (None: all).
    depth : float
        Interior depth, voxels (`~synthpack.measure.edges.interior_depth`).
    lags : int

    Returns
    -------
    dict
        ``"grains"`` and ``"pores"``: ndarray of float64, shape (lags,), or None.
    """
    return {phase: semivariogram(volume, mask, lags)
            for phase, mask in phase_interiors(distance, region, depth).items()}
