"""Batched, locked rigid-body pouring with pybullet (the default engine).

Implements the engine interface of :mod:`synthpack.physics.engine`; all lengths are
simulation units (about one grain diameter).

Choices, and why:

* Headless (``DIRECT``) on a physics client of its own (:class:`._bullet.Client`,
  which binds the client's id to pybullet's functions once), disconnected when the
  pour ends, so several pours can run in one process and none leaks. pybullet is
  imported when the first pour starts, not with this module.
* Deterministic: a fixed time step, ``deterministicOverlappingPairs=1``, bodies
  created in the same order, no real-time clock. The same input gives the same
  output on one machine (and, in practice, with the same pybullet build).
* Grains collide as their CONVEX HULLS (``GEOM_MESH`` from the hull vertices), as
  rigid bodies in maximal coordinates, simplified to at most ``max_hull_vertices``
  vertices (:mod:`synthpack.physics.hulls`, shared with the Blender engine).
  ``material.collision_shape == "decomposition"`` uses a V-HACD decomposition into
  several convex parts instead, for strongly concave grains (slower to prepare: 2-3 s
  per distinct grain, measured; done once per distinct grain of a pour).
* Real contacts: Bullet dilates every convex shape by its collision margin (a unit
  cube of margin m rests at 0.5 + m: measured), so each convex part is shrunk by
  ``material.collision_margin`` first (:func:`~synthpack.physics.hulls.shrink_hull`)
  and dilates back onto the hull: grains that touch in the simulation touch.
* Containment: the simplified hulls (and decompositions) are not exact, so a grain's
  mesh reaches a little outside its collision shape (up to about 0.4 voxel of a
  ~20-voxel grain, and 4x that for grains scaled by 4). The tube's colliders are
  moved inwards by the largest such reach of the pour's grains
  (:func:`~synthpack.physics.hulls.protrusion`), and the wall is a polygon inscribed
  in that smaller circle, so a grain resting against the colliders keeps its mesh
  inside the real tube. Grains have continuous collision detection
  (``ccdSweptSphereRadius``, half their inradius), against tunnelling when they move
  fast.
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
  contacts instead of convex-triangle ones), so it is the one used. The inner faces
  are a polygon inscribed in the (inset) circle, its corners on it. The boxes are
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
  the world still costs a little per step, so locked grains buried deeper than any
  later grain can reach are removed from the world (:mod:`synthpack.physics.burial`,
  shared with the Blender engine).
* Packing to a target (:mod:`synthpack.physics.compaction`): a
  :class:`~synthpack.physics.compaction.PackingController` sets each batch's knob
  before it falls: a lowered friction while it falls (denser, :func:`_compact`), or
  collision hulls inflated about the centre of mass (looser, :func:`_shape_for`);
  it measures the bulk after each batch is locked.
"""

from __future__ import annotations

import logging
import os
import tempfile
from collections.abc import Mapping
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any, Sequence

import numpy as np
import trimesh
from scipy.spatial.transform import Rotation

from .._shared.schema import setting
from ..errors import SynthpackInputError
from .burial import buried, largest_diameter
from .compaction import FALL_QUIET, FALL_STEPS, BatchCompaction, PackingController
from .engine import (
    Body,
    Engine,
    EngineOptions,
    EngineResult,
    Material,
    ProgressCallback,
    SettleCriteria,
    TubeSpec,
)
from .hulls import convex_hull, protrusion, shrink_hull, simplify_hull

if TYPE_CHECKING:
    from ._bullet import Client

logger = logging.getLogger(__name__)

__all__ = ["PybulletEngine", "PybulletOptions", "WALL_SEGMENTS", "SOLVER_ITERATIONS", "GRAVITY"]

#: Number of boxes in the wall ring.
WALL_SEGMENTS = 48
#: Constraint-solver iterations per step.
SOLVER_ITERATIONS = 20
#: Gravitational acceleration, simulation units / s^2 (along -z).
GRAVITY = 9.81
_MIN_COLLIDER_THICKNESS = 1.0  # sim units: walls and floor are at least this thick


@dataclass(frozen=True)
class PybulletOptions(EngineOptions):
    """Options of the pybullet engine (``engine_options`` of :func:`~synthpack.physics.pour`).

    Attributes
    ----------
    allow_sleeping : bool
        Let Bullet put grains that have been nearly still for 2 s to sleep (they wake
        when hit). False keeps every grain of the batch awake, as Blender's rigid
        bodies are by default (no deactivation).

    See :class:`~synthpack.physics.engine.EngineOptions` for ``max_hull_vertices``,
    ``fixed_steps`` and ``record_snapshots``.
    """

    allow_sleeping: bool = setting(
        True, None, "let grains that have been nearly still for 2 s sleep until something hits them"
    )


