"""Batched, locked rigid-body pouring with pybullet (the default engine).

Implements the engine interface of :mod:`synthpack.physics.engine`: a
:class:`~synthpack.physics.driver.World` whose hooks the one batch loop
(:func:`~synthpack.physics.driver.drive`) calls; all lengths are simulation units
(about one grain diameter).

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
* Mass and inertia: each body's frame is its grain's PRINCIPAL frame: origin at the
  mesh's centre of mass, axes the principal axes of the mesh's inertia tensor (uniform
  density, scaled to the body's mass; ``localInertiaDiagonal``), and the collision
  shape's vertices are given in it. With an inertial frame offset from the shape's
  (``baseInertialFramePosition/Orientation``, as before 0.12) pybullet wraps the hull
  in a compound shape at that offset (its URDF importer unwraps a single child only at
  the identity transform), and hull-hull contacts then go through the compound-compound
  algorithm: 17% of a pour's time in a py-spy profile, a quarter of the cost of a step
  on a bed of grains (docs/benchmarks.md). The local origin's pose is recovered as
  ``T_world_principal @ T_principal_local``.
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
  steps (at most ``max_steps``). With ``lock_quiet_grains`` (the default), once at
  most :data:`FREEZE_SHARE` of the batch still moves, each grain that has been below
  the settle speeds for ``quiet_steps`` steps is locked at once (made static, as
  below) while the last ones slide: Bullet keeps an island of touching grains awake
  while any of them moves, so a batch's last sliding grains otherwise keep all of its
  grains in the collision detection, for about half of its steps.
* Locking: a settled batch's bodies are removed and re-created as STATIC bodies
  (mass 0) at their final poses, with the same collision shapes. Static bodies are
  never integrated and static-static pairs are never collided, but every body in
  the world still costs a little per step, so the driver retires locked grains
  buried deeper than any later grain can reach (:mod:`synthpack.physics.burial`):
  they are removed from the world.
* Packing to a target (:mod:`synthpack.physics.compaction`, steered by the driver): a
  batch added at a lowered friction gets it while it falls (``changeDynamics``), and
  the material's back before it settles; a spaced batch collides as hulls inflated
  about the centre of mass (:func:`_shape_for`), with the true grain's mass and inertia,
  and a batch packed past full compaction as hulls shrunk about it (the engine
  :attr:`shrinks_shells`): their meshes reach further outside them, so the tube's
  colliders are moved further in (rebuilt) when a shrunk batch needs it.
"""

from __future__ import annotations

import logging
import os
import tempfile
from collections.abc import Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Sequence

import numpy as np
import trimesh
from scipy.spatial.transform import Rotation

from .._shared.schema import setting
from ..errors import SynthpackInputError
from .driver import LockedBatch, World
from .engine import Engine
from .hulls import convex_hull, protrusion, shrink_hull, simplify_hull
from .scene import Body, EngineConfig, Material, Scene, SettleCriteria, TubeSpec

if TYPE_CHECKING:
    from ._bullet import Client

logger = logging.getLogger(__name__)

__all__ = ["PybulletEngine", "PybulletConfig", "WALL_SEGMENTS", "SOLVER_ITERATIONS", "GRAVITY", "FREEZE_SHARE"]

#: Number of boxes in the wall ring.
WALL_SEGMENTS = 48
#: Constraint-solver iterations per step.
SOLVER_ITERATIONS = 20
#: Gravitational acceleration, simulation units / s^2 (along -z).
GRAVITY = 9.81
#: Quiet grains are made static early once at most this share of their batch still moves.
FREEZE_SHARE = 0.1
_MIN_COLLIDER_THICKNESS = 1.0  # sim units: walls and floor are at least this thick


