"""The one batch driver (synthpack.physics.driver): a toy engine of a few hooks gets locking, retiring and compaction.

The toy engine's world is pure NumPy: each grain of a batch drops straight down, in
the order of the batch, until the bounding box of its collision hull rests on the
floor or on the boxes of the grains below it (a height map of 0.1-unit columns).
Nothing in it knows about batches of batches, burial or target packing fractions.
"""

from __future__ import annotations

import logging
from dataclasses import replace

import numpy as np
import pytest
import trimesh
from scipy.spatial.transform import Rotation

from synthpack.errors import SynthpackInputError
from synthpack.physics import PourConfig
from synthpack.physics.burial import largest_diameter
from synthpack.physics.compaction import (
    FALL_QUIET,
    FALL_STEPS,
    PackingController,
    resolve_target,
)
from synthpack.physics.driver import LockedBatch, World
from synthpack.physics.engine import Engine
from synthpack.physics.hulls import convex_hull
from synthpack.physics.scene import Body, Scene, SettleCriteria, TubeSpec

MATERIAL = PourConfig().material()
SETTLE = SettleCriteria()
CELL = 0.1  # toy height-map column, simulation units
SLIDE, MAX_SLIDES = 0.1, 20  # a toy grain slides this far sideways, at most this often


class ToyWorld(World):
    """Grains dropped straight down onto a height map; every call is recorded in `calls`."""

    def __init__(self, scene: Scene, calls: list) -> None:
        self.scene, self.calls = scene, calls
        half = int(np.ceil(scene.tube.inner_radius / CELL))
        self.half, self.heights = half, np.zeros((2 * half, 2 * half))
        n = len(scene.bodies)
        self.positions, self.quaternions, self.inflations = np.zeros((n, 3)), np.zeros((n, 4)), np.zeros(n)
        self.surfaces = [_surface_points(b.vertices) for b in scene.bodies]  # points on each grain's hull
        self.in_world: set[int] = set()
        self.batch: list[int] = []

    def _world(self, i: int, points: np.ndarray) -> np.ndarray:
        """Points of grain `i` (local frame) in the world, its shell inflated by its own inflation."""
        body = self.scene.bodies[i]
        local = body.center_mass + (points - body.center_mass) * (1 + self.inflations[i])
        return Rotation.from_quat(self.quaternions[i], scalar_first=True).apply(local) + self.positions[i]

    def _world_hull(self, i: int) -> np.ndarray:
        return self._world(i, np.asarray(convex_hull(self.scene.bodies[i].vertices).vertices))

    def add_batch(self, members, positions, friction, inflation):
        self.calls.append(("add_batch", members.tolist(), friction, inflation, positions.copy()))
        self.batch, self.friction, self.dropped = [int(i) for i in members], friction, False
        self.inflations[members] = inflation
        self.positions[members] = positions
        self.quaternions[members] = [self.scene.bodies[i].orientation for i in members]
        self.in_world.update(self.batch)

    def settle(self, criteria, fixed_steps):
        self.calls.append(("settle", criteria, fixed_steps))
        if not self.dropped:  # a second settle (after set_friction) finds the grains at rest
            for i in self.batch:
                self._drop(i)
            self.dropped = True
        return (1 if fixed_steps is None else fixed_steps), True

    def _drop(self, i: int) -> None:
        """Drop grain `i` straight down, then slide it sideways while that lets it rest lower.

        The lower its friction, the more slides it gets: friction 0 slides :data:`MAX_SLIDES`
        times (at most), friction 1 not at all.
        """
        position = self.positions[i].copy()
        position[2] -= self._rest(i, position)[0]
        for _ in range(int(MAX_SLIDES * (1 - min(self.friction, 1.0)))):
            moves = [position + [SLIDE * np.cos(a), SLIDE * np.sin(a), 0.0] for a in np.arange(8) * np.pi / 4]
            for move in moves:
                move[2] -= self._rest(i, move)[0]
            best = min(moves, key=lambda move: move[2])
            if not best[2] < position[2]:
                break
            position = best
        self.positions[i] = position
        drop, cells, points = self._rest(i, position)
        np.maximum.at(self.heights.reshape(-1), cells, points[:, 2] - drop)

    def _rest(self, i: int, position: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
        """How far grain `i` at `position` falls until a column of it meets the height map (-inf: it leaves the tube)."""
        body = self.scene.bodies[i]
        local = body.center_mass + (self.surfaces[i] - body.center_mass) * (1 + self.inflations[i])
        points = Rotation.from_quat(self.quaternions[i], scalar_first=True).apply(local) + position
        if np.hypot(points[:, 0], points[:, 1]).max() > self.scene.tube.inner_radius:
            return -np.inf, np.empty(0, int), points
        cells = np.ravel_multi_index(tuple((np.floor(points[:, :2] / CELL).astype(int) + self.half).T),
                                     self.heights.shape)
        bottom = np.full(self.heights.size, np.inf)
        np.minimum.at(bottom, cells, points[:, 2])
        hit = np.isfinite(bottom)
        return float((bottom[hit] - self.heights.reshape(-1)[hit]).min()), cells, points

    def set_friction(self, friction):
        self.calls.append(("set_friction", friction))
        self.friction = friction

    def lock(self):
        self.calls.append(("lock",))
        hulls = [self._world_hull(i) for i in self.batch]
        batch, self.batch = self.batch, []
        return LockedBatch(self.positions[batch].copy(), self.quaternions[batch].copy(), hulls)

    def retire(self, indices):
        self.calls.append(("retire", list(indices)))
        self.in_world.difference_update(indices)

    def poses(self, indices):
        return self.positions[indices].copy(), self.quaternions[indices].copy()


def _surface_points(vertices: np.ndarray, per_edge: int = 6) -> np.ndarray:
    """(P, 3) points covering the convex hull of `vertices`: a barycentric grid on each face."""
    hull = convex_hull(vertices)
    k = np.array([(a, b) for a in range(per_edge + 1) for b in range(per_edge + 1 - a)]) / per_edge
    weights = np.column_stack([k, 1 - k.sum(axis=1)])
    return np.einsum("pk,fkd->fpd", weights, hull.triangles).reshape(-1, 3)


class ToyEngine(Engine):
    """An engine of a few hooks: its world is :class:`ToyWorld`."""

    name = "toy"

    def __init__(self) -> None:
        self.calls: list = []
        self.worlds: list[ToyWorld] = []

    def open(self, scene: Scene) -> World:
        self.worlds.append(ToyWorld(scene, self.calls))
        return self.worlds[-1]


class RigidToyEngine(ToyEngine):
    """The toy engine, claiming it cannot change friction nor inflate shells."""

    supports_compaction = False


def toy_scene(n_batches: int, per_batch: int, radius: float = 2.0, seed: int = 0,
              record_snapshots: bool = False) -> Scene:
    """Lumpy grains about one unit across, `per_batch` per batch, spawned in a column above the pack."""
    rng = np.random.default_rng(seed)
    bodies = []
    for batch in range(n_batches):
        for k in range(per_batch):
            mesh = trimesh.creation.icosphere(subdivisions=1, radius=0.5)
            mesh = trimesh.Trimesh(mesh.vertices * rng.uniform(0.6, 1.0, 3), mesh.faces)
            angle, r = rng.uniform(0, 2 * np.pi), rng.uniform(0, radius - 0.8)
            q = rng.standard_normal(4)
            bodies.append(Body(mesh.vertices, mesh.faces, mesh.volume, mesh.center_mass, q / np.linalg.norm(q),
                               np.array([r * np.cos(angle), r * np.sin(angle), 1.0 + 1.2 * k]), batch))
    tube = TubeSpec(inner_radius=radius, height=40.0, wall_thickness=0.2, base_thickness=0.2)
    options = ToyEngine().options({"record_snapshots": record_snapshots})
    return Scene(bodies, tube, MATERIAL, SETTLE, options)


def controller(scene: Scene, target: float) -> PackingController:
    return PackingController(target, scene.material.friction, [(b.vertices, b.faces) for b in scene.bodies],
                             scene.tube.inner_radius)


def test_the_driver_locks_batch_by_batch_and_snapshots_what_the_engine_reads():
    engine, scene = ToyEngine(), toy_scene(3, 5, radius=3.0, record_snapshots=True)
    progress = []
    result = engine.simulate(scene, progress=lambda i, n: progress.append((i, n)))
    names = [call[0] for call in engine.calls]
    assert names == ["add_batch", "settle", "lock"] * 3  # a free pour: no friction change, nothing buried
    assert [call[1] for call in engine.calls if call[0] == "add_batch"] == [[0, 1, 2, 3, 4], [5, 6, 7, 8, 9],
                                                                           [10, 11, 12, 13, 14]]
    assert {call[2] for call in engine.calls if call[0] == "add_batch"} == {MATERIAL.friction}
    assert progress == [(0, 3), (1, 3), (2, 3)]
    assert result.steps_per_batch == [1, 1, 1] and result.settled_per_batch == [True] * 3
    assert [len(p) for p, _ in result.snapshots] == [5, 10, 15]
    world = engine.worlds[0]
    np.testing.assert_array_equal(result.positions, world.positions)
    np.testing.assert_array_equal(result.snapshots[1][0], world.positions[:10])
    # each batch spawns dz above the top of the hulls locked before it
    spawns = [call[4] for call in engine.calls if call[0] == "add_batch"]
    dz = np.array([b.spawn_offset[2] for b in scene.bodies])
    np.testing.assert_array_equal(spawns[0][:, 2], dz[:5])
    top = max(world._world_hull(i)[:, 2].max() for i in range(5))
    np.testing.assert_allclose(spawns[1][:, 2], top + dz[5:10])
    np.testing.assert_array_equal(spawns[1][:, :2], [b.spawn_offset[:2] for b in scene.bodies[5:10]])


def test_a_toy_engine_gets_the_retiring_of_buried_grains_for_free(caplog):
    engine, scene = ToyEngine(), toy_scene(12, 10)
    with caplog.at_level(logging.DEBUG, logger="synthpack.physics.driver"):
        result = engine.simulate(scene)
    retired = [i for call in engine.calls if call[0] == "retire" for i in call[1]]
    assert retired and "Retired" in caplog.text
    assert len(set(retired)) == len(retired)  # each grain leaves the world once
    world = engine.worlds[0]
    assert world.in_world.isdisjoint(retired) and len(world.in_world) == len(scene.bodies) - len(retired)
    # only grains deep under the pack: more than two of the largest grains below its top
    largest = largest_diameter(b.vertices for b in scene.bodies)
    top = max(world._world_hull(i)[:, 2].max() for i in range(len(scene.bodies)))
    assert all(world._world_hull(i)[:, 2].max() < top - 2 * largest for i in retired)
    assert max(retired) < 100  # none of the last two batches
    np.testing.assert_array_equal(result.positions[retired], world.positions[retired])  # their poses are kept


def test_a_toy_engine_gets_compaction_for_free():
    """Dense target: the batch falls at a lowered friction, gets the material's back, settles again."""
    engine, scene = ToyEngine(), toy_scene(6, 10, radius=2.5)
    packing = controller(scene, 0.6)
    engine.simulate(scene, compaction=packing)
    batches = [k for k, call in enumerate(engine.calls) if call[0] == "add_batch"]
    first = engine.calls[batches[0]: batches[1]]
    assert [call[0] for call in first] == ["add_batch", "settle", "set_friction", "settle", "lock"]
    assert first[0][2] < MATERIAL.friction and first[2][1] == MATERIAL.friction
    fall, final = first[1][1], first[3][1]
    assert fall.linear_speed == SETTLE.linear_speed * FALL_QUIET and fall.max_steps == min(SETTLE.max_steps, FALL_STEPS)
    assert final == replace(SETTLE, min_steps=0)
    assert len(packing.knobs) == 6 and packing.layers  # the driver let the controller measure the toy's pack


def test_the_knob_reaches_the_toy_engine_spaced_looser_compacted_denser():
    """The first batch gets the prior's knob: a loose target spaces it (inflated shells), a dense one compacts it."""
    scene = toy_scene(1, 30, radius=2.5)
    heights = {}  # the mean height of the grains
    for target in (None, 0.25, 0.6):
        engine = ToyEngine()
        result = engine.simulate(scene, compaction=None if target is None else controller(scene, target))
        (_, _, friction, inflation, _), *_ = engine.calls
        heights[target] = result.positions[:, 2].mean()
        if target == 0.25:
            assert (inflation > 0).all() and friction == MATERIAL.friction
        if target == 0.6:
            assert (inflation == 0).all() and friction < MATERIAL.friction
    assert heights[0.25] > 1.2 * heights[None] > 1.2 * heights[0.6]


def test_bare_grains_of_a_spaced_batch_get_no_shell_and_the_others_thicker_ones():
    """The same batch, all in equal shells or with every third grain bare: the mean collision volume is kept."""
    scene = toy_scene(1, 30, radius=2.5)
    calls = {}
    for bare in (None, np.arange(30) % 3 == 0):
        engine, packing = ToyEngine(), controller(scene, 0.25)
        packing.bare = bare
        engine.simulate(scene, compaction=packing)
        calls[bare is None] = engine.calls[0][3]
    equal, mixed = calls[True], calls[False]
    assert np.ptp(equal) == 0 and equal[0] > 0
    np.testing.assert_array_equal(mixed[::3], 0.0)
    assert (np.delete(mixed, np.s_[::3]) > equal[0]).all()
    assert np.mean((1 + mixed) ** 3) == pytest.approx((1 + equal[0]) ** 3)


def test_an_engine_without_compaction_is_refused_a_target_and_pours_freely_for_source(large_library, caplog):
    rigid, scene = RigidToyEngine(), toy_scene(2, 5)
    with pytest.raises(SynthpackInputError, match="toy engine cannot pack"):
        rigid.simulate(scene, compaction=controller(scene, 0.5))
    assert rigid.calls == []  # refused before any work
    with caplog.at_level(logging.INFO, logger="synthpack.physics.compaction"):
        assert resolve_target("source", large_library, rigid) is None
    assert "free pour" in caplog.text
    with pytest.raises(SynthpackInputError, match="cannot pack"):
        resolve_target(0.5, large_library, rigid)
