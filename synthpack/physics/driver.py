"""The one batch loop every engine runs: spawn -> settle -> lock -> retire buried grains -> snapshot.

An engine does not write this loop: it implements a :class:`World`, the per-step
primitives of one pour in its simulator (add a batch of bodies, step until they have
settled, change their friction, lock them, remove locked ones, read poses), and
:func:`drive` runs it, batch by batch, as in the paper (section 3.3.3):

1. **Spawn.** The batch's bodies enter at ``(x, y, top + dz)`` (``Body.spawn_offset =
   (x, y, dz)``, ``top`` the highest point of the grains locked so far, 0 for the first
   batch), turned by ``Body.orientation`` (:meth:`World.add_batch`).
2. **Settle.** The engine steps until every body of the batch is quiet by the
   :class:`~synthpack.physics.scene.SettleCriteria`, or for exactly
   ``options.fixed_steps`` (:meth:`World.settle`).
3. **Lock.** The batch becomes static, so it never moves again; the engine reports its
   poses and its collision hulls in the world (:meth:`World.lock`).
4. **Retire.** Locked grains buried deeper than any later grain can reach
   (:func:`synthpack.physics.burial.buried`, judged here on the hulls) leave the
   engine's world (:meth:`World.retire`): every body in a world costs a little per step.
5. **Snapshot.** With ``options.record_snapshots``, the poses of every grain placed so
   far, as the engine reads them back (:meth:`World.poses`).

Packing to a target (:mod:`synthpack.physics.compaction`) attaches here, so every engine
gets it: before a batch spawns, the :class:`~synthpack.physics.compaction.PackingController`
gives its knob; the batch spawns at the knob's friction with collision shells inflated
by its inflation, each grain's own where some grains of a spaced pour are bare
(:func:`~synthpack.physics.shells.shell_inflations`, :meth:`World.add_batch`); a compacted
batch falls at that friction until nearly still, gets the material's friction back (:meth:`World.set_friction`) and
settles; once it is locked, the controller measures the bulk it completed.
"""

from __future__ import annotations

import abc
import logging
from dataclasses import dataclass, replace
from types import TracebackType
from typing import Callable, Sequence

import numpy as np

from .burial import buried, largest_diameter
from .compaction import FALL_QUIET, FALL_STEPS, BatchCompaction, PackingController
from .scene import Body, Scene, SettleCriteria
from .shells import shell_inflations

logger = logging.getLogger(__name__)

__all__ = ["World", "LockedBatch", "EngineResult", "ProgressCallback", "LockCallback", "drive"]

ProgressCallback = Callable[[int, int], None]
"""``progress(batch_index, n_batches)``, called after each batch has settled and been locked."""

LockCallback = Callable[[int, np.ndarray, np.ndarray, np.ndarray], None]
"""``locked(batch_index, members, positions, quaternions)``, called as each batch is locked: the body indices
of the batch and their final poses (simulation units, as the result's); a batch locked never moves again."""


@dataclass(frozen=True)
class LockedBatch:
    """What :meth:`World.lock` reports of the batch it locked, simulation units.

    Attributes
    ----------
    positions : numpy.ndarray
        (M, 3) float64 world positions of the bodies' LOCAL ORIGINS, in batch order.
    quaternions : numpy.ndarray
        (M, 4) float64 unit quaternions (w, x, y, z), local -> world.
    hulls : list of numpy.ndarray
        (H, 3) float64 world coordinates of each body's collision hull vertices (the
        inflated shell of a spaced batch): the pack top and burial are judged on them.
    """

    positions: np.ndarray
    quaternions: np.ndarray
    hulls: list[np.ndarray]


@dataclass
class EngineResult:
    """Final poses from an engine, simulation units.

    Attributes
    ----------
    positions : numpy.ndarray
        (N, 3) float64 world position of each body's LOCAL ORIGIN.
    quaternions : numpy.ndarray
        (N, 4) float64 unit quaternions (w, x, y, z), local -> world.
    steps_per_batch : list of int
        Steps simulated for each batch.
    settled_per_batch : list of bool
        False where ``max_steps`` was hit before the batch settled.
    snapshots : list of (numpy.ndarray, numpy.ndarray), optional
        For each batch k, ``(positions (n_k, 3), quaternions (n_k, 4))`` of the n_k
        bodies of batches 0..k once batch k had settled, as the engine reads them back;
        None unless ``options.record_snapshots``.
    """

    positions: np.ndarray
    quaternions: np.ndarray
    steps_per_batch: list[int]
    settled_per_batch: list[bool]
    snapshots: list[tuple[np.ndarray, np.ndarray]] | None = None


