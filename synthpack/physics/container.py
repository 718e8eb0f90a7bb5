"""The container grains are poured into: a closed-bottom cylindrical tube, and the interior crop of a pour.

A pack shows either the whole tube (``reconstruct.view: tube``) or an interior crop of its
bulk (``interior``): a box that keeps `CROP_WALL_MARGIN` median grain diameters from the
wall, one from the floor and two from the pack top (`crop_box`), with the source scan's
shape. `interior_radius` sizes the tube whose pour holds such a crop.
"""

from __future__ import annotations

import logging
import math
from dataclasses import asdict, dataclass
from collections.abc import Mapping
from typing import Any, Protocol

import numpy as np
import trimesh

from .._shared.text import sig
from ..errors import SynthpackInputError
from .scene import TubeSpec

logger = logging.getLogger(__name__)

__all__ = ["Tube", "CROP_WALL_MARGIN", "DEFAULT_PACKING_FRACTION", "MAX_FILL_ASPECT", "MIN_CROP", "crop_box",
           "crop_extent", "crop_half_sides", "holds_crop", "interior_grains", "interior_radius"]

#: Packing fraction assumed when sizing a tube for a number of grains: a loose
#: random packing of angular grains poured under gravity.
DEFAULT_PACKING_FRACTION = 0.55
#: Tallest default fill, in inner diameters of the tube: a default tube is widened past
#: the source scan's width rather than let the grains stack into a column taller than this.
MAX_FILL_ASPECT = 10.0
#: An interior crop keeps this many median grain diameters from the tube wall: one more than
#: the pour's bulk region (`~synthpack.physics.checks`), as the wall orders the grains next to it.
CROP_WALL_MARGIN = 2.0
#: The smallest interior crop, in median grain diameters along its shortest side.
MIN_CROP = 2.0
#: What the pour's bulk region leaves above the floor and below the pack top, in median grain diameters.
_FLOOR_MARGIN, _TOP_MARGIN = 1.0, 2.0


class LibraryLike(Protocol):
    """What the pour needs from a particle library (`synthpack.library.core.ParticleLibrary` has it).

    Physics sits below the library stage, so it names the interface rather than the class.
    """

    voxel_size: tuple[float, float, float]
    source_shape: tuple[int, int, int]
    equivalent_diameters: np.ndarray
    draw_weights: np.ndarray

    def __len__(self) -> int: ...
    def __getitem__(self, index: int) -> Any: ...


