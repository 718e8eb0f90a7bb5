import copy
import dataclasses
import json
import logging

import numpy as np
import pytest

import synthpack.store.pack as pack_module
from synthpack.pipeline.config import PackConfig
from synthpack.errors import PackBuildError, SynthpackInputError
from synthpack.pipeline.generate import build_pack, generate_packs, pack_seed
from synthpack.physics.config import DEFAULT_GRAINS
from synthpack.pipeline.view import resolve_pack, resolve_view
from synthpack.physics.container import interior_radius
from synthpack.realism import Specimen
from synthpack.store.pack import is_complete_pack, open_pack
from synthpack.render.pore_texture import PoreTextureConfig
from synthpack.render.kernel import resolve_kernel
from synthpack.render.torch_render import resolve_device

SMALL = PackConfig().replace(pour={"n_particles": 24, "batch_size": 12})


@pytest.fixture(scope="module")
def small_pack(large_library):
    return build_pack(large_library, SMALL, seed=11, progress=False)


def test_labels_are_consecutive_and_map_to_placements(small_pack):
    present = np.unique(small_pack.labels)
    np.testing.assert_array_equal(present, np.arange(len(small_pack.placements) + 1))
    assert small_pack.manifest["n_labels"] == len(small_pack.placements)


def test_voxel_counts_match_the_source_particles(small_pack, large_library):
    counts = np.bincount(small_pack.labels.ravel())[1:]
    source = np.array([large_library[int(i)].voxel_count for i in small_pack.placements.indices])
    expected = source * small_pack.placements.scales**3
    np.testing.assert_allclose(counts, expected, rtol=0.03)


def test_pack_sits_in_the_tube_with_wall_and_noise(small_pack, large_library):
    clean, tomogram, labels = small_pack.clean, small_pack.tomogram, small_pack.labels
    grains = labels > 0
    pore, contrast = large_library.statistics.pore_mean, large_library.statistics.contrast
    assert np.median(clean[grains]) > pore + 0.5 * contrast
    assert not np.array_equal(clean, tomogram)  # post-processing applied
    assert small_pack.manifest["postprocessing"]  # and recorded
    # the tube wall is brighter than the pores in the clean volume, at the outer radius
    tube = small_pack.placements.tube
    grid = small_pack.grid
    z0 = labels.shape[0] // 2
    y = grid.origin[1] + np.arange(labels.shape[1]) * grid.voxel_size[1]
    x = grid.origin[2] + np.arange(labels.shape[2]) * grid.voxel_size[2]
    radius = np.hypot(*np.meshgrid(y, x, indexing="ij"))
    wall = (radius > tube.inner_radius + 5) & (radius < tube.outer_radius - 5)
    assert clean[z0][wall].mean() > pore + 0.2 * contrast


def test_pore_texture_is_configured_and_recorded(small_pack, large_library):
    assert small_pack.manifest["config"]["reconstruct"]["pore_texture"] == dataclasses.asdict(PoreTextureConfig())
    statistics = large_library.statistics
    shape = small_pack.labels.shape
    period = PoreTextureConfig().period(shape)
    assert max(shape) <= period < 2 * max(shape)  # the texture does not repeat within the pack
    assert small_pack.manifest["pore_texture"] == {
        "model": "measured", "cutoff": 0.1, "rolloff": 0.1, "sigma": 0.8, "tile": 256, "histogram": True, "seed": 11,
        "period": period,
        "amplitude": pytest.approx(float(np.sqrt(PoreTextureConfig().density(statistics.pore_std,
                                                                       statistics.pore_spectrum, shape).mean())))}
    smoother = build_pack(large_library, SMALL.replace(reconstruct={"pore_texture": {"cutoff": 0.05}}), seed=11,
                          progress=False)
    assert smoother.manifest["pore_texture"]["cutoff"] == 0.05
    np.testing.assert_array_equal(smoother.labels, small_pack.labels)
    pores = small_pack.labels == 0
    assert not np.array_equal(smoother.clean[pores], small_pack.clean[pores])


def test_same_seed_same_pack(small_pack, large_library):
    again = build_pack(large_library, SMALL, seed=11, progress=False)
    np.testing.assert_array_equal(again.labels, small_pack.labels)
    np.testing.assert_array_equal(again.tomogram, small_pack.tomogram)


