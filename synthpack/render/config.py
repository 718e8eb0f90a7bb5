"""`ReconstructConfig`: the render's settings and their defaults (paper 3.4)."""

from __future__ import annotations

from dataclasses import dataclass, field

from .._shared.schema import finite, non_negative, one_of, setting
from ..source.statistics import SourceStatistics
from .partial_volume import PartialVolume
from .pore_texture import PoreTextureConfig
from .surface import SIGMA, Surface

__all__ = ["ReconstructConfig"]


@dataclass(frozen=True)
class ReconstructConfig:
    """Rebuilding the tomogram from the placements (paper 3.4): settings and their defaults.

    ``pore_texture`` is a sub-section: the settings of the pore texture (`PoreTextureConfig`).
    """

    order: int = setting(1, one_of((0, 1, 3)), "interpolation of intensities: 0, 1 (linear) or 3 (cubic)")
    wall: bool = setting(True, None, "draw the tube wall")
    wall_intensity: float | None = setting(None, finite, "wall intensity; default between pores and grains")
    margin: int = setting(4, non_negative, "voxels of margin around the tube")
    partial_volume: bool = setting(True, None, "composite each grain by the fraction of every voxel it fills "
                                   "(false: paste whole voxels, a hard step)")
    edge_shift: float | None = setting(None, finite, "partial volume: the grain's intensity edge relative to its "
                                       "label boundary, voxels (> 0 inside); default: the source's fitted edge shift")
    rim: float | None = setting(None, non_negative, "partial volume: depth (voxels) of each crop's blurred rim "
                                "replaced by its interior; default: from the source's fitted edge")
    surface_sigma: float = setting(SIGMA, non_negative, "smoothing of each grain's surface, voxels: labels and "
                                   "intensities are drawn from its Gaussian-smoothed signed distance, volume kept "
                                   "(0: the voxel staircase)")
    pore_texture: PoreTextureConfig = field(default_factory=PoreTextureConfig)

    def partial_volume_of(self, statistics: SourceStatistics) -> PartialVolume | None:
        """The partial volume to render grains of a source scan with; None for whole voxels."""
        if not self.partial_volume:
            return None
        return PartialVolume.from_source(statistics, self.edge_shift, self.rim)

    @property
    def surface(self) -> Surface:
        """How the grains' smooth surfaces are made (`synthpack.render.surface`)."""
        return Surface(self.surface_sigma)
