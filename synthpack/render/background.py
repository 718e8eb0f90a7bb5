"""What the render draws where no grain is: the pore level, the pore texture, the tube wall and the air beyond it.

The background is a function of the global voxel position, so a render does not depend on
its chunking. It is derived from the source scan's statistics in one place,
`Background.from_source`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..source.statistics import SourceStatistics
from .config import ReconstructConfig
from .grid import Grid
from .pore_texture import PoreTextureConfig

__all__ = ["WALL_FRACTION", "Background", "background_values"]

#: Default wall intensity, as a fraction of the way from pore to grain level (a plastic tube).
WALL_FRACTION = 0.4


@dataclass(frozen=True)
class Background:
    """What the render draws where no grain is, in the tomogram's intensity units.

    Attributes
    ----------
    pore_mean : float
        Pore level: the space between grains.
    pore_std : float
        The source's pore spread: the Gaussian texture's amplitude (0: flat pores, whatever the texture).
    wall : float or None
        Intensity of the tube wall; None draws no wall.
    wall_thickness : float or None
        Thickness of the drawn wall, voxels (the source's measured wall); None: the tube's own.
    air : float or None
        Intensity outside the wall, flat (the air the source shows around its container);
        None: the pores' level and texture go on outside it.
    extent : tuple of 3 int or None
        The shape of the volume drawn: the pore texture's period covers it (`PoreTextureConfig.period`);
        None: the texture's `~PoreTextureConfig.tile`.
    texture : PoreTextureConfig
        The pore texture's settings.
    pore_spectrum : tuple of float or None
        The source's pore spectrum (`~synthpack.source.SourceStatistics.pore_spectrum`), which the
        measured texture is drawn from; None: the Gaussian texture.
    pore_quantiles : tuple of float or None
        The source's pore histogram shape (`~synthpack.source.SourceStatistics.pore_quantiles`), which
        the measured texture's values are mapped onto (`PoreTextureConfig.histogram`); None: Gaussian values.
    """

    pore_mean: float
    pore_std: float = 0.0
    wall: float | None = None
    texture: PoreTextureConfig = PoreTextureConfig()
    pore_spectrum: tuple[float, ...] | None = None
    pore_quantiles: tuple[float, ...] | None = None
    wall_thickness: float | None = None
    extent: tuple[int, int, int] | None = None
    air: float | None = None

    @classmethod
    def from_source(cls, statistics: SourceStatistics, config: ReconstructConfig) -> Background:
        """The background of a pack of grains from a source scan: the one place it is derived.

        Pore level, spread, spectrum and histogram shape are the source's. The wall has the
        intensity ``config.wall_intensity`` if set, else the source's measured wall's
        (`~synthpack.source.SourceStatistics.wall_intensity`), else `WALL_FRACTION` of
        the way from pore to grain level; the source's measured wall's thickness, else
        the tube's; ``config.wall = False`` draws none. Outside a drawn wall, the air the source
        shows around its container (`~synthpack.source.SourceStatistics.air_intensity`), where measured.
        """
        if config.wall_intensity is not None:
            wall = config.wall_intensity
        elif statistics.wall_intensity is not None:
            wall = statistics.wall_intensity
        else:
            wall = statistics.pore_mean + WALL_FRACTION * statistics.contrast
        return cls(statistics.pore_mean, statistics.pore_std, wall if config.wall else None, config.pore_texture,
                   statistics.pore_spectrum, statistics.pore_quantiles,
                   statistics.wall_thickness if config.wall else None,
                   air=statistics.air_intensity if config.wall else None)

    def wall_radii(self, inner: float, outer: float, voxel: float) -> tuple[float, float]:
        """The drawn wall's inner and outer radius for a tube of `inner` and `outer` radius (physical units).

        The outer radius is ``inner + wall_thickness * voxel`` where the source's wall was
        measured (`voxel`: the lateral voxel size), else the tube's `outer`.
        """
        return inner, outer if self.wall_thickness is None else inner + self.wall_thickness * voxel

    def wall_record(self, radii: tuple[float, float]) -> dict | None:
        """The drawn wall for the manifest: intensity, inner and outer radius (`radii`, physical units); None: none."""
        if self.wall is None:
            return None
        return {"intensity": float(self.wall), "inner_radius": float(radii[0]), "outer_radius": float(radii[1]),
                "measured": self.wall_thickness is not None}

    def texture_values(self, lo: np.ndarray, hi: np.ndarray, seed: int) -> np.ndarray:
        """The pore texture over the global index box ``[lo, hi)``, intensity units (see `PoreTextureConfig.sample`)."""
        return self.texture.sample(lo, hi, seed, self.pore_std, self.pore_spectrum, self.pore_quantiles, self.extent)

    def texture_density(self) -> np.ndarray:
        """The pore texture's power spectral density on its tile's FFT grid (see `PoreTextureConfig.density`).

        Float64, shape ``(period,) * 3`` (`PoreTextureConfig.period` of `extent`), intensity units squared times
        voxels cubed; zeros for flat pores.
        """
        density = self.texture.density(self.pore_std, self.pore_spectrum, self.extent)
        return density if self.pore_std > 0 else np.zeros_like(density)

    def texture_record(self, seed: int) -> dict:
        """The pore texture drawn with render seed `seed`, for the manifest (see `PoreTextureConfig.record`)."""
        return self.texture.record(self.pore_std, self.pore_spectrum, seed, self.pore_quantiles, self.extent)


def background_values(
    grid: Grid, lo: np.ndarray, hi: np.ndarray, background: Background, tube: tuple[float, float, float] | None,
    seed: int,
) -> np.ndarray:
    """The background over the box ``[lo, hi)``: pore level + pore texture, then the wall and the air beyond it.

    Returns
    -------
    ndarray of float32, shape hi - lo
    """
    values = np.full(tuple(hi - lo), background.pore_mean, dtype=np.float32)
    if background.pore_std > 0:
        values += background.texture_values(lo, hi, seed)
    if tube is not None and background.wall is not None:
        inner, outer, base = tube
        index = np.ogrid[lo[0] : hi[0], lo[1] : hi[1], lo[2] : hi[2]]
        z, y, x = (grid.origin[a] + index[a] * grid.voxel_size[a] for a in range(3))
        radius = np.sqrt(x**2 + y**2)
        in_wall = (radius <= outer) & (z >= base) & ((radius >= inner) | (z < 0))
        values[np.broadcast_to(in_wall, values.shape)] += np.float32(background.wall - background.pore_mean)
        if background.air is not None:
            values[np.broadcast_to((radius > outer) | (z < base), values.shape)] = np.float32(background.air)
    return values
