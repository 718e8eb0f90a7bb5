"""Issue 28 probe: one 200-grain batch settling on a bed, NVIDIA Newton (Warp's CPU device) against pybullet.

Not part of the library and not imported by it. Newton lives in a virtual environment of
its own (the project's does not have it), so each engine runs in its own interpreter::

    python3 -m venv /tmp/newton-venv
    /tmp/newton-venv/bin/pip install newton scipy          # newton 1.8.0, warp-lang 1.19.0
    OMP_NUM_THREADS=2 .venv/bin/python bench/probe_newton.py --engine pybullet
    OMP_NUM_THREADS=2 /tmp/newton-venv/bin/python bench/probe_newton.py --engine newton --cold
    OMP_NUM_THREADS=2 /tmp/newton-venv/bin/python bench/probe_newton.py --engine newton --substeps 4

Newton runs ``SolverXPBD`` with 2 substeps of 4 iterations by default: with one substep per
1/240 s step it lets the falling grains into the bed and diverges (measured); the figures
are in docs/benchmarks.md ("Newton (Warp, CPU), probed").

The scene, the same for both (lengths in cm, mass in g, time in s; gravity 981 cm/s^2):

* 20 distinct grains, convex hulls of 40 random points on an ellipsoid of radii
  (1.0, 0.8, 0.6) cm, each radius and point jittered (seed 28), recentred on their
  centroid; density 2.65 g/cm^3; friction 0.6, restitution 0.1.
* A static ground plane at z = 0 inside a tube of radius 10 cm made of 48 static boxes
  (inner faces a regular polygon, 60 cm tall).
* A bed of 400 STATIC grains laid upright on a staggered grid of 1.8 x 1.45 x 1.0 cm cells
  from the floor up (four full layers and a partial fifth; neighbours overlap, so the bed has
  no holes to fall through, but a ring of about 1 cm is left between the bed and the wall).
* 200 dynamic grains (the 20 shapes in turn) on a jittered 2.6 cm grid above the bed,
  random orientations, at rest.
* Steps of 1/240 s until every dynamic grain is slower than 1e-3 cm/s for 30 consecutive
  steps, or 4,000 steps. The project's own criterion (0.05 units/s and 0.5 rad/s, with
  units ~ a grain diameter, here read as cm/s) is recorded on the way.

Reported (one JSON line, the last; Warp logs its kernel loads before it): setup time, the first 10 steps (Warp compiles its kernels there;
in Newton's case the kernel compilation is also reported on its own from a cold cache),
mean ms per step after them, steps and wall time to settle, and sanity checks: fraction
of grains inside the tube, largest contact penetration at the end, final mean height.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time

import numpy as np

N_GRAINS = 200
N_BED = 400
N_SHAPES = 20
RADII = np.array([1.0, 0.8, 0.6])  # cm
DENSITY = 2.65  # g/cm^3
FRICTION = 0.6
RESTITUTION = 0.1
GRAVITY = 981.0  # cm/s^2
DT = 1.0 / 240.0
TUBE_RADIUS = 10.0  # cm
TUBE_HEIGHT = 60.0
WALL_SEGMENTS = 48
WALL_THICKNESS = 2.0
WARMUP_STEPS = 10
SEED = 28


# --------------------------------------------------------------------------- the scene


def grain_shapes(rng: np.random.Generator) -> list[tuple[np.ndarray, np.ndarray]]:
    """20 rock-like convex hulls (vertices centred on the solid's centroid, outward faces)."""
    from scipy.spatial import ConvexHull

    shapes = []
    for _ in range(N_SHAPES):
        radii = RADII * rng.uniform(0.85, 1.15, 3)
        d = rng.normal(size=(40, 3))
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        points = d * radii * rng.uniform(0.85, 1.0, (40, 1))
        hull = ConvexHull(points)
        vertices = points[hull.vertices]
        hull = ConvexHull(vertices)
        faces = hull.simplices.copy()
        # orient faces outwards
        centre = vertices.mean(axis=0)
        for f in faces:
            a, b, c = vertices[f]
            if np.dot(np.cross(b - a, c - a), a - centre) < 0:
                f[[1, 2]] = f[[2, 1]]
        # centroid of the solid (tetrahedra from the mean point)
        a, b, c = (vertices[faces[:, i]] for i in range(3))
        vol = np.einsum("ij,ij->i", a - centre, np.cross(b - centre, c - centre)) / 6.0
        com = ((a + b + c + centre) / 4.0 * vol[:, None]).sum(axis=0) / vol.sum()
        shapes.append((vertices - com, faces.astype(np.int32)))
    return shapes


def random_quats(rng: np.random.Generator, n: int) -> np.ndarray:
    """Uniform random unit quaternions, (x, y, z, w)."""
    q = rng.normal(size=(n, 4))
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def bed_poses(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """400 static grains, upright, on a staggered grid tight enough that they overlap (no holes)."""
    dx, dy, dz = 1.8, 1.45, 1.0  # < the grains' diameters (~1.9-2.3, 1.5-1.8, 1.1-1.4)
    r_max = TUBE_RADIUS - 1.2
    positions = []
    layer = 0
    while len(positions) < N_BED:
        off = 0.5 * (layer % 2)
        z = 0.7 + layer * dz
        for i in range(-10, 11):
            for j in range(-12, 13):
                x, y = (i + off) * dx, (j + off) * dy
                if x * x + y * y <= r_max * r_max and len(positions) < N_BED:
                    positions.append((x, y, z))
        layer += 1
    quats = np.tile([0.0, 0.0, 0.0, 1.0], (N_BED, 1))
    return np.array(positions), quats


def drop_poses(rng: np.random.Generator, bed_top: float) -> tuple[np.ndarray, np.ndarray]:
    """200 grains on a jittered 2.6 cm grid above the bed."""
    s = 2.6
    r_max = TUBE_RADIUS - 1.5
    cells = [(i * s, j * s) for i in range(-4, 5) for j in range(-4, 5) if (i * s) ** 2 + (j * s) ** 2 <= r_max**2]
    positions = []
    layer = 0
    while len(positions) < N_GRAINS:
        for x, y in cells:
            if len(positions) < N_GRAINS:
                positions.append((x, y, bed_top + 1.5 + layer * s))
        layer += 1
    positions = np.array(positions) + rng.uniform(-0.25, 0.25, (N_GRAINS, 3))
    return positions, random_quats(rng, N_GRAINS)


def wall_boxes() -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """(centre, half extents, quaternion xyzw) of the 48 wall boxes."""
    apothem = TUBE_RADIUS * np.cos(np.pi / WALL_SEGMENTS)
    half_width = apothem * np.tan(np.pi / WALL_SEGMENTS) * 1.02
    boxes = []
    for k in range(WALL_SEGMENTS):
        angle = 2 * np.pi * k / WALL_SEGMENTS
        r = apothem + WALL_THICKNESS / 2
        centre = np.array([r * np.cos(angle), r * np.sin(angle), TUBE_HEIGHT / 2])
        half = np.array([WALL_THICKNESS / 2, half_width, TUBE_HEIGHT / 2])
        quat = np.array([0.0, 0.0, np.sin(angle / 2), np.cos(angle / 2)])
        boxes.append((centre, half, quat))
    return boxes


def build_scene() -> dict:
    rng = np.random.default_rng(SEED)
    shapes = grain_shapes(rng)
    bed_p, bed_q = bed_poses(rng)
    drop_p, drop_q = drop_poses(rng, bed_p[:, 2].max() + 0.6)
    return dict(shapes=shapes, bed_p=bed_p, bed_q=bed_q, drop_p=drop_p, drop_q=drop_q, walls=wall_boxes())


def grain_volume(vertices: np.ndarray, faces: np.ndarray) -> float:
    a, b, c = (vertices[faces[:, i]] for i in range(3))
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)


# --------------------------------------------------------------------------- the run


class Settle:
    """Settle detection: strict (1e-3, issue 28) and the project's (0.05 / 0.5 rad/s)."""

    def __init__(self) -> None:
        self.quiet = 0
        self.quiet_project = 0
        self.project_step: int | None = None

    def update(self, step: int, lin: np.ndarray, ang: np.ndarray) -> bool:
        v = np.linalg.norm(lin, axis=1)
        w = np.linalg.norm(ang, axis=1)
        self.quiet = self.quiet + 1 if v.max() < 1e-3 else 0
        self.quiet_project = self.quiet_project + 1 if (v.max() < 0.05 and w.max() < 0.5) else 0
        if self.project_step is None and step >= 60 and self.quiet_project >= 30:
            self.project_step = step
        return self.quiet >= 30


def run(engine, max_steps: int) -> dict:
    """Step `engine` (an object with step(), velocities(), positions(), penetration())."""
    settle = Settle()
    step_times = []
    t0 = time.perf_counter()
    steps, settled = max_steps, False
    for step in range(1, max_steps + 1):
        ts = time.perf_counter()
        engine.step()
        step_times.append(time.perf_counter() - ts)
        lin, ang = engine.velocities()
        if settle.update(step, lin, ang):
            steps, settled = step, True
            break
    wall = time.perf_counter() - t0
    p = engine.positions()
    r = np.hypot(p[:, 0], p[:, 1])
    inside = (r < TUBE_RADIUS) & (p[:, 2] > 0) & (p[:, 2] < TUBE_HEIGHT)
    lin, _ = engine.velocities()
    st = np.array(step_times)
    return dict(
        warmup_s=float(st[:WARMUP_STEPS].sum()),
        first_step_s=float(st[0]),
        ms_per_step=float(st[WARMUP_STEPS:].mean() * 1e3) if len(st) > WARMUP_STEPS else None,
        ms_per_step_median=float(np.median(st[WARMUP_STEPS:]) * 1e3) if len(st) > WARMUP_STEPS else None,
        steps=steps,
        settled=settled,
        steps_project_criterion=settle.project_step,
        wall_s=wall,
        inside_fraction=float(inside.mean()),
        max_radius_cm=float(r.max()),
        mean_height_cm=float(p[:, 2].mean()),
        min_height_cm=float(p[:, 2].min()),
        max_speed_end_cm_s=float(np.linalg.norm(lin, axis=1).max()),
        max_penetration_cm=engine.penetration(),
    )


# --------------------------------------------------------------------------- pybullet


class Bullet:
    def __init__(self, scene: dict) -> None:
        import pybullet as pb

        self.pb = pb
        self.c = pb.connect(pb.DIRECT)
        kw = dict(physicsClientId=self.c)
        pb.setGravity(0, 0, -GRAVITY, **kw)
        # as synthpack's engine: 20 solver iterations, deterministic pairs, sleeping allowed
        pb.setPhysicsEngineParameter(fixedTimeStep=DT, numSubSteps=0, numSolverIterations=20,
                                     deterministicOverlappingPairs=1, **kw)
        plane = pb.createCollisionShape(pb.GEOM_PLANE, **kw)
        ground = pb.createMultiBody(0, plane, **kw)
        pb.changeDynamics(ground, -1, lateralFriction=FRICTION, restitution=RESTITUTION, **kw)
        for centre, half, quat in scene["walls"]:
            box = pb.createCollisionShape(pb.GEOM_BOX, halfExtents=half.tolist(), **kw)
            b = pb.createMultiBody(0, box, basePosition=centre.tolist(), baseOrientation=quat.tolist(), **kw)
            pb.changeDynamics(b, -1, lateralFriction=FRICTION, restitution=RESTITUTION, **kw)
        shapes = [pb.createCollisionShape(pb.GEOM_MESH, vertices=v.tolist(), **kw) for v, _ in scene["shapes"]]
        masses = [DENSITY * grain_volume(v, f) for v, f in scene["shapes"]]
        inertias = [_inertia(v, f) for v, f in scene["shapes"]]
        for k, (p, q) in enumerate(zip(scene["bed_p"], scene["bed_q"])):
            b = pb.createMultiBody(0, shapes[k % N_SHAPES], basePosition=p.tolist(), baseOrientation=q.tolist(),
                                   useMaximalCoordinates=True, **kw)
            pb.changeDynamics(b, -1, lateralFriction=FRICTION, restitution=RESTITUTION, **kw)
        self.bodies = []
        for k, (p, q) in enumerate(zip(scene["drop_p"], scene["drop_q"])):
            s = k % N_SHAPES
            b = pb.createMultiBody(masses[s], shapes[s], basePosition=p.tolist(), baseOrientation=q.tolist(),
                                   useMaximalCoordinates=True, **kw)
            # mass passed again: pybullet 3.2.x zeroes it when the inertia is changed (as synthpack's engine)
            pb.changeDynamics(b, -1, mass=masses[s], localInertiaDiagonal=inertias[s].tolist(), ccdSweptSphereRadius=0.25,
                              lateralFriction=FRICTION, restitution=RESTITUTION, collisionMargin=0.01, **kw)
            self.bodies.append(b)

    def step(self) -> None:
        self.pb.stepSimulation(physicsClientId=self.c)

    def velocities(self) -> tuple[np.ndarray, np.ndarray]:
        v = [self.pb.getBaseVelocity(b, physicsClientId=self.c) for b in self.bodies]
        return np.array([a for a, _ in v]), np.array([w for _, w in v])

    def positions(self) -> np.ndarray:
        return np.array([self.pb.getBasePositionAndOrientation(b, physicsClientId=self.c)[0] for b in self.bodies])

    def penetration(self) -> float:
        d = [c[8] for c in self.pb.getContactPoints(physicsClientId=self.c)]
        return float(max(0.0, -min(d))) if d else 0.0


def _inertia(v: np.ndarray, f: np.ndarray) -> np.ndarray:
    """Diagonal of the solid hull's inertia tensor about its centroid (uniform density), g cm^2."""
    import trimesh

    return np.diag(trimesh.Trimesh(v, f, process=False).moment_inertia) * DENSITY


# --------------------------------------------------------------------------- Newton


class NewtonEngine:
    def __init__(self, scene: dict, solver: str, substeps: int, iterations: int, gap: float = 0.5) -> None:
        import warp as wp

        import newton

        self.wp, self.newton = wp, newton
        self.substeps = substeps
        wp.set_device("cpu")
        builder = newton.ModelBuilder(up_axis=newton.Axis.Z, gravity=(0.0, 0.0, -GRAVITY))
        cfg = newton.ModelBuilder.ShapeConfig(mu=FRICTION, restitution=RESTITUTION, density=DENSITY)
        cfg.gap = gap  # cm: contacts detected this far ahead (a grain falls ~0.5 cm per step)
        builder.default_shape_cfg = cfg
        builder.add_ground_plane(cfg=cfg)
        for centre, half, quat in scene["walls"]:
            builder.add_shape_box(-1, xform=wp.transform(wp.vec3(*centre), wp.quat(*quat)),
                                  hx=half[0], hy=half[1], hz=half[2], cfg=cfg)
        meshes = [newton.Mesh(v.astype(np.float32), f.flatten()) for v, f in scene["shapes"]]
        for k, (p, q) in enumerate(zip(scene["bed_p"], scene["bed_q"])):
            builder.add_shape_convex_hull(-1, xform=wp.transform(wp.vec3(*p), wp.quat(*q)),
                                          mesh=meshes[k % N_SHAPES], cfg=cfg)
        self.first_body = builder.body_count
        for k, (p, q) in enumerate(zip(scene["drop_p"], scene["drop_q"])):
            b = builder.add_body(xform=wp.transform(wp.vec3(*p), wp.quat(*q)))
            builder.add_shape_convex_hull(b, mesh=meshes[k % N_SHAPES], cfg=cfg)
        if solver == "vbd":
            builder.color()
        self.model = builder.finalize(device="cpu")
        if solver == "xpbd":
            self.solver = newton.solvers.SolverXPBD(self.model, iterations=iterations, enable_restitution=True)
        elif solver == "steel":
            self.solver = newton.solvers.SolverSteel(self.model, iterations=iterations)
        elif solver == "semi":
            self.solver = newton.solvers.SolverSemiImplicit(self.model)
        else:
            raise SystemExit(f"unknown solver {solver}")
        self.state_0, self.state_1 = self.model.state(), self.model.state()
        self.control = self.model.control()
        self.pipeline = newton.CollisionPipeline(self.model, broad_phase="sap")
        self.contacts = self.pipeline.contacts()
        self.n = N_GRAINS

    def step(self) -> None:
        dt = DT / self.substeps
        for _ in range(self.substeps):
            self.state_0.clear_forces()
            self.pipeline.collide(self.state_0, self.contacts)
            self.solver.step(self.state_0, self.state_1, self.control, self.contacts, dt)
            self.state_0, self.state_1 = self.state_1, self.state_0
        self.wp.synchronize()

    def velocities(self) -> tuple[np.ndarray, np.ndarray]:
        qd = self.state_0.body_qd.numpy()[self.first_body:]
        return qd[:, :3], qd[:, 3:]

    def positions(self) -> np.ndarray:
        return self.state_0.body_q.numpy()[self.first_body:, :3]

    def penetration(self) -> float:
        """Largest overlap among the final contacts: -(n . (X1 p1 - X0 p0) - margin0 - margin1)."""
        self.pipeline.collide(self.state_0, self.contacts)
        c = self.contacts
        n = int(c.rigid_contact_count.numpy()[0])
        if n == 0:
            return 0.0
        body_q = self.state_0.body_q.numpy()
        shape_body = self.model.shape_body.numpy()

        def world(points: np.ndarray, shapes: np.ndarray) -> np.ndarray:
            out = points.copy()
            bodies = shape_body[shapes]
            for i, b in enumerate(bodies):
                if b >= 0:
                    p, q = body_q[b, :3], body_q[b, 3:]
                    out[i] = p + _rotate(q, points[i])
            return out

        s0 = c.rigid_contact_shape0.numpy()[:n]
        s1 = c.rigid_contact_shape1.numpy()[:n]
        p0 = world(c.rigid_contact_point0.numpy()[:n], s0)
        p1 = world(c.rigid_contact_point1.numpy()[:n], s1)
        normal = c.rigid_contact_normal.numpy()[:n]
        m = c.rigid_contact_margin0.numpy()[:n] + c.rigid_contact_margin1.numpy()[:n]
        d = np.einsum("ij,ij->i", normal, p1 - p0) - m
        return float(max(0.0, -d.min()))


def _rotate(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    x, y, z, w = q
    u = np.array([x, y, z])
    return v + 2.0 * np.cross(u, np.cross(u, v) + w * v)


# --------------------------------------------------------------------------- main


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--engine", choices=["newton", "pybullet"], required=True)
    ap.add_argument("--solver", default="xpbd", help="Newton solver: xpbd (default; the only one measured), steel, semi")
    ap.add_argument("--substeps", type=int, default=2, help="Newton substeps per 1/240 s step")
    ap.add_argument("--iterations", type=int, default=4, help="Newton solver iterations per substep")
    ap.add_argument("--gap", type=float, default=0.5, help="Newton contact gap (speculative distance), cm")
    ap.add_argument("--max-steps", type=int, default=4000)
    ap.add_argument("--cold", action="store_true", help="Newton: clear Warp's kernel cache first (times compilation)")
    args = ap.parse_args()

    scene = build_scene()
    info: dict = dict(engine=args.engine, python=platform.python_version(), load_avg_start=os.getloadavg())
    t0 = time.perf_counter()
    if args.engine == "pybullet":
        import importlib.metadata as md

        info["pybullet"] = md.version("pybullet")
        engine = Bullet(scene)
    else:
        import importlib.metadata as md

        info.update(newton=md.version("newton"), warp_lang=md.version("warp-lang"), solver=args.solver,
                    substeps=args.substeps, iterations=args.iterations, gap_cm=args.gap)
        import warp as wp

        wp.config.quiet = True
        wp.init()
        if args.cold:
            wp.clear_kernel_cache()  # Warp compiles every kernel again (setup and the first steps)
        info["cold_kernel_cache"] = args.cold
        engine = NewtonEngine(scene, args.solver, args.substeps, args.iterations, args.gap)
    info["setup_s"] = time.perf_counter() - t0
    info.update(run(engine, args.max_steps))
    info["load_avg_end"] = os.getloadavg()
    print(json.dumps(info))
    sys.stdout.flush()


if __name__ == "__main__":
    main()
