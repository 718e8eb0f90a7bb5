"""Batched pouring of grains into a tube with Blender's rigid-body simulator.

This file runs INSIDE a Blender Python interpreter (``bpy``), never inside synthpack:
it imports only the standard library, ``bpy`` and ``numpy`` (both ship with
Blender), and loads synthpack's NumPy-only ``burial.py`` from this folder by file path
(no synthpack package is imported). :mod:`synthpack.physics.blender_engine` writes its
input and starts it in a subprocess, either as::

    PYTHON_WITH_BPY blender_script.py SCENE_JSON RESULT_JSON
    blender --background --factory-startup --python blender_script.py -- SCENE_JSON RESULT_JSON

Input (``SCENE_JSON``, all lengths in simulation units, z up, gravity -z)::

    {"tube": {"inner_radius", "height", "wall_thickness", "base_thickness"},
     "material": {"friction", "restitution", "linear_damping", "angular_damping",
                  "collision_margin"},
     "settle": {"time_step", "substeps", "linear_speed", "angular_speed",
                "quiet_steps", "max_steps", "min_steps"},
     "solver_iterations": int,
     "fixed_steps": null, or run every batch for exactly this many frames,
     "record_snapshots": bool, also report the poses of all grains placed so far,
                         read back from Blender, after each batch,
     "blend_file": null or path of a .blend to save the final pack into,
     "bodies": [{"mesh": npz file (relative to the scene file) holding "vertices"
                 (V, 3) and "faces" (F, 3) of the grain and "hull_vertices" (H, 3) and
                 "hull_faces" (G, 3) of its convex hull, particle-local frame;
                 "mass", "center_mass" [3], "orientation" [w, x, y, z],
                 "spawn_offset" [x, y, dz], "batch"}, ...]}

Method, batch by batch (batches in increasing order, as in the paper's section 3.3):

1. Each grain becomes an ACTIVE rigid body with a CONVEX_HULL collision shape built
   from its hull vertices, shifted so that the object ORIGIN is the grain's centre of
   mass (Blender's rigid bodies rotate about the origin). It spawns with the given
   orientation, its particle-local origin at ``(x, y, top + dz)``, where ``top`` is the
   highest world z of all grains already placed (0 for the first batch).
2. The timeline restarts at frame 1 and frames are stepped one by one (each frame is
   ``time_step`` seconds, split into ``substeps`` solver substeps). A grain is quiet
   when the frame-to-frame motion of its centre of mass is below ``linear_speed`` and
   the rotation angle between frames below ``angular_speed`` (both per second); the
   batch has settled after ``quiet_steps`` consecutive frames in which all its grains
   are quiet, and at least ``min_steps`` frames; ``max_steps`` caps the batch. (With
   ``fixed_steps``, every batch runs exactly that many frames: the paper's schedule.)
3. The batch is LOCKED: each grain becomes a PASSIVE rigid body at its settled pose,
   with the same convex-hull collision shape; Blender never moves a passive body.
   Locked grains buried too deep for any later grain to reach are then deleted (see
   :func:`retire_buried`, the rule of ``burial.py`` that the pybullet engine uses too):
   Blender's cost per frame grows with the number of objects.

The tube is a PASSIVE box floor and a PASSIVE triangle-mesh wall; the wall is raised
above ``height`` when a batch spawns higher, so no grain escapes over the rim while it
falls. Masses are rescaled so the lightest grain weighs 1 (only ratios matter, and
Blender clamps masses below 0.001).

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

Output (``RESULT_JSON``): per body the final world position of its particle-LOCAL
origin and its quaternion (w, x, y, z), local -> world (read back from Blender at the
end for every grain still in the scene, so a locked grain that moved would show);
optional per-batch snapshots of the same; frames and settled flag per batch; the
Blender version; the run time in seconds. Each batch prints one line
``BATCH k/n frames=F settled=0|1 seconds=S locked_in_scene=L`` to stdout.
"""

import importlib.util
import json
import math
import os
import sys
import time

NO_BPY_EXIT_CODE = 3
"""Exit status when ``bpy`` cannot be imported (the engine turns it into a setup hint)."""

try:
    import bpy
except ImportError:
    sys.stderr.write("this Python interpreter has no 'bpy' module: %s\n" % sys.executable)
    sys.exit(NO_BPY_EXIT_CODE)

import numpy as np


