"""Tests of the Blender engine: real pours in a Blender / bpy subprocess.

The pour tests need Blender: set SYNTHPACK_BLENDER to a Python interpreter that has
bpy (``bash .ci/make-blender-venv`` makes ``.venv-blender``) or to a ``blender``
executable; without one they are skipped. Run only them with ``pytest -m blender``.
"""

from __future__ import annotations

import ast
import importlib.util
import sys
import types
from dataclasses import replace

import numpy as np
import pytest
import trimesh

from synthpack import physics
from synthpack.errors import SynthpackInputError
from synthpack.physics import ENGINES, PourConfig, Tube, blender_engine
from synthpack.physics.compaction import TARGET_TOLERANCE
from synthpack.physics.hulls import MAX_HULL_VERTICES
from synthpack.physics.scene import Body, Scene, SettleCriteria, TubeSpec

TUBE = TubeSpec(inner_radius=2.0, height=12.0, wall_thickness=0.2, base_thickness=0.2)
MATERIAL = PourConfig().material()
SETTLE = SettleCriteria()
N_BATCHES, PER_BATCH = 3, 6
BLENDER = ENGINES["blender"]

requires_blender = pytest.mark.skipif(
    not BLENDER.available(),
    reason="no Blender found: set SYNTHPACK_BLENDER to a Python with bpy or to a blender "
    "executable (`bash .ci/make-blender-venv` makes .venv-blender)",
)


def scene(bodies: list[Body], tube: TubeSpec = TUBE, material=MATERIAL, settle: SettleCriteria = SETTLE,
          options: dict | None = None) -> Scene:
    """A Blender scene of `bodies`, with the Blender engine's `options` (its defaults when None)."""
    return Scene(bodies, tube, material, settle, BLENDER.options(options))


def rotation_matrix(q: np.ndarray) -> np.ndarray:
    """(3, 3) rotation of a unit quaternion (w, x, y, z)."""
    return trimesh.transformations.quaternion_matrix(q)[:3, :3]


def world_vertices(body: Body, position: np.ndarray, quaternion: np.ndarray) -> np.ndarray:
    """(V, 3) world coordinates of a body's vertices at a pose of its local origin."""
    return body.vertices @ rotation_matrix(quaternion).T + position


def placed_vertices(bodies: list[Body], result) -> list[np.ndarray]:
    """World vertices of every body at its final pose in an EngineResult."""
    poses = zip(bodies, result.positions, result.quaternions)
    return [world_vertices(b, p, q) for b, p, q in poses]


def random_grain(rng: np.random.Generator) -> trimesh.Trimesh:
    """A lumpy, flattened icosphere about 1 unit across, not centred on its origin."""
    sphere = trimesh.creation.icosphere(subdivisions=2, radius=0.5)
    bumps = 1 + 0.1 * rng.standard_normal(len(sphere.vertices))
    vertices = sphere.vertices * bumps[:, None] * [1.2, 1.0, 0.8] + rng.uniform(-0.1, 0.1, 3)
    return trimesh.Trimesh(vertices, sphere.faces)


def make_bodies(seed: int = 0) -> list[Body]:
    """N_BATCHES x PER_BATCH grains spawned in a column above the pack, random poses."""
    rng = np.random.default_rng(seed)
    bodies = []
    for batch in range(N_BATCHES):
        for k in range(PER_BATCH):
            mesh = random_grain(rng)
            angle, radius = rng.uniform(0, 2 * np.pi), rng.uniform(0, 0.8)
            q = rng.standard_normal(4)
            bodies.append(
                Body(
                    vertices=mesh.vertices,
                    faces=mesh.faces,
                    mass=mesh.volume * 2.65,
                    center_mass=mesh.center_mass,
                    orientation=q / np.linalg.norm(q),
                    spawn_offset=np.array(
                        [radius * np.cos(angle), radius * np.sin(angle), 0.8 + 1.1 * k]
                    ),
                    batch=batch,
                )
            )
    return bodies


def hull_penetration(a: np.ndarray, b: np.ndarray) -> float:
    """Depth (>= 0) by which points ``a`` (n, 3) reach into the convex hull of ``b`` (m, 3).

    The signed distance of a point to a convex polytope is the largest signed distance to
    its facet planes when the point is inside, so this is exact for inside points.
    """
    hull = trimesh.convex.convex_hull(b)
    normals = hull.face_normals
    offsets = np.einsum("ij,ij->i", normals, hull.triangles[:, 0])
    signed = (a @ normals.T - offsets).max(axis=1)
    return float(max(0.0, -signed.min()))


