"""The pour's settings (paper 3.3) with their defaults: the ``pour`` section of a pack config."""

from __future__ import annotations

from dataclasses import dataclass, field

from .._schema import in_range, non_negative, one_of, positive, setting
from .registry import DEFAULT_ENGINE, ENGINES, get_engine

__all__ = ["PourConfig"]


@dataclass(frozen=True)
class PourConfig:
    """Batched rigid-body pouring (paper 3.3).

    ``engine_options`` holds the options of the chosen engine that differ from its
    defaults (:class:`~synthpack.physics.pybullet_engine.PybulletOptions`,
    :class:`~synthpack.physics.blender_engine.BlenderOptions`); they are checked
    against that engine when the config is made.

    Raises
    ------
    SynthpackInputError
        For an option the engine does not have, or a bad value; the message names
        the key (``pour.engine_options.<option>``).
    """

    n_particles: int = setting(150, positive, "grains poured into the tube")
    batch_size: int = setting(50, positive, "grains per batch; each batch settles and is locked")
    engine: str = setting(DEFAULT_ENGINE, one_of(ENGINES), "rigid-body engine: " + " or ".join(ENGINES))
    scale: float | list = setting(1.0, None, "grain scale factor, or [min, max] drawn per grain")
    tube_radius: float | None = setting(None, positive, "inner tube radius (physical units); default from the scan")
    tube_height: float | None = setting(None, positive, "tube height (physical units); default from n_particles")
    friction: float = setting(0.6, non_negative, "friction coefficient")
    restitution: float = setting(0.1, in_range(0.0, 1.0), "restitution (bounciness)")
    # A dict default needs a factory, which setting() makes for lists only.
    engine_options: dict = field(default_factory=dict, metadata={
        "check": None, "help": "options of the engine that differ from its defaults, e.g. {max_hull_vertices: 32}",
    })

    def __post_init__(self) -> None:
        get_engine(self.engine).options(self.engine_options, prefix="pour.engine_options.")
