"""The pour's settings (paper 3.3) with their defaults: the ``pour`` section of a pack config."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from .._shared.schema import in_range, non_negative, one_of, positive, setting
from ..errors import SynthpackInputError
from .scene import COLLISION_SHAPES, Material, SettleCriteria
from .compaction import MAX_TARGET, TARGET_SOURCE, expected_fraction, parse_target
from .container import DEFAULT_PACKING_FRACTION, LibraryLike, Tube, holds_crop, interior_grains, interior_radius
from .plan import parse_scale
from .registry import DEFAULT_ENGINE, ENGINES, get_engine
from .shells import parse_coordination

__all__ = ["PourConfig", "DEFAULT_GRAINS", "GRAINS_AUTO"]

#: Grains a pour of ``n_particles: auto`` pours into a tube (an interior crop takes more where it needs them).
DEFAULT_GRAINS = 150
#: The ``n_particles`` value that resolves the count from the source (`PourConfig.grains`).
GRAINS_AUTO = "auto"


def _scale(value: float | list) -> bool:
    """a positive number, or [min, max] with 0 < min <= max"""
    try:
        parse_scale(value)
    except (SynthpackInputError, TypeError, ValueError):
        return False
    return True


def _target(value: Any) -> bool:
    try:
        parse_target(value)
    except SynthpackInputError:
        return False
    return True


_target.__doc__ = (f"'source', a number in (0, {MAX_TARGET:g}] (no pour of rigid grains packs denser), "
                   "or none")


def _grains(value: Any) -> bool:
    if isinstance(value, str):
        return value == GRAINS_AUTO
    return isinstance(value, int) and not isinstance(value, bool) and value > 0


_grains.__doc__ = f"a whole number > 0, or {GRAINS_AUTO!r}"


def _coordination(value: Any) -> bool:
    """'source', a number >= 0 (contacts per grain), or none"""
    try:
        parse_coordination(value)
    except SynthpackInputError:
        return False
    return True


@dataclass(frozen=True)
class PourConfig:
    """Batched rigid-body pouring (paper 3.3).

    ``engine_options`` holds the options of the chosen engine that differ from its
    defaults (:class:`~synthpack.physics.pybullet_engine.PybulletConfig`,
    :class:`~synthpack.physics.blender_engine.BlenderConfig`); they are checked
    against that engine when the config is made.

    Raises
    ------
    SynthpackInputError
        For an option the engine does not have, or a bad value; the message names
        the key (``pour.engine_options.<option>``).
    """

    n_particles: int | str = setting(
        GRAINS_AUTO, _grains,
        f"grains poured, or {GRAINS_AUTO} ({DEFAULT_GRAINS} into a tube; for an interior crop of the source, as many "
        "more as fill one)")
    batch_size: int = setting(50, positive, "grains per batch; each batch settles and is locked")
    engine: str = setting(DEFAULT_ENGINE, one_of(ENGINES), "rigid-body engine: " + " or ".join(ENGINES))
    scale: float | list = setting(1.0, _scale, "grain scale factor, or [min, max] drawn per grain")
    tube_radius: float | None = setting(None, positive, "inner tube radius (physical units); default from the scan")
    tube_height: float | None = setting(None, positive, "tube height (physical units); default from n_particles")
    friction: float = setting(0.6, non_negative, "friction coefficient")
    restitution: float = setting(0.1, in_range(0.0, 1.0), "restitution (bounciness)")
    collision_shape: str = setting(
        "hull", one_of(COLLISION_SHAPES),
        "how grains collide: hull (convex hull) or decomposition (V-HACD convex parts, for concave "
        "grains; pybullet only, 2-3 s per distinct grain to prepare)",
    )
    target_solid_fraction: float | str | None = setting(
        TARGET_SOURCE, _target,
        "bulk solid fraction to pack to, batch by batch: 'source' (the source scan's), a number, or none (free pour)")
    target_coordination: float | str | None = setting(
        TARGET_SOURCE, _coordination,
        "mean contacts per grain a pour looser than a free one aims at, by leaving some grains without a spacing "
        "shell: 'source' (the source scan's), a number, or none (every grain in an equal shell)")
    engine_options: dict = setting({}, None, "options of the engine that differ from its defaults, "
                                              "e.g. {max_hull_vertices: 32}")

    def __post_init__(self) -> None:
        engine = get_engine(self.engine)
        engine.check(self.material(), SettleCriteria(),
                     engine.options(self.engine_options, prefix="pour.engine_options."))
        target = parse_target(self.target_solid_fraction, "pour.target_solid_fraction")
        object.__setattr__(self, "target_solid_fraction", target)  # 'none' -> None, '0.5' -> 0.5
        object.__setattr__(self, "target_coordination",
                           parse_coordination(self.target_coordination, "pour.target_coordination"))
        if isinstance(target, float) and not engine.supports_compaction:
            raise SynthpackInputError(
                f"config key 'pour.target_solid_fraction': the {self.engine} engine cannot pack to "
                f"{target:g}; use engine pybullet, or target_solid_fraction: none (or 'source', "
                "which it pours freely)."
            )

    def material(self) -> Material:
        """The pour's :class:`~synthpack.physics.scene.Material`: these settings, the rest its defaults."""
        return Material(friction=self.friction, restitution=self.restitution,
                        collision_shape=self.collision_shape)

    def grains(self, library: LibraryLike, *, interior: bool = False) -> int:
        """The number of grains this pour pours: ``n_particles``, or for ``auto`` the count it resolves to.

        ``auto`` is `DEFAULT_GRAINS` for a tube, and for an interior crop (`interior`) as many
        more as the crop needs (`crop_grains`, in the given ``tube_radius`` where there is one),
        so a pack of a crop-like source is a crop by default.

        Parameters
        ----------
        library : ParticleLibrary
            The grains and the source scan's shape.
        interior : bool
            For the pour of an interior crop (``reconstruct.view: interior``).

        Returns
        -------
        int
        """
        if self.n_particles != GRAINS_AUTO:
            return self.n_particles
        return max(DEFAULT_GRAINS, self.crop_grains(library)) if interior else DEFAULT_GRAINS

    def tube(self, library: LibraryLike, *, interior: bool = False) -> Tube:
        """The tube this pour fills, sized for `library`; ``tube_radius`` and ``tube_height`` override it.

        The one sizing of a pour's tube (:meth:`Tube.for_library`), for `pour`, ``synthpack
        generate`` and ``synthpack pour`` alike: for the pour's grains (:meth:`grains`) of `library` at the
        largest ``scale``, at the packing fraction the target gives
        (:func:`~synthpack.physics.compaction.expected_fraction`: the usual
        :data:`~synthpack.physics.container.DEFAULT_PACKING_FRACTION`, or a looser target,
        so a spaced pack fits). With `interior`, the tube is wide enough for an interior crop
        of the source's shape (:func:`~synthpack.physics.container.interior_radius`), or as
        large a crop as the grains allow.

        Parameters
        ----------
        library : ParticleLibrary
            The grains; for ``target_solid_fraction: source`` its source scan's solid fraction.
        interior : bool
            Size it for an interior crop (``reconstruct.view: interior``).

        Returns
        -------
        Tube
            Physical units (the library's ``unit``).

        Raises
        ------
        SynthpackInputError
            With `interior`, where the grains, or the given ``tube_radius``, cannot hold a
            crop (it says what can).
        """
        scale = parse_scale(self.scale)[1]
        fraction = expected_fraction(self.target_solid_fraction, library, DEFAULT_PACKING_FRACTION)
        grains = self.grains(library, interior=interior)
        radius = self.tube_radius
        if interior and radius is None:
            radius = interior_radius(library, grains, scale=scale, packing_fraction=fraction)
            if radius is None:
                needed = self.crop_grains(library)
                raise SynthpackInputError(
                    f"{grains} grains are too few for an interior crop of these grains: pour at least "
                    f"{needed} (pour.n_particles, or auto), or show the tube (reconstruct.view: tube)."
                )
        elif interior and not holds_crop(library, grains, radius, scale=scale, packing_fraction=fraction):
            raise SynthpackInputError(
                f"a tube of radius {radius:g} (pour.tube_radius) with {grains} grains holds no interior "
                "crop of these grains: widen it or leave it out, pour more grains (pour.n_particles), "
                "or show the tube (reconstruct.view: tube)."
            )
        return Tube.for_library(library, grains, scale=scale, inner_radius=radius,
                                height=self.tube_height, packing_fraction=fraction)

    def crop_grains(self, library: LibraryLike) -> int:
        """The fewest grains of `library` whose pour holds an interior crop of its source, at this pour's largest
        ``scale`` and packing fraction, in the given ``tube_radius`` or the narrowest tube that holds one
        (`~synthpack.physics.container.interior_grains`)."""
        return interior_grains(library, scale=parse_scale(self.scale)[1],
                               packing_fraction=expected_fraction(self.target_solid_fraction, library,
                                                                  DEFAULT_PACKING_FRACTION),
                               radius=self.tube_radius)