@pytest.fixture(scope="module")
def pour(tmp_path_factory: pytest.TempPathFactory):
    """One Blender pour of 18 grains in 3 batches (and the progress calls it made)."""
    bodies = make_bodies()
    calls: list[tuple[int, int]] = []
    blend = tmp_path_factory.mktemp("blend") / "pack.blend"
    result = BLENDER.simulate(scene(bodies, options={"record_snapshots": True, "blend_file": blend}),
                              progress=lambda i, n: calls.append((i, n)))
    return bodies, result, calls, blend


@pytest.mark.blender
@requires_blender
class TestPour:
    def test_every_batch_settles_and_reports_progress(self, pour):
        bodies, result, calls, _ = pour
        assert result.positions.shape == (len(bodies), 3)
        assert result.quaternions.shape == (len(bodies), 4)
        np.testing.assert_allclose(np.linalg.norm(result.quaternions, axis=1), 1.0, atol=1e-6)
        assert result.settled_per_batch == [True] * N_BATCHES
        assert all(SETTLE.min_steps <= s < SETTLE.max_steps for s in result.steps_per_batch)
        assert calls == [(k, N_BATCHES) for k in range(N_BATCHES)]

    def test_grains_rest_inside_the_tube_below_the_fill_height(self, pour):
        bodies, result, _, _ = pour
        tol = 0.02
        total_volume = sum(trimesh.Trimesh(b.vertices, b.faces).volume for b in bodies)
        # A pack at least 25 % dense is at most this high, plus one grain on top.
        fill_height = total_volume / (0.25 * np.pi * TUBE.inner_radius**2) + 1.5
        for world in placed_vertices(bodies, result):
            assert np.hypot(world[:, 0], world[:, 1]).max() < TUBE.inner_radius + tol
            assert world[:, 2].min() > -tol
            assert world[:, 2].max() < fill_height
        # The first batch lands on the floor: its lowest grain touches it (one collision
        # margin above it, less what the simplified hull leaves out).
        lowest = min(w[:, 2].min() for w in placed_vertices(bodies, result))
        assert lowest == pytest.approx(MATERIAL.collision_margin, abs=0.01)

    def test_no_grain_pushes_into_another(self, pour):
        bodies, result, _, _ = pour
        worlds = placed_vertices(bodies, result)
        centres = np.array([w.mean(axis=0) for w in worlds])
        radii = np.array([np.linalg.norm(w - c, axis=1).max() for w, c in zip(worlds, centres)])
        pairs = 0
        for i in range(len(worlds)):
            for j in range(len(worlds)):
                if i != j and np.linalg.norm(centres[i] - centres[j]) < radii[i] + radii[j]:
                    pairs += 1
                    assert hull_penetration(worlds[i], worlds[j]) < 0.05, (i, j)
        assert pairs > 0  # the grains do touch: the check looked at real contacts

    def test_locked_batches_never_move_again(self, pour):
        """The poses Blender reports for a batch once it has settled are its final poses."""
        bodies, result, _, _ = pour
        assert len(result.snapshots) == N_BATCHES
        for k, (positions, quaternions) in enumerate(result.snapshots):
            n = (k + 1) * PER_BATCH
            assert positions.shape == (n, 3) and quaternions.shape == (n, 4)
            np.testing.assert_allclose(positions, result.positions[:n], atol=1e-5)
            alignment = np.abs(np.einsum("ij,ij->i", quaternions, result.quaternions[:n]))
            np.testing.assert_allclose(alignment, 1.0, atol=1e-6)

    def test_saves_a_blend_file(self, pour):
        header = pour[3].read_bytes()[:7]
        assert header == b"BLENDER" or header[:4] == b"\x28\xb5\x2f\xfd"  # plain or zstd


@pytest.mark.blender
@requires_blender
def test_off_centre_centre_of_mass_rolls_to_the_bottom():
    """A ball weighted off its centre rolls until its centre of mass is below its centre.

    Checks both directions of the centre-of-mass conversion: Blender must rotate the
    grain about ``center_mass`` (else the ball would not roll) and the returned pose must
    be that of the particle-local origin (else the ball would not rest on the floor).
    """
    ball = trimesh.creation.icosphere(subdivisions=3, radius=0.5)
    offset = np.array([0.3, -0.2, 0.1])  # the local origin (crop centre) is off the centre
    vertices = ball.vertices + offset
    center_mass = offset + np.array([0.25, 0.0, 0.0])  # weighted towards +x
    upright, above_floor = np.array([1.0, 0, 0, 0]), np.array([0.0, 0.0, 1.0])
    body = Body(vertices, ball.faces, 1.0, center_mass, upright, above_floor, 0)
    damped = replace(MATERIAL, angular_damping=0.5)  # a weighted ball rocks long with little damping
    result = BLENDER.simulate(scene([body], material=damped, options={"max_hull_vertices": None}))
    assert result.settled_per_batch == [True]
    p, q = result.positions[0], result.quaternions[0]
    rotation = rotation_matrix(q)
    ball_centre = p + rotation @ offset
    com = p + rotation @ center_mass
    # The ball rests on the floor, one collision margin above it (the floor is a box,
    # whose margin lies inside it).
    margin = MATERIAL.collision_margin
    assert world_vertices(body, p, q)[:, 2].min() == pytest.approx(margin, abs=0.003)
    assert ball_centre[2] == pytest.approx(0.5 + margin, abs=0.003)
    down = (com - ball_centre) / 0.25
    assert down[2] < -0.95  # within ~18 degrees of straight down


