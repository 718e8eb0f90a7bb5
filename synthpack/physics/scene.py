"""The scene of a pour: what every rigid-body engine simulates, as one plain description.

Everything here is in SIMULATION UNITS: the frontend (:func:`synthpack.physics.pour`)
divides physical lengths by one length scale (the library's median equivalent
diameter) so grains are about one unit across, gravity is 9.81 units/s^2 along -z,
and converts the engine's results back. World frame: (x, y, z), z up, tube axis along
z through x = y = 0, inner tube floor at z = 0.

A :class:`Scene` holds the grains (:class:`Body`), the :class:`TubeSpec`, the
:class:`Material`, the :class:`SettleCriteria` and the engine's options
(:class:`EngineConfig`); each engine is a view of it, as Kubric's simulators are
views of its scene. :meth:`Scene.save` writes it as JSON plus one ``.npz`` of arrays, which
is how it reaches an engine that runs in a process of its own (Blender).

:class:`Material` and :class:`SettleCriteria` are settings dataclasses
(:func:`synthpack._shared.schema.setting`), checked by :func:`check_material` and
:func:`check_settle` through :func:`synthpack._shared.schema.build`. The material's
friction, restitution and collision shape have no defaults here: they are the pour's
settings, whose defaults are :class:`~synthpack.physics.config.PourConfig`'s
(``PourConfig().material()``).
"""

from __future__ import annotations

import dataclasses
import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from .._shared.schema import build, in_range, non_negative, one_of, positive, setting
from ..errors import SynthpackInputError
from .hulls import MAX_HULL_VERTICES

__all__ = [
    "COLLISION_SHAPES",
    "Body",
    "TubeSpec",
    "Material",
    "SettleCriteria",
    "EngineConfig",
    "Scene",
    "SCENE_FILE",
    "BODIES_FILE",
    "check_bodies",
    "check_tube",
    "check_material",
    "check_settle",
]

#: How grains collide: as their (simplified) convex hulls, or as a convex decomposition
#: (several convex parts, for concave grains; slower to prepare).
COLLISION_SHAPES = ("hull", "decomposition")
#: File names :meth:`Scene.save` writes: the description, and the bodies' arrays.
SCENE_FILE, BODIES_FILE = "scene.json", "bodies.npz"
#: ``format`` and ``version`` of a saved scene.
_FORMAT, _VERSION = "synthpack-scene", 1


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


@dataclass(frozen=True, kw_only=True)
class Material:
    """Contact and damping properties shared by all grains and the tube.

    ``friction``, ``restitution`` and ``collision_shape`` are the pour's settings and
    have no default here: ``PourConfig().material()`` is the default material
    (:meth:`~synthpack.physics.config.PourConfig.material`).

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

    friction: float = setting(dataclasses.MISSING, non_negative, "Coulomb friction coefficient")
    restitution: float = setting(dataclasses.MISSING, in_range(0.0, 1.0), "coefficient of restitution")
    rolling_friction: float = setting(0.0, non_negative, "rolling friction (pybullet only)")
    linear_damping: float = setting(0.05, in_range(0.0, 1.0), "linear velocity damping, fraction per second")
    angular_damping: float = setting(0.1, in_range(0.0, 1.0), "angular velocity damping, fraction per second")
    collision_margin: float = setting(0.005, non_negative, "collision margin, simulation units")
    collision_shape: str = setting(dataclasses.MISSING, one_of(COLLISION_SHAPES), "how grains collide")


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

    time_step: float = setting(1 / 240, positive, "seconds per step")
    substeps: int = setting(1, positive, "solver substeps per step")
    linear_speed: float = setting(0.05, positive, "a grain is quiet below this speed, units per second")
    angular_speed: float = setting(0.5, positive, "a grain is quiet below this rotation speed, radians per second")
    quiet_steps: int = setting(30, positive, "consecutive quiet steps that settle a batch")
    max_steps: int = setting(4000, positive, "steps after which a batch is locked as it is")
    min_steps: int = setting(60, non_negative, "steps every batch runs at least")


@dataclass(frozen=True)
class EngineConfig:
    """The options every engine takes: ``engine_options`` of :func:`~synthpack.physics.pour`.

    Each engine's ``Options`` extends it. Build them with
    :meth:`~synthpack.physics.engine.Engine.options`, which checks every value; the
    defaults are what a pour without ``engine_options`` uses.

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


