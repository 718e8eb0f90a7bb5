"""Batched, locked rigid-body pouring with pybullet (the default engine).

Implements the engine interface of :mod:`synthpack.physics.engine`; all lengths are
simulation units (about one grain diameter).

Choices, and why:

* Headless (``p.DIRECT``) on a physics client of its own, disconnected in a
  ``finally``, so several pours can run in one process and none leaks.
* Deterministic: a fixed time step, ``deterministicOverlappingPairs=1``, bodies
  created in the same order, no real-time clock. The same input gives the same
  output on one machine (and, in practice, with the same pybullet build).
* Grains collide as their CONVEX HULLS (``GEOM_MESH`` from the hull vertices), as
  rigid bodies in maximal coordinates. Hulls with more than ``max_hull_vertices``
  (default :data:`MAX_HULL_VERTICES`) vertices are simplified by quadric decimation:
  contact cost grows with the vertex count (measured: about 1.5x faster per step
  at 64 vertices than with the ~170-vertex hulls of 500-face grains), and for
  grains of ~20 voxels across the 64-vertex hull stays within about 0.4 voxel of
  the true hull. ``convex_decomposition=True`` uses a V-HACD decomposition into
  several convex parts instead, for strongly concave grains (slower to prepare:
  2-3 s per distinct grain, measured).
* Mass and inertia: the body frame is the particle-local frame; the inertial frame
  sits at the mesh's centre of mass, turned to the principal axes of the mesh's
  inertia tensor (uniform density, scaled to the body's mass), passed as
  ``baseInertialFramePosition/Orientation`` plus ``localInertiaDiagonal``. pybullet
  reports the INERTIAL frame's pose (``getBasePositionAndOrientation``; measured),
  so the local origin's pose is recovered as ``T_world_inertial @ T_inertial_local``.
* The tube is a ring of static boxes (their inner faces form a regular polygon of
  :data:`WALL_SEGMENTS` sides with apothem ``inner_radius``) on a static box floor.
  A concave triangle mesh (``GEOM_FORCE_CONCAVE_TRIMESH``, 48 sections) was
  measured against it on the same pours (150 grains in batches of 50, two seeds):
  both kept every grain inside with at most 0.22 voxel of wall penetration and gave
  the same packing fraction, but the box ring ran 1.3-2x faster (convex-convex
  contacts instead of convex-triangle ones), so it is the one used. The boxes are
  thickened outwards and the floor downwards to at least one unit so a fast grain
  cannot tunnel through. The wall is extended
  above ``tube.height`` as needed to cover each batch's spawn layers, so a grain
  cannot escape over the rim while it falls; grains that end above the rim are
  reported by the frontend's checks.
* Settling: after ``min_steps`` steps, a batch has settled once all its grains are
  below ``linear_speed`` and ``angular_speed`` for ``quiet_steps`` consecutive
  steps (at most ``max_steps``).
* Locking: a settled batch's bodies are removed and re-created as STATIC bodies
  (mass 0) at their final poses, with the same collision shapes. Static bodies are
  never integrated and static-static pairs are never collided, but every body in
  the world still costs a little per step (measured: 4,000 static grains made a
  step of 50 falling grains 3-6x slower). So locked grains buried deeper than any
  later grain can reach are removed from the world (see :func:`_retire_buried`);
  the cost per grain then stays about flat however many grains are poured.
"""

from __future__ import annotations

import logging
import os
import tempfile
from dataclasses import dataclass
from typing import Sequence

import numpy as np
import trimesh
from scipy.spatial import ConvexHull
from scipy.spatial.transform import Rotation

from ..errors import SynthpackInputError
from ._bullet import connect, silenced_stdout
from ._bullet import pybullet as p
from .engine import Body, EngineResult, Material, ProgressCallback, SettleCriteria, TubeSpec

logger = logging.getLogger(__name__)

__all__ = ["simulate", "WALL_SEGMENTS", "SOLVER_ITERATIONS", "GRAVITY", "MAX_HULL_VERTICES"]

#: Default cap on the vertices of a grain's collision hull.
MAX_HULL_VERTICES = 64
#: Number of boxes in the wall ring.
WALL_SEGMENTS = 48
#: Constraint-solver iterations per step.
SOLVER_ITERATIONS = 20
#: Gravitational acceleration, simulation units / s^2 (along -z).
GRAVITY = 9.81
_MIN_COLLIDER_THICKNESS = 1.0  # sim units: walls and floor are at least this thick