class PybulletEngine(Engine):
    """The default engine: headless, deterministic pybullet (see the module's notes)."""

    name = "pybullet"
    Options = PybulletOptions
    supports_compaction = True

    def options(
        self, values: Mapping[str, Any] | None = None, prefix: str = "engine_options."
    ) -> EngineOptions:
        """As :meth:`Engine.options`; the former ``convex_decomposition`` option gets a pointer to its successor."""
        if isinstance(values, Mapping) and "convex_decomposition" in values:
            raise SynthpackInputError(
                f"'{prefix}convex_decomposition' is now the collision shape: set pour.collision_shape: "
                "decomposition in the config, --collision-shape decomposition on the command line, or "
                "Material(collision_shape='decomposition') in Python."
            )
        return super().options(values, prefix)

    def _simulate(
        self,
        bodies: Sequence[Body],
        tube: TubeSpec,
        material: Material,
        settle: SettleCriteria,
        options: PybulletOptions,
        progress: ProgressCallback | None,
        compaction: PackingController | None = None,
    ) -> EngineResult:
        from ._bullet import Client

        with Client() as client:
            return _pour(client, bodies, tube, material, settle, progress, options, compaction)


@dataclass(frozen=True)
class _Shape:
    """A collision shape and the inertial frame of one distinct grain geometry."""

    shape_id: int
    com: np.ndarray  # (3,) local frame
    inertial_quat: np.ndarray  # (4,) x, y, z, w: principal axes, local frame
    inertia_diagonal: np.ndarray  # (3,) principal moments for the body's mass
    hull_vertices: np.ndarray  # (H, 3) local frame: for the pack top
    protrusion: float  # how far the mesh reaches outside the collision shape
    inradius: float  # distance from the centre of mass to the hull's nearest face


def _pour(
    client: Client,
    bodies: Sequence[Body],
    tube: TubeSpec,
    material: Material,
    settle: SettleCriteria,
    progress: ProgressCallback | None,
    options: PybulletOptions,
    compaction: PackingController | None = None,
) -> EngineResult:
    """Pour `bodies`, batch by batch, on a fresh physics client (see :class:`PybulletEngine`)."""
    _configure(client, settle)
    shapes: dict[bytes, _Shape] = {}
    body_shapes = [_shape_for(client, body, shapes, material, options.max_hull_vertices)
                   for body in bodies]
    inset = max(shape.protrusion for shape in shapes.values())
    logger.debug("Tube colliders inset by %.4f (the grains' largest reach outside their shapes)", inset)
    wall_top = _build_tube(client, tube, material, 0.0, tube.height, inset)
    n = len(bodies)
    positions = np.zeros((n, 3))
    quaternions = np.zeros((n, 4))
    steps_per_batch: list[int] = []
    settled_per_batch: list[bool] = []
    snapshots: list[tuple[np.ndarray, np.ndarray]] = []
    locked: dict[int, np.ndarray] = {}  # static body id -> its hull's world vertices
    largest = largest_diameter(b.vertices for b in bodies)
    top = 0.0
    batches = np.array([b.batch for b in bodies], dtype=np.int64)
    batch_ids = np.unique(batches)
    for number, batch in enumerate(batch_ids):
        members = np.flatnonzero(batches == batch)
        plan = None if compaction is None else compaction.next_batch()
        inflation = 0.0 if plan is None else plan.inflation
        spawn = [_spawn_pose(bodies[i], top) for i in members]
        reach = max(pos[2] + float(np.linalg.norm(bodies[i].vertices, axis=1).max())
                    for i, (pos, _) in zip(members, spawn))
        if reach > wall_top:
            wall_top = _build_tube(client, tube, material, wall_top, reach + 1.0, inset)
        active = []
        for i, (pos, quat) in zip(members, spawn):
            shape = body_shapes[i] if inflation == 0 else _shape_for(
                client, bodies[i], shapes, material, options.max_hull_vertices, inflation)
            body_id = _create_dynamic(client, shape, bodies[i].mass, pos, quat, material)
            if plan is not None and plan.settle_friction != material.friction:
                client.changeDynamics(body_id, -1, lateralFriction=plan.settle_friction)
            if not options.allow_sleeping:
                client.changeDynamics(body_id, -1,
                                      activationState=client.ACTIVATION_STATE_DISABLE_SLEEPING)
            active.append((body_id, shape))
        if plan is not None and plan.compacts and options.fixed_steps is None:
            steps, settled = _compact(client, [a for a, _ in active], plan, material, settle)
        else:
            steps, settled = _run_batch(client, [a for a, _ in active], settle, options.fixed_steps)
        for i, (body_id, shape) in zip(members, active):
            positions[i], quaternions[i] = _local_pose(client, body_id, shape)
            client.removeBody(body_id)
            static = _create_static(client, shape, positions[i], quaternions[i], material)
            rotation = Rotation.from_quat(quaternions[i], scalar_first=True)
            locked[static] = rotation.apply(shape.hull_vertices) + positions[i]
            top = max(top, float(locked[static][:, 2].max()))
        _retire_buried(client, locked, tube.inner_radius, largest)
        if compaction is not None:
            compaction.observe(members, positions[members], quaternions[members])
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