@dataclass(frozen=True)
class Scene:
    """Everything an engine needs to pour: the grains, the tube, the material, settling, options.

    Attributes
    ----------
    bodies : sequence of Body
        The grains in simulation units, ordered by batch.
    tube : TubeSpec
        The container.
    material : Material
        Friction, restitution, damping and collision margin of grains and tube.
    settle : SettleCriteria
        Time step, substeps and when a batch counts as settled.
    options : EngineConfig
        The engine's options (:meth:`~synthpack.physics.engine.Engine.options`).
    """

    bodies: Sequence[Body]
    tube: TubeSpec
    material: Material
    settle: SettleCriteria
    options: EngineConfig

    def batches(self) -> list[np.ndarray]:
        """The indices (into :attr:`bodies`) of each batch's bodies, batches in increasing order."""
        numbers = np.array([body.batch for body in self.bodies], dtype=np.int64)
        return [np.flatnonzero(numbers == batch) for batch in np.unique(numbers)]

    def to_dict(self) -> dict[str, Any]:
        """The scene without its bodies' arrays, JSON-able: tube, material, settle and options by field."""
        return {
            "format": _FORMAT,
            "version": _VERSION,
            "tube": dataclasses.asdict(self.tube),
            "material": dataclasses.asdict(self.material),
            "settle": dataclasses.asdict(self.settle),
            "options": dataclasses.asdict(self.options),
            "n_bodies": len(self.bodies),
            "bodies": BODIES_FILE,
        }

    def save(self, directory: str | Path) -> Path:
        """Write the scene into `directory`: :data:`SCENE_FILE` (:meth:`to_dict`) and :data:`BODIES_FILE`.

        The ``.npz`` holds the bodies' meshes end to end, ``vertices`` (sum V, 3) float64
        and ``faces`` (sum F, 3) int64 (each body's own vertex numbers), with
        ``vertex_offsets`` and ``face_offsets`` (N + 1,) int64 (body k's rows are
        ``offsets[k]:offsets[k + 1]``), and ``mass`` (N,), ``center_mass`` (N, 3),
        ``orientation`` (N, 4), ``spawn_offset`` (N, 3) float64 and ``batch`` (N,) int64.
        It needs NumPy only to read (1.x or 2.x).

        Returns
        -------
        pathlib.Path
            The path of :data:`SCENE_FILE`.
        """
        directory = Path(directory)
        vertices = [np.asarray(b.vertices, dtype=np.float64) for b in self.bodies]
        faces = [np.asarray(b.faces, dtype=np.int64) for b in self.bodies]
        np.savez(
            directory / BODIES_FILE,
            vertices=np.concatenate(vertices).reshape(-1, 3),
            faces=np.concatenate(faces).reshape(-1, 3),
            vertex_offsets=np.cumsum([0, *map(len, vertices)], dtype=np.int64),
            face_offsets=np.cumsum([0, *map(len, faces)], dtype=np.int64),
            mass=np.array([b.mass for b in self.bodies], dtype=np.float64),
            center_mass=np.array([b.center_mass for b in self.bodies], dtype=np.float64).reshape(-1, 3),
            orientation=np.array([b.orientation for b in self.bodies], dtype=np.float64).reshape(-1, 4),
            spawn_offset=np.array([b.spawn_offset for b in self.bodies], dtype=np.float64).reshape(-1, 3),
            batch=np.array([b.batch for b in self.bodies], dtype=np.int64),
        )
        path = directory / SCENE_FILE
        path.write_text(json.dumps(self.to_dict()))
        return path


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


def _check_settings(value: Any, cls: type) -> None:
    """Raise SynthpackInputError unless `value` is a `cls` whose every field passes its check.

    Rebuilds it with :func:`~synthpack._shared.schema.build`, so a message names the
    field as ``ClassName.field``.
    """
    if not isinstance(value, cls):
        raise SynthpackInputError(
            f"{cls.__name__.lower()} must be a {cls.__name__}, got {type(value).__name__}."
        )
    fields = {field.name: getattr(value, field.name) for field in dataclasses.fields(cls)}
    build(cls, fields, f"{cls.__name__}.", name=str)


def check_material(material: Material) -> None:
    """Raise SynthpackInputError unless `material` is a Material with every value in range."""
    _check_settings(material, Material)


def check_settle(settle: SettleCriteria) -> None:
    """Raise SynthpackInputError unless `settle` is a SettleCriteria with every value in range.

    Beyond each field's own check, ``min_steps`` must not exceed ``max_steps``.
    """
    _check_settings(settle, SettleCriteria)
    if settle.min_steps > settle.max_steps:
        raise SynthpackInputError(
            f"SettleCriteria.min_steps must be at most max_steps ({settle.max_steps}), got {settle.min_steps}."
        )
