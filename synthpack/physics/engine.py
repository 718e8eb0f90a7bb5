"""The engine interface: the scene every rigid-body engine simulates, and the engine base class.

Everything here is in SIMULATION UNITS: the frontend (:func:`synthpack.physics.pour`)
divides physical lengths by one length scale (the library's median equivalent
diameter) so grains are about one unit across, gravity is 9.81 units/s^2 along -z,
and converts the engine's results back. World frame: (x, y, z), z up, tube axis along
z through x = y = 0, inner tube floor at z = 0.

The scene (:class:`Body` per grain, :class:`TubeSpec`, :class:`Material`,
:class:`SettleCriteria`) is one description, and each engine is a view of it (as
Kubric's simulators are views of its scene). An engine is an :class:`Engine`: a
``name``, a frozen dataclass of its ``Options`` (built on :mod:`synthpack._shared.schema`, so
``engine_options`` are checked like every other setting), checks of what it can
simulate, an availability check, and :meth:`Engine.simulate`. For each batch, in
order, it spawns the batch's bodies at ``(x, y, top + dz)`` (``spawn_offset = (x, y,
dz)``, ``top`` = the highest z of all grains already placed, or 0 for the first batch)
with ``orientation``, simulates until the batch has settled (see
:class:`SettleCriteria`), and then LOCKS the batch (static / passive) so it never
moves again. The engines are listed by name in :mod:`synthpack.physics.registry`.
"""

from __future__ import annotations

import abc
import math
import os
from collections.abc import Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Callable, ClassVar, Sequence

import numpy as np

from .._shared.schema import build, in_range, positive, setting
from ..errors import SynthpackInputError
from .hulls import MAX_HULL_VERTICES

if TYPE_CHECKING:
    from .compaction import PackingController

__all__ = [
    "Body",
    "TubeSpec",
    "Material",
    "SettleCriteria",
    "EngineResult",
    "ProgressCallback",
    "COLLISION_SHAPES",
    "EngineOptions",
    "Engine",
    "check_bodies",
    "check_tube",
    "check_material",
    "check_settle",
]

#: How grains collide: as their (simplified) convex hulls, or as a convex decomposition
#: (several convex parts, for concave grains; slower to prepare).
COLLISION_SHAPES = ("hull", "decomposition")

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
        Collision margin in simulation units. Bullet dilates a convex shape by its
        margin; the pybullet engine shrinks each collision shape by it first
        (:func:`~synthpack.physics.hulls.shrink_hull`), so touching grains touch.
    collision_shape : str
        One of :data:`COLLISION_SHAPES`: ``"hull"`` collides each grain as its convex
        hull (simplified to ``max_hull_vertices``); ``"decomposition"`` as a V-HACD
        convex decomposition (pybullet only; 2-3 s per distinct grain to prepare).
    """

    friction: float = 0.6
    restitution: float = 0.1
    rolling_friction: float = 0.0
    linear_damping: float = 0.05
    angular_damping: float = 0.1
    collision_margin: float = 0.005
    collision_shape: str = "hull"


@dataclass(frozen=True)
class SettleCriteria:
    """When a batch counts as settled.

    A batch has settled when all of its bodies move slower than ``linear_speed`` and
    rotate slower than ``angular_speed`` for ``quiet_steps`` consecutive steps, after at
    least ``min_steps`` steps; the engine gives up after ``max_steps`` steps.

    The default step is 1/240 s (0.125 s quiet, 0.25 s at least, 16.7 s at most). A
    1/120 s step with the same durations halves the steps and keeps the contacts of
    grains ~1 unit across (largest grain overlap 1.04 against 1.09 voxels, 300 grains
    scaled by 2, measured), but the low-friction fall of a compacted batch then packs
    less: 400 grains of the `small` sample reached a bulk solid fraction of 0.570 against
    0.605 at 1/240 s (target 0.596), so the default stays 1/240 s.
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


