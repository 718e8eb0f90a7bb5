"""Packing to a target solid fraction (synthpack.physics.compaction): reached, reported, reproducible."""

import logging
import re
import subprocess
import sys

import numpy as np
import pytest
import trimesh
from scipy.spatial import ConvexHull
from scipy.spatial.transform import Rotation

from synthpack.artefacts.recipes import bulk_region
from synthpack.pipeline.config import PackConfig
from synthpack.pipeline.generate import build_pack
from synthpack.errors import SynthpackInputError
from synthpack.library.core import ParticleLibrary
from synthpack.physics import PourConfig, Tube, get_engine, pour
from synthpack.physics.compaction import (MAX_KNOB, TARGET_TOLERANCE, BatchCompaction, PackingController,
                                          PackingPrior, parse_target, resolve_target)
from synthpack.physics.checks import solid_fraction_of
from synthpack.physics.container import crop_half_sides
from synthpack.physics.shells import MAX_BARE, bare_fraction, bare_grains, resolve_coordination, shell_inflations
from synthpack.scan.samples import sample_scan
from synthpack.measure.contacts import centred_grains, coordination_numbers
from synthpack.measure.specimen import solid_fraction, specimen_mask


@pytest.fixture(scope="module")
def small_library() -> ParticleLibrary:
    """The 'small' sample's library (many small grains)."""
    return ParticleLibrary.from_scan(sample_scan("small", seed=0), workers=1, progress=False)


def _narrow_tube(library: ParticleLibrary, n: int, radius: float) -> Tube:
    """A tube `radius` median diameters wide, so a small pour still has a bulk region."""
    return Tube.for_library(library, n, inner_radius=radius * float(np.median(library.equivalent_diameters)),
                            packing_fraction=0.3)


# the control's reach in a pour of 150 grains depends on the draw (with 0.7.0's streams, large in
# batches of 30 reaches 0.57 for seeds 2 and 3, not 1 or 4; in batches of 15 for seeds 1 and 4):
# this checks that it can reach the target, not how reliably in so short a pour (issue 26)
@pytest.mark.parametrize("sample, target, batch", [("large", 0.57, 15), ("small", 0.58, 30)])
def test_a_target_above_the_free_pour_is_reached(sample, target, batch, large_library, small_library):
    library = large_library if sample == "large" else small_library
    tube = _narrow_tube(library, 150, 2.5)
    free, packed = (pour(library, PourConfig(n_particles=150, batch_size=batch, target_solid_fraction=value), 1,
                         container=tube, progress=False) for value in (None, target))
    assert free.checks.packing_fraction < target - TARGET_TOLERANCE  # the free pour is looser
    assert abs(packed.checks.packing_fraction - target) <= TARGET_TOLERANCE
    assert packed.checks.target_reached is True and packed.checks.target_packing_fraction == target
    assert packed.checks.n_outside == 0
    assert max(packed.checks.compaction["knobs"]) > 0  # compacted, not spaced


def test_a_target_below_the_free_pour_is_reached_with_spaced_grains(large_library):
    tube = _narrow_tube(large_library, 150, 2.5)
    config = PourConfig(n_particles=150, batch_size=30, target_solid_fraction=0.30, target_coordination=None)
    packed = pour(large_library, config, 1, container=tube, progress=False)
    assert abs(packed.checks.packing_fraction - 0.30) <= TARGET_TOLERANCE
    assert packed.checks.target_reached is True
    assert min(packed.checks.compaction["knobs"]) < 0  # spaced shells
    assert packed.checks.max_grain_penetration_voxels < 1.0  # rendered at their true size: apart, not overlapping
    assert packed.checks.n_outside == 0


def test_an_impossible_target_is_reported_not_hidden(large_library, caplog):
    tube = _narrow_tube(large_library, 120, 2.5)
    with caplog.at_level(logging.WARNING, logger="synthpack.physics.compaction"):
        config = PourConfig(n_particles=120, batch_size=40, target_solid_fraction=0.75)
        placements = pour(large_library, config, 0, container=tube, progress=False)
    checks = placements.checks
    assert checks.target_reached is False and checks.target_packing_fraction == 0.75
    assert checks.packing_fraction < 0.75 - TARGET_TOLERANCE
    assert "NOT reached" in caplog.text and "0.750" in caplog.text
    record = checks.to_dict()
    assert record["target_reached"] is False and record["compaction"]["knobs"]
    assert placements.parameters["target_solid_fraction"] == 0.75
    assert "reached=False" in checks.summary()