@dataclass(frozen=True)
class _Shape:
    """A collision shape and the inertial frame of one distinct grain geometry."""

    shape_id: int
    com: np.ndarray  # (3,) local frame
    inertial_quat: np.ndarray  # (4,) x, y, z, w: principal axes, local frame
    inertia_diagonal: np.ndarray  # (3,) principal moments for the body's mass
    hull_vertices: np.ndarray  # (H, 3) local frame: for the pack top


def simulate(
    bodies: Sequence[Body],
    tube: TubeSpec,
    material: Material,
    settle: SettleCriteria,
    progress: ProgressCallback | None = None,
    *,
    convex_decomposition: bool = False,
    max_hull_vertices: int | None = MAX_HULL_VERTICES,
    record_snapshots: bool = False,
    fixed_steps: int | None = None,
    allow_sleeping: bool = True,
) -> EngineResult:
    """Pour `bodies` batch by batch into `tube` with pybullet, locking each batch.

    Parameters
    ----------
    bodies : sequence of Body
        Grains in simulation units, ordered by batch (see :class:`~.engine.Body`).
    tube : TubeSpec
        The container, simulation units.
    material : Material
        Friction, restitution, damping and collision margin of grains and tube.
    settle : SettleCriteria
        Time step, substeps and when a batch counts as settled.
    progress : callable, optional
        ``progress(batch_index, n_batches)`` after each batch is locked.
    convex_decomposition : bool
        Collide grains as V-HACD convex decompositions instead of convex hulls.
    max_hull_vertices : int or None
        Simplify collision hulls to at most this many vertices (>= 8); None keeps
        the full hulls.
    record_snapshots : bool
        Also return, after each batch, the poses of all grains placed so far
        (``EngineResult.snapshots``), to check that locked grains stay put.
    fixed_steps : int, optional
        Run every batch for exactly this many steps, with no settle detection (the
        paper's fixed-frame Blender schedule; for benchmarks). None: detect settling.
    allow_sleeping : bool
        Let Bullet put grains that have been nearly still for 2 s to sleep (they
        wake when hit). False keeps every grain of the batch awake, as Blender's
        rigid bodies are by default (no deactivation).

    Returns
    -------
    EngineResult
        Final poses of every body's local origin, steps per batch, settled flags.

    Raises
    ------
    SynthpackInputError
        For an invalid `max_hull_vertices` or `fixed_steps`.
    """
    options = _Options(convex_decomposition, max_hull_vertices, record_snapshots, fixed_steps,
                       allow_sleeping)
    batches = np.array([b.batch for b in bodies], dtype=np.int64)
    if np.any(np.diff(batches) < 0):
        raise ValueError("bodies must be ordered by batch")
    client = connect()
    try:
        return _pour(client, bodies, batches, tube, material, settle, progress, options)
    finally:
        p.disconnect(physicsClientId=client)


@dataclass(frozen=True)
class _Options:
    """The engine options of :func:`simulate`, validated."""

    convex_decomposition: bool
    max_hull_vertices: int | None
    record_snapshots: bool
    fixed_steps: int | None
    allow_sleeping: bool

    def __post_init__(self) -> None:
        if self.max_hull_vertices is not None and not (
            isinstance(self.max_hull_vertices, int) and self.max_hull_vertices >= 8
        ):
            raise SynthpackInputError(
                "max_hull_vertices must be a whole number >= 8 or None, "
                f"got {self.max_hull_vertices!r}."
            )
        if self.fixed_steps is not None and not (
            isinstance(self.fixed_steps, int) and self.fixed_steps >= 1
        ):
            raise SynthpackInputError(
                f"fixed_steps must be a whole number >= 1 or None, got {self.fixed_steps!r}."
            )


