"""Pouring: plan, engine (pybullet, real simulation), locking, checks, placements I/O."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
import trimesh
from scipy.spatial.transform import Rotation

from synthpack.pipeline import generate
from synthpack.pipeline.config import PackConfig
from synthpack.errors import SynthpackInputError
from synthpack.physics import ENGINES, LockedGrains, Placements, PourConfig, SettleCriteria, Tube, get_engine, pour
from synthpack.physics import blender_engine, burial, driver, hulls, pybullet_engine
from synthpack.physics import checks as pour_checks
from synthpack.physics.checks import compute_checks, winding_number
from synthpack.physics.container import MAX_FILL_ASPECT
from synthpack.physics.engine import Engine
from synthpack.physics.scene import Body, EngineConfig, Scene, TubeSpec
from synthpack.physics.plan import make_plan

TOLERANCE_VOXELS = 0.5  # largest penetration into the tube wall or floor accepted
# Largest grain-grain overlap of the convex hulls accepted. Since the collision shapes are shrunk by the
# margin (so that grains that touch in the simulation touch in the voxels), resting contacts show the
# solver's slop as hull overlap: 0.44-0.54 voxel measured over seeds 4-5 on the narrow pours below,
# against 0.25 with the 2-margin gap before; the hulls are larger than the concave grains.
GRAIN_OVERLAP_VOXELS = 0.6


@pytest.fixture(scope="module")
def narrow_tube(large_library) -> Tube:
    """A tube about 3.6 median grain diameters wide, so 45 grains make a deep pack."""
    d = float(np.median(large_library.equivalent_diameters))
    return Tube(inner_radius=1.8 * d, height=12 * d, wall_thickness=30.0, base_thickness=30.0)


@pytest.fixture(scope="module")
def poured_locked(large_library, narrow_tube) -> tuple[Placements, list[LockedGrains]]:
    """45 real grains in 3 batches, with per-batch snapshots, poured freely: the contacts are the engine's own
    (packed to the source's 0.62, this narrow pour falls short and shrinks the shells: tests/test_compaction.py);
    and the batches the pour handed over as it locked them."""
    config = PourConfig(n_particles=45, batch_size=15, target_solid_fraction=None,
                        engine_options={"record_snapshots": True})
    locked: list[LockedGrains] = []
    return pour(large_library, config, 3, container=narrow_tube, progress=False, on_lock=locked.append), locked


@pytest.fixture(scope="module")
def poured(poured_locked) -> Placements:
    return poured_locked[0]


def test_each_batch_is_handed_over_as_it_is_locked_with_the_placements_final_poses(poured_locked):
    placements, locked = poured_locked
    assert [batch.batch for batch in locked] == [0, 1, 2]
    np.testing.assert_array_equal(np.concatenate([batch.members for batch in locked]), np.arange(45))
    for name in ("indices", "positions", "quaternions", "scales"):
        np.testing.assert_array_equal(np.concatenate([getattr(batch, name) for batch in locked]),
                                      getattr(placements, name), err_msg=name)


def _world_vertices(library, placements: Placements) -> list[np.ndarray]:
    rotations = placements.rotation_matrices()
    return [
        (library[i].mesh.vertices * s) @ r.T + t
        for i, s, r, t in zip(
            placements.indices, placements.scales, rotations, placements.positions
        )
    ]


def test_every_grain_rests_inside_the_tube_below_the_fill_height(large_library, poured):
    tube, voxel = poured.tube, min(large_library.voxel_size)
    checks = poured.checks
    assert len(poured) == 45 and poured.batches.tolist() == [0] * 15 + [1] * 15 + [2] * 15
    assert all(checks.settled_per_batch) and len(checks.steps_per_batch) == 3
    assert max(checks.steps_per_batch) < 4000  # settled, not capped
    world = _world_vertices(large_library, poured)
    radial = max(np.hypot(w[:, 0], w[:, 1]).max() for w in world)
    lowest = min(w[:, 2].min() for w in world)
    top = max(w[:, 2].max() for w in world)
    assert radial <= tube.inner_radius + TOLERANCE_VOXELS * voxel
    assert lowest >= -TOLERANCE_VOXELS * voxel
    assert top == pytest.approx(checks.fill_height) and top < tube.height
    assert checks.n_outside == 0 and checks.n_above_rim == 0
    # the grains fell: the pack is far below the spawn heights, about 5-7.5 diameters deep (seeds 3-5)
    d = np.median(large_library.equivalent_diameters)
    assert 3 * d < top < 8 * d


def test_no_two_grains_interpenetrate(poured):
    checks = poured.checks
    assert checks.max_grain_penetration_voxels < GRAIN_OVERLAP_VOXELS
    assert checks.max_wall_penetration_voxels < TOLERANCE_VOXELS
    assert checks.overlap_fraction < 0.01
    # a plausible random loose-to-dense packing of angular grains (45 grains in a narrow tube:
    # it varies by about +-0.04 between seeds, measured 0.44-0.55)
    assert 0.42 < checks.packing_fraction < 0.68


def test_locked_batches_never_move_again(poured):
    snapshots = poured.snapshots
    assert [len(pos) for pos, _ in snapshots] == [15, 30, 45]
    for pos, quat in snapshots[:-1]:
        n = len(pos)
        np.testing.assert_array_equal(poured.positions[:n], pos)
        np.testing.assert_array_equal(poured.quaternions[:n], quat)
    # ... while the grains of the next batch did move after they spawned
    first, _ = snapshots[0]
    assert not np.allclose(snapshots[1][0][15:], first[:15])


def test_quiet_grains_locked_before_their_batch_settles_pack_as_when_the_batch_is_locked_whole(
        large_library, narrow_tube, caplog):
    def run(lock):
        config = PourConfig(n_particles=45, batch_size=15, target_solid_fraction=None,
                            engine_options={"lock_quiet_grains": lock})
        return pour(large_library, config, 4, container=narrow_tube, progress=False).checks

    with caplog.at_level("DEBUG", logger="synthpack.physics.pybullet_engine"):
        early = run(True)
    locked_early = [int(r.args[0]) for r in caplog.records if r.msg.startswith("Batch locked: %d")]
    assert len(locked_early) == 3 and min(locked_early) > 0  # every batch locked some of its grains early
    whole = run(False)
    for checks in (early, whole):
        assert checks.n_outside == 0 and all(checks.settled_per_batch)
        assert checks.max_grain_penetration_voxels < GRAIN_OVERLAP_VOXELS
    # seeds 3-5 of this pour pack at 0.47-0.52 either way (measured): the same packing within that spread
    assert abs(early.packing_fraction - whole.packing_fraction) < 0.05


def test_same_seed_same_pack_other_seed_other_pack(large_library, narrow_tube):
    def run(seed):
        return pour(large_library, PourConfig(n_particles=16, batch_size=8), seed, container=narrow_tube,
                    progress=False)

    a, b, c = run(11), run(11), run(12)
    for name in ("indices", "positions", "quaternions", "scales", "batches"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    assert a.checks.steps_per_batch == b.checks.steps_per_batch
    assert not np.array_equal(a.indices, c.indices)
    assert not np.allclose(a.positions, c.positions)


def _rx(t):
    return np.array([[1, 0, 0], [0, np.cos(t), -np.sin(t)], [0, np.sin(t), np.cos(t)]])


def _ry(t):
    return np.array([[np.cos(t), 0, np.sin(t)], [0, 1, 0], [-np.sin(t), 0, np.cos(t)]])


def _rz(t):
    return np.array([[np.cos(t), -np.sin(t), 0], [np.sin(t), np.cos(t), 0], [0, 0, 1]])


def test_euler_angles_and_quaternions_describe_the_same_rotation(poured):
    matrices = poured.rotation_matrices()
    angles = poured.euler_angles()
    for (theta, phi, psi), m, q in zip(angles, matrices, poured.quaternions):
        # paper eq. 2-4: R = Rz(psi) Ry(phi) Rx(theta)
        np.testing.assert_allclose(_rz(psi) @ _ry(phi) @ _rx(theta), m, atol=1e-10)
        w, x, y, z = q
        from_quat = np.array([
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ])
        np.testing.assert_allclose(from_quat, m, atol=1e-10)
    assert np.all(poured.quaternions[:, 0] >= 0)
    np.testing.assert_allclose(np.linalg.norm(poured.quaternions, axis=1), 1.0, atol=1e-12)
    assert np.all(np.abs(angles[:, 1]) <= np.pi / 2 + 1e-12)


def test_save_load_round_trip(poured, tmp_path):
    path = poured.save(tmp_path / "out" / "placements.json")
    loaded = Placements.load(path)
    assert [p.name for p in path.parent.iterdir()] == ["placements.json"]  # no temp file left
    for name in ("indices", "positions", "quaternions", "scales", "batches"):
        np.testing.assert_array_equal(getattr(loaded, name), getattr(poured, name))
    assert loaded.tube == poured.tube and loaded.seed == 3 and loaded.engine == "pybullet"
    assert loaded.checks == poured.checks
    assert loaded.parameters["batch_size"] == 15 and loaded.unit == poured.unit


def test_load_rejects_missing_and_corrupt_files(poured, tmp_path):
    with pytest.raises(SynthpackInputError, match="No placements file"):
        Placements.load(tmp_path / "nope.json")
    bad = tmp_path / "bad.json"
    bad.write_text("{ not json")
    with pytest.raises(SynthpackInputError, match="corrupt"):
        Placements.load(bad)
    data = poured.to_dict()
    del data["positions"]
    bad.write_text(json.dumps(data))
    with pytest.raises(SynthpackInputError, match="incomplete or corrupt"):
        Placements.load(bad)
    bad.write_text(json.dumps({"format": "other"}))
    with pytest.raises(SynthpackInputError, match="not a synthpack placements"):
        Placements.load(bad)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"n_particles": 0}, "n_particles must be a whole number"),
        ({"batch_size": 0}, "batch_size must be a whole number"),
        ({"seed": -1}, "seed must be a whole number >= 0"),
        ({"n_particles": 2.5}, "n_particles must be a whole number"),
        ({"engine": "bullet3"}, "Unknown engine 'bullet3'; choose one of: pybullet, blender"),
        ({"scale": -1.0}, "scale must be a finite positive"),
        ({"scale": (2.0, 1.0)}, "max < min"),
        ({"size_classes": [(5.0, 1.0, 1.0)]}, "d_min < d_max"),
        ({"size_classes": [(1.0, 2.0, 1.0)]}, "No grain of the library"),
        ({"engine_options": {"warp_speed": 9}}, "unknown config key 'pour.engine_options.warp_speed'"),
        ({"engine_options": {"fixed_steps": 0}}, "'pour.engine_options.fixed_steps' is out of range"),
        ({"engine_options": {"blend_file": "a.blend"}}, "unknown config key 'pour.engine_options.blend_file'"),
        ({"container": Tube(50.0, 1000.0, 10.0, 10.0)}, "too narrow for the largest grain"),
        ({"restitution": 1.5},
         r"Material.restitution is out of range: got 1.5, expected between 0.0 and 1.0"),
        ({"settle": SettleCriteria(quiet_steps=0)}, "SettleCriteria.quiet_steps is out of range"),
        ({"settle": SettleCriteria(quiet_steps=2.5)}, "SettleCriteria.quiet_steps has the wrong type"),
        ({"settle": SettleCriteria(min_steps=10, max_steps=5)}, "min_steps must be at most max_steps"),
    ],
)
def test_bad_arguments_raise_clear_errors(large_library, kwargs, match):
    """A bad setting is refused by PourConfig or by pour, a bad keyword by pour, before any simulation."""
    fields = {field.name for field in dataclasses.fields(PourConfig)}
    settings = {"n_particles": 4, "batch_size": 2, **{k: v for k, v in kwargs.items() if k in fields}}
    keywords = {k: v for k, v in kwargs.items() if k not in fields}
    with pytest.raises(SynthpackInputError, match=match):
        pour(large_library, PourConfig(**settings), keywords.pop("seed", 0), progress=False, **keywords)


def test_empty_library_and_bad_tube_raise():
    class Empty:
        def __len__(self):
            return 0

    with pytest.raises(SynthpackInputError, match="library is empty"):
        pour(Empty(), PourConfig(n_particles=3, batch_size=1), 0, progress=False)
    with pytest.raises(SynthpackInputError, match="config must be a PourConfig, got int"):
        pour(Empty(), 3, 1)
    with pytest.raises(SynthpackInputError, match="inner_radius must be a finite positive"):
        Tube(0.0, 1.0, 1.0, 1.0)


def test_plan_spawns_without_overlap_inside_the_tube(large_library, narrow_tube):
    plan = make_plan(large_library, 60, 30, narrow_tube, seed=5, scale=(0.8, 1.2))
    assert np.all((plan.scales >= 0.8) & (plan.scales <= 1.2))
    for b in range(plan.n_batches):
        members = np.flatnonzero(plan.batches == b)
        xyz, radii = plan.spawn_offsets[members], plan.bounding_radii[members]
        gaps = np.linalg.norm(xyz[:, None] - xyz[None], axis=2) - (radii[:, None] + radii[None])
        assert gaps[~np.eye(len(members), dtype=bool)].min() > 0
        assert np.all(np.hypot(xyz[:, 0], xyz[:, 1]) + radii < narrow_tube.inner_radius)
        assert np.all(xyz[:, 2] - radii > 0)  # above the pack top
    rotations = Rotation.from_quat(plan.quaternions, scalar_first=True)
    # uniform orientations: the mean rotated z axis is near 0
    assert np.linalg.norm(rotations.apply([0, 0, 1]).mean(axis=0)) < 0.35


def test_plan_follows_size_classes(large_library, narrow_tube):
    d = large_library.equivalent_diameters
    cut = float(np.median(d))
    classes = [(0.0, cut, 0.25), (cut, float(d.max()) + 1, 0.75)]
    plan = make_plan(large_library, 100, 10, narrow_tube, seed=1, size_classes=classes)
    small = np.count_nonzero(d[plan.indices] < cut)
    assert small == 25
    assert len(set(plan.batches[d[plan.indices] < cut].tolist())) > 3  # classes are mixed


def test_default_tube_fits_the_source_scan_and_the_grains(large_library):
    tube = Tube.for_library(large_library, 500)
    lateral = large_library.source_shape[2] * large_library.voxel_size[2]
    assert tube.outer_radius < lateral / 2
    solid = 500 * np.mean([p.volume for p in large_library])
    assert tube.height > solid / (0.55 * np.pi * tube.inner_radius**2)
    mesh = tube.mesh()
    assert mesh.is_watertight
    expected = np.pi * (tube.outer_radius**2 * (tube.height + tube.base_thickness)
                        - tube.inner_radius**2 * tube.height)
    assert mesh.volume == pytest.approx(expected, rel=0.01)
    # a narrower tube given by radius is made taller for the same grains
    narrower = Tube.for_library(large_library, 500, inner_radius=tube.inner_radius / 2)
    assert narrower.inner_radius == pytest.approx(tube.inner_radius / 2)
    assert narrower.height > 3 * tube.height
    assert Tube.for_library(large_library, 500, height=123.0).height == 123.0
    with pytest.raises(SynthpackInputError, match="inner_radius must be a finite positive"):
        Tube.for_library(large_library, 500, inner_radius=-1.0)


def test_default_tube_follows_the_grain_scale_and_never_stacks_a_tall_column(large_library):
    unscaled = Tube.for_library(large_library, 200)
    assert Tube.for_library(large_library, 200, scale=2.0).inner_radius == pytest.approx(2 * unscaled.inner_radius)
    assert Tube.for_library(large_library, 200, scale=0.5).inner_radius == pytest.approx(unscaled.inner_radius)
    many = Tube.for_library(large_library, 20_000, scale=2.0)
    assert many.inner_radius > 2 * unscaled.inner_radius  # widened for the many grains
    fill = 20_000 * np.mean([p.volume for p in large_library]) * 8 / (0.55 * np.pi * many.inner_radius**2)
    assert fill <= MAX_FILL_ASPECT * 2 * many.inner_radius * (1 + 1e-9)
    # a radius given by the user is kept, however tall the fill
    assert Tube.for_library(large_library, 20_000, inner_radius=unscaled.inner_radius).inner_radius == \
        pytest.approx(unscaled.inner_radius)


def test_grains_scaled_by_2_in_the_default_tube_pour_like_unscaled_ones(large_library):
    """Simulation units follow the scale: the same pour, twice as large (it took 2x the steps before)."""
    one, two = (pour(large_library, PourConfig(n_particles=40, batch_size=20, scale=s, target_solid_fraction=None),
                     3, progress=False) for s in (1.0, 2.0))
    assert two.parameters["length_scale"] == pytest.approx(2 * one.parameters["length_scale"])
    assert sum(two.checks.steps_per_batch) == pytest.approx(sum(one.checks.steps_per_batch), rel=0.1)
    assert two.checks.n_outside == 0 and all(two.checks.settled_per_batch)
    np.testing.assert_allclose(two.positions, 2 * one.positions, atol=0.5 * 2 * one.parameters["length_scale"])


def test_checks_measure_known_overlap_and_packing():
    box = trimesh.creation.box(extents=(1.0, 1.0, 1.0))
    meshes = [(np.asarray(box.vertices), np.asarray(box.faces))]
    tube = Tube(inner_radius=10.0, height=20.0, wall_thickness=1.0, base_thickness=1.0)
    # two unit cubes overlapping by 0.3 along x, resting on the floor
    positions = np.array([[0.0, 0.0, 0.5], [0.7, 0.0, 0.5]])
    identity = np.tile([1.0, 0, 0, 0], (2, 1))
    checks = compute_checks(
        meshes, np.array([0, 0]), positions, identity, np.ones(2), tube,
        voxel_size=0.1, length_scale=1.0,
    )
    assert checks.max_grain_penetration == pytest.approx(0.3, abs=1e-3)
    assert checks.max_grain_penetration_voxels == pytest.approx(3.0, abs=1e-2)
    assert checks.n_outside == 0 and checks.max_wall_penetration == pytest.approx(0.0, abs=1e-9)
    # a cube sticking 0.5 through the wall is outside
    checks = compute_checks(
        meshes, np.array([0]), np.array([[10.0, 0.0, 0.5]]), identity[:1], np.ones(1), tube,
        voxel_size=0.1, length_scale=1.0,
    )
    assert checks.n_outside == 1
    assert checks.max_wall_penetration == pytest.approx(np.hypot(10.5, 0.5) - 10.0)  # corner


def test_checks_packing_fraction_of_a_solid_column():
    # cubes of side 1 stacked in a 6x6 grid, 8 high: the bulk cylinder (radius 2.9) is solid
    box = trimesh.creation.box(extents=(1.0, 1.0, 1.0))
    grid = np.stack(np.meshgrid(np.arange(-2.5, 3), np.arange(-2.5, 3), np.arange(0.5, 8)), -1)
    positions = grid.reshape(-1, 3)
    n = len(positions)
    checks = compute_checks(
        [(np.asarray(box.vertices), np.asarray(box.faces))], np.zeros(n, dtype=int), positions,
        np.tile([1.0, 0, 0, 0], (n, 1)), np.ones(n),
        Tube(inner_radius=3.9, height=10.0, wall_thickness=1.0, base_thickness=1.0),
        voxel_size=0.1, length_scale=1.0, n_samples=3000,
    )
    assert checks.packing_fraction == pytest.approx(1.0)
    assert checks.overlap_fraction == 0.0


def test_winding_number_separates_inside_from_outside():
    sphere = trimesh.creation.icosphere(subdivisions=3)
    points = np.array([[0, 0, 0], [0.5, 0.3, 0.1], [1.2, 0, 0], [0, 0, -1.5]])
    w = winding_number(points, np.asarray(sphere.vertices), np.asarray(sphere.faces))
    np.testing.assert_allclose(w, [1, 1, 0, 0], atol=1e-6)


def test_the_points_tested_against_a_grain_are_every_point_in_its_box():
    """The Monte-Carlo packing fraction tests a grain's hull only on the points `_in_box` picks: it must miss
    none of the points in the grain's box (brute force), boxes at the edges of the points' range included."""
    rng = np.random.default_rng(7)
    points = rng.uniform(-5, 5, (20_000, 3))
    by_x = np.argsort(points[:, 0], kind="stable")
    for _ in range(50):
        lo = rng.uniform(-6, 5, 3)
        hi = lo + rng.uniform(0.01, 3, 3)
        picked = pour_checks._in_box(points, by_x, points[by_x, 0], lo, hi)
        inside = np.flatnonzero(np.all((points >= lo) & (points <= hi), axis=1))
        assert np.all(np.diff(picked) > 0)
        assert set(inside) <= set(picked)  # the pad may add points within 1e-9 of the box, never drop one
        assert len(picked) - len(inside) <= 1


def test_convex_decomposition_pours_a_concave_aware_pack(large_library):
    one = large_library[:1]  # one distinct grain: a single V-HACD run
    placements = pour(one, PourConfig(n_particles=3, batch_size=3, collision_shape="decomposition"), 2, progress=False)
    assert placements.checks.n_outside == 0 and all(placements.checks.settled_per_batch)
    assert placements.parameters["material"]["collision_shape"] == "decomposition"
    with pytest.raises(SynthpackInputError, match="now the collision shape: set pour.collision_shape"):
        PourConfig(engine_options={"convex_decomposition": True})


def test_big_grains_in_a_narrow_tube_stay_inside(large_library):
    """Grains scaled by 4 in a tube 3 of their median diameters wide (64 of 799 ended outside at 1024^3)."""
    d = float(np.median(large_library.equivalent_diameters))
    tube = Tube.for_library(large_library, 40, scale=4.0, inner_radius=1.5 * 4.0 * d)
    placements = pour(large_library, PourConfig(n_particles=40, batch_size=20, scale=4.0), 0, container=tube,
                      progress=False)
    checks = placements.checks
    assert checks.n_outside == 0 and checks.n_above_rim == 0
    assert checks.max_wall_penetration_voxels < TOLERANCE_VOXELS
    assert placements.parameters["settle"]["substeps"] == 1  # contained on the first run


def test_a_shrunk_hull_with_its_margin_rests_touching_the_floor():
    """Bullet dilates a hull by its margin; the hull shrunk by the margin dilates back onto the cube."""
    from synthpack.physics._bullet import Client

    cube = trimesh.creation.box(extents=(1.0, 1.0, 1.0))
    margin = 0.05
    shrunk = hulls.shrink_hull(cube, margin)
    np.testing.assert_allclose(np.abs(shrunk), 0.5 - margin, atol=1e-9)
    rest = {}
    for name, vertices in (("hull", np.asarray(cube.vertices)), ("shrunk", shrunk)):
        with Client() as client:
            client.setGravity(0, 0, -9.81)
            floor = client.createCollisionShape(client.GEOM_BOX, halfExtents=[5, 5, 0.5])
            client.createMultiBody(0, floor, -1, basePosition=[0, 0, -0.5])
            shape = client.createCollisionShape(client.GEOM_MESH, vertices=vertices.tolist())
            body = client.createMultiBody(1.0, shape, -1, basePosition=[0, 0, 1], useMaximalCoordinates=True)
            client.changeDynamics(body, -1, collisionMargin=margin)
            for _ in range(600):
                client.stepSimulation()
            rest[name] = client.getBasePositionAndOrientation(body)[0][2]
    assert rest["hull"] == pytest.approx(0.5 + margin, abs=2e-3)  # the gap the margin leaves
    assert rest["shrunk"] == pytest.approx(0.5, abs=2e-3)  # touching


def test_protrusion_measures_how_far_points_reach_outside_the_parts():
    cube = np.asarray(trimesh.creation.box(extents=(1.0, 1.0, 1.0)).vertices)
    points = np.array([[0.0, 0.0, 0.0], [0.7, 0.0, 0.0], [1.9, 0.0, 0.0]])
    assert hulls.protrusion(points[:2], [cube]) == pytest.approx(0.2)
    assert hulls.protrusion(points, [cube, cube + [1.5, 0, 0]]) == pytest.approx(0.2)  # the third is in part 2
    assert hulls.protrusion(points[:1], [cube]) == 0.0


def test_bad_engine_option_values_raise():
    with pytest.raises(SynthpackInputError, match="'pour.engine_options.max_hull_vertices' is out of range"):
        PourConfig(engine_options={"max_hull_vertices": 3})


def test_deeply_buried_grains_leave_the_world_without_harm(large_library, narrow_tube, caplog):
    tall = Tube(narrow_tube.inner_radius, 3 * narrow_tube.height, 30.0, 30.0)  # poured freely: a dense target
    # shrinks the shells past full compaction, and their hulls then overlap by design
    with caplog.at_level("DEBUG", logger="synthpack.physics.driver"):
        placements = pour(large_library, PourConfig(n_particles=140, batch_size=20, target_solid_fraction=None,
                                                    engine_options={"record_snapshots": True}),
                          4, container=tall, progress=False)
    assert any("Retired" in r.message for r in caplog.records)
    checks = placements.checks
    assert checks.n_outside == 0 and all(checks.settled_per_batch)
    assert checks.max_grain_penetration_voxels < GRAIN_OVERLAP_VOXELS
    np.testing.assert_array_equal(placements.snapshots[2][0], placements.positions[:60])


def test_the_registry_lists_both_engines():
    assert list(ENGINES) == ["pybullet", "blender"]  # the default first
    for name, engine in ENGINES.items():
        assert isinstance(engine, Engine) and engine.name == name and get_engine(name) is engine
        assert issubclass(engine.Options, EngineConfig)
        assert engine.options() == engine.Options()  # no options: the defaults
    assert isinstance(ENGINES["pybullet"], pybullet_engine.PybulletEngine)
    assert isinstance(ENGINES["blender"], blender_engine.BlenderEngine)
    assert ENGINES["pybullet"].available()
    with pytest.raises(SynthpackInputError, match="Unknown engine 'havok'; choose one of: pybullet, blender"):
        get_engine("havok")


def test_engine_options_are_typed_dataclasses_with_defaults(tmp_path):
    options = ENGINES["pybullet"].options({"max_hull_vertices": None, "fixed_steps": 5})
    assert options == pybullet_engine.PybulletConfig(max_hull_vertices=None, fixed_steps=5)
    assert options.allow_sleeping is True
    assert ENGINES["blender"].options().max_hull_vertices == hulls.MAX_HULL_VERTICES
    path = ENGINES["blender"].options({"blend_file": tmp_path / "pack.blend"}).blend_file
    assert path == str(tmp_path / "pack.blend")  # a path-like is kept as its string


def test_engine_options_reach_the_engine(large_library, monkeypatch):
    seen = []

    def spy(hull, max_vertices):
        seen.append(max_vertices)
        return hulls.simplify_hull(hull, max_vertices)

    monkeypatch.setattr(pybullet_engine, "simplify_hull", spy)
    placements = pour(large_library, PourConfig(n_particles=2, batch_size=2, engine_options={"max_hull_vertices": 16}),
                      1, progress=False)
    assert seen and set(seen) == {16}
    assert placements.parameters["engine_options"] == {"max_hull_vertices": 16}


def test_engine_options_of_a_config_reach_the_engine(large_library, monkeypatch):
    """YAML ``pour.engine_options`` and ``pour.collision_shape`` -> PourConfig -> build_pack -> pour -> the engine's options."""
    received = []

    class Stop(Exception):
        pass

    def capture(self, scene):
        received.append((scene.options, scene.material.collision_shape))
        raise Stop

    monkeypatch.setattr(pybullet_engine.PybulletEngine, "open", capture)
    config = PackConfig.from_dict({"pour": {"n_particles": 2, "batch_size": 2,
                                            "collision_shape": "decomposition",
                                            "engine_options": {"allow_sleeping": False}}})
    with pytest.raises(Stop):
        generate.build_pack(large_library, config, 0, progress=False)
    assert received == [(pybullet_engine.PybulletConfig(allow_sleeping=False), "decomposition")]
    with pytest.raises(SynthpackInputError, match="blender engine collides grains as convex hulls only"):
        PackConfig.from_dict({"pour": {"engine": "blender", "collision_shape": "decomposition"}})


def test_both_engines_use_the_shared_hull_helpers_and_the_drivers_burial_rule():
    assert pybullet_engine.simplify_hull is hulls.simplify_hull
    assert blender_engine.simplify_hull is hulls.simplify_hull
    assert pybullet_engine.convex_hull is blender_engine.convex_hull is hulls.convex_hull
    assert driver.buried is burial.buried and driver.largest_diameter is burial.largest_diameter
    for engine in (pybullet_engine, blender_engine):  # the driver retires buried grains, for every engine
        assert not hasattr(engine, "buried") and not hasattr(engine, "MAX_HULL_VERTICES")
    assert issubclass(pybullet_engine._PybulletWorld, driver.World)
    assert issubclass(blender_engine._BlenderWorld, driver.World)


def test_simplified_hulls_keep_at_most_the_vertices_asked_for():
    sphere = trimesh.creation.icosphere(subdivisions=3)
    hull = hulls.convex_hull(sphere.vertices)
    assert hulls.simplify_hull(hull, None) is hull and hulls.simplify_hull(hull, 1000) is hull
    simple = hulls.simplify_hull(hull, 32)
    assert len(simple.vertices) <= 32 and simple.is_convex and simple.volume < hull.volume


def test_burial_removes_only_grains_covered_by_a_thick_layer():
    corners = np.array([[x, y, 0.0] for x in (-0.5, 0.5) for y in (-0.5, 0.5)])
    deep, middle, top = corners + [0, 0, 0.5], corners + [0, 0, 7.5], corners + [0, 0, 9.0]
    assert burial.buried([deep, middle, top], 1.5, 1.0).tolist() == [True, False, False]
    # an uncovered column counts as the floor: nothing is buried
    assert not burial.buried([deep, top[:1]], 1.5, 1.0).any()
    assert burial.buried([], 1.5, 1.0).shape == (0,)
    # in a wide tube, a hole far away does not keep a covered grain in the world; one next to it does
    cover = {(x, y): 0.8 * corners + [x + 0.5, y + 0.5, 9.0] for x in range(-10, 10) for y in range(-10, 10)
             if np.hypot(x + 0.5, y + 0.5) <= 9.0}  # one grain per column, over the whole tube
    far = [hull for xy, hull in cover.items() if xy != (7, 0)]
    near = [hull for xy, hull in cover.items() if xy != (1, 0)]
    assert burial.buried([deep, *cover.values()], 10.0, 1.0)[0]
    assert burial.buried([deep, *far], 10.0, 1.0)[0] and not burial.buried([deep, *near], 10.0, 1.0)[0]
    assert burial.largest_diameter([corners, 3 * corners]) == pytest.approx(2 * 3 * np.sqrt(0.5))


def test_engines_refuse_bad_bodies_with_input_errors():
    box = trimesh.creation.box()

    def body(batch):
        return Body(box.vertices, box.faces, 1.0, np.zeros(3), np.array([1.0, 0, 0, 0]), np.zeros(3), batch)

    tube = TubeSpec(2.0, 5.0, 0.2, 0.2)
    engine = ENGINES["pybullet"]

    def scene(bodies, tube=tube, options=None):
        return Scene(bodies, tube, PourConfig().material(), SettleCriteria(), options or engine.options())

    with pytest.raises(SynthpackInputError, match="ordered by batch"):
        engine.simulate(scene([body(1), body(0)]))
    with pytest.raises(SynthpackInputError, match="TubeSpec.height must be > 0"):
        engine.simulate(scene([body(0)], TubeSpec(2.0, 0.0, 0.2, 0.2)))
    with pytest.raises(SynthpackInputError, match="takes PybulletConfig options"):
        engine.simulate(scene([body(0)], options=ENGINES["blender"].options()))


def test_a_decomposition_is_made_once_per_grain_and_scaled_for_every_shell(large_library):
    """Spacing and shrinking shells change a grain's collider every batch: V-HACD runs once, its parts are scaled."""
    from synthpack.physics._bullet import Client

    particle = large_library[0]
    body = Body(vertices=np.asarray(particle.mesh.vertices), faces=np.asarray(particle.mesh.faces), mass=1.0,
                center_mass=np.asarray(particle.mesh.center_mass), orientation=np.array([1.0, 0, 0, 0]),
                spawn_offset=np.zeros(3), batch=0)
    material = PourConfig(collision_shape="decomposition").material()
    client, shapes, parts = Client(), {}, {}
    try:
        true = pybullet_engine._shape_for(client, body, shapes, material, 64, 0.0, parts)
        (decomposed,) = parts.values()
        shell = pybullet_engine._shape_for(client, body, shapes, material, 64, 0.2, parts)
    finally:
        client.close()
    assert len(parts) == 1 and parts[next(iter(parts))] is decomposed  # no second V-HACD run
    assert len(shapes) == 2 and shell.shape_id != true.shape_id
    span = np.ptp(true.hull_vertices, axis=0)
    np.testing.assert_allclose(np.ptp(shell.hull_vertices, axis=0), 1.2 * span, rtol=1e-6)
    assert shell.protrusion < true.protrusion  # the scaled parts hold more of the true grain
