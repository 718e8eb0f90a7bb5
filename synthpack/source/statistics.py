"""`SourceStatistics`: what synthpack measures of a source scan, once, before it builds anything from it."""

from __future__ import annotations

import logging
from collections.abc import Mapping
from dataclasses import asdict, dataclass

from ..errors import SynthpackInputError
from ..scan import Scan
from .edges import volume_edge_width
from .noise import estimate_noise
from .phases import estimate_phases

logger = logging.getLogger(__name__)

__all__ = ["SourceStatistics", "measure_source"]


@dataclass(frozen=True)
class SourceStatistics:
    """Measured figures of a source scan that the later stages reproduce.

    Intensities are in the scan's own intensity units, lengths in voxels of the
    scan. The particle library stores them (`ParticleLibrary.statistics`; in
    ``library.json`` under ``phases``, one entry per field in this order, an
    optional field that was not measured left out).

    To add a statistic: add a field here, documented with its unit, and measure
    it in `measure_source` (a new field changes what a library holds on disk, so
    also raise the library's format version).

    Attributes
    ----------
    pore_mean : float
        Pore level: median intensity of the pore interior (voxels of label 0 at
        least `~synthpack.source.phases.PORE_INTERIOR_DEPTH` voxels from a grain).
        The value outside each particle's mask in its clean crop, and the level of
        the space between grains in a pack.
    pore_std : float
        Pore spread: robust standard deviation (1.4826 x MAD) of the pore interior;
        the amplitude of the pack's pore texture.
    grain_mean : float
        Grain level: median intensity of the grain voxels. Above or below the
        pore level: grains are darker than the phase around them in neutron CT,
        with doped brine, or for aggregates in cement paste (see `contrast`).
    noise_std : float
        Noise level, pooled over grains and pores (`~synthpack.source.noise.estimate_noise`).
    edge_width : float or None
        10-90 % rise distance (voxels) of the mean intensity profile across the
        grain-pore boundaries (`~synthpack.source.edges.volume_edge_width`), the
        same for grains brighter or darker than pores; None when it cannot be
        measured (no grain or pore interior, or grains and pores of one level).
    """

    pore_mean: float
    pore_std: float
    grain_mean: float
    noise_std: float
    edge_width: float | None = None

    @property
    def contrast(self) -> float:
        """Grain level minus pore level, intensity units: signed, negative for grains darker than pores.

        Amplitudes given as fractions of the contrast (noise, rings, histogram
        distances) use its magnitude; levels between the phases (the tube wall)
        use it signed.
        """
        return self.grain_mean - self.pore_mean

    def to_dict(self) -> dict[str, float]:
        """The measured fields as a JSON-able dict, in field order, without those that are None."""
        return {name: value for name, value in asdict(self).items() if value is not None}

    @classmethod
    def from_dict(cls, data: Mapping[str, float]) -> SourceStatistics:
        """Read back what `to_dict` wrote (a missing optional field is None)."""
        return cls(**data)


def measure_source(scan: Scan) -> SourceStatistics:
    """Measure every `SourceStatistics` field of `scan`.

    Parameters
    ----------
    scan : Scan
        Tomogram and labels (0 = pore, > 0 = grain).

    Returns
    -------
    SourceStatistics
        With ``edge_width = None`` (and a warning) when the scan's edges cannot be measured.

    Raises
    ------
    SynthpackInputError
        If the noise cannot be estimated (no grain or pore interior to measure it in).
    """
    levels = estimate_phases(scan)
    noise = estimate_noise(scan.tomogram, scan.labels)
    try:
        edge_width: float | None = volume_edge_width(scan.tomogram, scan.labels)
    except SynthpackInputError as error:
        logger.warning("the source's edge width cannot be measured (%s): packs of 'postprocess: calibrated' "
                       "(the default) will get noise matched to the source's level and no fitted blur", error)
        edge_width = None
    statistics = SourceStatistics(pore_mean=levels.pore_mean, pore_std=levels.pore_std,
                                  grain_mean=levels.grain_mean, noise_std=noise.std, edge_width=edge_width)
    logger.info("source statistics of %s: %s", scan.source or "the scan", statistics)
    return statistics