def _pour(
    client: int,
    bodies: Sequence[Body],
    batches: np.ndarray,
    tube: TubeSpec,
    material: Material,
    settle: SettleCriteria,
    progress: ProgressCallback | None,
    options: _Options,
) -> EngineResult:
    _configure(client, settle)
    wall_top = _build_tube(client, tube, material, 0.0, tube.height)
    n = len(bodies)
    positions = np.zeros((n, 3))
    quaternions = np.zeros((n, 4))
    steps_per_batch: list[int] = []
    settled_per_batch: list[bool] = []
    snapshots: list[tuple[np.ndarray, np.ndarray]] = []
    shapes: dict[bytes, _Shape] = {}
    locked: dict[int, np.ndarray] = {}  # static body id -> its hull's world vertices
    largest = 2 * max(float(np.linalg.norm(b.vertices, axis=1).max()) for b in bodies)
    top = 0.0
    batch_ids = np.unique(batches)
    for number, batch in enumerate(batch_ids):
        members = np.flatnonzero(batches == batch)
        spawn = [_spawn_pose(bodies[i], top) for i in members]
        reach = max(pos[2] + float(np.linalg.norm(bodies[i].vertices, axis=1).max())
                    for i, (pos, _) in zip(members, spawn))
        if reach > wall_top:
            wall_top = _build_tube(client, tube, material, wall_top, reach + 1.0)
        active = []
        for i, (pos, quat) in zip(members, spawn):
            shape = _shape_for(client, bodies[i], shapes, options.convex_decomposition,
                               options.max_hull_vertices)
            body_id = _create_dynamic(client, shape, bodies[i].mass, pos, quat, material)
            if not options.allow_sleeping:
                p.changeDynamics(body_id, -1, activationState=p.ACTIVATION_STATE_DISABLE_SLEEPING,
                                 physicsClientId=client)
            active.append((body_id, shape))
        steps, settled = _run_batch(client, [a for a, _ in active], settle, options.fixed_steps)
        for i, (body_id, shape) in zip(members, active):
            positions[i], quaternions[i] = _local_pose(client, body_id, shape)
            p.removeBody(body_id, physicsClientId=client)
            static = _create_static(client, shape, positions[i], quaternions[i], material)
            rotation = Rotation.from_quat(quaternions[i], scalar_first=True)
            locked[static] = rotation.apply(shape.hull_vertices) + positions[i]
            top = max(top, float(locked[static][:, 2].max()))
        _retire_buried(client, locked, tube.inner_radius, largest)
        steps_per_batch.append(steps)
        settled_per_batch.append(settled)
        if not settled:
            logger.warning(
                "Batch %d was not at rest after %d steps; it is locked as it is.", batch, steps
            )
        if options.record_snapshots:
            placed = np.flatnonzero(batches <= batch)
            snapshots.append((positions[placed].copy(), quaternions[placed].copy()))
        logger.debug("Batch %d: %d grains, %d steps, pack top %.3f",
                     batch, len(members), steps, top)
        if progress is not None:
            progress(number, len(batch_ids))
    return EngineResult(
        positions=positions,
        quaternions=quaternions,
        steps_per_batch=steps_per_batch,
        settled_per_batch=settled_per_batch,
        snapshots=snapshots if options.record_snapshots else None,
    )


def _configure(client: int, settle: SettleCriteria) -> None:
    p.resetSimulation(physicsClientId=client)
    p.setGravity(0.0, 0.0, -GRAVITY, physicsClientId=client)
    p.setPhysicsEngineParameter(
        fixedTimeStep=settle.time_step,
        numSubSteps=settle.substeps if settle.substeps > 1 else 0,
        numSolverIterations=SOLVER_ITERATIONS,
        deterministicOverlappingPairs=1,
        physicsClientId=client,
    )


def _apply_material(client: int, body_id: int, material: Material, *, grain: bool) -> None:
    options = dict(
        lateralFriction=material.friction,
        restitution=material.restitution,
        rollingFriction=material.rolling_friction,
        physicsClientId=client,
    )
    if grain:
        options.update(
            linearDamping=material.linear_damping,
            angularDamping=material.angular_damping,
            collisionMargin=material.collision_margin,
        )
    p.changeDynamics(body_id, -1, **options)


def _build_tube(client: int, tube: TubeSpec, material: Material, z0: float, z1: float) -> float:
    """Add the wall between heights `z0` and `z1` (and the floor when ``z0 == 0``)."""
    thickness = max(tube.wall_thickness, _MIN_COLLIDER_THICKNESS)
    half_height = (z1 - z0) / 2
    half_width = tube.inner_radius * np.tan(np.pi / WALL_SEGMENTS) * 1.02
    box = p.createCollisionShape(
        p.GEOM_BOX, halfExtents=[thickness / 2, half_width, half_height], physicsClientId=client
    )
    centre = tube.inner_radius + thickness / 2
    for k in range(WALL_SEGMENTS):
        angle = 2 * np.pi * k / WALL_SEGMENTS
        body = p.createMultiBody(
            0.0, box, -1,
            basePosition=[centre * np.cos(angle), centre * np.sin(angle), z0 + half_height],
            baseOrientation=p.getQuaternionFromEuler([0.0, 0.0, angle]),
            physicsClientId=client,
        )
        _apply_material(client, body, material, grain=False)
    if z0 == 0.0:
        base = max(tube.base_thickness, _MIN_COLLIDER_THICKNESS)
        extent = tube.inner_radius + thickness
        floor = p.createCollisionShape(
            p.GEOM_BOX, halfExtents=[extent, extent, base / 2], physicsClientId=client
        )
        body = p.createMultiBody(0.0, floor, -1, basePosition=[0.0, 0.0, -base / 2],
                                 physicsClientId=client)
        _apply_material(client, body, material, grain=False)
    return z1