def _configure(client: Client, settle: SettleCriteria) -> None:
    client.resetSimulation()
    client.setGravity(0.0, 0.0, -GRAVITY)
    client.setPhysicsEngineParameter(
        fixedTimeStep=settle.time_step,
        numSubSteps=settle.substeps if settle.substeps > 1 else 0,
        numSolverIterations=SOLVER_ITERATIONS,
        deterministicOverlappingPairs=1,
    )


def _apply_material(client: Client, body_id: int, material: Material, *, grain: bool) -> None:
    options = dict(
        lateralFriction=material.friction,
        restitution=material.restitution,
        rollingFriction=material.rolling_friction,
    )
    if grain:
        options.update(
            linearDamping=material.linear_damping,
            angularDamping=material.angular_damping,
            collisionMargin=material.collision_margin,
        )
    client.changeDynamics(body_id, -1, **options)


def _build_tube(
    client: Client, tube: TubeSpec, material: Material, z0: float, z1: float, inset: float
) -> float:
    """Add the wall between heights `z0` and `z1` (and the floor when ``z0 == 0``).

    The colliders lie `inset` inside the tube: the floor's top face at ``z = inset``,
    the wall's inner faces a polygon inscribed in the circle of radius
    ``inner_radius - inset``.
    """
    thickness = max(tube.wall_thickness, _MIN_COLLIDER_THICKNESS)
    half_height = (z1 - z0) / 2
    apothem = (tube.inner_radius - inset) * np.cos(np.pi / WALL_SEGMENTS)
    half_width = apothem * np.tan(np.pi / WALL_SEGMENTS) * 1.02
    box = client.createCollisionShape(
        client.GEOM_BOX, halfExtents=[thickness / 2, half_width, half_height]
    )
    centre = apothem + thickness / 2
    for k in range(WALL_SEGMENTS):
        angle = 2 * np.pi * k / WALL_SEGMENTS
        body = client.createMultiBody(
            0.0, box, -1,
            basePosition=[centre * np.cos(angle), centre * np.sin(angle), z0 + half_height],
            baseOrientation=client.getQuaternionFromEuler([0.0, 0.0, angle]),
        )
        _apply_material(client, body, material, grain=False)
    if z0 == 0.0:
        base = max(tube.base_thickness, _MIN_COLLIDER_THICKNESS)
        extent = tube.inner_radius + thickness
        floor = client.createCollisionShape(
            client.GEOM_BOX, halfExtents=[extent, extent, base / 2]
        )
        body = client.createMultiBody(0.0, floor, -1, basePosition=[0.0, 0.0, inset - base / 2])
        _apply_material(client, body, material, grain=False)
    return z1


def _spawn_pose(body: Body, top: float) -> tuple[np.ndarray, np.ndarray]:
    """World position of the local origin and (w, x, y, z) orientation at spawn."""
    x, y, dz = np.asarray(body.spawn_offset, dtype=float)
    return np.array([x, y, top + dz]), np.asarray(body.orientation, dtype=float)


