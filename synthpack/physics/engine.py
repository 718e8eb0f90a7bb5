"""Engine interface shared by the rigid-body simulators (pybullet, Blender).

Everything here is in SIMULATION UNITS: the frontend (:func:`synthpack.physics.pour`)
divides physical lengths by one length scale (the library's median equivalent
diameter) so grains are about one unit across, gravity is 9.81 units/s^2 along -z,
and converts the engine's results back. World frame: (x, y, z), z up, tube axis along
z through x = y = 0, inner tube floor at z = 0.

An engine is a module with a function ``simulate(bodies, tube, material, settle,
progress=None) -> EngineResult``. For each batch, in order, it spawns the batch's
bodies at ``(x, y, top + dz)`` (``spawn_offset = (x, y, dz)``, ``top`` = the highest z
of all grains already placed, or 0 for the first batch) with ``orientation``,
simulates until the batch has settled (see :class:`SettleCriteria`), and then LOCKS
the batch (static / passive) so it never moves again.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Protocol, Sequence

import numpy as np

__all__ = [
    "Body",
    "TubeSpec",
    "Material",
    "SettleCriteria",
    "EngineResult",
    "ProgressCallback",
    "SimulateFunction",
]

ProgressCallback = Callable[[int, int], None]
"""``progress(batch_index, n_batches)``, called after each batch has settled and been locked."""


@dataclass(frozen=True)
class Body:
    """One grain to drop, in simulation units, in its particle-local frame.

    Attributes
    ----------
    vertices : numpy.ndarray
        (V, 3) float64 mesh vertices in the particle-local frame, already scaled.
    faces : numpy.ndarray
        (F, 3) int64 triangle vertex indices (watertight, outward normals).
    mass : float
        Mass (density * volume, in whatever mass unit; only ratios matter).
    center_mass : numpy.ndarray
        (3,) float64 centre of mass in the particle-local frame.
    orientation : numpy.ndarray
        (4,) float64 unit quaternion (w, x, y, z), local -> world, at spawn.
    spawn_offset : numpy.ndarray
        (3,) float64 ``(x, y, dz)``: world x, y of the local origin and its height dz
        above the current pack top.
    batch : int
        0-based batch number; batches run in increasing order.
    """

    vertices: np.ndarray
    faces: np.ndarray
    mass: float
    center_mass: np.ndarray
    orientation: np.ndarray
    spawn_offset: np.ndarray
    batch: int


@dataclass(frozen=True)
class TubeSpec:
    """Closed-bottom cylindrical tube, simulation units.

    Attributes
    ----------
    inner_radius : float
        Inner radius of the wall; the axis is the world z axis.
    height : float
        Height of the wall above the inner floor (z = 0 .. height).
    wall_thickness : float
        Radial thickness of the wall.
    base_thickness : float
        Thickness of the floor below z = 0.
    """

    inner_radius: float
    height: float
    wall_thickness: float
    base_thickness: float


@dataclass(frozen=True)
class Material:
    """Contact and damping properties shared by all grains and the tube.

    Attributes
    ----------
    friction : float
        Coulomb (lateral) friction coefficient.
    restitution : float
        Coefficient of restitution (0 = perfectly inelastic).
    rolling_friction : float
        Rolling friction (pybullet only; Blender ignores it).
    linear_damping, angular_damping : float
        Velocity damping (fraction per second).
    collision_margin : float
        Collision margin in simulation units.
    """

    friction: float = 0.6
    restitution: float = 0.1
    rolling_friction: float = 0.0
    linear_damping: float = 0.05
    angular_damping: float = 0.1
    collision_margin: float = 0.005


@dataclass(frozen=True)
class SettleCriteria:
    """When a batch counts as settled.

    A batch has settled when all of its bodies move slower than ``linear_speed`` and
    rotate slower than ``angular_speed`` for ``quiet_steps`` consecutive steps, after at
    least ``min_steps`` steps; the engine gives up after ``max_steps`` steps.

    Attributes
    ----------
    time_step : float
        Simulated seconds per step.
    substeps : int
        Solver substeps per step.
    linear_speed : float
        Speed threshold, simulation units / s.
    angular_speed : float
        Angular speed threshold, rad / s.
    quiet_steps : int
        Consecutive quiet steps needed.
    max_steps : int
        Cap on steps per batch.
    min_steps : int
        Steps always run per batch.
    """

    time_step: float = 1 / 240
    substeps: int = 1
    linear_speed: float = 0.05
    angular_speed: float = 0.5
    quiet_steps: int = 30
    max_steps: int = 4000
    min_steps: int = 60


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
        Optional diagnostic: for each batch k, ``(positions (n_k, 3), quaternions
        (n_k, 4))`` of the n_k bodies of batches 0..k right after batch k was locked.
        None where the engine was not asked to (or cannot) record them.
    """

    positions: np.ndarray
    quaternions: np.ndarray
    steps_per_batch: list[int]
    settled_per_batch: list[bool]
    snapshots: list[tuple[np.ndarray, np.ndarray]] | None = None


class SimulateFunction(Protocol):
    """Signature every engine's ``simulate`` implements."""

    def __call__(
        self,
        bodies: Sequence[Body],
        tube: TubeSpec,
        material: Material,
        settle: SettleCriteria,
        progress: ProgressCallback | None = None,
    ) -> EngineResult: ...