@dataclass(frozen=True)
class Tube:
    """A static, closed-bottom cylindrical tube in physical units.

    The tube's axis is the world z axis through ``x = y = 0``; the inner floor is at
    ``z = 0`` and the wall rises to ``z = height``. The wall occupies
    ``inner_radius <= sqrt(x**2 + y**2) <= inner_radius + wall_thickness`` and the base
    ``-base_thickness <= z <= 0``. Grains fall inside it (it is concave).

    Parameters
    ----------
    inner_radius : float
        Inner radius of the wall, physical units (the library's ``unit``).
    height : float
        Height of the wall above the inner floor, physical units.
    wall_thickness : float
        Radial thickness of the wall, physical units.
    base_thickness : float
        Thickness of the floor, physical units.

    Raises
    ------
    SynthpackInputError
        If a dimension is not a finite positive number.
    """

    inner_radius: float
    height: float
    wall_thickness: float
    base_thickness: float

    def __post_init__(self) -> None:
        for name in ("inner_radius", "height", "wall_thickness", "base_thickness"):
            value = getattr(self, name)
            try:
                number = float(value)
            except (TypeError, ValueError):
                number = math.nan
            if not math.isfinite(number) or number <= 0:
                raise SynthpackInputError(
                    f"Tube {name} must be a finite positive length, got {value!r}; "
                    "give it in the library's physical unit."
                )
            object.__setattr__(self, name, number)

    @property
    def outer_radius(self) -> float:
        """Outer radius of the wall, physical units."""
        return self.inner_radius + self.wall_thickness

    @classmethod
    def for_library(
        cls,
        library: LibraryLike,
        n_particles: int,
        *,
        scale: float = 1.0,
        packing_fraction: float = DEFAULT_PACKING_FRACTION,
        headroom: float = 1.3,
        inner_radius: float | None = None,
        height: float | None = None,
    ) -> Tube:
        """Size a tube for pouring `n_particles` grains of `library`.

        The inner radius follows the source scan: half its smaller lateral extent
        (``source_shape[1:] * voxel_size[1:]``) minus the wall and two voxels, so a
        reconstruction on the source's lateral grid holds the whole tube, times
        ``max(scale, 1)``, so grains scaled up fill a tube as many grain diameters
        across as the scan is (scaled down, they fill the scan's width). Where the
        expected fill would still be taller than :data:`MAX_FILL_ASPECT` inner
        diameters (many grains), the radius grows until it is not. Wall and base are
        three voxels thick. The height holds the expected fill height (``n_particles``
        grains of the library's mean volume times ``scale**3`` at `packing_fraction`)
        times `headroom`, plus four of the largest grains.

        Parameters
        ----------
        library : ParticleLibrary
            Needs ``voxel_size`` (dz, dy, dx), ``source_shape`` (Z, Y, X) and particles
            with ``volume`` and ``equivalent_diameter``.
        n_particles : int
            Number of grains to pour.
        scale : float
            Largest scale factor the grains will get.
        packing_fraction : float
            Expected solid fraction of the pack, in (0, 1).
        headroom : float
            Factor (>= 1) on the expected fill height.
        inner_radius : float, optional
            Use this inner radius (physical units) instead; the height is then sized
            for it.
        height : float, optional
            Use this height (physical units) instead.

        Returns
        -------
        Tube
        """
        voxel = float(min(library.voxel_size))
        lateral = min(
            library.source_shape[1] * library.voxel_size[1],
            library.source_shape[2] * library.voxel_size[2],
        )
        wall = 3.0 * voxel
        if inner_radius is None:
            radius = lateral / 2.0 - wall - 2.0 * voxel
            if radius <= 0:
                raise SynthpackInputError(
                    f"The source scan's lateral extent ({lateral:g}) is too small to size a "
                    "tube; give the inner radius explicitly."
                )
        else:
            radius = cls(inner_radius, 1.0, wall, wall).inner_radius  # validates it
        volumes = np.array([library[i].volume for i in range(len(library))], dtype=float)
        diameters = np.array([library[i].equivalent_diameter for i in range(len(library))])
        solid = n_particles * float(volumes.mean()) * scale**3
        if inner_radius is None:
            # fill = solid / (pf pi r^2) <= MAX_FILL_ASPECT * 2 r  <=>  r**3 >= solid / (2 aspect pf pi)
            widest = (solid / (2.0 * MAX_FILL_ASPECT * packing_fraction * math.pi)) ** (1.0 / 3.0)
            radius = max(radius * max(scale, 1.0), widest)
        fill = solid / (packing_fraction * math.pi * radius**2)
        if height is None:
            height = fill * headroom + 4.0 * float(diameters.max()) * scale
        tube = cls(inner_radius=radius, height=height, wall_thickness=wall, base_thickness=wall)
        logger.debug(  # the pour logs the tube it pours into, once (this is also called to check sizes)
            "Tube for %d grains: inner radius %s, height %s (expected fill %s)",
            n_particles, sig(radius), sig(height), sig(fill),
        )
        return tube

    def spec(self, length_scale: float) -> TubeSpec:
        """The tube in simulation units (lengths divided by `length_scale`)."""
        return TubeSpec(
            inner_radius=self.inner_radius / length_scale,
            height=self.height / length_scale,
            wall_thickness=self.wall_thickness / length_scale,
            base_thickness=self.base_thickness / length_scale,
        )

    def mesh(self, sections: int = 64) -> trimesh.Trimesh:
        """Watertight surface of the wall and base, physical units.

        Parameters
        ----------
        sections : int
            Number of segments around the circumference.

        Returns
        -------
        trimesh.Trimesh
            The solid tube (wall + base) as one closed mesh with outward normals,
            made by revolving its (r, z) profile about the z axis.
        """
        r, big_r = self.inner_radius, self.outer_radius
        profile = np.array(
            [
                [0.0, -self.base_thickness],
                [big_r, -self.base_thickness],
                [big_r, self.height],
                [r, self.height],
                [r, 0.0],
                [0.0, 0.0],
            ]
        )
        mesh = trimesh.creation.revolve(profile, sections=sections)
        if mesh.volume < 0:
            mesh.invert()
        return mesh

    def to_dict(self) -> dict[str, float]:
        """JSON-able dictionary of the four dimensions."""
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> Tube:
        """Inverse of :meth:`to_dict`."""
        names = ("inner_radius", "height", "wall_thickness", "base_thickness")
        return cls(**{k: data[k] for k in names})


