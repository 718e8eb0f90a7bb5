"""The render while pouring (issue 28): the same pack voxel for voxel, and only the chunks drawn as final are kept."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from synthpack.errors import SynthpackInputError
from synthpack.physics import Placements, pour
from synthpack.physics.placements import rotation_matrices
from synthpack.pipeline.config import PackConfig
from synthpack.pipeline import generate
from synthpack.pipeline.generate import generate_packs, pack_seed
from synthpack.pipeline.pour_process import pour_in_process
from synthpack.render import Background, Grid, pose_maps, reconstruct
from synthpack.render.streamed import LockedRender
from synthpack.store.pack import open_pack
from synthpack.store.zarr_pack import LevelledVolume, create_levelled_volume

# a tall pour (5 batches) in thin rows of chunks, so that most rows are buried before the pour ends (a row's
# one chunk covers the tube's width: small Zarr chunks cost more to write than to draw); a pore texture period
# that no pack height changes (the render while pouring needs one)
CHUNKS = (16, 80, 80)
TALL = PackConfig().replace(
    pour={"n_particles": 60, "batch_size": 12, "tube_radius": 300, "target_solid_fraction": None}, postprocess="none",
    reconstruct={"view": "tube", "pore_texture": {"tile": 64}}, run={"chunks": list(CHUNKS), "threads": 2},
)


@pytest.fixture(scope="module")
def while_pouring(large_library, tmp_path_factory):
    """A Zarr pack rendered while it was poured."""
    (path,) = generate_packs(large_library, tmp_path_factory.mktemp("overlap"), 1, TALL.replace(run={"overlap": "on"}),
                             format="zarr", progress=False)
    return open_pack(path)


@pytest.fixture(scope="module")
def placements(while_pouring) -> Placements:
    return Placements.load(while_pouring.path / "placements.json")


@pytest.fixture(scope="module")
def after_pour(large_library, placements):
    """The same placements rendered after the pour, in memory, as a pack with ``run.overlap: off`` is."""
    config = TALL.replace(run={"overlap": "off"})
    return generate._render(large_library, placements, config, "tube", pack_seed(TALL.seed, 0),
                            tuple(config.run.chunks), 2, generate._numpy_volume, None, None)


def test_a_zarr_pack_rendered_while_pouring_is_the_pack_rendered_after_it(while_pouring, after_pour):
    pack = while_pouring
    overlap = pack.manifest["overlap"]
    assert overlap["chunks_while_pouring"] >= 12 and overlap["drawn_again"] == 0
    assert pack.manifest["timings"]["render_while_pouring"] > 0
    assert after_pour.overlap is None and pack.manifest["shape"] == list(after_pour.grid.shape)
    np.testing.assert_array_equal(np.asarray(pack.clean[:]), after_pour.clean)
    np.testing.assert_array_equal(np.asarray(pack.labels[:]), after_pour.labels)
    np.testing.assert_array_equal(np.asarray(pack.tomogram[:]), after_pour.clean)  # postprocess: none
    assert pack.manifest["contested_voxels"] == after_pour.contested
    assert pack.manifest["n_labels"] == int(np.count_nonzero(after_pour.present[1:]))


def _locked_render(library, grid: Grid, out) -> LockedRender:
    config = TALL.reconstruct
    background = dataclasses.replace(Background.from_source(library.statistics, config), extent=grid.shape)
    return LockedRender([(p.tomogram, p.mask) for p in library], grid, background, out,
                        n_placed=TALL.pour.n_particles, tube=None, order=config.order, seed=pack_seed(TALL.seed, 0),
                        chunks=CHUNKS, partial_volume=None,
                        surface=config.surface, kernel="auto", reach=config.surface.reach(None), workers=1)


def test_a_chunk_reached_otherwise_after_the_pour_is_drawn_again(large_library, placements, after_pour):
    shape = after_pour.grid.shape
    grid = dataclasses.replace(after_pour.grid, shape=(shape[0] + 40, *shape[1:]))  # deeper than the pack, as the tube
    out = (np.zeros(grid.shape, np.float32), np.zeros(grid.shape, np.int32))
    rotations = placements.rotation_matrices()
    with _locked_render(large_library, grid, out) as early:
        for number in range(int(placements.batches.max()) + 1):
            members = np.flatnonzero(placements.batches == number)
            early.add(number, members, placements.indices[members], rotations[members], placements.positions[members],
                      placements.scales[members])
        final = pose_maps([p.mask for p in large_library], placements.indices, rotations, placements.positions,
                          placements.scales, after_pour.grid, reach=TALL.reconstruct.surface.reach(None))
        done, _, redrawn = early.finish(final, shape)
        assert len(done) >= 12 and redrawn == 0
        moved = 0  # a grain of the first batch, in chunks drawn early
        nudged = dataclasses.replace(final, offset=final.offset.copy())
        nudged.offset[moved] += 1e-9
        kept, _, again = early.finish(nudged, shape)
    reached = {lo for lo in done if np.all((final.box_lo[moved] < np.minimum(np.array(lo) + CHUNKS, shape))
                                           & (final.box_hi[moved] > np.array(lo)))}
    assert reached and again == len(reached) and kept == done - reached
    # the chunks kept hold the render after the pour's voxels
    for lo in kept:
        window = tuple(slice(a, min(a + c, n)) for a, c, n in zip(lo, CHUNKS, shape))
        np.testing.assert_array_equal(out[1][window], after_pour.labels[window])


def test_rotation_matrices_are_the_placements(placements):
    np.testing.assert_array_equal(rotation_matrices(placements.quaternions), placements.rotation_matrices())


def test_the_pour_process_raises_the_pour_s_error_here(large_library):
    with pytest.raises(SynthpackInputError, match="config must be a PourConfig"):
        pour_in_process(pour, lambda grains: None, library=large_library, config="not a config", seed=0)


def test_a_levelled_volume_resized_keeps_its_blocks_and_its_level_one(tmp_path):
    rng = np.random.default_rng(0)
    values = rng.random((150, 128, 128), dtype=np.float32)
    layout = dict(chunks=(1, 64, 64), shards=(64, 64, 64))
    deep = create_levelled_volume(tmp_path / "a", "tomogram", (256, 128, 128), np.float32, (1.0,) * 3, "um", **layout)
    made = create_levelled_volume(tmp_path / "b", "tomogram", (150, 128, 128), np.float32, (1.0,) * 3, "um", **layout)
    assert isinstance(deep, LevelledVolume) and isinstance(made, LevelledVolume)
    deep[0:128, :, :] = values[:128]
    deep.resize((150, 128, 128))
    deep[128:150, :, :] = values[128:]
    made[0:128, :, :] = values[:128]
    made[128:150, :, :] = values[128:]
    assert deep.shape == made.shape and deep.level_one and made.level_one
    np.testing.assert_array_equal(deep[:], made[:])
    np.testing.assert_array_equal(deep.half[:], made.half[:])
    assert deep.half.shards == made.half.shards
    # a depth with no level 1: dropped, for the levels to build from level 0
    shallow = create_levelled_volume(tmp_path / "c", "labels", (256, 128, 128), np.int32, (1.0,) * 3, "um", **layout)
    shallow.resize((100, 128, 128))
    assert not shallow.level_one and not (tmp_path / "c" / "labels" / "instances" / "1").exists()
    assert shallow.shape == (100, 128, 128)


def test_reconstruct_skips_the_chunks_done(large_library, placements, after_pour):
    maps = pose_maps([p.mask for p in large_library], placements.indices, placements.rotation_matrices(),
                     placements.positions, placements.scales, after_pour.grid)
    background = Background.from_source(large_library.statistics, TALL.reconstruct)
    out = (np.full(after_pour.grid.shape, -1, np.float32), np.full(after_pour.grid.shape, -1, np.int32))
    reconstruct([(p.tomogram, p.mask) for p in large_library], maps, after_pour.grid, background, chunks=CHUNKS,
                out=out, done={(0, 0, 0)}, workers=1)
    assert np.all(out[1][:16] == -1) and np.all(out[1][16:] >= 0)  # the first row is one chunk