def _spawn_pose(body: Body, top: float) -> tuple[np.ndarray, np.ndarray]:
    """World position of the local origin and (w, x, y, z) orientation at spawn."""
    x, y, dz = np.asarray(body.spawn_offset, dtype=float)
    return np.array([x, y, top + dz]), np.asarray(body.orientation, dtype=float)


def _shape_for(
    client: int, body: Body, cache: dict[bytes, _Shape], decompose: bool, max_vertices: int | None
) -> _Shape:
    """Collision shape and inertial frame of `body`, shared by identical geometries."""
    vertices = np.ascontiguousarray(body.vertices, dtype=np.float64)
    faces = np.ascontiguousarray(body.faces, dtype=np.int64)
    key = vertices.tobytes() + faces.tobytes() + np.float64(body.mass).tobytes()
    if key in cache:
        return cache[key]
    hull = vertices[ConvexHull(vertices).vertices]
    if decompose:
        shape_id = _decomposed_shape(client, vertices, faces)
    else:
        collider = _simplified_hull(hull, max_vertices)
        shape_id = p.createCollisionShape(p.GEOM_MESH, vertices=collider.tolist(),
                                          physicsClientId=client)
    mesh = trimesh.Trimesh(vertices, faces, process=False)
    inertia = np.asarray(mesh.moment_inertia) * (body.mass / mesh.volume)
    moments, axes = np.linalg.eigh(inertia)
    if np.linalg.det(axes) < 0:
        axes[:, 2] *= -1
    shape = _Shape(
        shape_id=shape_id,
        com=np.asarray(body.center_mass, dtype=float),
        inertial_quat=Rotation.from_matrix(axes).as_quat(),
        inertia_diagonal=np.maximum(moments, 1e-12),
        hull_vertices=hull,
    )
    cache[key] = shape
    return shape


def _simplified_hull(hull_vertices: np.ndarray, max_vertices: int | None) -> np.ndarray:
    """Vertices of the convex hull, simplified to at most `max_vertices` (quadric decimation)."""
    if max_vertices is None or len(hull_vertices) <= max_vertices:
        return hull_vertices
    hull = trimesh.Trimesh(hull_vertices, ConvexHull(hull_vertices).simplices).convex_hull
    simple = hull.simplify_quadric_decimation(face_count=2 * max(max_vertices, 8) - 4)
    return np.asarray(simple.convex_hull.vertices)


def _decomposed_shape(client: int, vertices: np.ndarray, faces: np.ndarray) -> int:
    """Collision shape from a V-HACD convex decomposition of the mesh."""
    with tempfile.TemporaryDirectory(prefix="synthpack-vhacd-") as tmp:
        source, target = os.path.join(tmp, "in.obj"), os.path.join(tmp, "out.obj")
        trimesh.Trimesh(vertices, faces, process=False).export(source)
        with silenced_stdout():  # V-HACD prints its progress from C
            p.vhacd(source, target, os.path.join(tmp, "log.txt"), physicsClientId=client)
        return p.createCollisionShape(p.GEOM_MESH, fileName=target, physicsClientId=client)


def _create_dynamic(
    client: int, shape: _Shape, mass: float, position: np.ndarray, quat_wxyz: np.ndarray,
    material: Material,
) -> int:
    body = p.createMultiBody(
        baseMass=mass,
        baseCollisionShapeIndex=shape.shape_id,
        basePosition=position.tolist(),
        baseOrientation=_xyzw(quat_wxyz),
        baseInertialFramePosition=shape.com.tolist(),
        baseInertialFrameOrientation=shape.inertial_quat.tolist(),
        useMaximalCoordinates=True,
        physicsClientId=client,
    )
    # The mass must be repeated: for maximal-coordinate bodies pybullet otherwise
    # resets it to 0 when the inertia is changed (measured with pybullet 3.2.x).
    p.changeDynamics(body, -1, mass=mass, localInertiaDiagonal=shape.inertia_diagonal.tolist(),
                     physicsClientId=client)
    _apply_material(client, body, material, grain=True)
    return body