def test_missing_blender_gives_setup_hint(monkeypatch, tmp_path):
    monkeypatch.setenv(blender_engine.BLENDER_ENV_VAR, str(tmp_path / "no" / "blender"))
    assert blender_engine.find_blender() is None
    assert not BLENDER.available()
    with pytest.raises(SynthpackInputError, match="make-blender-venv"):
        BLENDER.simulate(scene(make_bodies()[:1]))


def test_python_without_bpy_gives_setup_hint(monkeypatch):
    monkeypatch.setenv(blender_engine.BLENDER_ENV_VAR, sys.executable)
    assert blender_engine.find_blender() == [sys.executable]
    with pytest.raises(SynthpackInputError, match="cannot import bpy"):
        BLENDER.simulate(scene(make_bodies()[:1]))


@pytest.mark.blender
@requires_blender
def test_runs_a_blender_executable_with_fixed_steps(monkeypatch, tmp_path):
    """A path named 'blender' is run as `blender --background ... --python SCRIPT -- ARGS`.

    The stand-in executable hands Blender's whole command line to the bpy interpreter,
    as Blender does (the script reads its arguments after '--').
    """
    python = blender_engine.find_blender()[0]
    blender = tmp_path / "blender"
    blender.write_text(
        '#!/bin/sh\nwhile [ "$1" != "--python" ]; do shift; done\n'
        f'shift\nexec "{python}" "$1" --background "$@"\n'
    )
    blender.chmod(0o755)
    monkeypatch.setenv(blender_engine.BLENDER_ENV_VAR, str(blender))
    prefix = blender_engine.find_blender()
    assert prefix[0] == str(blender) and "--background" in prefix and prefix[-1] == "--python"
    bodies = make_bodies()[:2]
    low_tube = TubeSpec(TUBE.inner_radius, 1.0, TUBE.wall_thickness, TUBE.base_thickness)
    result = BLENDER.simulate(scene(bodies, low_tube, options={"fixed_steps": 90}))
    assert result.steps_per_batch == [90]
    spawn_heights = np.array([b.spawn_offset[2] for b in bodies])
    assert np.all(result.positions[:, 2] < spawn_heights)  # both grains fell ...
    worlds = placed_vertices(bodies, result)
    assert abs(min(w[:, 2].min() for w in worlds)) < 0.03  # ... onto the floor ...
    # ... inside the wall (rebuilt higher than the 1-unit tube for the upper grain).
    assert max(np.hypot(w[:, 0], w[:, 1]).max() for w in worlds) < low_tube.inner_radius + 0.02


def test_bad_input_is_rejected():
    with pytest.raises(SynthpackInputError, match="no bodies"):
        BLENDER.simulate(scene([]))
    with pytest.raises(SynthpackInputError, match="linear_damping"):
        BLENDER.simulate(scene(make_bodies()[:1], material=replace(MATERIAL, linear_damping=2.0)))
    with pytest.raises(SynthpackInputError, match="collision_margin must be within"):
        BLENDER.simulate(scene(make_bodies()[:1], material=replace(MATERIAL, collision_margin=2.0)))
    with pytest.raises(SynthpackInputError, match="Blender's last frame"):
        BLENDER.simulate(scene(make_bodies()[:1], settle=SettleCriteria(max_steps=2_000_000)))
    with pytest.raises(SynthpackInputError, match="'engine_options.fixed_steps' is out of range"):
        BLENDER.options({"fixed_steps": 2_000_000})
    with pytest.raises(SynthpackInputError, match="takes BlenderConfig options"):
        BLENDER.simulate(Scene(make_bodies()[:1], TUBE, MATERIAL, SETTLE, ENGINES["pybullet"].options()))