def _shape_for(
    client: Client, body: Body, cache: dict[bytes, _Shape], material: Material,
    max_vertices: int | None, inflation: float = 0.0,
) -> _Shape:
    """Collision shape and inertial frame of `body`, shared by identical geometries.

    With `inflation` > 0 the collider is the grain inflated by that fraction of its
    size about its centre of mass (a spacing shell, :mod:`.compaction`); mass,
    inertia and the pose of the local origin stay those of the true grain.
    """
    vertices = np.ascontiguousarray(body.vertices, dtype=np.float64)
    faces = np.ascontiguousarray(body.faces, dtype=np.int64)
    key = vertices.tobytes() + faces.tobytes() + np.float64(body.mass).tobytes() + np.float64(inflation).tobytes()
    if key in cache:
        return cache[key]
    true_vertices = vertices
    if inflation > 0:
        centre = np.asarray(body.center_mass, dtype=np.float64)
        vertices = centre + (vertices - centre) * (1.0 + inflation)
    hull = convex_hull(vertices)
    if material.collision_shape == "decomposition":
        parts = _decomposed_parts(client, vertices, faces)
    else:
        parts = [simplify_hull(hull, max_vertices)]
    shrunk = [shrink_hull(part, material.collision_margin) for part in parts]
    shape_id = _collision_shape(client, shrunk)
    mesh = trimesh.Trimesh(true_vertices, faces, process=False)
    inertia = np.asarray(mesh.moment_inertia) * (body.mass / mesh.volume)
    moments, axes = np.linalg.eigh(inertia)
    if np.linalg.det(axes) < 0:
        axes[:, 2] *= -1
    shape = _Shape(
        shape_id=shape_id,
        com=np.asarray(body.center_mass, dtype=float),
        inertial_quat=Rotation.from_matrix(axes).as_quat(),
        inertia_diagonal=np.maximum(moments, 1e-12),
        hull_vertices=np.asarray(hull.vertices),
        protrusion=protrusion(true_vertices, shrunk),
        inradius=max(0.0, float(np.einsum("fi,fi->f", hull.face_normals,
                                          hull.triangles[:, 0] - body.center_mass).min())),
    )
    cache[key] = shape
    return shape


def _decomposed_parts(client: Client, vertices: np.ndarray, faces: np.ndarray) -> list[trimesh.Trimesh]:
    """The convex parts of a V-HACD decomposition of the mesh (pybullet's ``vhacd``)."""
    from ._bullet import silenced_stdout

    with tempfile.TemporaryDirectory(prefix="synthpack-vhacd-") as tmp:
        source, target = os.path.join(tmp, "in.obj"), os.path.join(tmp, "out.obj")
        trimesh.Trimesh(vertices, faces, process=False).export(source)
        with silenced_stdout():  # V-HACD prints its progress from C
            client.vhacd(source, target, os.path.join(tmp, "log.txt"))
        with open(target) as obj:
            lines = obj.read().splitlines()
    parts: list[list[list[float]]] = []
    for line in lines:  # "o convex_k" starts part k; its "v x y z" lines follow
        if line.startswith("o "):
            parts.append([])
        elif line.startswith("v ") and parts:
            parts[-1].append([float(v) for v in line.split()[1:4]])
    return [convex_hull(np.array(part)) for part in parts if len(part) >= 4]


def _collision_shape(client: Client, parts: list[np.ndarray]) -> int:
    """One collision shape made of the convex hulls of `parts` (vertex arrays, local frame).

    pybullet takes a single convex hull from a vertex list; several parts go through
    an OBJ file of one object per part, which it loads as a compound of convex hulls.
    """
    if len(parts) == 1:
        return client.createCollisionShape(client.GEOM_MESH, vertices=parts[0].tolist())
    with tempfile.TemporaryDirectory(prefix="synthpack-parts-") as tmp:
        path = os.path.join(tmp, "parts.obj")
        with open(path, "w") as obj:
            first = 1  # OBJ numbers vertices from 1, across objects
            for k, part in enumerate(parts):
                hull = convex_hull(part)
                obj.write(f"o part_{k}\n")
                obj.writelines(f"v {x:.17g} {y:.17g} {z:.17g}\n" for x, y, z in hull.vertices)
                obj.writelines(f"f {a + first} {b + first} {c + first}\n" for a, b, c in hull.faces)
                first += len(hull.vertices)
        return client.createCollisionShape(client.GEOM_MESH, fileName=path)


def _create_dynamic(
    client: Client, shape: _Shape, mass: float, position: np.ndarray, quat_wxyz: np.ndarray,
    material: Material,
) -> int:
    body = client.createMultiBody(
        baseMass=mass,
        baseCollisionShapeIndex=shape.shape_id,
        basePosition=position.tolist(),
        baseOrientation=_xyzw(quat_wxyz),
        baseInertialFramePosition=shape.com.tolist(),
        baseInertialFrameOrientation=shape.inertial_quat.tolist(),
        useMaximalCoordinates=True,
    )
    # The mass must be repeated: for maximal-coordinate bodies pybullet otherwise
    # resets it to 0 when the inertia is changed (measured with pybullet 3.2.x).
    client.changeDynamics(body, -1, mass=mass, localInertiaDiagonal=shape.inertia_diagonal.tolist(),
                          ccdSweptSphereRadius=0.5 * shape.inradius)
    _apply_material(client, body, material, grain=True)
    return body