@dataclass(frozen=True)
class EngineOptions:
    """The options every engine takes: ``engine_options`` of :func:`~synthpack.physics.pour`.

    Each engine's ``Options`` extends it. Build them with :meth:`Engine.options`, which
    checks every value; the defaults are what a pour without ``engine_options`` uses.

    Attributes
    ----------
    max_hull_vertices : int or None
        Simplify each grain's collision hull to at most this many vertices (>= 8; see
        :mod:`synthpack.physics.hulls`); None keeps the full hulls.
    fixed_steps : int or None
        Run every batch for exactly this many steps, with no settle detection (the
        paper's fixed-frame schedule); None detects settling (:class:`SettleCriteria`).
    record_snapshots : bool
        Also return, after each batch, the poses of all grains placed so far
        (``EngineResult.snapshots``), to check that locked grains stay put.
    """

    max_hull_vertices: int | None = setting(
        MAX_HULL_VERTICES, in_range(8, math.inf),
        "simplify each grain's collision hull to at most this many vertices; null keeps the full hull",
    )
    fixed_steps: int | None = setting(
        None, positive, "run every batch for exactly this many steps, without settle detection"
    )
    record_snapshots: bool = setting(
        False, None, "also return the poses of all grains placed so far after each batch"
    )


class Engine(abc.ABC):
    """A rigid-body engine: a view of the scene that pours it batch by batch.

    Subclasses set :attr:`name` and :attr:`Options`, implement :meth:`_simulate`, and
    may extend :meth:`check` (limits of their own) and :meth:`check_available`.
    """

    #: The name of the engine in ``pour(engine=...)`` and in the config's ``pour.engine``.
    name: ClassVar[str]
    #: The engine's options: an :class:`EngineOptions` subclass.
    Options: ClassVar[type[EngineOptions]] = EngineOptions
    #: Whether the engine packs to a target (:mod:`synthpack.physics.compaction`).
    supports_compaction: ClassVar[bool] = False

    def options(
        self, values: Mapping[str, Any] | None = None, prefix: str = "engine_options."
    ) -> EngineOptions:
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

    def check(self, material: Material, settle: SettleCriteria, options: EngineOptions) -> None:
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

    def simulate(
        self,
        bodies: Sequence[Body],
        tube: TubeSpec,
        material: Material,
        settle: SettleCriteria,
        options: EngineOptions | None = None,
        progress: ProgressCallback | None = None,
        compaction: PackingController | None = None,
    ) -> EngineResult:
        """Pour `bodies` batch by batch into `tube`, locking each batch once it has settled.

        Parameters
        ----------
        bodies : sequence of Body
            Grains in simulation units, ordered by batch.
        tube : TubeSpec
            The container, simulation units.
        material : Material
            Friction, restitution, damping and collision margin of grains and tube.
        settle : SettleCriteria
            Time step, substeps and when a batch counts as settled.
        options : EngineOptions, optional
            The engine's ``Options`` (:meth:`options`); default: its defaults.
        progress : callable, optional
            ``progress(batch_index, n_batches)`` after each batch is locked.
        compaction : PackingController, optional
            Packs each batch toward a target solid fraction before it is locked
            (:mod:`synthpack.physics.compaction`); None: a free pour. Only for an
            engine that :attr:`supports_compaction`.

        Returns
        -------
        EngineResult
            Final poses of every body's local origin, in the order of `bodies`; steps
            and settled flag per batch; snapshots when asked for.

        Raises
        ------
        SynthpackInputError
            For input the engine cannot simulate (compaction included), or when it
            cannot run here.
        """
        options = self.Options() if options is None else options
        check_bodies(bodies)
        check_tube(tube)
        self.check(material, settle, options)
        if compaction is not None and not self.supports_compaction:
            raise SynthpackInputError(
                f"The {self.name} engine cannot pack to a target solid fraction; "
                "use the pybullet engine or target_solid_fraction: none."
            )
        self.check_available()
        return self._simulate(bodies, tube, material, settle, options, progress, compaction)

    @abc.abstractmethod
    def _simulate(
        self,
        bodies: Sequence[Body],
        tube: TubeSpec,
        material: Material,
        settle: SettleCriteria,
        options: EngineOptions,
        progress: ProgressCallback | None,
        compaction: PackingController | None = None,
    ) -> EngineResult:
        """The simulation itself, on checked input (see :meth:`simulate`)."""

    def __repr__(self) -> str:
        return f"{type(self).__name__}(name={self.name!r})"