class World(abc.ABC):
    """One pour in an engine's simulator: the hooks :func:`drive` calls.

    Made by :meth:`Engine.open <synthpack.physics.engine.Engine.open>` with the tube
    built and nothing poured; a context manager that frees the simulator on exit
    (:meth:`close`). Bodies are named by their index into ``scene.bodies``. One batch
    is in flight at a time: :meth:`add_batch` starts it, :meth:`lock` ends it.
    """

    @abc.abstractmethod
    def add_batch(self, members: np.ndarray, positions: np.ndarray, friction: float, inflation: np.ndarray) -> None:
        """Add the bodies `members` as moving bodies, at rest.

        Parameters
        ----------
        members : numpy.ndarray
            (M,) int64 indices of the batch's bodies, increasing.
        positions : numpy.ndarray
            (M, 3) float64 world positions of their local origins; their orientations are
            ``Body.orientation``.
        friction : float
            Their friction coefficient until :meth:`set_friction` or :meth:`lock` (the
            material's, or lower for a compacted batch).
        inflation : numpy.ndarray
            (M,) float64: each collides as its hull inflated by this fraction of its
            size about its centre of mass (:mod:`~synthpack.physics.compaction`,
            :mod:`~synthpack.physics.shells`); its mass stays that of the true grain. The
            wall must reach above every spawned body. < 0 only for an engine that
            :attr:`~synthpack.physics.engine.Engine.shrinks_shells`: hulls shrunk by
            ``-inflation``, their true meshes still kept inside the tube.
        """

    @abc.abstractmethod
    def settle(self, criteria: SettleCriteria, fixed_steps: int | None) -> tuple[int, bool]:
        """Step the batch until it has settled by `criteria`, or for exactly `fixed_steps`.

        Returns
        -------
        (int, bool)
            The steps run, and whether the batch settled (with `fixed_steps`: whether all
            its bodies were quiet on the last step).
        """

    @abc.abstractmethod
    def set_friction(self, friction: float) -> None:
        """Give the batch's bodies friction coefficient `friction` (they keep moving from where they are)."""

    @abc.abstractmethod
    def lock(self) -> LockedBatch:
        """Make the batch static at its current poses, with the material's friction; report them."""

    @abc.abstractmethod
    def retire(self, indices: Sequence[int]) -> None:
        """Remove the locked bodies `indices` from the world, in this order (their poses stay known)."""

    @abc.abstractmethod
    def poses(self, indices: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World poses of the local origins of bodies `indices` (locked or in the batch), as the engine reads them.

        Returns
        -------
        (numpy.ndarray, numpy.ndarray)
            (K, 3) positions and (K, 4) (w, x, y, z) quaternions, float64.
        """

    def close(self) -> None:
        """Free the simulator (the default does nothing)."""

    def __enter__(self) -> World:
        return self

    def __exit__(self, kind: type[BaseException] | None, error: BaseException | None,
                 traceback: TracebackType | None) -> None:
        self.close()


def drive(
    world: World,
    scene: Scene,
    progress: ProgressCallback | None = None,
    compaction: PackingController | None = None,
    locked_batch: LockCallback | None = None,
) -> EngineResult:
    """Pour `scene` in `world`, batch by batch (see the module docstring).

    Parameters
    ----------
    world : World
        The engine's world for `scene`, with nothing poured yet.
    scene : Scene
        Checked input (:meth:`Engine.simulate <synthpack.physics.engine.Engine.simulate>`).
    progress : callable, optional
        ``progress(batch_index, n_batches)`` after each batch is locked.
    compaction : PackingController, optional
        Packs each batch toward a target solid fraction; None: a free pour.
    locked_batch : callable, optional
        ``locked_batch(batch_index, members, positions, quaternions)`` as each batch is locked
        (`LockCallback`), e.g. to render it while the pour goes on.

    Returns
    -------
    EngineResult
        The poses the engine reads back at the end, in the order of ``scene.bodies``.
    """
    bodies, options = scene.bodies, scene.options
    n = len(bodies)
    positions, quaternions = np.zeros((n, 3)), np.zeros((n, 4))
    steps_per_batch: list[int] = []
    settled_per_batch: list[bool] = []
    snapshots: list[tuple[np.ndarray, np.ndarray]] = []
    locked: dict[int, np.ndarray] = {}  # body index -> its collision hull's world vertices, in locking order
    largest = largest_diameter(b.vertices for b in bodies)
    top = 0.0
    batches = scene.batches()
    for number, members in enumerate(batches):
        plan = None if compaction is None else compaction.next_batch()
        friction = scene.material.friction if plan is None else plan.settle_friction
        world.add_batch(members, np.array([_spawn_position(bodies[i], top) for i in members]).reshape(-1, 3),
                        friction, _inflations(members, plan, compaction))
        if plan is not None and plan.compacts and options.fixed_steps is None:
            steps, settled = _compact(world, plan, scene)
        else:
            steps, settled = world.settle(scene.settle, options.fixed_steps)
        if options.record_snapshots:
            snapshots.append(world.poses(np.arange(members[-1] + 1)))
        batch = world.lock()
        positions[members], quaternions[members] = batch.positions, batch.quaternions
        for i, hull in zip(members, batch.hulls):
            locked[int(i)] = hull
            top = max(top, float(hull[:, 2].max()))
        _retire_buried(world, locked, scene.tube.inner_radius, largest)
        if compaction is not None:
            compaction.observe(members, positions[members], quaternions[members])
        if locked_batch is not None:
            locked_batch(number, members, positions[members], quaternions[members])
        steps_per_batch.append(steps)
        settled_per_batch.append(settled)
        if not settled:
            logger.warning("Batch %d was not at rest after %d steps; it is locked as it is.", number, steps)
        logger.debug("Batch %d: %d grains, %d steps, pack top %.3f", number, len(members), steps, top)
        if progress is not None:
            progress(number, len(batches))
    positions, quaternions = world.poses(np.arange(n))
    return EngineResult(
        positions=positions,
        quaternions=quaternions,
        steps_per_batch=steps_per_batch,
        settled_per_batch=settled_per_batch,
        snapshots=snapshots if options.record_snapshots else None,
    )


def _spawn_position(body: Body, top: float) -> np.ndarray:
    """World position (3,) of a body's local origin at spawn: ``(x, y, top + dz)``."""
    x, y, dz = np.asarray(body.spawn_offset, dtype=float)
    return np.array([x, y, top + dz])


def _inflations(members: np.ndarray, plan: BatchCompaction | None,
                compaction: PackingController | None) -> np.ndarray:
    """(M,) shell inflation of each body of a batch: 0 in a free pour, else its share of the knob's."""
    if plan is None or compaction is None:
        return np.zeros(len(members))
    bare = np.zeros(len(members), dtype=bool) if compaction.bare is None else compaction.bare[members]
    return shell_inflations(plan.inflation, bare)


def _compact(world: World, plan: BatchCompaction, scene: Scene) -> tuple[int, bool]:
    """Settle a compacted batch (:mod:`.compaction`); (steps, settled) as :meth:`World.settle`.

    The batch (added at ``plan.settle_friction``) falls until it moves slower than
    :data:`~synthpack.physics.compaction.FALL_QUIET` times the settle thresholds (at
    most :data:`~synthpack.physics.compaction.FALL_STEPS` steps); then it gets the
    material's friction back and settles by ``scene.settle``.
    """
    settle = scene.settle
    fall = replace(settle, max_steps=min(settle.max_steps, FALL_STEPS),
                   linear_speed=settle.linear_speed * FALL_QUIET, angular_speed=settle.angular_speed * FALL_QUIET)
    steps, _ = world.settle(fall, None)
    world.set_friction(scene.material.friction)
    final, settled = world.settle(replace(settle, min_steps=0), None)
    return steps + final, settled


def _retire_buried(world: World, locked: dict[int, np.ndarray], radius: float, largest: float) -> None:
    """Retire the locked grains :func:`~synthpack.physics.burial.buried` says no grain can reach.

    `locked` maps body indices to their hulls' world vertices; the retired grains leave
    it and the world (their final poses are already recorded).
    """
    indices = list(locked)
    retired = [i for i, gone in zip(indices, buried([locked[i] for i in indices], radius, largest)) if gone]
    if retired:
        world.retire(retired)
        for i in retired:
            del locked[i]
        logger.debug("Retired %d buried grains; %d locked grains remain", len(retired), len(locked))