def test_generate_writes_complete_packs_and_skips_them_on_rerun(large_library, tmp_path):
    config = SMALL.replace(pour={"n_particles": 10, "batch_size": 10})
    (path,) = generate_packs(large_library, tmp_path, 1, config, progress=False)
    assert is_complete_pack(path)
    names = sorted(p.name for p in path.iterdir())
    assert names == [".synthpack-files", "clean.tif", "labels.tif", "manifest.json", "placements.json", "tomogram.tif"]
    manifest = json.loads((path / "manifest.json").read_text())
    assert manifest["seed"] == pack_seed(config.seed, 0)
    assert manifest["config"]["pour"]["n_particles"] == 10
    assert {"pour", "reconstruct", "postprocess"} <= set(manifest["timings"])
    assert "numpy" in manifest["versions"] and "contested_voxels" in manifest
    on = resolve_device(config.run.device) or "cpu"  # "cpu": NumPy
    kernel = resolve_kernel("auto") if on == "cpu" else None  # the compiled kernel, where numba is installed
    assert manifest["devices"] == {"render": on, "render_kernel": kernel, "postprocess": on}
    pack = open_pack(path)
    assert isinstance(pack.labels, np.memmap)
    assert pack.voxel_size == large_library.voxel_size
    before = (path / "tomogram.tif").stat().st_mtime_ns
    generate_packs(large_library, tmp_path, 1, config, progress=False)
    assert (path / "tomogram.tif").stat().st_mtime_ns == before


def test_interrupted_write_leaves_no_complete_looking_pack(large_library, tmp_path, monkeypatch):
    config = SMALL.replace(pour={"n_particles": 6, "batch_size": 6})
    real_write_tiff = pack_module.write_tiff

    def failing_write_tiff(path, volume, *args, **kwargs):
        if path.name == "labels.tif":
            raise OSError("disk full")
        return real_write_tiff(path, volume, *args, **kwargs)

    monkeypatch.setattr(pack_module, "write_tiff", failing_write_tiff)
    with pytest.raises(PackBuildError, match="pack_0000: OSError: disk full"):
        generate_packs(large_library, tmp_path, 1, config, progress=False)
    assert list(tmp_path.iterdir()) == []
    assert not is_complete_pack(tmp_path / "pack_0000")


def test_zarr_packs_open_lazily(large_library, tmp_path):
    config = SMALL.replace(pour={"n_particles": 6, "batch_size": 6}, postprocess="none")
    (path,) = generate_packs(large_library, tmp_path, 1, config, format="zarr", progress=False)
    pack = open_pack(path)
    assert pack.manifest["format"] == "zarr"
    middle = pack.labels.shape[0] // 2
    np.testing.assert_array_equal(pack.tomogram[middle], pack.clean[middle])  # no post-processing
    assert pack.labels[middle].max() >= 1


INTERIOR = PackConfig().replace(seed=2, pour={"batch_size": 50, "target_solid_fraction": None})  # n_particles: auto


@pytest.fixture(scope="module")
def interior_pack(large_library, tmp_path_factory):
    """A pack of the `large` sample (an interior crop, no wall) as the default view and grain count make it: a crop,
    no tube."""
    (path,) = generate_packs(large_library, tmp_path_factory.mktemp("interior"), 1, INTERIOR, progress=False)
    return path


def test_an_interior_crop_is_full_of_grains_to_its_edges_with_no_wall_or_air(interior_pack, large_library):
    pack = open_pack(interior_pack)
    manifest = pack.manifest
    assert manifest["view"]["view"] == "interior" and manifest["view"]["requested"] == "auto"
    assert manifest["config"]["pour"]["n_particles"] == "auto"  # as asked: the same config makes the same pack
    assert manifest["n_particles"] == INTERIOR.pour.crop_grains(large_library) > DEFAULT_GRAINS  # as many as a crop needs
    assert manifest["wall"] is None
    lo, hi = (np.array(manifest["view"]["crop"][k]) for k in ("lo", "hi"))
    assert np.allclose((hi - lo) / pack.voxel_size, np.array(pack.shape) - 1, atol=1)  # the grid is the crop
    container = manifest["view"]["container"]
    assert hi[1] ** 2 + hi[2] ** 2 < container["inner_radius"] ** 2  # inside the tube, off its wall
    grains = np.asarray(pack.labels[:]) > 0
    bulk = grains.mean()
    assert abs(bulk - manifest["pour_checks"]["packing_fraction"]) < 0.05
    for axis in range(3):  # every slice, along every axis, holds about the bulk's fraction of grain
        slices = grains.mean(axis=tuple(a for a in range(3) if a != axis))
        assert slices.min() > 0.6 * bulk, axis
    quarter = np.array(grains.shape[1:]) // 4
    for corner in (grains[:, :quarter[0], :quarter[1]], grains[:, -quarter[0]:, -quarter[1]:],
                   grains[:, :quarter[0], -quarter[1]:], grains[:, -quarter[0]:, :quarter[1]]):
        assert corner.mean() > 0.6 * bulk  # no empty corners: a tube's are air
    assert manifest["postprocess_mode"] == "calibrated"  # fitted in the crop, all of it bulk
    in_view = np.unique(np.asarray(pack.labels[:]))  # counted as the render wrote the chunks: the grains cut away
    assert manifest["n_labels"] == len(in_view) - 1 < manifest["n_particles"]  # by the crop are not
    specimen = Specimen.from_pack(interior_pack)
    assert specimen.region.all()