@dataclass(frozen=True)
class PybulletConfig(EngineConfig):
    """Options of the pybullet engine (``engine_options`` of :func:`~synthpack.physics.pour`).

    Attributes
    ----------
    allow_sleeping : bool
        Let Bullet put grains that have been nearly still for 2 s to sleep (they wake
        when hit). False keeps every grain of the batch awake, as Blender's rigid
        bodies are by default (no deactivation).
    lock_quiet_grains : bool
        Make each grain static (as :meth:`_PybulletWorld.lock` does) once it has been
        below the settle speeds for ``quiet_steps`` consecutive steps, while the rest of
        its batch still moves. Bullet wakes a whole island of touching grains while one
        of them moves, so without it the batch's last sliding grains keep every grain
        of the batch in the collision detection.

    See :class:`~synthpack.physics.scene.EngineConfig` for ``max_hull_vertices``,
    ``fixed_steps`` and ``record_snapshots``.
    """

    allow_sleeping: bool = setting(
        True, None, "let grains that have been nearly still for 2 s sleep until something hits them"
    )
    lock_quiet_grains: bool = setting(
        True, None, "make each grain static once it has been quiet for quiet_steps steps, while the rest of its "
        "batch still moves"
    )


class PybulletEngine(Engine):
    """The default engine: headless, deterministic pybullet (see the module's notes)."""

    name = "pybullet"
    Options = PybulletConfig
    supports_compaction = True
    shrinks_shells = True

    def options(
        self, values: Mapping[str, Any] | None = None, prefix: str = "engine_options."
    ) -> EngineConfig:
        """As :meth:`Engine.options`; the former ``convex_decomposition`` option gets a pointer to its successor."""
        if isinstance(values, Mapping) and "convex_decomposition" in values:
            raise SynthpackInputError(
                f"'{prefix}convex_decomposition' is now the collision shape: set pour.collision_shape: "
                "decomposition in the config, --collision-shape decomposition on the command line, or "
                "Material(collision_shape='decomposition') in Python."
            )
        return super().options(values, prefix)

    def open(self, scene: Scene) -> World:
        """A fresh physics client holding the scene's tube (:class:`_PybulletWorld`)."""
        from ._bullet import Client

        return _PybulletWorld(Client(), scene)


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