def test_same_seed_same_placements_with_compaction(large_library):
    config = PourConfig(n_particles=40, batch_size=20, target_solid_fraction=0.6)
    runs = [pour(large_library, config, 3, progress=False) for _ in range(2)]
    np.testing.assert_array_equal(runs[0].positions, runs[1].positions)
    np.testing.assert_array_equal(runs[0].quaternions, runs[1].quaternions)


def test_the_source_target_is_the_source_scans_bulk_solid_fraction(large_scan, large_library):
    measured = solid_fraction(large_scan.labels, specimen_mask(large_scan.labels))
    assert large_library.statistics.solid_fraction == pytest.approx(measured)
    assert resolve_target("source", large_library, get_engine("pybullet")) == pytest.approx(measured)


@pytest.mark.parametrize("value, expected", [("source", "source"), (None, None), ("none", None), (0.55, 0.55)])
def test_the_config_takes_source_a_number_or_none(value, expected):
    config = PackConfig.from_dict({"pour": {"target_solid_fraction": value}})
    assert config.pour.target_solid_fraction == expected


@pytest.mark.parametrize("value", [1.5, 0.0, "dense", True])
def test_a_bad_target_is_refused_with_the_key(value):
    with pytest.raises(SynthpackInputError, match="target_solid_fraction"):
        PackConfig.from_dict({"pour": {"target_solid_fraction": value}})


def test_the_knob_compacts_above_zero_and_spaces_below():
    dense, free, loose = (BatchCompaction.from_knob(k, friction=0.6) for k in (1.0, 0.0, -0.2))
    assert dense.compacts and dense.settle_friction < 0.6 and dense.inflation == 0
    assert not free.compacts and free.settle_friction == 0.6 and free.inflation == 0
    assert not loose.compacts and loose.inflation == pytest.approx(0.2)


def test_the_controller_stops_steering_when_the_bulk_layers_hold_no_solid(caplog):
    """A layer measured at 0 used to make the knob 'wanted / 0' (ZeroDivisionError mid-pour)."""
    tetrahedron = (np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1.0]]),
                   np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]]))
    controller = PackingController(0.45, 0.6, [tetrahedron], inner_radius=3.0)
    first = controller.next_batch()
    controller.layers.append((1.0, 2.0, 0.0, first.knob))  # a bulk layer that no grain reached
    with caplog.at_level(logging.WARNING, logger="synthpack.physics.compaction"):
        second = controller.next_batch()
    assert np.isfinite(second.knob) and second.knob == first.knob  # the prior's knob for the target
    assert controller.degenerate and controller.record()["layers"][0]["packing_fraction"] == 0
    assert "cannot be steered" in caplog.text
    assert -1 < first.knob < 0  # spaced: 0.45 is looser than a free pour
    controller.layers.append((2.0, 3.0, 0.55, second.knob))  # denser than the prior says: steering again
    assert controller.next_batch().knob < second.knob  # spaced wider


@pytest.mark.parametrize("value", [0.81, 0.99])
def test_a_target_no_rigid_grain_pack_reaches_is_refused_naming_the_limit(value):
    with pytest.raises(SynthpackInputError, match=r"target_solid_fraction.*0\.8\]"):
        PackConfig.from_dict({"pour": {"target_solid_fraction": value}})
    with pytest.raises(SynthpackInputError, match="cannot be reached"):
        parse_target(value)


def test_the_cli_refuses_an_unreachable_target_before_any_work(tmp_path):
    out = tmp_path / "packs"
    run = subprocess.run([sys.executable, "-m", "synthpack", "-q", "generate", "--sample", "small",
                          "--n-particles", "4", "--target-solid-fraction", "0.99", "--out", str(out)],
                         capture_output=True, text=True)
    assert run.returncode == 2 and "Traceback" not in run.stderr
    assert run.stderr.splitlines()[0].startswith("synthpack: error: config key 'pour.target_solid_fraction'")
    assert "0.8]" in run.stderr.splitlines()[0] and not out.exists()


def test_a_target_that_cannot_be_measured_is_a_warning_with_the_grains_a_bulk_needs(large_library, caplog):
    with caplog.at_level(logging.WARNING, logger="synthpack.physics.compaction"):
        placements = pour(large_library, PourConfig(n_particles=4, batch_size=4, target_solid_fraction=0.6), 2,
                          progress=False)
    assert placements.checks.target_reached is None and np.isnan(placements.checks.packing_fraction)
    (line,) = [r.getMessage() for r in caplog.records if "0.600" in r.getMessage()]
    assert "not judged (" in line and "a bulk needs > 3" in line
    needed = int(re.search(r"pour ~(\d+):", line).group(1))
    assert needed > 4 and f"--n-particles {needed} (pour.n_particles)" in line