def crop_extent(library: LibraryLike, scale: float = 1.0) -> np.ndarray:
    """The shape an interior crop aims at: the source scan's extent times ``max(scale, 1)``.

    Parameters
    ----------
    library : ParticleLibrary
        Needs ``source_shape`` (Z, Y, X) and ``voxel_size`` (dz, dy, dx).
    scale : float
        Largest scale factor of the grains (scaled up, the crop is as many grains across as the scan).

    Returns
    -------
    (3,) ndarray of float
        ``(Z, Y, X)`` extent, physical units.
    """
    return np.asarray(library.source_shape, dtype=float) * np.asarray(library.voxel_size, dtype=float) * max(scale, 1.0)


class _CropSizing:
    """The sizes `interior_radius` and `interior_grains` weigh: a crop of ``t`` times the source's shape."""

    def __init__(self, library: LibraryLike, scale: float, packing_fraction: float) -> None:
        self.extent = crop_extent(library, scale)
        self.diameter = float(np.median(np.asarray(library.equivalent_diameters, dtype=float))) * scale
        self.grain_volume = float(np.mean([library[i].volume for i in range(len(library))])) * scale**3
        self.packing_fraction = packing_fraction
        self.smallest = MIN_CROP * self.diameter / float(self.extent.min())  # t of the smallest crop

    def radius(self, t: float) -> float:
        """Inner radius of the tube that holds the crop ``t``."""
        return t * math.hypot(self.extent[1], self.extent[2]) / 2.0 + CROP_WALL_MARGIN * self.diameter

    def grains(self, t: float, radius: float | None = None) -> float:
        """Grains whose expected fill in the tube of `radius` (None: the one that holds it) reaches the top of the crop ``t``."""
        fill = t * self.extent[0] + (_FLOOR_MARGIN + _TOP_MARGIN) * self.diameter
        radius = self.radius(t) if radius is None else radius
        return self.packing_fraction * math.pi * radius**2 * fill / self.grain_volume


def interior_radius(
    library: LibraryLike, n_particles: int, *, scale: float = 1.0, packing_fraction: float = DEFAULT_PACKING_FRACTION,
) -> float | None:
    """Inner radius of a tube whose pour of `n_particles` grains holds an interior crop of the source's shape.

    The crop (`crop_box`) keeps `CROP_WALL_MARGIN` median grain diameters ``d`` (at the
    largest `scale`) from the wall, ``d`` from the floor and ``2 d`` from the pack top; its
    shape is `crop_extent` ``(Z, Y, X)`` times the largest ``t <= 1`` for which the
    expected fill height (the grains' solid volume over ``packing_fraction pi R^2``, as in
    `Tube.for_library`) reaches its top::

        solid / (packing_fraction pi R(t)^2) >= t Z + 3 d,    R(t) = t hypot(Y, X) / 2 + CROP_WALL_MARGIN d

    With ``t = 1`` and grains to spare, the crop is taller than the source (and for a
    source under `MIN_CROP` diameters across, ``t`` may reach the crop that size).

    Parameters
    ----------
    library : ParticleLibrary
        The grains (volumes, equivalent diameters) and the source scan's shape.
    n_particles : int
        Number of grains to pour.
    scale : float
        Largest scale factor the grains will get.
    packing_fraction : float
        Expected solid fraction of the pack, in (0, 1).

    Returns
    -------
    float or None
        The inner radius, physical units; None where `n_particles` grains cannot hold a crop
        `MIN_CROP` diameters on its shortest side (`interior_grains` can).
    """
    sizing = _CropSizing(library, scale, packing_fraction)
    t = max(1.0, sizing.smallest)  # a scan under MIN_CROP grains across: a crop that size
    if sizing.grains(t) > n_particles:
        low, high = 0.0, t  # bisection: the grains a crop needs grow with t
        for _ in range(50):
            middle = (low + high) / 2
            low, high = (middle, high) if sizing.grains(middle) <= n_particles else (low, middle)
        t = low
    if t < sizing.smallest:
        logger.debug("%d grains hold no interior crop %s diameters across", n_particles, sig(MIN_CROP))
        return None
    logger.debug("Interior crop for %d grains: %.3g of the source's shape, tube radius %s",
                 n_particles, t, sig(sizing.radius(t)))
    return sizing.radius(t)