def load_burial():
    """synthpack's ``burial.py`` (next to this file), loaded by path without the synthpack package."""
    path = os.path.join(os.path.dirname(os.path.abspath(__file__)), "burial.py")
    spec = importlib.util.spec_from_file_location("synthpack_burial", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


burial = load_burial()

TUBE_CHORD_TOLERANCE = 0.002
"""Largest gap (simulation units) between the tube's polygonal inner wall and the circle."""


def parse_args(argv):
    """Return (scene_path, result_path) from the command line.

    Parameters
    ----------
    argv : list of str
        ``sys.argv``; when Blender runs the script, the script's own arguments follow
        ``--``.
    """
    args = argv[argv.index("--") + 1 :] if "--" in argv else argv[1:]
    if len(args) != 2:
        raise SystemExit("usage: blender_script.py SCENE_JSON RESULT_JSON")
    return args[0], args[1]


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


class Grain:
    """One body of the scene: its hull in the centre-of-mass frame and its pose."""

    def __init__(self, index, spec, scene_dir, mass_scale):
        data = np.load(os.path.join(scene_dir, spec["mesh"]))
        self.index = index
        self.spec = spec
        self.mass = spec["mass"] * mass_scale
        self.center_mass = np.asarray(spec["center_mass"], dtype=np.float64)
        self.hull = np.asarray(data["hull_vertices"], dtype=np.float64) - self.center_mass
        self.hull_faces = np.asarray(data["hull_faces"], dtype=np.int64)
        self.vertices = np.asarray(data["vertices"], dtype=np.float64)
        self.faces = np.asarray(data["faces"], dtype=np.int64)
        self.rotation = quaternion_to_matrix(spec["orientation"])
        self.com_position = None  # world position of the centre of mass
        self.obj = None

    def spawn(self, top):
        """Create the ACTIVE grain object at its spawn pose above ``top``."""
        x, y, dz = self.spec["spawn_offset"]
        origin = np.array([x, y, top + dz])
        self.com_position = origin + self.rotation @ self.center_mass
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


def lock_batch(grains):
    """Lock settled grains: PASSIVE rigid bodies at their settled poses, same hull shape.

    Blender never moves a passive body, so the grains' poses are final from here on.
    The object's location and rotation (which the simulation does not write back) are
    set to the settled pose, which the world rebuilt at the next batch's first frame
    uses.
    """
    for grain in grains:
        grain.obj.location = grain.com_position
        grain.obj.rotation_quaternion = matrix_to_quaternion(grain.rotation)
        grain.obj.rigid_body.type = "PASSIVE"


def retire_buried(locked, radius, largest):
    """Delete the locked grains that ``burial.buried`` says no later grain can reach.

    Their final poses are already recorded. This keeps the number of objects, and with
    it Blender's cost per frame, bounded as the pack grows (the pybullet engine uses
    the same rule).

    Parameters
    ----------
    locked : list of Grain
        Locked grains still in the scene; the retired ones are removed from it.
    radius : float
        Inner radius of the tube.
    largest : float
        Largest grain diameter.
    """
    gone = burial.buried([g.world_hull() for g in locked], radius, largest)
    for grain in (g for g, out in zip(locked, gone) if out):
        mesh = grain.obj.data
        bpy.data.objects.remove(grain.obj, do_unlink=True)
        bpy.data.meshes.remove(mesh)
        grain.obj = None
    locked[:] = [g for g, out in zip(locked, gone) if not out]


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


def run(scene_path, result_path):
    """Simulate the scene described in ``scene_path`` and write ``result_path``."""
    start = time.perf_counter()
    with open(scene_path) as handle:
        spec = json.load(handle)
    settle, material = spec["settle"], spec["material"]
    scene_dir = os.path.dirname(os.path.abspath(scene_path))
    masses = np.array([b["mass"] for b in spec["bodies"]], dtype=np.float64)
    mass_scale = 1.0 / masses.min()  # only mass ratios matter; Blender's minimum mass is 0.001
    grains = [Grain(i, b, scene_dir, mass_scale) for i, b in enumerate(spec["bodies"])]
    batch_ids = sorted({g.spec["batch"] for g in grains})
    fixed_steps = spec["fixed_steps"]
    scene = setup_world(settle, spec["solver_iterations"], (fixed_steps or settle["max_steps"]) + 1)
    wall_top = spec["tube"]["height"]
    floor = build_floor(spec["tube"], material)
    wall = build_wall(spec["tube"], material, wall_top)

    largest = burial.largest_diameter(g.vertices for g in grains)
    top = 0.0
    frames, settled, locked, placed, snapshots = [], [], [], [], []
    for k, batch_id in enumerate(batch_ids):
        batch = [g for g in grains if g.spec["batch"] == batch_id]
        for grain in batch:
            grain.spawn(top)
        reach = max(float(g.world_hull()[:, 2].max()) for g in batch)
        if reach > wall_top:  # raise the wall so no grain escapes over the rim
            wall_top = reach + 1.0
            wall = build_wall(spec["tube"], material, wall_top, old=wall)
        add_rigid_bodies([g.obj for g in batch], "ACTIVE", "CONVEX_HULL", material)
        for grain in batch:
            grain.obj.rigid_body.mass = grain.mass
        batch_start = time.perf_counter()
        n_frames, ok = settle_batch(scene, batch, settle, fixed_steps)
        frames.append(n_frames)
        settled.append(bool(ok))
        placed.extend(batch)
        if spec["record_snapshots"]:
            update_from_blender(placed)
            snapshots.append(pose_lists(sorted(placed, key=lambda g: g.index)))
        lock_batch(batch)
        top = max(top, max(float(g.world_hull()[:, 2].max()) for g in batch))
        locked.extend(batch)
        retire_buried(locked, spec["tube"]["inner_radius"], largest)
        print(
            "BATCH %d/%d frames=%d settled=%d seconds=%.2f locked_in_scene=%d"
            % (k + 1, len(batch_ids), n_frames, ok, time.perf_counter() - batch_start, len(locked)),
            flush=True,
        )

    update_from_blender(grains)
    positions, quaternions = pose_lists(grains)
    if spec["blend_file"]:
        save_blend(spec["blend_file"], grains, [floor, wall])
    result = {
        "blender_version": bpy.app.version_string,
        "positions": positions,
        "quaternions": quaternions,
        "snapshots": snapshots if spec["record_snapshots"] else None,
        "frames_per_batch": frames,
        "settled_per_batch": settled,
        "seconds": time.perf_counter() - start,
    }
    with open(result_path, "w") as handle:
        json.dump(result, handle)


if __name__ == "__main__":
    run(*parse_args(sys.argv))