def _bulk_structure(library: ParticleLibrary, seed: int, **pour_settings) -> tuple[float, float, dict]:
    """Solid fraction and mean coordination of a rendered pack's bulk (as the realism report measures), its record."""
    config = PackConfig().replace(postprocess="none", reconstruct={"view": "tube"},
                                  pour={"n_particles": 150, "batch_size": 30, **pour_settings})
    pack = build_pack(library, config, seed, progress=False)
    labels, checks = np.asarray(pack.labels), pack.placements.checks
    region = bulk_region(labels.shape, pack.grid.origin, library.voxel_size, checks.packing_region)
    grains = centred_grains(labels, region)
    assert len(grains) >= 30  # enough grains for a mean
    return solid_fraction(labels, region), float(coordination_numbers(labels)[grains].mean()), checks.compaction


# the bulk of a 150-grain pour holds about 60 grains, and its contacts follow its density: seed 1 gives 0.84
# contacts per grain at 0.289, seed 2 1.40 at 0.311 (target 1.0 at 0.30); this checks that bare grains bring
# the contacts near the target, not how closely in so short a pour (the concrete scan's 300 grains: README)
@pytest.mark.slow
def test_a_spaced_pour_reaches_the_target_coordination_and_still_the_solid_fraction(even_large_library):
    """Equal shells keep every grain apart; with some grains bare, they touch about as often as asked.

    The grains drawn evenly, as a scan in a container's are (the concrete scan's): BARE_CONTACTS was
    measured so, and a library whose large grains weigh more gives more contacts per bare grain.
    """
    library = even_large_library
    radius = 3.2 * float(np.median(library.equivalent_diameters))
    settings = {"target_solid_fraction": 0.3, "tube_radius": radius}
    apart = _bulk_structure(library, 1, target_coordination="none", **settings)
    touching = _bulk_structure(library, 1, target_coordination=1.0, **settings)  # the concrete scan's 1.05
    assert apart[1] < 0.75  # equal shells: the few grains whose voxels meet across a thin shell
    assert "bare_grains" not in apart[2]
    assert touching[1] == pytest.approx(1.0, rel=0.3)
    assert touching[2]["bare_grains"] == 5 * round(30 * bare_fraction(1.0))
    for fraction, _, _ in (apart, touching):
        assert fraction == pytest.approx(0.3, abs=0.03)


@pytest.mark.parametrize("value, expected",
                         [("source", "source"), (None, None), ("none", None), (1.5, 1.5), (0, 0.0)])
def test_the_config_takes_a_target_coordination(value, expected):
    assert PackConfig.from_dict({"pour": {"target_coordination": value}}).pour.target_coordination == expected


@pytest.mark.parametrize("value", [-0.5, "many", True, float("inf")])
def test_a_bad_target_coordination_is_refused_with_the_key(value):
    with pytest.raises(SynthpackInputError, match="target_coordination"):
        PackConfig.from_dict({"pour": {"target_coordination": value}})


def test_the_source_coordination_is_the_source_scans(large_library):
    source = large_library.statistics.coordination
    assert resolve_coordination("source", large_library) == source > 3  # a dense pack
    assert resolve_coordination(None, large_library) is None and resolve_coordination(0.5, large_library) == 0.5


def test_the_bare_grains_are_a_share_that_grows_with_the_target_and_keeps_the_mean_collision_volume():
    assert bare_fraction(None) == bare_fraction(0.0) == 0.0
    assert 0 < bare_fraction(0.5) < bare_fraction(1.0) < bare_fraction(2.0) < MAX_BARE == bare_fraction(50.0)
    batches = np.repeat(np.arange(40), 50)
    assert bare_grains(batches, 0.0, seed=3) is None
    drawn = bare_grains(batches, 0.4, seed=3)
    assert (np.bincount(batches[drawn]) == 20).all()  # 40% of each batch: no binomial spread
    np.testing.assert_array_equal(drawn, bare_grains(batches, 0.4, seed=3))  # the seed's own stream
    assert not np.array_equal(drawn, bare_grains(batches, 0.4, seed=4))
    shells = shell_inflations(0.3, drawn[:50])
    assert (shells[drawn[:50]] == 0).all() and (shells[~drawn[:50]] > 0.3).all()
    assert np.mean((1 + shells) ** 3) == pytest.approx(1.3**3)
    np.testing.assert_array_equal(shell_inflations(0.3, np.zeros(5, bool)), 0.3)  # no bare grain: equal shells
    np.testing.assert_array_equal(shell_inflations(0.0, drawn[:50]), 0.0)  # a free or compacted batch


