"""Intensity levels of the pore (label 0) and grain phases of a labelled scan."""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from ..errors import SynthpackInputError
from ..scan.core import Scan

logger = logging.getLogger(__name__)

__all__ = ["MIN_CONTRAST", "PORE_INTERIOR_DEPTH", "PhaseLevels", "estimate_phases"]

#: Pore voxels this close to a grain (in voxels) are left out of the pore statistics.
PORE_INTERIOR_DEPTH = 2

#: Below this grain-pore level difference, in pore spreads (`PhaseLevels.pore_std`), a labelled
#: scan has no contrast: its labels do not mark grains of this tomogram. Measured in the specimen:
#: the neutron concrete gives 2.7, sand 8.1, the built-in small sample 17.6; with their labels
#: shifted by 37 voxels along x the concrete gives 0.05 and sand 0.0, and the concrete's
#: unregistered X-ray scan with the neutron labels 0.04.
MIN_CONTRAST = 0.1


@dataclass(frozen=True)
class PhaseLevels:
    """Pore and grain intensity levels of a scan, in its intensity units (see `estimate_phases`).

    Attributes
    ----------
    pore_mean : float
        Median intensity of the pore interior: the background value of the clean crops.
    pore_std : float
        Robust standard deviation (1.4826 x the median absolute deviation) of the pore interior.
    grain_mean : float
        Median grain intensity.
    """

    pore_mean: float
    pore_std: float
    grain_mean: float

    def check_contrast(self) -> None:
        """Refuse levels whose grains and pores cannot be told apart (see `MIN_CONTRAST`).

        Raises
        ------
        SynthpackInputError
            If the grain and pore levels differ by `MIN_CONTRAST` pore spreads or less:
            a constant (blank) tomogram, or labels that are not the grains of this tomogram.
        """
        if abs(self.grain_mean - self.pore_mean) <= MIN_CONTRAST * self.pore_std:
            raise SynthpackInputError(
                f"the scan has no contrast: its labelled grains (median grey value {self.grain_mean:.6g}) and "
                f"pores ({self.pore_mean:.6g}, spread {self.pore_std:.3g}) cannot be told apart; check that the "
                "tomogram is not blank and that the labels are the grains of this very tomogram"
            )


def estimate_phases(scan: Scan, max_samples: int = 2_000_000, region: np.ndarray | None = None) -> PhaseLevels:
    """Intensity levels of the pore (label 0) and grain phases of `scan`.

    Parameters
    ----------
    scan : Scan
        The source scan.
    max_samples : int
        The volume is subsampled with a regular stride so that at most about this
        many voxels are read.
    region : ndarray of bool, shape (Z, Y, X), optional
        Voxels to measure in (e.g. `~synthpack.measure.specimen.specimen_mask`, which
        leaves out the container and the air around the specimen); default all.

    Returns
    -------
    PhaseLevels
        In the tomogram's units. The pore statistics come from the pore interior:
        pore voxels at least `PORE_INTERIOR_DEPTH` voxels (of the subsampled grid)
        from any grain, because the pore voxels along grain boundaries are
        brightened by the scanner's blur (partial volume), which the pack's blur
        adds back. With too thin pores all pore voxels are used; with fewer than
        0.1% pore voxels the pore values fall back to the 1st intensity percentile
        and 0.
    """
    stride = max(1, int(np.ceil((scan.labels.size / max_samples) ** (1.0 / 3.0))))
    tomo = scan.tomogram[::stride, ::stride, ::stride].astype(np.float64)
    labels = scan.labels[::stride, ::stride, ::stride]
    inside = np.ones(labels.shape, bool) if region is None else np.asarray(region)[::stride, ::stride, ::stride]
    pores, grains = (labels == 0) & inside, (labels > 0) & inside
    grain_mean = float(np.median(tomo[grains])) if grains.any() else float(np.median(tomo))
    minimum = 0.001 * pores.size
    if np.count_nonzero(pores) < minimum:
        logger.warning("almost no background voxels: using the 1st intensity percentile")
        return PhaseLevels(pore_mean=float(np.percentile(tomo, 1)), pore_std=0.0, grain_mean=grain_mean)
    interior = ndimage.binary_erosion(pores, iterations=PORE_INTERIOR_DEPTH, border_value=1)
    values = tomo[interior] if np.count_nonzero(interior) >= minimum else tomo[pores]
    median = float(np.median(values))
    spread = 1.4826 * float(np.median(np.abs(values - median)))
    return PhaseLevels(pore_mean=median, pore_std=spread, grain_mean=grain_mean)
