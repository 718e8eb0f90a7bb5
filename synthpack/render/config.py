"""`ReconstructConfig`: the render's settings and their defaults (paper 3.4)."""

from __future__ import annotations

from dataclasses import dataclass, field

from ..errors import SynthpackInputError
from .._shared.schema import finite, non_negative, one_of, setting
from ..source.statistics import SourceStatistics
from .partial_volume import PartialVolume
from .pore_texture import PoreTextureConfig
from .segmented_labels import LABEL_STYLES, SegmentedLabels
from .surface import SIGMA, Surface

__all__ = ["KERNELS", "VIEWS", "ReconstructConfig"]

#: What a pack shows (``reconstruct.view``): ``tube``, the whole tube with its wall, in air;
#: ``interior``, a crop of the pack's bulk with no wall and no air, every slice full of grains;
#: ``auto``, an interior crop where the source scan is one, else the tube.
VIEWS = ("auto", "tube", "interior")
#: How the CPU render draws each grain (``reconstruct.kernel``, `synthpack.render.kernel`): ``numba``,
#: one compiled pass over its box; ``scipy``, SciPy's interpolation; ``auto``, numba where it can be imported.
KERNELS = ("auto", "numba", "scipy")


@dataclass(frozen=True)
class ReconstructConfig:
    """Rebuilding the tomogram from the placements (paper 3.4): settings and their defaults.

    ``pore_texture`` is a sub-section: the settings of the pore texture (`PoreTextureConfig`).
    """

    view: str = setting("auto", one_of(VIEWS),
                        "what the pack shows: tube (the tube with its wall, in air), interior (a crop of the "
                        "bulk, full of grains to its edges, as a scan cut out of a larger specimen) or auto "
                        "(interior where the source scan is an interior crop, else tube)")
    order: int = setting(1, one_of((0, 1, 3)), "interpolation of intensities: 0, 1 (linear) or 3 (cubic)")
    wall: bool = setting(True, None, "draw the tube wall (view tube)")
    wall_intensity: float | None = setting(None, finite, "wall intensity; default between pores and grains")
    margin: int = setting(4, non_negative, "voxels of margin around the tube (view tube)")
    partial_volume: bool = setting(True, None, "composite each grain by the fraction of every voxel it fills "
                                   "(false: paste whole voxels, a hard step)")
    edge_shift: float | None = setting(None, finite, "partial volume: the grain's intensity edge relative to its "
                                       "label boundary, voxels (> 0 inside); default: the source's fitted edge shift")
    rim: float | None = setting(None, non_negative, "partial volume: depth (voxels) of each crop's blurred rim "
                                "replaced by its interior; default: from the source's fitted edge")
    surface_sigma: float = setting(SIGMA, non_negative, "smoothing of each grain's surface, voxels: labels and "
                                   "intensities are drawn from its Gaussian-smoothed signed distance, volume kept "
                                   "(0: the voxel staircase)")
    kernel: str = setting("auto", one_of(KERNELS),
                          "how the CPU render draws each grain: numba (one compiled pass over its box), scipy "
                          "(SciPy's interpolation) or auto (numba where it can be imported); the same labels and "
                          "intensities either way")
    labels: str = setting("exact", one_of(LABEL_STYLES),
                          "how the labels are drawn: exact (every voxel whose centre lies in a grain) or segmented "
                          "(as a threshold segmentation of the scan draws them: the grain mask blurred by the "
                          "source's edge spread, thresholded at the level that keeps its volume, so gaps narrower "
                          "than the blur close, as in a labelled scan)")
    pore_texture: PoreTextureConfig = field(default_factory=PoreTextureConfig)

    def view_of(self, statistics: SourceStatistics) -> str:
        """``"tube"`` or ``"interior"``: `view`, with ``auto`` resolved from the source scan.

        ``auto`` is ``interior`` where the source is an interior crop
        (`~synthpack.source.SourceStatistics.interior_crop`: no wall, grains to its edges).
        """
        if self.view != "auto":
            return self.view
        return "interior" if statistics.interior_crop else "tube"

    def partial_volume_of(self, statistics: SourceStatistics) -> PartialVolume | None:
        """The partial volume to render grains of a source scan with; None for whole voxels."""
        if not self.partial_volume:
            return None
        return PartialVolume.from_source(statistics, self.edge_shift, self.rim)

    def segmented_labels_of(self, statistics: SourceStatistics) -> SegmentedLabels | None:
        """How to redraw the labels of a pack of a source scan (``labels: segmented``); None for exact labels.

        Raises
        ------
        SynthpackInputError
            For ``segmented`` where the source's edge spread was not measured.
        """
        if self.labels == "exact":
            return None
        if statistics.edge_sigma is None:
            raise SynthpackInputError(
                "reconstruct.labels: segmented needs the source scan's edge spread, which was not measured "
                "(too few grain-pore boundaries): use reconstruct.labels: exact")
        return SegmentedLabels(float(statistics.edge_sigma))

    @property
    def surface(self) -> Surface:
        """How the grains' smooth surfaces are made (`synthpack.render.surface`)."""
        return Surface(self.surface_sigma)