def _create_static(
    client: Client, shape: _Shape, position: np.ndarray, quat_wxyz: np.ndarray, material: Material
) -> int:
    body = client.createMultiBody(
        baseMass=0.0,
        baseCollisionShapeIndex=shape.shape_id,
        basePosition=position.tolist(),
        baseOrientation=_xyzw(quat_wxyz),
        useMaximalCoordinates=True,
    )
    _apply_material(client, body, material, grain=True)
    return body


def _retire_buried(
    client: Client, locked: dict[int, np.ndarray], radius: float, largest: float
) -> None:
    """Remove the locked grains :func:`~synthpack.physics.burial.buried` says no grain can reach.

    `locked` maps static body ids to their hulls' world vertices; the retired grains
    leave it and the world (their final poses are already recorded).
    """
    ids = list(locked)
    retired = [i for i, gone in zip(ids, buried([locked[i] for i in ids], radius, largest)) if gone]
    for body_id in retired:
        client.removeBody(body_id)
        del locked[body_id]
    if retired:
        logger.debug("Retired %d buried grains; %d locked grains remain", len(retired), len(locked))


def _run_batch(
    client: Client, body_ids: list[int], settle: SettleCriteria, fixed_steps: int | None
) -> tuple[int, bool]:
    """Step until the batch has settled (or for exactly `fixed_steps`); (steps, settled)."""
    if fixed_steps is not None:
        for _ in range(fixed_steps):
            client.stepSimulation()
        return fixed_steps, _is_quiet(client, body_ids, settle)
    quiet = 0
    for step in range(1, settle.max_steps + 1):
        client.stepSimulation()
        quiet = quiet + 1 if _is_quiet(client, body_ids, settle) else 0
        if step >= settle.min_steps and quiet >= settle.quiet_steps:
            return step, True
    return settle.max_steps, False


def _compact(
    client: Client, body_ids: list[int], plan: BatchCompaction, material: Material, settle: SettleCriteria
) -> tuple[int, bool]:
    """Settle a batch with compaction (:mod:`.compaction`); (steps, settled) as :func:`_run_batch`.

    The batch (created at ``plan.settle_friction``) falls until it moves slower than
    :data:`~synthpack.physics.compaction.FALL_QUIET` times the settle thresholds (at
    most :data:`~synthpack.physics.compaction.FALL_STEPS` steps); then it gets the
    material's friction back and settles by `settle`.
    """
    fall = replace(settle, max_steps=min(settle.max_steps, FALL_STEPS),
                   linear_speed=settle.linear_speed * FALL_QUIET, angular_speed=settle.angular_speed * FALL_QUIET)
    steps, _ = _run_batch(client, body_ids, fall, None)
    for body in body_ids:
        client.changeDynamics(body, -1, lateralFriction=material.friction)
    final, settled = _run_batch(client, body_ids, replace(settle, min_steps=0), None)
    return steps + final, settled


def _is_quiet(client: Client, body_ids: list[int], settle: SettleCriteria) -> bool:
    for body in body_ids:
        linear, angular = client.getBaseVelocity(body)
        if (linear[0] ** 2 + linear[1] ** 2 + linear[2] ** 2 > settle.linear_speed**2
                or angular[0] ** 2 + angular[1] ** 2 + angular[2] ** 2 > settle.angular_speed**2):
            return False
    return True


def _local_pose(client: Client, body_id: int, shape: _Shape) -> tuple[np.ndarray, np.ndarray]:
    """World pose of the local origin, from pybullet's inertial-frame pose."""
    com_world, inertial_xyzw = client.getBasePositionAndOrientation(body_id)
    local = Rotation.from_quat(inertial_xyzw) * Rotation.from_quat(shape.inertial_quat).inv()
    position = np.asarray(com_world) - local.apply(shape.com)
    quat = local.as_quat(scalar_first=True)
    return position, quat * (1.0 if quat[0] >= 0 else -1.0)


def _xyzw(quat_wxyz: np.ndarray) -> list[float]:
    w, x, y, z = (float(v) for v in quat_wxyz)
    return [x, y, z, w]