def test_a_source_with_a_container_keeps_the_tube_and_few_grains_fall_back_to_it(large_library, caplog):
    walled = dataclasses.replace(large_library.statistics, wall_intensity=0.5, wall_thickness=3.0, wall_gap=1.0)
    library = copy.copy(large_library)
    library.statistics = walled
    assert resolve_view(library, INTERIOR) == "tube"  # a container in view: the tube with its wall
    assert resolve_view(large_library, INTERIOR) == "interior"
    few = SMALL.replace(pour={"n_particles": 23})  # a count no other test pours: its warning is not yet given
    with caplog.at_level(logging.DEBUG, logger="synthpack.pipeline.view"):
        assert resolve_view(large_library, few) == "tube"  # 23 grains hold no crop
    assert "23 grains are too few" in caplog.text and "pour at least" in caplog.text
    needed = few.pour.crop_grains(large_library)  # the one line shown says how many a crop needs
    (line,) = [r.getMessage() for r in caplog.records if r.levelno == logging.INFO]
    assert line.startswith("view auto: the tube: 23 grains are too few") and f"({needed} or more" in line
    assert resolve_view(large_library, few.replace(pour={"n_particles": needed})) == "interior"
    with pytest.raises(SynthpackInputError, match=r"too few for an interior crop.*pour at least \d+"):
        resolve_view(large_library, SMALL.replace(reconstruct={"view": "interior"}))
    assert resolve_view(large_library, INTERIOR.replace(reconstruct={"view": "tube"})) == "tube"
    narrow = INTERIOR.replace(pour={"tube_radius": 400.0})  # a given tube too narrow for a crop: the tube, before the pour
    assert resolve_view(large_library, narrow) == "tube"
    with pytest.raises(SynthpackInputError, match=r"tube of radius 400 .*holds no interior crop"):
        resolve_view(large_library, narrow.replace(reconstruct={"view": "interior"}))
    wide = interior_radius(large_library, 200)
    assert resolve_view(large_library, INTERIOR.replace(pour={"tube_radius": wide})) == "interior"


def test_the_default_grain_count_is_a_tubes_or_as_many_as_an_interior_crop_needs(large_library):
    needed = INTERIOR.pour.crop_grains(large_library)
    assert needed > DEFAULT_GRAINS  # the built-in sample's grains need more than a tube's count
    config, view = resolve_pack(large_library, INTERIOR)  # n_particles: auto, a crop-like source
    assert (view, config.pour.n_particles) == ("interior", needed)
    assert config.replace(pour={"n_particles": "auto"}) == INTERIOR  # nothing else resolved
    walled = copy.copy(large_library)
    walled.statistics = dataclasses.replace(large_library.statistics, wall_intensity=0.5, wall_thickness=3.0,
                                            wall_gap=1.0)
    assert resolve_pack(walled, INTERIOR)[0].pour.n_particles == DEFAULT_GRAINS  # a container in view: the tube's
    tube = INTERIOR.replace(reconstruct={"view": "tube"})
    assert resolve_pack(large_library, tube)[0].pour.n_particles == DEFAULT_GRAINS
    given = INTERIOR.replace(pour={"n_particles": needed + 7})
    assert resolve_pack(large_library, given) == (given, "interior")  # a given count is kept
    assert INTERIOR.pour.tube(large_library, interior=True) == config.pour.tube(large_library, interior=True)


def test_a_tube_pack_records_its_view(small_pack):
    view = small_pack.manifest["view"]
    assert view["view"] == "tube" and view["crop"] is None
    assert view["container"] == small_pack.placements.tube.to_dict()