def test_a_target_looser_than_a_free_pour_is_never_compacted():
    tetrahedron = (np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1.0]]),
                   np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]]))
    controller = PackingController(0.45, 0.6, [tetrahedron], inner_radius=3.0)
    first = controller.next_batch()
    controller.layers.append((1.0, 2.0, 0.2, first.knob))  # far looser than aimed at
    assert controller.next_batch().knob == 0.0  # a free batch, not a compacted one
    dense = PackingController(0.58, 0.6, [tetrahedron], inner_radius=3.0)
    dense.layers.append((1.0, 2.0, 0.5, dense.next_batch().knob))
    assert dense.next_batch().knob > 0


def test_a_bulk_layer_is_measured_only_once_the_grains_cover_the_floor():
    """A heap in one corner reaches high but leaves the floor bare: no layer until a batch covers it."""
    import trimesh

    cube = trimesh.creation.box(extents=(1.0, 1.0, 1.0)).subdivide().subdivide()
    centres = np.array([(x, y, z + 0.5) for z in range(5) for y in range(-3, 4) for x in range(-3, 4)], float)
    controller = PackingController(0.3, 0.6, [(cube.vertices, cube.faces)] * len(centres), inner_radius=3.0)
    identity = np.tile([1.0, 0, 0, 0], (len(centres), 1))
    heap = np.flatnonzero((centres[:, 0] == 3) & (centres[:, 1] == 3))  # a column of 5 in a corner
    controller.next_batch()
    controller.observe(heap, centres[heap], identity[heap])
    assert controller.layers == []  # 5 high, but the floor shows: measured later
    rest = np.setdiff1d(np.arange(len(centres)), heap)
    controller.next_batch()
    controller.observe(rest, centres[rest], identity[rest])
    ((z0, z1, fraction, _),) = controller.layers
    assert z0 == 1.0 and z1 == pytest.approx(3.0)  # two below the top (5), one below the surface
    assert fraction == pytest.approx(1.0, abs=0.05)  # solid cubes


def _star(depth: float) -> tuple[np.ndarray, np.ndarray]:
    """A concave grain: an icosphere with every other vertex pulled in to `depth` of the radius."""
    sphere = trimesh.creation.icosphere(subdivisions=1)
    vertices = np.array(sphere.vertices)
    vertices[::2] *= depth
    return vertices, np.array(sphere.faces)


def test_the_prior_packs_the_hulls_scaled_by_the_grains_convexity_and_inverts_to_its_knob():
    convex, sand = PackingPrior(1.0, 0.1), PackingPrior(0.81, 1 - 0.81 ** (1 / 3))
    assert sand.dense == pytest.approx(0.81 * convex.dense) and sand.free == pytest.approx(0.81 * convex.free)
    assert 0.5 < sand.dense < 0.54 < 0.58 < convex.dense  # sand's hulls: full compaction short of its scan's 0.58
    assert sand.fraction(MAX_KNOB) == pytest.approx(convex.dense)  # the most shrunk shell holds the grain's volume
    for prior in (convex, sand):
        assert prior.fraction(0.0) == prior.free and prior.fraction(1.0) == pytest.approx(prior.dense)
        for knob in (-0.4, -0.1, 0.3, 0.9, 1.2, 1.8):
            assert prior.knob(prior.fraction(knob), highest=MAX_KNOB) == pytest.approx(knob)
        assert prior.knob(prior.fraction(1.8), highest=1.0) == 1.0  # clipped where shells may not shrink


