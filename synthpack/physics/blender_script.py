"""The Blender side of the Blender engine: the driver's hooks, served inside Blender's Python.

This file runs INSIDE a Blender Python interpreter (``bpy``), never inside synthpack:
it imports only the standard library, ``bpy`` and ``numpy`` (both ship with
Blender; NumPy 1.x there). :mod:`synthpack.physics.blender_engine` saves the pour's
scene (:meth:`synthpack.physics.scene.Scene.save`: ``scene.json`` and ``bodies.npz``)
and the grains' collision hulls (``hulls.npz``) into one folder and starts it, either as::

    PYTHON_WITH_BPY blender_script.py SCENE_JSON
    blender --background --factory-startup --python blender_script.py -- SCENE_JSON

The batch loop is not here: synthpack's driver (:func:`synthpack.physics.driver.drive`)
runs it, the same for every engine, and sends this script one call per hook on stdin,
one JSON object a line, ``{"call": NAME, "args": {...}}``; each reply is one line
``@synthpack-reply@ {JSON}`` on stdout (the rest of stdout is Blender's own log). The
calls, all lengths in simulation units, z up, gravity -z:

``open(hulls, solver_iterations)``
    An empty factory scene with a rigid-body world stepping ``time_step`` per frame
    (``substeps`` solver substeps), the tube, and the grains read from the scene; reply
    ``{"blender_version"}``.
``add_batch(members, positions, friction, inflation)``
    Each grain of ``members`` becomes an ACTIVE rigid body with a CONVEX_HULL collision
    shape built from its hull (inflated by its entry of ``inflation`` of its size about the
    centre of mass), shifted so that the object ORIGIN is the grain's centre of mass (Blender's
    rigid bodies rotate about the origin), its particle-local origin at ``positions``,
    turned by its orientation, at ``friction``. The wall is raised when the batch
    reaches above it, so no grain escapes over the rim while it falls.
``settle(criteria, fixed_steps)``
    The timeline restarts at frame 1 and frames are stepped one by one. A grain is quiet
    when the frame-to-frame motion of its centre of mass is below ``linear_speed`` and
    the rotation angle between frames below ``angular_speed`` (both per second); the
    batch has settled after ``quiet_steps`` consecutive frames in which all its grains
    are quiet, and at least ``min_steps`` frames; ``max_steps`` caps it (with
    ``fixed_steps``, exactly that many frames). Reply ``{"steps", "settled"}``.
``set_friction(friction)``
    The batch's grains get ``friction``, from where they are: the next ``settle`` starts
    them from their current poses (at rest: the timeline restarts).
``lock()``
    Each grain of the batch becomes a PASSIVE rigid body at its settled pose, with the
    same collision shape and the material's friction; Blender never moves a passive
    body. Reply ``{"positions", "quaternions", "hulls"}``: the poses of the particle-local
    origins (w, x, y, z) and the hull vertices in the world.
``retire(indices)``
    Deletes these locked grains (the driver judges which are buried): Blender's cost per
    frame grows with the number of objects.
``poses(indices)``
    The grains' poses read back from Blender (a locked grain that moved would show; a
    deleted one keeps its last pose): ``{"positions", "quaternions"}``.
``close()``
    Saves the final pack as a .blend file when the options name one, replies
    ``{"seconds"}`` and ends the script.

The tube is a PASSIVE box floor and a PASSIVE triangle-mesh wall. Masses are rescaled so
the lightest grain weighs 1 (only ratios matter, and Blender clamps masses below 0.001).

The paper locked batches with keyframes on one continuous timeline. That works in
Blender 5 too (keyframing ``rigid_body.kinematic`` False -> True at frames t, t+1 with
the location and rotation keyed to the settled pose; measured drift < 1e-6), but every
kinematic body is re-posed on every substep and the point cache stores every object
on every frame, so it was 3-4x slower at a few hundred grains and its memory and frame
numbers grow without bound. Restarting the timeline for each batch, with the locked
grains PASSIVE, gives the same physics (the locked grains are immovable obstacles, the
new batch starts at rest at its spawn poses), a short point cache and frame numbers far
below Blender's limit, so the number of batches is unlimited. Merging each locked batch
into one passive triangle-mesh object (fewer objects) was measured too: convex-versus-
triangle contacts made it 3x slower than passive convex hulls.
"""

