"""The render while pouring (issue 28): the same pack voxel for voxel, and only the chunks drawn as final are kept."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from synthpack.errors import SynthpackInputError
from synthpack.physics import pour
from synthpack.physics.placements import rotation_matrices
from synthpack.pipeline.config import PackConfig
from synthpack.pipeline.generate import build_pack, generate_packs, pack_seed
from synthpack.pipeline.pour_process import pour_in_process
from synthpack.render import Background, Grid, pose_maps, reconstruct
from synthpack.render.streamed import LockedRender
from synthpack.store.pack import open_pack
from synthpack.store.zarr_pack import LevelledVolume, create_levelled_volume

# a tall pour (6 batches) in small chunks, so that most rows of chunks are buried before the pour ends; a pore
# texture period that no pack height changes (the render while pouring needs one)
TALL = PackConfig().replace(
    pour={"n_particles": 60, "batch_size": 12, "tube_radius": 300, "target_solid_fraction": None}, postprocess="none",
    reconstruct={"view": "tube", "pore_texture": {"tile": 64}}, run={"chunks": [16, 48, 48], "threads": 2},
)


@pytest.fixture(scope="module")
def after_pour(large_library):
    """The pack rendered after its pour, in memory."""
    return build_pack(large_library, TALL.replace(run={"overlap": "off"}), seed=pack_seed(TALL.seed, 0), progress=False)


def test_a_zarr_pack_rendered_while_pouring_is_the_pack_rendered_after_it(large_library, after_pour, tmp_path):
    (path,) = generate_packs(large_library, tmp_path, 1, TALL.replace(run={"overlap": "on"}), format="zarr",
                             progress=False)
    pack = open_pack(path)
    overlap = pack.manifest["overlap"]
    assert overlap["chunks_while_pouring"] >= 20 and overlap["drawn_again"] == 0
    assert after_pour.manifest["overlap"] is None
    assert pack.manifest["seed"] == after_pour.manifest["seed"]
    for name in ("clean", "labels", "tomogram"):
        np.testing.assert_array_equal(np.asarray(getattr(pack, name)[:]), getattr(after_pour, name), err_msg=name)
    for key in ("contested_voxels", "n_labels", "shape"):
        assert pack.manifest[key] == after_pour.manifest[key]
    assert pack.manifest["timings"]["render_while_pouring"] > 0


def _locked_render(library, grid: Grid, out) -> LockedRender:
    config = TALL.reconstruct
    background = dataclasses.replace(Background.from_source(library.statistics, config), extent=grid.shape)
    return LockedRender([(p.tomogram, p.mask) for p in library], grid, background, out,
                        n_placed=TALL.pour.n_particles, tube=None, order=config.order, seed=pack_seed(TALL.seed, 0), chunks=(16, 48, 48), partial_volume=None,
                        surface=config.surface, kernel="auto", reach=config.surface.reach(None), workers=1)


def test_a_chunk_reached_otherwise_after_the_pour_is_drawn_again(large_library, after_pour):
    placements = after_pour.placements
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
        assert len(done) >= 20 and redrawn == 0
        moved = 0  # a grain of the first batch, in chunks drawn early
        nudged = dataclasses.replace(final, offset=final.offset.copy())
        nudged.offset[moved] += 1e-9
        kept, _, again = early.finish(nudged, shape)
    reached = {lo for lo in done if np.all((final.box_lo[moved] < np.minimum(np.array(lo) + (16, 48, 48), shape))
                                           & (final.box_hi[moved] > np.array(lo)))}
    assert reached and again == len(reached) and kept == done - reached
    # the chunks kept hold the render after the pour's voxels
    for lo in kept:
        window = tuple(slice(a, min(a + c, n)) for a, c, n in zip(lo, (16, 48, 48), shape))
        np.testing.assert_array_equal(out[1][window], after_pour.labels[window])


def test_rotation_matrices_are_the_placements(after_pour):
    placements = after_pour.placements
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


def test_reconstruct_skips_the_chunks_done(large_library, after_pour):
    placements = after_pour.placements
    maps = pose_maps([p.mask for p in large_library], placements.indices, placements.rotation_matrices(),
                     placements.positions, placements.scales, after_pour.grid)
    background = Background.from_source(large_library.statistics, TALL.reconstruct)
    out = (np.full(after_pour.grid.shape, -1, np.float32), np.full(after_pour.grid.shape, -1, np.int32))
    reconstruct([(p.tomogram, p.mask) for p in large_library], maps, after_pour.grid, background, chunks=(16, 48, 48),
                out=out, done={(0, 0, 0)}, workers=1)
    assert np.all(out[1][:16, :48, :48] == -1) and np.all(out[1][16:] >= 0)