def test_past_full_compaction_the_shells_shrink_once_the_prior_or_the_layers_say_it_falls_short():
    shrunk = BatchCompaction.from_knob(1.5, friction=0.6, max_shrink=0.08)
    assert shrunk.compacts and shrunk.inflation == pytest.approx(-0.04) and shrunk.settle_friction == 0.02
    assert BatchCompaction.from_knob(1.5, friction=0.6).knob == 1.0  # an engine that cannot shrink: full compaction
    concave = [_star(0.7)] * 4
    early = PackingController(0.60, 0.6, concave, inner_radius=3.0, shrinks=True)
    convexity = trimesh.Trimesh(*concave[0]).volume / trimesh.Trimesh(*concave[0]).convex_hull.volume
    assert early.max_shrink == pytest.approx(1 - convexity ** (1 / 3)) and early.max_shrink > 0.02
    assert early.prior == PackingPrior(pytest.approx(convexity), early.max_shrink) and early.prior.dense < 0.58
    first = early.next_batch()  # the prior says these hulls pack short of 0.60: no batch spent at full compaction
    assert 1.0 < first.knob <= MAX_KNOB and first.inflation < 0 and early.shrinking
    early.layers.append((1.0, 2.0, 0.56, first.knob))
    assert first.knob < early.next_batch().knob <= first.knob + 0.5  # damped: at most 0.5 a batch
    last = early.knobs[-1]
    early.layers.append((2.0, 3.0, 0.75, last))  # far denser than the target: the knob falls, as damped
    assert early.prior.knob(0.55) < last - 0.75 <= early.next_batch().knob < last
    assert early.record()["max_shrink"] == round(early.max_shrink, 4)
    rigid = PackingController(0.60, 0.6, concave, inner_radius=3.0)  # an engine that does not shrink shells
    assert rigid.next_batch().knob == 1.0 and rigid.max_shrink == 0 and "max_shrink" not in rigid.record()
    convex = [_star(0.9)]  # nearly convex: its shells may still shrink a little
    controller = PackingController(0.60, 0.6, convex, inner_radius=3.0, shrinks=True)
    assert controller.next_batch().knob < 1.0 and not controller.shrinking  # the prior: convex hulls reach 0.60
    controller.layers.append((1.0, 2.0, 0.585, 0.9))  # short, but on course for the target at full compaction
    assert 0.9 < controller.next_batch().knob <= 1.0 and not controller.shrinking
    controller.layers.append((2.0, 3.0, 0.50, 1.0))  # full compaction short of the target: shells shrink
    assert 1.0 < controller.next_batch().knob <= 1.5 and controller.shrinking
    reached = PackingController(0.60, 0.6, convex, inner_radius=3.0, shrinks=True)
    reached.next_batch()
    reached.layers.append((1.0, 2.0, 0.598, 1.0))  # full compaction reaches it: never shrinks
    assert reached.next_batch().knob <= 1.0 and not reached.shrinking


def test_a_thin_noisy_layer_moves_the_knob_less_than_a_thick_one():
    """The measured ratio to the prior is shrunk toward 1 as by a pseudo-layer at the prior: one thin dense layer
    (the sand micro-CT's 2x finer variant: 0.639 at knob 1.63 against 0.583 swung the knob to 0.88) is not taken
    at its word."""
    knobs = {}
    for height in (0.3, 3.0):
        controller = PackingController(0.583, 0.6, [_star(0.7)] * 4, inner_radius=3.0, shrinks=True)
        first = controller.next_batch().knob
        controller.layers.append((1.0, 1.0 + height, 0.639, first))
        knobs[height] = controller.next_batch().knob
    assert knobs[3.0] < knobs[0.3] < first


def test_the_past_layers_are_made_up_over_the_bulk_still_to_come():
    """Early in a long pour a layer off target is made up over the layers to come, near its end in the next."""
    cube = trimesh.creation.box(extents=(1.0, 1.0, 1.0)).subdivide().subdivide()  # vertices in every surface column
    centres = np.array([(x, y, z + 0.5) for z in range(5) for y in range(-3, 4) for x in range(-3, 4)], float)
    identity = np.tile([1.0, 0, 0, 0], (len(centres), 1))
    knobs = {}
    for n_grains in (len(centres), 4 * len(centres)):  # the whole pour observed, or a quarter of it
        controller = PackingController(0.5, 0.6, [(cube.vertices, cube.faces)] * n_grains, inner_radius=3.0)
        controller.next_batch()
        controller.observe(np.arange(len(centres)), centres, identity)
        ((z0, z1, _, knob),) = controller.layers
        controller.layers[0] = (z0, z1, 0.47, knob)  # short of the target by 0.03 over 2 diameters
        knobs[n_grains] = controller.next_batch().knob
    # the pour's last layer makes up the whole 0.03 (2 diameters high, as the past); the quarter's is spread over the
    # 16 diameters of bulk its surface (5) says 4x the grains reach: the knobs' prior fractions differ by that ratio
    aimed = [controller.prior.fraction(knobs[n]) for n in (len(centres), 4 * len(centres))]
    assert aimed[0] / aimed[1] == pytest.approx((0.5 + 0.03) / (0.5 + 0.03 * 2 / 16), rel=1e-6)


