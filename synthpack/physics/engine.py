"""The engine interface: the base class every rigid-body engine subclasses.

An engine is an :class:`Engine`: a ``name``, a frozen dataclass of its ``Options``
(an :class:`~synthpack.physics.scene.EngineConfig`, built on
:mod:`synthpack._shared.schema`, so ``engine_options`` are checked like every other
setting), checks of what it can simulate, an availability check, and :meth:`Engine.open`,
which makes a :class:`~synthpack.physics.driver.World` for a
:class:`~synthpack.physics.scene.Scene`: the engine's per-step primitives. The batch loop
itself is not the engine's: :meth:`Engine.simulate` checks the scene and runs
:func:`~synthpack.physics.driver.drive` on the world, the same loop for every engine,
compaction and the retiring of buried grains included. The engines are listed by name
in :mod:`synthpack.physics.registry`.
"""

from __future__ import annotations

import abc
import os
from collections.abc import Mapping
from typing import Any, ClassVar

from .._shared.schema import build
from ..errors import SynthpackInputError
from .compaction import PackingController
from .driver import EngineResult, LockCallback, ProgressCallback, World, drive
from .scene import (
    EngineConfig,
    Material,
    Scene,
    SettleCriteria,
    check_bodies,
    check_material,
    check_settle,
    check_tube,
)

__all__ = ["Engine"]


class Engine(abc.ABC):
    """A rigid-body engine: a view of the scene that pours it batch by batch.

    Subclasses set :attr:`name` and :attr:`Options`, implement :meth:`open` (their
    :class:`~synthpack.physics.driver.World`: the per-step primitives the one batch loop
    calls), and may extend :meth:`check` (limits of their own) and :meth:`check_available`.
    """

    #: The name of the engine in ``pour(engine=...)`` and in the config's ``pour.engine``.
    name: ClassVar[str]
    #: The engine's options: an :class:`EngineConfig` subclass.
    Options: ClassVar[type[EngineConfig]] = EngineConfig
    #: Whether the engine packs to a target (:mod:`synthpack.physics.compaction`): whether its
    #: world honours the friction and the inflated shells :meth:`World.add_batch
    #: <synthpack.physics.driver.World.add_batch>` asks for and :meth:`World.set_friction
    #: <synthpack.physics.driver.World.set_friction>`. The driver does the rest for every engine;
    #: one that cannot sets False, and a pour refuses a target for it (``"source"`` pours freely).
    supports_compaction: ClassVar[bool] = True
    #: Whether its world shrinks collision shells for a negative ``inflation`` (:meth:`World.add_batch
    #: <synthpack.physics.driver.World.add_batch>`), keeping the grains' true meshes in the tube: then
    #: compaction may go past full compaction (knobs above 1, :mod:`synthpack.physics.compaction`).
    shrinks_shells: ClassVar[bool] = False

    def options(
        self, values: Mapping[str, Any] | None = None, prefix: str = "engine_options."
    ) -> EngineConfig:
        """The engine's options from a mapping of those that differ from the defaults.

        Parameters
        ----------
        values : mapping, optional
            Option name -> value; a path-like value is taken as its string.
        prefix : str
            Put before an option's name in error messages, e.g.
            ``"pour.engine_options."`` for a config file.

        Raises
        ------
        SynthpackInputError
            For an unknown option, a wrong type or a value out of range; the message
            names the option (``prefix + name``).
        """
        if isinstance(values, Mapping):
            values = {k: os.fspath(v) if isinstance(v, os.PathLike) else v for k, v in values.items()}
        return build(self.Options, {} if values is None else values, prefix)

    def check(self, material: Material, settle: SettleCriteria, options: EngineConfig) -> None:
        """Raise SynthpackInputError for settings this engine cannot simulate.

        Cheap, so :func:`~synthpack.physics.pour` calls it before any work; engines
        with limits of their own extend it.
        """
        check_material(material)
        check_settle(settle)
        if not isinstance(options, self.Options):
            raise SynthpackInputError(
                f"The {self.name} engine takes {self.Options.__name__} options, "
                f"got {type(options).__name__}; build them with its options() method."
            )

    def check_available(self) -> None:
        """Raise SynthpackInputError when the engine cannot run here; the message says how to set it up."""

    def available(self) -> bool:
        """True when the engine can run here (:meth:`check_available` passes)."""
        try:
            self.check_available()
        except SynthpackInputError:
            return False
        return True

    @abc.abstractmethod
    def open(self, scene: Scene) -> World:
        """A world of this engine holding `scene`'s tube and nothing poured yet (checked input).

        The world is a context manager: :meth:`simulate` closes it when the pour ends
        or fails.
        """

    def simulate(
        self,
        scene: Scene,
        progress: ProgressCallback | None = None,
        compaction: PackingController | None = None,
        locked_batch: LockCallback | None = None,
    ) -> EngineResult:
        """Pour `scene` batch by batch, locking each batch once it has settled (:func:`~.driver.drive`).

        Parameters
        ----------
        scene : Scene
            The grains (simulation units, ordered by batch), the tube, the material, the
            settle criteria and this engine's ``Options`` (:meth:`options`).
        progress : callable, optional
            ``progress(batch_index, n_batches)`` after each batch is locked.
        compaction : PackingController, optional
            Packs each batch toward a target solid fraction before it is locked
            (:mod:`synthpack.physics.compaction`); None: a free pour. Only for an
            engine that :attr:`supports_compaction`.
        locked_batch : callable, optional
            ``locked_batch(batch_index, members, positions, quaternions)`` as each batch
            is locked (:data:`~.driver.LockCallback`).

        Returns
        -------
        EngineResult
            Final poses of every body's local origin, in the order of ``scene.bodies``;
            steps and settled flag per batch; snapshots when asked for.

        Raises
        ------
        SynthpackInputError
            For input the engine cannot simulate (compaction included), or when it
            cannot run here.
        """
        check_bodies(scene.bodies)
        check_tube(scene.tube)
        self.check(scene.material, scene.settle, scene.options)
        if compaction is not None and not self.supports_compaction:
            raise SynthpackInputError(
                f"The {self.name} engine cannot pack to a target solid fraction; "
                "use another engine or target_solid_fraction: none."
            )
        self.check_available()
        with self.open(scene) as world:
            return drive(world, scene, progress, compaction, locked_batch)

    def __repr__(self) -> str:
        return f"{type(self).__name__}(name={self.name!r})"