def check_bodies(bodies: Sequence[Body]) -> None:
    """Raise SynthpackInputError unless `bodies` are grains an engine can pour.

    At least one body; batches in non-decreasing order; (V >= 4, 3) vertices, (F > 0,
    3) faces and a positive mass per body.
    """
    if len(bodies) == 0:
        raise SynthpackInputError("simulate() got no bodies: pass at least one Body to pour.")
    if np.any(np.diff([body.batch for body in bodies]) < 0):
        raise SynthpackInputError("bodies must be ordered by batch (non-decreasing Body.batch).")
    for i, body in enumerate(bodies):
        vertices, faces = np.asarray(body.vertices), np.asarray(body.faces)
        if vertices.ndim != 2 or vertices.shape[1] != 3 or len(vertices) < 4:
            raise SynthpackInputError(
                f"body {i}: vertices must have shape (V>=4, 3), got {vertices.shape}."
            )
        if faces.ndim != 2 or faces.shape[1] != 3 or len(faces) == 0:
            raise SynthpackInputError(f"body {i}: faces must have shape (F>0, 3), got {faces.shape}.")
        if not body.mass > 0:
            raise SynthpackInputError(f"body {i}: mass must be > 0, got {body.mass}.")


def check_tube(tube: TubeSpec) -> None:
    """Raise SynthpackInputError unless every size of `tube` is a finite positive number."""
    for name in ("inner_radius", "height", "wall_thickness", "base_thickness"):
        value = getattr(tube, name)
        if not (isinstance(value, (int, float)) and 0 < value < math.inf):
            raise SynthpackInputError(
                f"TubeSpec.{name} must be > 0, got {value!r}; pass a positive size."
            )


def check_material(material: Material) -> None:
    """Raise SynthpackInputError unless `material` is a Material with every value in range."""
    if not isinstance(material, Material):
        raise SynthpackInputError(f"material must be a Material, got {type(material).__name__}.")
    ranges = {
        "friction": (0.0, math.inf), "restitution": (0.0, 1.0), "rolling_friction": (0.0, math.inf),
        "linear_damping": (0.0, 1.0), "angular_damping": (0.0, 1.0),
        "collision_margin": (0.0, math.inf),
    }
    for name, (low, high) in ranges.items():
        value = getattr(material, name)
        if not (isinstance(value, (int, float)) and low <= value <= high):
            raise SynthpackInputError(
                f"Material.{name} must be a number in [{low:g}, {high:g}], got {value!r}."
            )
    if material.collision_shape not in COLLISION_SHAPES:
        raise SynthpackInputError(
            f"Material.collision_shape must be one of {', '.join(COLLISION_SHAPES)}, "
            f"got {material.collision_shape!r}."
        )


def check_settle(settle: SettleCriteria) -> None:
    """Raise SynthpackInputError unless `settle` is a SettleCriteria with every value in range."""
    if not isinstance(settle, SettleCriteria):
        raise SynthpackInputError(f"settle must be a SettleCriteria, got {type(settle).__name__}.")
    for name in ("time_step", "linear_speed", "angular_speed"):
        value = getattr(settle, name)
        if not (isinstance(value, (int, float)) and 0 < value < math.inf):
            raise SynthpackInputError(f"SettleCriteria.{name} must be > 0, got {value!r}.")
    for name in ("substeps", "quiet_steps", "max_steps"):
        value = getattr(settle, name)
        if not (isinstance(value, int) and value >= 1):
            raise SynthpackInputError(
                f"SettleCriteria.{name} must be a whole number >= 1, got {value!r}."
            )
    if not (isinstance(settle.min_steps, int) and 0 <= settle.min_steps <= settle.max_steps):
        raise SynthpackInputError(
            "SettleCriteria.min_steps must be a whole number in [0, max_steps], "
            f"got {settle.min_steps!r}."
        )
