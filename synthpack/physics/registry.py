"""The rigid-body engines, by name: the one list that ``pour``, the config and the CLI read.

Each engine is an :class:`~synthpack.physics.engine.Engine` with a ``name``, an
``Options`` dataclass, checks, an availability check and ``simulate``:

* ``pybullet`` (the default): :class:`~synthpack.physics.pybullet_engine.PybulletEngine`,
  options :class:`~synthpack.physics.pybullet_engine.PybulletConfig`;
* ``blender`` (the paper's): :class:`~synthpack.physics.blender_engine.BlenderEngine`,
  options :class:`~synthpack.physics.blender_engine.BlenderConfig`.

Importing this module imports neither pybullet nor Blender: pybullet is imported when
the first pour starts, and Blender runs in a process of its own.
"""

from __future__ import annotations

from collections.abc import Mapping
from types import MappingProxyType

from ..errors import SynthpackInputError
from .blender_engine import BlenderEngine
from .engine import Engine
from .pybullet_engine import PybulletEngine

__all__ = ["ENGINES", "DEFAULT_ENGINE", "get_engine"]

#: Engine name -> engine, the default first.
ENGINES: Mapping[str, Engine] = MappingProxyType(
    {engine.name: engine for engine in (PybulletEngine(), BlenderEngine())}
)
#: The engine a pour uses unless told otherwise.
DEFAULT_ENGINE = "pybullet"


def get_engine(name: str) -> Engine:
    """The engine called `name`.

    Raises
    ------
    SynthpackInputError
        For a name that is not in :data:`ENGINES`.
    """
    if not isinstance(name, str) or name not in ENGINES:
        raise SynthpackInputError(f"Unknown engine {name!r}; choose one of: {', '.join(ENGINES)}.")
    return ENGINES[name]