def interior_grains(library: LibraryLike, *, scale: float = 1.0, packing_fraction: float = DEFAULT_PACKING_FRACTION,
                    radius: float | None = None) -> int:
    """The fewest grains whose pour holds an interior crop `MIN_CROP` diameters across (see `interior_radius`), in a
    tube of inner `radius` (physical units; None: the narrowest that holds it; `holds_crop` says whether one does)."""
    sizing = _CropSizing(library, scale, packing_fraction)
    return math.ceil(sizing.grains(sizing.smallest, radius))


def holds_crop(
    library: LibraryLike, n_particles: int, radius: float, *, scale: float = 1.0,
    packing_fraction: float = DEFAULT_PACKING_FRACTION,
) -> bool:
    """Whether a pour of `n_particles` grains into a tube of inner `radius` is expected to hold an interior crop.

    The smallest crop (`MIN_CROP` median diameters on its shortest side, `interior_radius`)
    must fit inside `CROP_WALL_MARGIN` diameters from the wall, and the expected fill must reach its top.

    Parameters
    ----------
    library : ParticleLibrary
        The grains and the source scan's shape.
    n_particles : int
        Number of grains to pour.
    radius : float
        Inner radius of the tube, physical units (a given ``pour.tube_radius``).
    scale, packing_fraction : float
        As `interior_radius`.

    Returns
    -------
    bool
    """
    sizing = _CropSizing(library, scale, packing_fraction)
    return radius >= sizing.radius(sizing.smallest) and n_particles >= sizing.grains(sizing.smallest, radius)


def crop_box(region: Mapping[str, float], lateral: tuple[float, float]) -> tuple[np.ndarray, np.ndarray] | None:
    """The interior crop of a pour: the largest box of the source's lateral proportions in its bulk cylinder.

    Parameters
    ----------
    region : mapping
        The pour's bulk cylinder about the z axis, ``radius``, ``z_min`` and ``z_max``, physical
        units (`~synthpack.physics.checks.PourChecks.packing_region` of a pour measured
        `CROP_WALL_MARGIN` diameters from the wall).
    lateral : (float, float)
        ``(Y, X)`` extent the crop aims at (`crop_extent`), physical units: its sides keep their
        ratio and are at most these.

    Returns
    -------
    (ndarray, ndarray) or None
        ``lo`` and ``hi``, (3,) float ``(z, y, x)`` world corners, physical units, centred on the
        tube axis; None for an empty region.
    """
    if region["radius"] <= 0 or region["z_max"] <= region["z_min"]:
        return None
    half = crop_half_sides(region["radius"], lateral)
    return (np.array([region["z_min"], -half[0], -half[1]], dtype=float),
            np.array([region["z_max"], half[0], half[1]], dtype=float))


def crop_half_sides(radius: float, lateral: tuple[float, float]) -> np.ndarray:
    """Half the sides of the interior crop in a bulk cylinder of `radius` (`crop_box`'s lateral extent).

    Parameters
    ----------
    radius : float
        The bulk cylinder's radius.
    lateral : (float, float)
        ``(Y, X)`` extent the crop aims at, in the unit of `radius`.

    Returns
    -------
    (2,) ndarray of float
        ``(Y, X)`` half sides: the largest box of `lateral`'s proportions within `radius` of the
        axis, at most `lateral`.
    """
    y, x = (float(v) for v in lateral)
    shrink = min(1.0, 2.0 * float(radius) / math.hypot(y, x))
    return np.array([y, x]) * shrink / 2.0
