"""Post-processing fitted to a source scan: noise that matches its level, blur and noise that match its edges.

The clean synthetic volume is rebuilt from the source's masked grain crops: each
grain keeps its own partial-volume rim but the pore side of every edge is flat
background, so its edges are sharper than the source's, and its noise is the
source's noise thinned by resampling. Two measured figures of the source scan
(`~synthpack.source.SourceStatistics` ``edge_width`` and ``noise_std``) are
matched in turn, inside a region of the pack (its bulk):

1. **Blur.** The clean volume is blurred with `~synthpack.artefacts.GaussianBlur`
   of every sigma on a grid (default 0 to 2 voxels in steps of 0.1) and the 10-90
   edge width (`synthpack.source.edges`) measured each time. The sigma whose width
   equals the source's is interpolated linearly between grid points (0 if the
   clean volume is already as blurred, the grid's top if it cannot get there).
2. **Noise.** The noise of the volume blurred with that sigma is measured
   (`~synthpack.source.noise.estimate_noise`) and the white Gaussian noise that
   brings it to the source's level is added (`noise_to_add`: variances add).

The fit has no random part; with the pack's seed the noise realisation is
reproducible too. It records the grid search and the values it matched.
"""

from __future__ import annotations

import logging
import math
from dataclasses import asdict, dataclass

import numpy as np

from ..errors import SynthpackInputError
from ..source.edges import edge_profile, edge_width, signed_distance
from ..source.noise import estimate_noise
from ._base import Compose
from .blur import GaussianBlur
from .noise import GaussianNoise

logger = logging.getLogger(__name__)

__all__ = ["Calibration", "SIGMA_GRID", "calibrate", "noise_to_add"]

#: Blur sigmas (voxels) tried by the edge-width search.
SIGMA_GRID = tuple(round(0.1 * k, 1) for k in range(21))


def noise_to_add(source: float, clean: float) -> GaussianNoise:
    """Gaussian noise of std ``sqrt(max(source^2 - clean^2, 0))``: variances add.

    Parameters
    ----------
    source, clean : float
        Noise standard deviations (as `~synthpack.source.noise.estimate_noise`
        measures them) of the real scan and of the clean synthetic volume, in
        intensity units.

    Returns
    -------
    GaussianNoise
        With a fixed `std` (0 when the clean volume is already as noisy).
    """
    std = math.sqrt(max(source * source - clean * clean, 0.0))
    if source <= clean:
        logger.warning(
            "the clean volume (noise %.4g) is already at least as noisy as the source (%.4g): "
            "no noise added", clean, source,
        )
    logger.info("matched noise: source %.4g, clean %.4g -> add std %.4g", source, clean, std)
    return GaussianNoise(std=std)


@dataclass
class Calibration:
    """The fitted post-processing and what it matched.

    Attributes
    ----------
    blur_sigma : float
        Gaussian blur, voxels.
    noise_std : float
        Gaussian noise added after the blur, intensity units.
    target_edge_width, target_noise : float
        The source's 10-90 edge width (voxels) and noise level (intensity units).
    edge_width : float
        Edge width of the clean volume blurred by `blur_sigma`, voxels.
    blurred_noise : float
        Noise level of that blurred volume, before the added noise.
    sigmas, widths : list of float
        The search: edge width of the clean volume blurred by each sigma.
    """

    blur_sigma: float
    noise_std: float
    target_edge_width: float
    target_noise: float
    edge_width: float
    blurred_noise: float
    sigmas: list[float]
    widths: list[float]

    def pipeline(self) -> Compose:
        """``Compose([GaussianBlur(blur_sigma), GaussianNoise(noise_std)])``."""
        return Compose([GaussianBlur(sigma=self.blur_sigma), GaussianNoise(std=self.noise_std)])

    def to_dict(self) -> dict:
        """JSON-able dict of every field."""
        return asdict(self)