def test_the_cheap_count_of_hull_hits_is_corrected_where_hulls_overlap():
    cube = trimesh.creation.box((2.0, 2.0, 2.0))  # two cubes of side 2, the second shifted by 1 along x
    vertices, faces = np.asarray(cube.vertices), np.asarray(cube.faces)
    hull = ConvexHull(vertices).equations
    grains = [(vertices, faces, hull, np.array([dx, 0.0, 0.0]), Rotation.identity(), 1.0,
               vertices + [dx, 0, 0], 1.0) for dx in (0.0, 1.0)]
    box = dict(half_sides=(2.0, 2.0))  # |x|, |y| < 2, |z| < 1: 32; the cubes' union 12, their sum 16
    exact = solid_fraction_of(grains, 3.0, -1.0, 1.0, 20_000, np.random.default_rng(0), **box)
    cheap = solid_fraction_of(grains, 3.0, -1.0, 1.0, 20_000, np.random.default_rng(0), n_exact=0, **box)
    corrected = solid_fraction_of(grains, 3.0, -1.0, 1.0, 20_000, np.random.default_rng(0), n_exact=4000, **box)
    assert exact == pytest.approx(12 / 32, abs=0.015) and cheap == pytest.approx(16 / 32, abs=0.015)
    assert corrected == pytest.approx(12 / 32, abs=0.015)


def test_the_bulk_of_an_interior_crop_is_measured_in_the_crop_s_footprint():
    cube = trimesh.creation.box((2.0, 2.0, 2.0))  # one grain filling the box |x|, |y|, |z| < 1
    vertices, faces = np.asarray(cube.vertices), np.asarray(cube.faces)
    hull = ConvexHull(vertices).equations
    grain = (vertices, faces, hull, np.zeros(3), Rotation.identity(), 1.0, vertices, 1.0)
    rng = np.random.default_rng(0)
    cylinder = solid_fraction_of([grain], 2.0, -1.0, 1.0, 20_000, rng)
    assert cylinder == pytest.approx(4.0 / (np.pi * 4.0), abs=0.01)  # the square's share of the disc
    assert solid_fraction_of([grain], 2.0, -1.0, 1.0, 2_000, rng, half_sides=(1.0, 1.0)) == 1.0
    wider = solid_fraction_of([grain], 2.0, -1.0, 1.0, 20_000, rng, half_sides=(1.0, 2.0))
    assert wider == pytest.approx(0.5, abs=0.01)
    # the crop's footprint: the box of the source's proportions inscribed in the bulk cylinder, at most the source
    assert crop_half_sides(5.0, (6.0, 8.0)) == pytest.approx((3.0, 4.0))
    assert crop_half_sides(2.5, (6.0, 8.0)) == pytest.approx((1.5, 2.0))
    assert crop_half_sides(10.0, (6.0, 8.0)) == pytest.approx((3.0, 4.0))


# the `large` sample's grains pack at about 0.60 under full compaction, below the scan's 0.617, and the
# prior says so (their hulls at 0.65, times their convexity 0.92): the shells shrink from the first batch;
# this checks that the crop gets the source's fraction with shrunk shells, in a short pour
def test_the_source_fraction_is_reached_in_an_interior_crop_past_full_compaction(large_library):
    config = PackConfig().replace(pour={"n_particles": 200, "batch_size": 40}, postprocess="none")
    pack = build_pack(large_library, config, seed=2, progress=False)
    checks = pack.placements.checks
    assert pack.manifest["view"]["view"] == "interior"
    target = large_library.statistics.solid_fraction
    assert checks.target_packing_fraction == pytest.approx(target) and checks.target_reached
    assert abs(float(np.mean(pack.labels > 0)) - target) <= TARGET_TOLERANCE  # in the crop, on the labels
    lo, hi = (np.array(pack.manifest["view"]["crop"][k]) for k in ("lo", "hi"))
    assert checks.packing_region["crop_half_sides"] == pytest.approx((hi[1:] - lo[1:]) / 2)  # measured where shown
    assert max(checks.compaction["knobs"]) > 1 and checks.compaction["max_shrink"] > 0  # shells shrunk
    assert checks.n_outside == 0 and checks.overlap_fraction < 0.005 and checks.max_grain_penetration_voxels < 2