def test_blender_failure_shows_its_output(monkeypatch, tmp_path):
    """A script that fails mid-pour: the error holds its exit status and the end of its output."""
    failing = tmp_path / "failing_script.py"
    failing.write_text("import sys\nsys.stdin.readline()\n"  # the open call: answered, then the first batch fails
                       f"print({blender_engine.REPLY!r} + '{{\"blender_version\": \"0\"}}', flush=True)\n"
                       "print('opened')\nsys.stdin.readline()\nraise RuntimeError('boom')\n")
    monkeypatch.setattr(blender_engine, "SCRIPT", failing)
    monkeypatch.setenv(blender_engine.BLENDER_ENV_VAR, sys.executable)
    with pytest.raises(blender_engine.BlenderError, match="(?s)exit status 1.*opened.*RuntimeError: boom"):
        BLENDER.simulate(scene(make_bodies()[:1]))


def test_unwritable_blend_file_is_rejected_before_simulating(tmp_path):
    with pytest.raises(SynthpackInputError, match="missing-folder"):
        blend = tmp_path / "missing-folder" / "a.blend"
        BLENDER.simulate(scene(make_bodies()[:1], options={"blend_file": blend}))


def load_script(monkeypatch: pytest.MonkeyPatch) -> types.ModuleType:
    """blender_script.py as a module, outside Blender (with an empty stand-in for bpy)."""
    monkeypatch.setitem(sys.modules, "bpy", types.ModuleType("bpy"))  # the script needs it to load
    spec = importlib.util.spec_from_file_location("blender_script_under_test", blender_engine.SCRIPT)
    script = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(script)
    return script


def test_the_script_reads_the_saved_scene_without_importing_synthpack(monkeypatch, tmp_path):
    """Blender is fed the scene Scene.save writes, read back bit for bit with NumPy alone."""
    tree = ast.parse(blender_engine.SCRIPT.read_text())
    imported = [a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names]
    imported += [n.module for n in ast.walk(tree) if isinstance(n, ast.ImportFrom)]
    assert sorted({name.split(".")[0] for name in imported}) == ["bpy", "json", "math", "numpy", "os", "sys", "time"]
    script = load_script(monkeypatch)
    assert script.REPLY == blender_engine.REPLY and script.NO_BPY_EXIT_CODE == blender_engine.NO_BPY_EXIT_CODE
    bodies = make_bodies()
    saved = blender_engine._save_scene(tmp_path, scene(bodies, options={"fixed_steps": 7}))
    spec, read = script.read_scene(str(saved))
    assert spec["options"]["fixed_steps"] == 7 and spec["settle"]["max_steps"] == SETTLE.max_steps
    assert spec["material"]["friction"] == MATERIAL.friction and spec["tube"]["inner_radius"] == TUBE.inner_radius
    for body, got in zip(bodies, read, strict=True):
        for name in ("vertices", "faces", "center_mass", "orientation", "spawn_offset"):
            np.testing.assert_array_equal(got[name], getattr(body, name))
        assert got["mass"] == body.mass and got["batch"] == body.batch
    hulls = script.read_hulls(str(tmp_path / blender_engine.HULLS_FILE), len(bodies))
    for body, (vertices, faces) in zip(bodies, hulls):
        assert len(vertices) <= MAX_HULL_VERTICES and faces.max() == len(vertices) - 1
        assert trimesh.Trimesh(vertices, faces).is_convex


@pytest.mark.blender
@requires_blender
@pytest.mark.slow
@pytest.mark.parametrize("target", [0.57, 0.30])
def test_the_driver_packs_a_blender_pour_to_a_target(even_large_library, target):
    """Compaction attaches to the driver, so Blender gets it: denser by a friction schedule, looser by spacing.

    A free Blender pour of these 150 grains, drawn evenly, packs at 0.527 (measured). Equal shells (no target
    coordination): the large sample's own seven contacts per grain would leave most grains bare,
    which no spaced pour of 0.30 allows.
    """
    large_library = even_large_library
    assert PourConfig(engine="blender", target_solid_fraction=target).target_solid_fraction == target
    tube = Tube.for_library(large_library, 150, packing_fraction=0.3,
                            inner_radius=2.5 * float(np.median(large_library.equivalent_diameters)))
    config = PourConfig(n_particles=150, batch_size=30, engine="blender", target_solid_fraction=target,
                        target_coordination="none")
    packed = physics.pour(large_library, config, 1, container=tube, progress=False)
    checks = packed.checks
    assert checks.target_reached is True and abs(checks.packing_fraction - target) <= TARGET_TOLERANCE
    knobs = checks.compaction["knobs"]
    assert max(knobs) > 0 if target > 0.527 else max(knobs) < 0  # compacted, or spaced
    assert checks.n_outside == 0 and checks.max_grain_penetration_voxels < 0.5