import json
import math
import os
import sys
import time

NO_BPY_EXIT_CODE = 3
"""Exit status when ``bpy`` cannot be imported (the engine turns it into a setup hint)."""

REPLY = "@synthpack-reply@ "
"""What starts each reply line on stdout (the engine reads the JSON after it)."""

try:
    import bpy
except ImportError:
    sys.stderr.write("this Python interpreter has no 'bpy' module: %s\n" % sys.executable)
    sys.exit(NO_BPY_EXIT_CODE)

import numpy as np

TUBE_CHORD_TOLERANCE = 0.002
"""Largest gap (simulation units) between the tube's polygonal inner wall and the circle."""


def parse_args(argv):
    """Return the scene path from the command line.

    Parameters
    ----------
    argv : list of str
        ``sys.argv``; when Blender runs the script, the script's own arguments follow
        ``--``.
    """
    args = argv[argv.index("--") + 1 :] if "--" in argv else argv[1:]
    if len(args) != 1:
        raise SystemExit("usage: blender_script.py SCENE_JSON")
    return args[0]


def quaternion_to_matrix(q):
    """Rotation matrix (3, 3) float64 of a unit quaternion (w, x, y, z)."""
    w, x, y, z = np.asarray(q, dtype=np.float64) / np.linalg.norm(q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def matrix_to_quaternion(r):
    """Unit quaternion (w, x, y, z) float64, w >= 0, of a (3, 3) rotation matrix."""
    r = np.asarray(r, dtype=np.float64)
    trace = r[0, 0] + r[1, 1] + r[2, 2]
    if trace > 0:
        s = 2.0 * math.sqrt(trace + 1.0)
        q = [0.25 * s, (r[2, 1] - r[1, 2]) / s, (r[0, 2] - r[2, 0]) / s, (r[1, 0] - r[0, 1]) / s]
    elif r[0, 0] > r[1, 1] and r[0, 0] > r[2, 2]:
        s = 2.0 * math.sqrt(1.0 + r[0, 0] - r[1, 1] - r[2, 2])
        q = [(r[2, 1] - r[1, 2]) / s, 0.25 * s, (r[0, 1] + r[1, 0]) / s, (r[0, 2] + r[2, 0]) / s]
    elif r[1, 1] > r[2, 2]:
        s = 2.0 * math.sqrt(1.0 + r[1, 1] - r[0, 0] - r[2, 2])
        q = [(r[0, 2] - r[2, 0]) / s, (r[0, 1] + r[1, 0]) / s, 0.25 * s, (r[1, 2] + r[2, 1]) / s]
    else:
        s = 2.0 * math.sqrt(1.0 + r[2, 2] - r[0, 0] - r[1, 1])
        q = [(r[1, 0] - r[0, 1]) / s, (r[0, 2] + r[2, 0]) / s, (r[1, 2] + r[2, 1]) / s, 0.25 * s]
    q = np.array(q) / np.linalg.norm(q)
    return -q if q[0] < 0 else q


def rotation_angles(r_new, r_old):
    """Angles (n,) in radians of the rotations taking each ``r_old`` to ``r_new``.

    Uses atan2(sin, cos) of the relative rotation, which stays accurate for the tiny
    angles of a grain at rest (an arccos of the quaternion's w would not).
    """
    rel = np.einsum("nij,nkj->nik", r_new, r_old)
    vee = np.stack(
        [rel[:, 2, 1] - rel[:, 1, 2], rel[:, 0, 2] - rel[:, 2, 0], rel[:, 1, 0] - rel[:, 0, 1]],
        axis=1,
    )
    trace = rel[:, 0, 0] + rel[:, 1, 1] + rel[:, 2, 2]
    return np.arctan2(0.5 * np.linalg.norm(vee, axis=1), 0.5 * (trace - 1.0))


def new_mesh(name, vertices, faces):
    """A Blender mesh datablock from (V, 3) vertices and (F, 3) triangle indices."""
    mesh = bpy.data.meshes.new(name)
    mesh.vertices.add(len(vertices))
    mesh.vertices.foreach_set("co", np.asarray(vertices, dtype=np.float32).ravel())
    mesh.loops.add(3 * len(faces))
    mesh.loops.foreach_set("vertex_index", np.asarray(faces, dtype=np.int32).ravel())
    mesh.polygons.add(len(faces))
    mesh.polygons.foreach_set("loop_start", np.arange(0, 3 * len(faces), 3, dtype=np.int32))
    mesh.update()
    return mesh


def new_object(name, mesh):
    """Link a new object holding ``mesh`` into the scene and return it."""
    obj = bpy.data.objects.new(name, mesh)
    bpy.context.scene.collection.objects.link(obj)
    return obj


def add_rigid_bodies(objects, body_type, shape, material):
    """Make ``objects`` rigid bodies of ``body_type`` ('ACTIVE'/'PASSIVE') and ``shape``."""
    with bpy.context.temp_override(
        object=objects[0],
        active_object=objects[0],
        selected_objects=objects,
        selected_editable_objects=objects,
    ):
        bpy.ops.rigidbody.objects_add(type=body_type)
    for obj in objects:
        body = obj.rigid_body
        if body is None:
            raise RuntimeError("Blender did not make %s a rigid body" % obj.name)
        body.collision_shape = shape
        body.mesh_source = "BASE"
        body.use_margin = True
        body.collision_margin = material["collision_margin"]
        body.friction = material["friction"]
        body.restitution = material["restitution"]
        body.linear_damping = material["linear_damping"]
        body.angular_damping = material["angular_damping"]
        body.use_deactivation = False


def setup_world(settle, solver_iterations, frames):
    """Empty factory scene with a rigid-body world stepping ``time_step`` per frame."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    scene.use_gravity = True
    scene.gravity = (0.0, 0.0, -9.81)
    # Blender steps 1 / (fps / fps_base) * time_scale seconds per frame.
    fps = min(max(int(round(1.0 / settle["time_step"])), 1), 32767)
    scene.render.fps = fps
    scene.render.fps_base = fps * settle["time_step"]
    bpy.ops.rigidbody.world_add()
    world = scene.rigidbody_world
    world.time_scale = 1.0
    world.substeps_per_frame = settle["substeps"]
    world.solver_iterations = solver_iterations
    world.use_split_impulse = True
    # The point cache (and with it the simulation) stops at frame_end: 250 by default.
    world.point_cache.frame_start = 1
    world.point_cache.frame_end = frames
    scene.frame_start = 1
    scene.frame_end = frames
    return scene


def wall_mesh(tube, wall_top, bottom):
    """Vertices and faces of the tube's wall, a closed ring solid with outward normals.

    The inner face is a polygon inscribed in the circle of ``inner_radius`` (so grains
    stay inside the circle) with enough sides to lie within ``TUBE_CHORD_TOLERANCE`` of
    it; the wall reaches from ``bottom`` (inside the floor) up to ``wall_top``.
    """
    r_in = tube["inner_radius"]
    r_out = r_in + tube["wall_thickness"]
    step = math.acos(max(1.0 - TUBE_CHORD_TOLERANCE / r_in, -1.0))
    n = int(min(max(math.ceil(math.pi / step), 32), 4096))
    angles = 2 * math.pi * np.arange(n) / n
    ring = np.stack([np.cos(angles), np.sin(angles)], axis=1)
    rings = [(r_in, bottom), (r_in, wall_top), (r_out, wall_top), (r_out, bottom)]
    vertices = np.concatenate([np.column_stack([r * ring, np.full(n, z)]) for r, z in rings])
    i = np.arange(n)
    j = (i + 1) % n
    faces = []
    for k in range(4):  # inner face (up), rim (out), outer face (down), base (in)
        a, b = k * n + i, k * n + j
        c, d = (k + 1) % 4 * n + j, (k + 1) % 4 * n + i
        faces += [np.stack([a, d, c], 1), np.stack([a, c, b], 1)]
    return vertices, np.concatenate(faces)


def build_floor(tube, material):
    """Add the tube's floor: a PASSIVE BOX rigid body whose top face is z = 0.

    A box rather than a triangle fan: grains on a fan touch many thin triangles, each a
    separate contact test (measured: the first batch ran twice as slow). It is at least
    one unit thick so a fast grain cannot tunnel through it.
    """
    half = tube["inner_radius"] + tube["wall_thickness"]
    depth = max(tube["base_thickness"], 1.0)
    corners = np.array([[x, y, z] for x in (-half, half) for y in (-half, half) for z in (-1, 1)])
    corners = corners * [1.0, 1.0, depth / 2]
    faces = [(0, 1, 3), (0, 3, 2), (4, 6, 7), (4, 7, 5), (0, 4, 5), (0, 5, 1),
             (2, 3, 7), (2, 7, 6), (0, 2, 6), (0, 6, 4), (1, 5, 7), (1, 7, 3)]
    obj = new_object("tube_floor", new_mesh("tube_floor", corners, np.array(faces)))
    obj.location = (0.0, 0.0, -depth / 2)  # a BOX shape is centred on the object origin
    add_rigid_bodies([obj], "PASSIVE", "BOX", material)
    return obj


def build_wall(tube, material, wall_top, old=None):
    """Add the tube's wall, up to ``wall_top``, as a PASSIVE rigid body with a MESH shape.

    ``old``, the wall object built before (or None), is removed first.
    """
    if old is not None:
        mesh = old.data
        bpy.data.objects.remove(old, do_unlink=True)
        bpy.data.meshes.remove(mesh)
    vertices, faces = wall_mesh(tube, wall_top, -max(tube["base_thickness"], 1.0))
    obj = new_object("tube_wall", new_mesh("tube_wall", vertices, faces))
    add_rigid_bodies([obj], "PASSIVE", "MESH", material)
    return obj


def read_scene(scene_path):
    """The scene's description (``scene.json``) and its bodies' arrays, one dict per body.

    Reads what :meth:`synthpack.physics.scene.Scene.save` writes: each body's
    ``vertices``, ``faces``, ``mass``, ``center_mass``, ``orientation``, ``spawn_offset``
    and ``batch``, float64 / int64 as saved.
    """
    with open(scene_path) as handle:
        scene = json.load(handle)
    folder = os.path.dirname(os.path.abspath(scene_path))
    with np.load(os.path.join(folder, scene["bodies"])) as data:
        arrays = {name: data[name] for name in data.files}
    v, f = arrays["vertex_offsets"], arrays["face_offsets"]
    bodies = []
    for k in range(scene["n_bodies"]):
        body = {name: arrays[name][k] for name in ("mass", "center_mass", "orientation", "spawn_offset", "batch")}
        body["vertices"] = arrays["vertices"][v[k]:v[k + 1]]
        body["faces"] = arrays["faces"][f[k]:f[k + 1]]
        bodies.append(body)
    return scene, bodies


def read_hulls(path, n):
    """The (vertices (H, 3), faces (G, 3)) of each of the ``n`` grains' collision hulls, local frame."""
    with np.load(path) as data:
        vertices, faces = data["vertices"], data["faces"]
        v, f = data["vertex_offsets"], data["face_offsets"]
    return [(vertices[v[k]:v[k + 1]], faces[f[k]:f[k + 1]]) for k in range(n)]


class Grain:
    """One body of the scene: its hull in the centre-of-mass frame and its pose."""

    def __init__(self, index, body, hull, mass_scale):
        self.index = index
        self.mass = body["mass"] * mass_scale
        self.center_mass = np.asarray(body["center_mass"], dtype=np.float64)
        self.hull = np.asarray(hull[0], dtype=np.float64) - self.center_mass
        self.hull_faces = np.asarray(hull[1], dtype=np.int64)
        self.vertices = np.asarray(body["vertices"], dtype=np.float64)
        self.faces = np.asarray(body["faces"], dtype=np.int64)
        self.rotation = quaternion_to_matrix(body["orientation"])
        self.com_position = None  # world position of the centre of mass
        self.obj = None

    def spawn(self, origin, inflation):
        """Create the grain's object with its particle-local origin at ``origin`` (3,).

        With ``inflation`` > 0 its collision hull is inflated by that fraction about the
        centre of mass (the object's origin).
        """
        if inflation > 0:
            self.hull = self.hull * (1.0 + inflation)
        self.com_position = np.asarray(origin, dtype=np.float64) + self.rotation @ self.center_mass
        mesh = new_mesh("grain", self.hull, self.hull_faces)
        self.obj = new_object("grain_%06d" % self.index, mesh)
        self.obj.rotation_mode = "QUATERNION"
        self.obj.rotation_quaternion = matrix_to_quaternion(self.rotation)
        self.obj.location = self.com_position

    def world_hull(self):
        """(H, 3) world coordinates of the hull vertices at the current pose."""
        return self.hull @ self.rotation.T + self.com_position

    def origin_position(self):
        """World position (3,) of the particle-local origin: com - R @ center_mass."""
        return self.com_position - self.rotation @ self.center_mass

    def place(self):
        """Set the object's location and rotation (which the simulation does not write back) to the current pose.

        The world rebuilt at the next first frame starts the grain there.
        """
        self.obj.location = self.com_position
        self.obj.rotation_quaternion = matrix_to_quaternion(self.rotation)


def read_poses(grains):
    """Rotations (n, 3, 3) and centre-of-mass positions (n, 3) from Blender, float64."""
    matrices = np.array([np.array(g.obj.matrix_world) for g in grains], dtype=np.float64)
    return matrices[:, :3, :3], matrices[:, :3, 3]


def update_from_blender(grains):
    """Re-read the poses of the grains still in the scene from Blender.

    Locked grains are PASSIVE, so this returns the poses they were locked at unless
    something moved them: it is what makes the reported poses a check of the locking.
    """
    present = [g for g in grains if g.obj is not None]
    if present:
        rotations, positions = read_poses(present)
        for grain, rotation, position in zip(present, rotations, positions):
            grain.rotation = rotation
            grain.com_position = position


def pose_lists(grains):
    """JSON-able positions of the local origins and quaternions (w, x, y, z) of ``grains``."""
    positions = [g.origin_position().tolist() for g in grains]
    quaternions = [matrix_to_quaternion(g.rotation).tolist() for g in grains]
    return positions, quaternions


def settle_batch(scene, grains, settle, fixed_steps):
    """Step frames 2, 3, ... until the batch is at rest; return (frames, settled).

    With ``fixed_steps`` (an int), run exactly that many frames instead; the batch
    then counts as settled when all its grains are quiet on the last frame.
    """
    dt = settle["time_step"]
    limit = settle["max_steps"] if fixed_steps is None else fixed_steps
    scene.frame_set(1)
    rotations, positions = read_poses(grains)
    quiet = 0
    for step in range(1, limit + 1):
        scene.frame_set(step + 1)
        new_rotations, new_positions = read_poses(grains)
        speed = np.linalg.norm(new_positions - positions, axis=1) / dt
        spin = rotation_angles(new_rotations, rotations) / dt
        rotations, positions = new_rotations, new_positions
        still = np.all(speed < settle["linear_speed"]) and np.all(spin < settle["angular_speed"])
        quiet = quiet + 1 if still else 0
        if fixed_steps is None and step >= settle["min_steps"] and quiet >= settle["quiet_steps"]:
            break
    for grain, rotation, position in zip(grains, rotations, positions):
        grain.rotation = rotation
        grain.com_position = position
    if fixed_steps is not None:
        return step, quiet > 0
    return step, quiet >= settle["quiet_steps"] and step >= settle["min_steps"]


def remove_object(obj):
    """Delete ``obj`` and its mesh from Blender."""
    mesh = obj.data
    bpy.data.objects.remove(obj, do_unlink=True)
    bpy.data.meshes.remove(mesh)


def save_blend(path, grains, tube_objects):
    """Save the final pack (tube and full grain meshes, no physics) as a .blend file."""
    for obj in [o for o in bpy.data.objects if o not in tube_objects]:
        bpy.data.objects.remove(obj, do_unlink=True)
    bpy.ops.rigidbody.world_remove()
    collection = bpy.data.collections.new("grains")
    bpy.context.scene.collection.children.link(collection)
    for grain in grains:
        obj = bpy.data.objects.new(
            "grain_%06d" % grain.index, new_mesh("grain", grain.vertices, grain.faces)
        )
        collection.objects.link(obj)
        obj.rotation_mode = "QUATERNION"
        obj.rotation_quaternion = matrix_to_quaternion(grain.rotation)
        obj.location = grain.origin_position()
    bpy.ops.wm.save_as_mainfile(filepath=os.path.abspath(path), check_existing=False)


class World:
    """The pour in Blender: one method per call of the driver (see the module docstring)."""

    def __init__(self, scene_path):
        self.start = time.perf_counter()
        self.spec, bodies = read_scene(scene_path)
        self.folder = os.path.dirname(os.path.abspath(scene_path))
        self.bodies = bodies
        self.grains, self.batch, self.friction = [], [], None
        self.scene = self.floor = self.wall = self.wall_top = None

    def open(self, hulls, solver_iterations):
        spec = self.spec
        settle, material, fixed_steps = spec["settle"], spec["material"], spec["options"]["fixed_steps"]
        masses = np.array([b["mass"] for b in self.bodies], dtype=np.float64)
        mass_scale = 1.0 / masses.min()  # only mass ratios matter; Blender's minimum mass is 0.001
        shapes = read_hulls(os.path.join(self.folder, hulls), len(self.bodies))
        self.grains = [Grain(i, b, h, mass_scale) for i, (b, h) in enumerate(zip(self.bodies, shapes))]
        self.scene = setup_world(settle, solver_iterations, (fixed_steps or settle["max_steps"]) + 1)
        self.wall_top = spec["tube"]["height"]
        self.floor = build_floor(spec["tube"], material)
        self.wall = build_wall(spec["tube"], material, self.wall_top)
        return {"blender_version": bpy.app.version_string}

    def add_batch(self, members, positions, friction, inflation):
        tube, material = self.spec["tube"], self.spec["material"]
        self.batch = [self.grains[i] for i in members]
        for grain, origin, shell in zip(self.batch, positions, inflation):
            grain.spawn(origin, shell)
        reach = max(float(g.world_hull()[:, 2].max()) for g in self.batch)
        if reach > self.wall_top:  # raise the wall so no grain escapes over the rim
            self.wall_top = reach + 1.0
            self.wall = build_wall(tube, material, self.wall_top, old=self.wall)
        add_rigid_bodies([g.obj for g in self.batch], "ACTIVE", "CONVEX_HULL", dict(material, friction=friction))
        for grain in self.batch:
            grain.obj.rigid_body.mass = grain.mass
        self.friction = friction
        return {}

    def settle(self, criteria, fixed_steps):
        steps, settled = settle_batch(self.scene, self.batch, criteria, fixed_steps)
        return {"steps": steps, "settled": bool(settled)}

    def set_friction(self, friction):
        for grain in self.batch:
            grain.place()
            grain.obj.rigid_body.friction = friction
        self.friction = friction
        return {}

    def lock(self):
        """PASSIVE rigid bodies at the settled poses, same hull shape: Blender never moves them again."""
        material_friction = self.spec["material"]["friction"]
        for grain in self.batch:
            grain.place()
            grain.obj.rigid_body.type = "PASSIVE"
            if self.friction != material_friction:
                grain.obj.rigid_body.friction = material_friction
        positions, quaternions = pose_lists(self.batch)
        hulls = [g.world_hull().tolist() for g in self.batch]
        self.batch = []
        return {"positions": positions, "quaternions": quaternions, "hulls": hulls}

    def retire(self, indices):
        for i in indices:
            remove_object(self.grains[i].obj)
            self.grains[i].obj = None
        return {}

    def poses(self, indices):
        grains = [self.grains[i] for i in indices]
        update_from_blender(grains)
        positions, quaternions = pose_lists(grains)
        return {"positions": positions, "quaternions": quaternions}

    def close(self):
        blend = self.spec["options"].get("blend_file")
        if blend:
            save_blend(blend, self.grains, [self.floor, self.wall])
        return {"seconds": time.perf_counter() - self.start}


def reply(value):
    """Write one reply line (after a newline, so it starts a line whatever Blender printed)."""
    sys.stdout.write("\n" + REPLY + json.dumps(value) + "\n")
    sys.stdout.flush()


def serve(scene_path):
    """Answer the driver's calls from stdin until ``close`` (or the end of the input)."""
    world = World(scene_path)
    calls = {name: getattr(world, name) for name in
             ("open", "add_batch", "settle", "set_friction", "lock", "retire", "poses", "close")}
    for line in sys.stdin:
        request = json.loads(line)
        reply(calls[request["call"]](**request["args"]))
        if request["call"] == "close":
            break


if __name__ == "__main__":
    serve(parse_args(sys.argv))