def _crop(region: np.ndarray, halo: int) -> tuple[slice, ...]:
    """Bounding box of `region` grown by `halo` voxels (clipped to the volume)."""
    where = np.argwhere(region)
    low, high = where.min(axis=0) - halo, where.max(axis=0) + 1 + halo
    return tuple(slice(max(0, int(lo)), min(n, int(hi))) for lo, hi, n in zip(low, high, region.shape))


def _blur_for_width(sigmas: np.ndarray, widths: np.ndarray, target: float) -> float:
    """The sigma whose edge width is `target`, interpolated on the (running-maximum) widths."""
    rising = np.maximum.accumulate(widths)
    if target <= rising[0]:
        logger.warning("the clean pack's edges (width %.3f voxels) are already as soft as the source's "
                       "(%.3f): no blur", rising[0], target)
        return 0.0
    if target >= rising[-1]:
        logger.warning("blurring by sigma %.2f gives edges of %.3f voxels, still sharper than the source's "
                       "(%.3f): using that sigma", sigmas[-1], rising[-1], target)
        return float(sigmas[-1])
    i = int(np.searchsorted(rising, target))
    t = (target - rising[i - 1]) / (rising[i] - rising[i - 1])
    return float(sigmas[i - 1] + t * (sigmas[i] - sigmas[i - 1]))


def calibrate(
    clean: np.ndarray,
    labels: np.ndarray,
    region: np.ndarray,
    *,
    target_edge_width: float,
    target_noise: float,
    sigmas: tuple[float, ...] = SIGMA_GRID,
) -> Calibration:
    """Fit blur sigma and noise std so the pack's edges and noise match the source's.

    Parameters
    ----------
    clean : ndarray of float32, shape (Z, Y, X)
        The synthetic volume before post-processing (or an array-like that
        slicing reads, e.g. a Zarr array: only `region`'s box is read).
    labels : ndarray of int, shape (Z, Y, X)
        Its labels (0 = pore, tube or outside).
    region : ndarray of bool, shape (Z, Y, X)
        Where to measure (the pack's bulk region, `~synthpack.postprocess.bulk_region`).
    target_edge_width : float
        The source's 10-90 edge width, voxels (`~synthpack.source.SourceStatistics.edge_width`).
    target_noise : float
        The source's noise level, intensity units (`~synthpack.source.SourceStatistics.noise_std`).
    sigmas : tuple of float
        Increasing blur sigmas (voxels) to search, starting at 0.

    Returns
    -------
    Calibration
    """
    if not (math.isfinite(target_edge_width) and target_edge_width > 0 and math.isfinite(target_noise)
            and target_noise >= 0):
        raise SynthpackInputError(
            f"calibration targets must be a positive edge width and a noise level >= 0, got "
            f"{target_edge_width!r} and {target_noise!r}"
        )
    grid = np.asarray(sigmas, dtype=np.float64)
    box = _crop(region, int(math.ceil(4 * grid.max())) + 2)
    volume, box_labels, box_region = clean[box], np.asarray(labels[box]), region[box]
    distance = signed_distance(box_labels)
    widths = np.array([
        edge_width(edge_profile(GaussianBlur(sigma=float(s))(volume, 0), distance, box_region)) for s in grid
    ])
    sigma = _blur_for_width(grid, widths, target_edge_width)
    blurred = GaussianBlur(sigma=sigma)(volume, 0)
    width = edge_width(edge_profile(blurred, distance, box_region))
    blurred_noise = estimate_noise(blurred, np.where(box_region, box_labels, -1)).std
    noise = noise_to_add(target_noise, blurred_noise)
    calibration = Calibration(
        blur_sigma=sigma, noise_std=float(noise.std), target_edge_width=float(target_edge_width),
        target_noise=float(target_noise), edge_width=width, blurred_noise=float(blurred_noise),
        sigmas=grid.tolist(), widths=widths.tolist(),
    )
    logger.info("calibrated post-processing: blur sigma %.3f (edge width %.3f, source %.3f), noise std %.4g "
                "(blurred %.4g, source %.4g)", sigma, width, target_edge_width, calibration.noise_std,
                blurred_noise, target_noise)
    return calibration