class _PybulletWorld(World):
    """One pour on its own physics client: the hooks :func:`~synthpack.physics.driver.drive` calls.

    Every distinct grain's collision shape is made when the world is (the tube's inset
    needs the largest reach of all of them); a spaced batch's inflated shapes when it
    is added. A locked grain is a static body at the pose it settled at.
    """

    def __init__(self, client: Client, scene: Scene) -> None:
        self.client, self.scene = client, scene
        try:
            _configure(client, scene.settle)
            self._shapes: dict[bytes, _Shape] = {}
            self._parts: dict[bytes, list[trimesh.Trimesh]] = {}  # each grain's V-HACD parts, for every shell
            self._body_shapes = [self._shape(body, 0.0) for body in scene.bodies]
            self._inset = max(shape.protrusion for shape in self._shapes.values())
            logger.debug("Tube colliders inset by %.4f (the grains' largest reach outside their shapes)", self._inset)
            self._walls: list[int] = []  # the tube's collider bodies
            self._wall_top = _build_tube(client, scene.tube, scene.material, 0.0, scene.tube.height, self._inset,
                                         self._walls)
        except BaseException:
            client.close()
            raise
        self._batch: list[tuple[int, int, _Shape]] = []  # (body index, body id, shape) of the batch, in order
        self._frozen: dict[int, tuple[np.ndarray, np.ndarray]] = {}  # batch grains made static early: pose
        self._friction = scene.material.friction  # the batch's friction now
        self._static: dict[int, int] = {}  # body index -> its static body id, while it is in the world
        n = len(scene.bodies)
        self._positions, self._quaternions = np.zeros((n, 3)), np.zeros((n, 4))  # poses of the locked grains

    def _shape(self, body: Body, inflation: float) -> _Shape:
        return _shape_for(self.client, body, self._shapes, self.scene.material,
                          self.scene.options.max_hull_vertices, inflation, self._parts)

    def add_batch(self, members: np.ndarray, positions: np.ndarray, friction: float, inflation: np.ndarray) -> None:
        client, scene, bodies = self.client, self.scene, self.scene.bodies
        reach = max(pos[2] + float(np.linalg.norm(bodies[i].vertices, axis=1).max())
                    for i, pos in zip(members, positions))
        shapes = [self._body_shapes[i] if shell == 0 else self._shape(bodies[i], float(shell))
                  for i, shell in zip(members, np.asarray(inflation, dtype=float))]
        inset = max([self._inset] + [shape.protrusion for shape in shapes])
        if inset > self._inset:  # shrunk shells: their meshes reach further out; rebuild the tube further in
            for body_id in self._walls:
                client.removeBody(body_id)
            self._walls, self._inset = [], inset
            logger.debug("Tube colliders rebuilt, inset by %.4f (a batch of shrunk shells)", inset)
            self._wall_top = _build_tube(client, scene.tube, scene.material, 0.0, self._wall_top, inset, self._walls)
        if reach > self._wall_top:
            self._wall_top = _build_tube(client, scene.tube, scene.material, self._wall_top, reach + 1.0, self._inset,
                                         self._walls)
        for i, position, shape in zip(members, positions, shapes):
            orientation = np.asarray(bodies[i].orientation, dtype=float)
            body_id = _create_dynamic(client, shape, bodies[i].mass, position, orientation, scene.material)
            if friction != scene.material.friction:
                client.changeDynamics(body_id, -1, lateralFriction=friction)
            if not scene.options.allow_sleeping:
                client.changeDynamics(body_id, -1, activationState=client.ACTIVATION_STATE_DISABLE_SLEEPING)
            self._batch.append((int(i), body_id, shape))
        self._friction = friction

    def settle(self, criteria: SettleCriteria, fixed_steps: int | None) -> tuple[int, bool]:
        if fixed_steps is not None:
            return _run_fixed(self.client, [body_id for _, body_id, _ in self._batch], criteria, fixed_steps)
        return self._settle(criteria, self.scene.options.lock_quiet_grains)

    def _settle(self, criteria: SettleCriteria, lock_quiet: bool) -> tuple[int, bool]:
        """Step until the batch has settled by `criteria`; with `lock_quiet`, making quiet grains static as it goes.

        A grain below the scene's settle speeds (not `criteria`'s, which a compacted
        batch's fall loosens) for its ``quiet_steps`` consecutive steps, after
        `criteria`'s ``min_steps`` and once at most `FREEZE_SHARE` of the batch still
        moves, is made static where it is (:meth:`_freeze`).
        """
        client, strict = self.client, self.scene.settle
        loud_linear, loud_angular = criteria.linear_speed**2, criteria.angular_speed**2
        calm_linear, calm_angular = strict.linear_speed**2, strict.angular_speed**2
        calm = {i: 0 for i, _, _ in self._batch if i not in self._frozen}
        quiet, loud = 0, len(self._batch)
        for step in range(1, criteria.max_steps + 1):
            client.stepSimulation()
            freezing = lock_quiet and step >= criteria.min_steps and loud <= FREEZE_SHARE * len(self._batch)
            loud = 0
            for k, (i, body_id, _) in enumerate(self._batch):
                if i in self._frozen:
                    continue
                (vx, vy, vz), (wx, wy, wz) = client.getBaseVelocity(body_id)
                linear, angular = vx * vx + vy * vy + vz * vz, wx * wx + wy * wy + wz * wz
                if linear > loud_linear or angular > loud_angular:
                    loud += 1
                calm[i] = calm[i] + 1 if linear <= calm_linear and angular <= calm_angular else 0
                if freezing and calm[i] >= strict.quiet_steps:
                    self._freeze(k)
            quiet = quiet + 1 if loud == 0 else 0
            if step >= criteria.min_steps and (quiet >= criteria.quiet_steps or len(self._frozen) == len(self._batch)):
                return step, True
        return criteria.max_steps, False

    def _freeze(self, k: int) -> None:
        """Make the batch's `k`-th grain a static body at its pose, keeping the batch's friction."""
        index, body_id, shape = self._batch[k]
        position, quaternion = _local_pose(self.client, body_id, shape)
        self.client.removeBody(body_id)
        static = _create_static(self.client, shape, position, quaternion, self.scene.material)
        if self._friction != self.scene.material.friction:
            self.client.changeDynamics(static, -1, lateralFriction=self._friction)
        self._batch[k] = (index, static, shape)
        self._frozen[index] = (position, quaternion)

    def set_friction(self, friction: float) -> None:
        for _, body_id, _ in self._batch:
            self.client.changeDynamics(body_id, -1, lateralFriction=friction)
        self._friction = friction

    def lock(self) -> LockedBatch:
        """Each body of the batch removed and re-created as a STATIC body (mass 0), same shape, same pose."""
        client, material = self.client, self.scene.material
        hulls = []
        for i, body_id, shape in self._batch:
            if i in self._frozen:  # static already
                position, quaternion = self._frozen[i]
                self._static[i] = body_id
                if self._friction != material.friction:
                    client.changeDynamics(body_id, -1, lateralFriction=material.friction)
            else:
                position, quaternion = _local_pose(client, body_id, shape)
                client.removeBody(body_id)
                self._static[i] = _create_static(client, shape, position, quaternion, material)
            self._positions[i], self._quaternions[i] = position, quaternion
            hulls.append(Rotation.from_quat(quaternion, scalar_first=True).apply(shape.hull_vertices) + position)
        members = [i for i, _, _ in self._batch]
        logger.debug("Batch locked: %d of its %d grains were made static early, when quiet", len(self._frozen),
                     len(members))
        self._batch, self._frozen = [], {}
        self._friction = material.friction
        return LockedBatch(self._positions[members].copy(), self._quaternions[members].copy(), hulls)

    def retire(self, indices: Sequence[int]) -> None:
        for i in indices:
            self.client.removeBody(self._static.pop(i))

    def poses(self, indices: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The batch's poses from pybullet; a locked grain's the pose it was locked at (static bodies never move)."""
        positions, quaternions = self._positions[indices].copy(), self._quaternions[indices].copy()
        moving = {i: (body_id, shape) for i, body_id, shape in self._batch if i not in self._frozen}
        for k, i in enumerate(indices):
            if int(i) in self._frozen:
                positions[k], quaternions[k] = self._frozen[int(i)]
            elif int(i) in moving:
                positions[k], quaternions[k] = _local_pose(self.client, *moving[int(i)])
        return positions, quaternions

    def close(self) -> None:
        self.client.close()


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
    client: Client, tube: TubeSpec, material: Material, z0: float, z1: float, inset: float, bodies: list[int],
) -> float:
    """Add the wall between heights `z0` and `z1` (and the floor when ``z0 == 0``); `z1`.

    The colliders lie `inset` inside the tube: the floor's top face at ``z = inset``,
    the wall's inner faces a polygon inscribed in the circle of radius
    ``inner_radius - inset``. Their body ids are appended to `bodies`.
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
        bodies.append(body)
    if z0 == 0.0:
        base = max(tube.base_thickness, _MIN_COLLIDER_THICKNESS)
        extent = tube.inner_radius + thickness
        floor = client.createCollisionShape(
            client.GEOM_BOX, halfExtents=[extent, extent, base / 2]
        )
        body = client.createMultiBody(0.0, floor, -1, basePosition=[0.0, 0.0, inset - base / 2])
        _apply_material(client, body, material, grain=False)
        bodies.append(body)
    return z1


def _shape_for(
    client: Client, body: Body, cache: dict[bytes, _Shape], material: Material,
    max_vertices: int | None, inflation: float = 0.0, parts_cache: dict[bytes, list[trimesh.Trimesh]] | None = None,
) -> _Shape:
    """Collision shape and inertial frame of `body`, shared by identical geometries.

    With `inflation` > 0 the collider is the grain inflated by that fraction of its
    size about its centre of mass (a spacing shell, :mod:`.compaction`), with
    `inflation` < 0 shrunk by it (packing past full compaction); mass, inertia and the
    pose of the local origin stay those of the true grain. A decomposition is made once
    per grain geometry (in `parts_cache`, where given) and its parts scaled for each shell.
    """
    vertices = np.ascontiguousarray(body.vertices, dtype=np.float64)
    faces = np.ascontiguousarray(body.faces, dtype=np.int64)
    geometry = vertices.tobytes() + faces.tobytes()
    key = geometry + np.float64(body.mass).tobytes() + np.float64(inflation).tobytes()
    if key in cache:
        return cache[key]
    true_vertices = vertices
    centre = np.asarray(body.center_mass, dtype=np.float64)
    if inflation != 0:
        vertices = centre + (vertices - centre) * (1.0 + inflation)
    hull = convex_hull(vertices)
    if material.collision_shape == "decomposition":
        parts_cache = {} if parts_cache is None else parts_cache
        if geometry not in parts_cache:
            parts_cache[geometry] = _decomposed_parts(client, true_vertices, faces)
        parts = [convex_hull(centre + (part.vertices - centre) * (1.0 + inflation)) if inflation != 0 else part
                 for part in parts_cache[geometry]]
    else:
        parts = [simplify_hull(hull, max_vertices)]
    shrunk = [shrink_hull(part, material.collision_margin) for part in parts]
    mesh = trimesh.Trimesh(true_vertices, faces, process=False)
    inertia = np.asarray(mesh.moment_inertia) * (body.mass / mesh.volume)
    moments, axes = np.linalg.eigh(inertia)
    if np.linalg.det(axes) < 0:
        axes[:, 2] *= -1
    # The collider in the principal frame (origin at the centre of mass, axes the principal
    # axes): pybullet then keeps the bare hull, not a compound wrapping it at an offset.
    shape_id = _collision_shape(client, [(part - centre) @ axes for part in shrunk])
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
    centre, orientation = _principal_pose(shape, position, quat_wxyz)
    body = client.createMultiBody(
        baseMass=mass,
        baseCollisionShapeIndex=shape.shape_id,
        basePosition=centre,
        baseOrientation=orientation,
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
    centre, orientation = _principal_pose(shape, position, quat_wxyz)
    body = client.createMultiBody(
        baseMass=0.0,
        baseCollisionShapeIndex=shape.shape_id,
        basePosition=centre,
        baseOrientation=orientation,
        useMaximalCoordinates=True,
    )
    _apply_material(client, body, material, grain=True)
    return body


def _run_fixed(client: Client, body_ids: list[int], settle: SettleCriteria, steps: int) -> tuple[int, bool]:
    """Step exactly `steps` times (the paper's fixed-frame schedule); (steps, whether every body is quiet then)."""
    for _ in range(steps):
        client.stepSimulation()
    for body in body_ids:
        (vx, vy, vz), (wx, wy, wz) = client.getBaseVelocity(body)
        linear, angular = vx * vx + vy * vy + vz * vz, wx * wx + wy * wy + wz * wz
        if linear > settle.linear_speed**2 or angular > settle.angular_speed**2:
            return steps, False
    return steps, True


def _principal_pose(shape: _Shape, position: np.ndarray, quat_wxyz: np.ndarray) -> tuple[list[float], list[float]]:
    """pybullet's pose (centre of mass, x y z w) of a body whose local origin has the pose given."""
    local = Rotation.from_quat(quat_wxyz, scalar_first=True)
    centre = np.asarray(position, dtype=float) + local.apply(shape.com)
    return centre.tolist(), (local * Rotation.from_quat(shape.inertial_quat)).as_quat().tolist()


def _local_pose(client: Client, body_id: int, shape: _Shape) -> tuple[np.ndarray, np.ndarray]:
    """World pose of the local origin, from pybullet's inertial-frame pose."""
    com_world, inertial_xyzw = client.getBasePositionAndOrientation(body_id)
    local = Rotation.from_quat(inertial_xyzw) * Rotation.from_quat(shape.inertial_quat).inv()
    position = np.asarray(com_world) - local.apply(shape.com)
    quat = local.as_quat(scalar_first=True)
    return position, quat * (1.0 if quat[0] >= 0 else -1.0)