def _create_static(
    client: int, shape: _Shape, position: np.ndarray, quat_wxyz: np.ndarray, material: Material
) -> int:
    body = p.createMultiBody(
        baseMass=0.0,
        baseCollisionShapeIndex=shape.shape_id,
        basePosition=position.tolist(),
        baseOrientation=_xyzw(quat_wxyz),
        useMaximalCoordinates=True,
        physicsClientId=client,
    )
    _apply_material(client, body, material, grain=True)
    return body


def _retire_buried(
    client: int, locked: dict[int, np.ndarray], radius: float, largest: float
) -> None:
    """Remove locked grains buried too deep for any later grain to touch them.

    The pack's surface is sampled on a square grid of one-unit (about one grain)
    columns inside the tube: each column's height is the highest locked hull vertex
    in it. A locked grain whose top lies more than two of the largest grain
    diameters below the LOWEST column is covered everywhere by a thick layer of
    locked grains, so no later grain can reach it; it is removed from the world
    (its final pose is already recorded). A column without any vertex counts as
    the floor, so nothing is removed until the whole cross-section is covered. This
    keeps the number of bodies in the world, and so the cost of a step, bounded as
    the pack grows.
    """
    if not locked:
        return
    points = np.concatenate(list(locked.values()))
    half = int(np.ceil(radius))
    centres = np.arange(-half, half) + 0.5
    cx, cy = np.meshgrid(centres, centres, indexing="ij")
    inside = np.hypot(cx, cy) <= radius - 0.5
    if not inside.any():
        return
    ix = np.clip(np.floor(points[:, 0]).astype(np.int64) + half, 0, 2 * half - 1)
    iy = np.clip(np.floor(points[:, 1]).astype(np.int64) + half, 0, 2 * half - 1)
    heights = np.full(cx.shape, 0.0)
    np.maximum.at(heights, (ix, iy), points[:, 2])
    cut = float(heights[inside].min()) - 2 * largest
    buried = [b for b, v in locked.items() if v[:, 2].max() < cut]
    for body_id in buried:
        p.removeBody(body_id, physicsClientId=client)
        del locked[body_id]
    if buried:
        logger.debug("Retired %d buried grains below z = %.3f; %d locked grains remain",
                     len(buried), cut, len(locked))


def _run_batch(
    client: int, body_ids: list[int], settle: SettleCriteria, fixed_steps: int | None
) -> tuple[int, bool]:
    """Step until the batch has settled (or for exactly `fixed_steps`); (steps, settled)."""
    if fixed_steps is not None:
        for _ in range(fixed_steps):
            p.stepSimulation(physicsClientId=client)
        return fixed_steps, _is_quiet(client, body_ids, settle)
    quiet = 0
    for step in range(1, settle.max_steps + 1):
        p.stepSimulation(physicsClientId=client)
        quiet = quiet + 1 if _is_quiet(client, body_ids, settle) else 0
        if step >= settle.min_steps and quiet >= settle.quiet_steps:
            return step, True
    return settle.max_steps, False


def _is_quiet(client: int, body_ids: list[int], settle: SettleCriteria) -> bool:
    for body in body_ids:
        linear, angular = p.getBaseVelocity(body, physicsClientId=client)
        if (linear[0] ** 2 + linear[1] ** 2 + linear[2] ** 2 > settle.linear_speed**2
                or angular[0] ** 2 + angular[1] ** 2 + angular[2] ** 2 > settle.angular_speed**2):
            return False
    return True


def _local_pose(client: int, body_id: int, shape: _Shape) -> tuple[np.ndarray, np.ndarray]:
    """World pose of the local origin, from pybullet's inertial-frame pose."""
    com_world, inertial_xyzw = p.getBasePositionAndOrientation(body_id, physicsClientId=client)
    local = Rotation.from_quat(inertial_xyzw) * Rotation.from_quat(shape.inertial_quat).inv()
    position = np.asarray(com_world) - local.apply(shape.com)
    quat = local.as_quat(scalar_first=True)
    return position, quat * (1.0 if quat[0] >= 0 else -1.0)


def _xyzw(quat_wxyz: np.ndarray) -> list[float]:
    w, x, y, z = (float(v) for v in quat_wxyz)
    return [x, y, z, w]
