import dataclasses

import numpy as np
import pytest
import torch
from scipy import ndimage
from scipy.spatial.transform import Rotation

from synthpack.errors import SynthpackInputError
from synthpack.render import (
    Background,
    Grid,
    PartialVolume,
    PoreTextureConfig,
    ReconstructConfig,
    TorchRenderer,
    pose_maps,
    reconstruct,
    resolve_device,
    Surface,
)
from synthpack.render.partial_volume import FAR, PAD
from synthpack.measure import fit_edge_spread
from synthpack.source import SourceStatistics
from synthpack.measure.edges import edge_profile, signed_distance
from synthpack.measure.roughness import MIN_AREA, section_roughness


def _tight(volume):
    nonzero = np.nonzero(volume)
    return volume[tuple(slice(i.min(), i.max() + 1) for i in nonzero)]


@pytest.fixture
def particle():
    rng = np.random.default_rng(0)
    mask = np.zeros((7, 9, 11), dtype=bool)
    mask[1:6, 2:8, 3:9] = rng.random((5, 6, 6)) > 0.3
    tomogram = np.where(mask, rng.random(mask.shape), 0.1).astype(np.float32)
    return tomogram, mask


GRID = Grid((30, 30, 30), (0.0, 0.0, 0.0), (1.0, 1.0, 1.0))


#: Grains drawn from their voxel surface (no smoothing): what the voxels say, to the voxel.
VOXELS = Surface(0.0)


def _render(crops, index, rotations, positions, scales=None, grid=GRID, **kwargs):
    n = len(index)
    surface = kwargs.setdefault("surface", VOXELS)
    maps = pose_maps([c[1] for c in crops], np.asarray(index), np.asarray(rotations),
                     np.asarray(positions, dtype=float), np.ones(n) if scales is None else scales, grid,
                     reach=surface.reach(kwargs.get("partial_volume")))
    return reconstruct(crops, maps, grid, Background(0.1), **kwargs)


def test_identity_rotation_and_integer_translation_reproduce_the_voxels(particle):
    tomogram, mask = particle
    # crop centre (5, 4, 3) in (x, y, z) index units goes to world (15, 12, 10)
    out, labels, contested = _render([particle], [0], [np.eye(3)], [[15, 12, 10]])
    window = (slice(7, 14), slice(8, 17), slice(10, 21))
    np.testing.assert_array_equal(labels[window] == 1, mask)
    np.testing.assert_array_equal(out[window][mask], tomogram[mask])
    assert labels.sum() == mask.sum() and contested == 0
    assert np.all(out[labels == 0] == np.float32(0.1))


@pytest.mark.parametrize("quarter_turns", [1, 2, 3])
def test_quarter_turn_about_z_equals_rot90(particle, quarter_turns):
    tomogram, mask = particle
    rotation = Rotation.from_euler("z", 90 * quarter_turns, degrees=True).as_matrix()
    out, labels, _ = _render([particle], [0], [rotation], [[15, 12, 10]])
    # +90 degrees about z turns x into y: in (z, y, x) arrays that is rot90 from axis 2 to 1
    expected_mask = np.rot90(mask, k=quarter_turns, axes=(2, 1))
    np.testing.assert_array_equal(_tight(labels == 1), _tight(expected_mask))
    expected = np.rot90(np.where(mask, tomogram, 0), k=quarter_turns, axes=(2, 1))
    np.testing.assert_allclose(_tight(np.where(labels == 1, out, 0)), _tight(expected), atol=1e-6)


def test_chunking_does_not_change_the_result(large_library):
    rng = np.random.default_rng(1)
    crops = [(p.tomogram, p.mask) for p in large_library]
    n = 12
    index = rng.integers(0, len(crops), n)
    rotations = Rotation.random(n, random_state=2).as_matrix()
    positions = rng.uniform(-200, 200, size=(n, 3))
    grid = Grid.covering(400.0, -300.0, 300.0, large_library.voxel_size)
    background = Background(0.2, 0.05, 0.5)
    maps = pose_maps([c[1] for c in crops], index, rotations, positions, np.ones(n), grid)
    whole = reconstruct(crops, maps, grid, background, tube=(300.0, 330.0, -30.0), chunks=grid.shape, seed=4)
    for workers in (1, 2):
        chunked = reconstruct(crops, maps, grid, background, tube=(300.0, 330.0, -30.0), chunks=(13, 17, 29),
                              seed=4, workers=workers)
        np.testing.assert_array_equal(whole[0], chunked[0])
        np.testing.assert_array_equal(whole[1], chunked[1])
        assert whole[2] == chunked[2] > 0  # random positions overlap


def test_rotated_voxel_counts_within_2_percent(large_library):
    crops = [(p.tomogram, p.mask) for p in large_library]
    index = np.arange(0, len(crops), 4)
    n = len(index)
    rotations = Rotation.random(n, random_state=6).as_matrix()
    # far apart on a line, so no two particles touch
    positions = np.stack([np.zeros(n), np.zeros(n), 400.0 * np.arange(n)], axis=1)
    grid = Grid.covering(250.0, -250.0, 400.0 * n, large_library.voxel_size)
    maps = pose_maps([c[1] for c in crops], index, rotations, positions, np.ones(n), grid)
    _, labels, contested = reconstruct(crops, maps, grid, Background(0.2))
    counts = np.bincount(labels.ravel(), minlength=n + 1)[1:]
    source = np.array([crops[i][1].sum() for i in index])
    assert contested == 0
    np.testing.assert_allclose(counts, source, rtol=0.02)  # the smooth surface keeps each grain's volume


def _ellipsoid():
    zz, yy, xx = np.mgrid[:24, :30, :36]
    return ((zz - 11.5) / 10) ** 2 + ((yy - 14.5) / 12.5) ** 2 + ((xx - 17.5) / 15.5) ** 2 < 1


def test_oblique_sections_of_a_rendered_grain_are_as_smooth_as_its_own():
    # a digitised ellipsoid turned 30 degrees about x and 15 about y, sliced above its middle,
    # where the cut runs flat through its voxel terraces
    mask = _ellipsoid()
    own = np.median([section_roughness(section) for section in mask if section.sum() >= MIN_AREA])
    grid = Grid((48, 48, 48), (0.0, 0.0, 0.0), (1.0, 1.0, 1.0))
    rotation = Rotation.from_euler("xy", [30, 15], degrees=True).as_matrix()[None]
    maps = pose_maps([mask], np.array([0]), rotation, np.array([[24.0, 24.0, 24.0]]), np.ones(1), grid,
                     reach=Surface().reach())
    _, labels, _ = reconstruct([(mask.astype(np.float32), mask)], maps, grid, Background(0.0))
    # the voxels resampled: the mask interpolated linearly, at 0.5
    voxels = ndimage.affine_transform(np.pad(mask.astype(np.float32), 1), maps.matrix[0], offset=maps.offset[0] + 1,
                                      output_shape=grid.shape, order=1) > 0.5
    areas = np.count_nonzero(labels, axis=(1, 2))
    top = [z for z in range(int(np.argmax(areas)) + 1, 48) if MIN_AREA <= areas[z] <= 0.6 * areas.max()]
    smooth = np.median([section_roughness(labels[z] > 0) for z in top])
    stepped = np.median([section_roughness(voxels[z]) for z in top])
    assert len(top) >= 3
    assert abs(smooth - own) < 0.03 and stepped > smooth + 0.05
    assert np.count_nonzero(labels) == pytest.approx(mask.sum(), rel=0.02)


def test_the_smooth_surface_keeps_the_volume_and_stays_near_the_voxels(large_library):
    for particle in list(large_library)[::5]:
        mask = particle.mask
        distance = Surface().distance(mask)
        raw = signed_distance(np.pad(mask, PAD))
        assert not distance.flags.writeable and Surface().distance(mask) is distance  # prepared once
        assert np.all(distance[raw < 0] <= 0)  # never beyond the centres of the mask's outer neighbours
        assert np.count_nonzero(distance > 0) == pytest.approx(mask.sum(), rel=0.05)
        np.testing.assert_array_equal(VOXELS.distance(mask), raw)


def test_scale_changes_volume_by_its_cube(particle):
    big_mask = np.zeros((20, 20, 20), dtype=bool)
    zz, yy, xx = np.mgrid[:20, :20, :20]
    big_mask[(zz - 9.5) ** 2 + (yy - 9.5) ** 2 + (xx - 9.5) ** 2 < 64] = True
    crop = (big_mask.astype(np.float32), big_mask)
    grid = Grid((60, 60, 60), (0.0, 0.0, 0.0), (1.0, 1.0, 1.0))
    _, labels, _ = _render([crop], [0], [np.eye(3)], [[30, 30, 30]], scales=np.array([1.5]), grid=grid)
    assert labels.sum() == pytest.approx(big_mask.sum() * 1.5**3, rel=0.05)


def test_contested_voxels_go_to_the_deeper_grain_whatever_the_order():
    block = np.ones((6, 6, 6), dtype=bool)
    crop = (np.ones((6, 6, 6), dtype=np.float32), block)
    grid = Grid((20, 20, 20), (0.0, 0.0, 0.0), (1.0, 1.0, 1.0))
    # block A is grid-aligned on x = 6..11 (its last layer, x = 11, half a voxel deep); block B is
    # shifted by 0.3 voxel, so x = 11 is 0.2 voxel inside it and A must win it in either order
    positions = [[8.5, 8.5, 8.5], [13.8, 8.5, 8.5]]
    _, labels_ab, contested_ab = _render([crop], [0, 0], [np.eye(3)] * 2, positions, grid=grid)
    _, labels_ba, contested_ba = _render([crop], [0, 0], [np.eye(3)] * 2, positions[::-1], grid=grid)
    assert contested_ab == contested_ba == 36
    np.testing.assert_array_equal(labels_ab, np.where(labels_ba > 0, 3 - labels_ba, 0))
    assert np.all(labels_ab[6:12, 6:12, 11] == 1)
    # B on x = 9..14: away from the blocks' sides x = 9 is deeper in A, x = 11 in B, and on the
    # tie at x = 10 the earlier placement keeps it
    tie = [[8.5, 8.5, 8.5], [11.5, 8.5, 8.5]]
    for order in (1, -1):
        _, labels_tie, contested_tie = _render([crop], [0, 0], [np.eye(3)] * 2, tie[::order], grid=grid)
        first, second = (1, 2) if order == 1 else (2, 1)
        assert contested_tie == 3 * 36
        assert np.all(labels_tie[7:11, 7:11, 9] == first) and np.all(labels_tie[7:11, 7:11, 11] == second)
        assert np.all(labels_tie[6:12, 6:12, 10] == 1)


def test_background_texture_and_tube_wall():
    grid = Grid.covering(50.0, -10.0, 40.0, (1.0, 1.0, 1.0))
    crops, maps = [], pose_maps([], np.zeros(0, int), np.zeros((0, 3, 3)), np.zeros((0, 3)), np.zeros(0), grid)
    out, labels, _ = reconstruct(crops, maps, grid, Background(0.2, 0.03, 0.6), tube=(40.0, 45.0, -5.0))
    z, y, x = np.meshgrid(*(grid.origin[a] + np.arange(grid.shape[a]) for a in range(3)), indexing="ij")
    radius = np.hypot(x, y)
    pores = (radius < 38) & (z > 1)
    wall = (radius > 41) & (radius < 44) & (z > 1)
    assert out[pores].mean() == pytest.approx(0.2, abs=0.002)
    assert out[pores].std() == pytest.approx(0.03, rel=0.05)
    assert out[wall].mean() == pytest.approx(0.6, abs=0.005)
    assert not labels.any()
    # a source that shows the air around its container: flat air outside the wall and below the floor
    aired, _, _ = reconstruct(crops, maps, grid, Background(0.2, 0.03, 0.6, air=-0.4), tube=(40.0, 45.0, -5.0))
    outside = (radius > 45.5) | (z < -5.5)
    assert outside.any() and np.all(aired[outside] == np.float32(-0.4))
    inside = ~outside & (radius < 44.5) & (z > -4.5)
    np.testing.assert_array_equal(aired[inside], out[inside])


def test_bad_settings_are_rejected(particle):
    with pytest.raises(SynthpackInputError, match="order"):
        _render([particle], [0], [np.eye(3)], [[15, 12, 10]], order=2)
    with pytest.raises(SynthpackInputError, match="chunk"):
        _render([particle], [0], [np.eye(3)], [[15, 12, 10]], chunks=(0, 4, 4))


def _pore_texture_autocorrelation(texture: PoreTextureConfig) -> tuple[np.ndarray, float]:
    """The texture of an empty 64^3 grid (seed 3), and its correlation between neighbouring voxels along x."""
    grid = Grid((64, 64, 64), (0.0, 0.0, 0.0), (1.0, 1.0, 1.0))
    maps = pose_maps([], np.zeros(0, int), np.zeros((0, 3, 3)), np.zeros((0, 3)), np.zeros(0), grid)
    out, _, _ = reconstruct([], maps, grid, Background(0.0, 1.0, texture=texture), seed=3)
    return out, float(np.corrcoef(out[..., :-1].ravel(), out[..., 1:].ravel())[0, 1])


def test_pore_texture_settings_shape_the_texture():
    gaussian = PoreTextureConfig(model="gaussian", tile=64)
    default, correlation = _pore_texture_autocorrelation(gaussian)
    assert default.std() == pytest.approx(1.0, rel=1e-3)  # unit variance times the amplitude
    assert correlation == pytest.approx(np.exp(-1 / (4 * 0.8**2)), abs=0.05)  # Gaussian smoothing, sigma 0.8
    _, white = _pore_texture_autocorrelation(PoreTextureConfig(model="gaussian", sigma=0.0, tile=64))
    assert abs(white) < 0.02
    _, smoother = _pore_texture_autocorrelation(PoreTextureConfig(model="gaussian", sigma=2.0, tile=64))
    assert smoother > correlation
    short, _ = _pore_texture_autocorrelation(PoreTextureConfig(model="gaussian", tile=16))
    np.testing.assert_array_equal(short[:16, :16, :16], short[16:32, 32:48, 48:64])  # period 16
    assert not np.array_equal(default[:16, :16, :16], default[16:32, 32:48, 48:64])


def test_background_from_source_statistics():
    statistics = SourceStatistics(pore_mean=0.2, pore_std=0.03, grain_mean=0.7, noise_std=0.05)
    texture = PoreTextureConfig(sigma=1.2, tile=32)
    background = Background.from_source(statistics, ReconstructConfig(pore_texture=texture))
    assert background == Background(0.2, 0.03, 0.2 + 0.4 * 0.5, texture)  # no pore spectrum measured
    assert Background.from_source(statistics, ReconstructConfig(wall_intensity=0.9)).wall == 0.9
    assert Background.from_source(statistics, ReconstructConfig(wall=False)).wall is None
    walled = dataclasses.replace(statistics, wall_intensity=1.1, wall_thickness=2.5)
    assert Background.from_source(walled, ReconstructConfig()).wall == 1.1  # the source's measured wall
    assert Background.from_source(walled, ReconstructConfig(wall_intensity=0.9)).wall == 0.9  # the config wins
    assert Background.from_source(walled, ReconstructConfig()).air is None  # no air measured: pores go on outside
    aired = dataclasses.replace(walled, air_intensity=-0.3)
    assert Background.from_source(aired, ReconstructConfig()).air == -0.3
    assert Background.from_source(aired, ReconstructConfig(wall=False)).air is None  # no wall, no outside
    assert Background.from_source(walled, ReconstructConfig()).wall_radii(40.0, 43.0, 2.0) == (40.0, 45.0)
    assert background.wall_radii(40.0, 43.0, 2.0) == (40.0, 43.0)  # none measured: the tube's
    assert background.texture_record(seed=5) == {"model": "gaussian", "cutoff": 0.1, "rolloff": 0.1, "sigma": 1.2,
                                                 "tile": 32, "histogram": False, "amplitude": pytest.approx(0.03),
                                                 "period": 32, "seed": 5}
    measured = Background.from_source(
        dataclasses.replace(statistics, pore_spectrum=(1e-3, 5e-4, 1e-4), pore_quantiles=(-1.0, 0.0, 1.0)),
        ReconstructConfig())
    assert measured.pore_spectrum == (1e-3, 5e-4, 1e-4)
    assert measured.pore_quantiles == (-1.0, 0.0, 1.0)
    assert measured.texture_record(seed=5)["model"] == "measured"
    assert measured.texture_record(seed=5)["histogram"] is True


def _ball_scene(large_library, n=12):
    rng = np.random.default_rng(1)
    crops = [(p.tomogram, p.mask) for p in large_library]
    index = rng.integers(0, len(crops), n)
    rotations = Rotation.random(n, random_state=2).as_matrix()
    positions = rng.uniform(-200, 200, size=(n, 3))
    grid = Grid.covering(400.0, -300.0, 300.0, large_library.voxel_size)
    return crops, index, rotations, positions, grid


@pytest.mark.parametrize("shift", [0.0, 0.3, -0.4])
def test_partial_volume_keeps_the_labels_and_mixes_boundary_voxels(large_library, shift):
    crops, index, rotations, positions, grid = _ball_scene(large_library)
    background = Background(0.2, 0.05, 0.5)
    tube = (300.0, 330.0, -30.0)
    hard_maps = pose_maps([c[1] for c in crops], index, rotations, positions, np.ones(len(index)), grid)
    hard = reconstruct(crops, hard_maps, grid, background, tube=tube, seed=4)
    partial_volume = PartialVolume(shift=shift, rim=1.5)
    maps = pose_maps([c[1] for c in crops], index, rotations, positions, np.ones(len(index)), grid,
                     reach=Surface().reach(partial_volume))
    whole = reconstruct(crops, maps, grid, background, tube=tube, seed=4, chunks=grid.shape,
                        partial_volume=partial_volume)
    # labels and contested voxels are the hard render's, byte for byte
    np.testing.assert_array_equal(whole[1], hard[1])
    assert whole[2] == hard[2]
    # chunks and threads change nothing
    for workers in (1, 2):
        chunked = reconstruct(crops, maps, grid, background, tube=tube, seed=4, chunks=(13, 17, 29),
                              workers=workers, partial_volume=partial_volume)
        np.testing.assert_array_equal(chunked[0], whole[0])
        np.testing.assert_array_equal(chunked[1], whole[1])
    # boundary voxels mix grain and pore: the mean profile across the label boundary is
    # half-way at the shifted iso-surface, and the pore voxels next to a grain hold some of
    # it (in the hard render they are pore)
    distance = signed_distance(whole[1])
    profile = edge_profile(whole[0], distance)
    assert fit_edge_spread(profile).shift == pytest.approx(shift, abs=0.15)
    hard_profile = edge_profile(hard[0], distance)
    pore_side = profile.normalised[profile.distance == -0.5][0]
    assert abs(hard_profile.normalised[hard_profile.distance == -0.5][0]) < 0.05
    assert pore_side > 0.1 if shift <= 0 else pore_side > 0.0


def _reference_render(crops, maps, grid, pore, partial_volume, order):
    """The straightforward render: every grain's smooth surface resampled densely over its whole box, on one
    flat-pore volume."""
    tomogram = np.full(grid.shape, pore, dtype=np.float32)
    labels = np.zeros(grid.shape, dtype=np.int32)
    claim, occupancy, value = (np.zeros(grid.shape, dtype=np.float32) for _ in range(3))
    contested = 0
    for i, library_index in enumerate(maps.library_index):
        lo, hi = maps.box_lo[i], maps.box_hi[i]
        if np.any(hi <= lo):
            continue
        shape = tuple(int(n) for n in hi - lo)
        window = tuple(slice(a, b) for a, b in zip(lo, hi))
        crop, mask = crops[library_index]
        matrix = maps.matrix[i]
        offset = maps.offset[i] + matrix @ lo
        surface = Surface().distance(mask)
        scale = abs(np.linalg.det(matrix)) ** (-1.0 / 3.0)
        distance = ndimage.affine_transform(surface, matrix, offset=offset + PAD, output_shape=shape, order=1,
                                            mode="constant", cval=FAR) * np.float32(scale)
        inside = distance > 0
        region = claim[window]
        contested += int(np.count_nonzero(inside & (region > 0)))
        wins = inside & (distance > region)
        labels[window][wins] = i + 1
        region[wins] = distance[wins]
        if partial_volume is None:
            values = ndimage.affine_transform(crop, matrix, offset=offset, output_shape=shape, order=order,
                                              mode="nearest")
            tomogram[window][wins] = values[wins]
            continue
        intensity = partial_volume.prepare(crop, surface)
        grain = partial_volume.occupancy(distance)
        occupancy[window] += grain
        value[window] += grain * ndimage.affine_transform(intensity, matrix, offset=offset + PAD,
                                                          output_shape=shape, order=order, mode="nearest")
    if partial_volume is not None:
        tomogram = (1.0 - np.minimum(occupancy, 1.0)) * tomogram + value / np.maximum(occupancy, 1.0)
    return tomogram, labels, contested


def _mixed_scene(large_library, shift, n, seed):
    """Few library grains, each placed several times at scales 0.7-1.8, some overlapping; the partial volume."""
    rng = np.random.default_rng(seed)
    crops, _, rotations, positions, grid = _ball_scene(large_library, n=n)
    index = rng.integers(0, 4, len(rotations))
    scales = rng.uniform(0.7, 1.8, len(rotations))
    partial_volume = None if shift is None else PartialVolume(shift=shift, rim=1.5)
    maps = pose_maps([c[1] for c in crops], index, rotations, positions, scales, grid,
                     reach=Surface().reach(partial_volume))
    return crops, maps, grid, partial_volume


@pytest.mark.parametrize("shift, order", [(None, 1), (None, 3), (0.0, 1), (-0.4, 1), (0.3, 3)])
def test_render_equals_a_dense_reference_render(large_library, shift, order):
    # the render interpolates only the voxels near each grain; the reference every voxel of its box.
    # Few library grains, each placed several times at different scales, some overlapping.
    crops, maps, grid, partial_volume = _mixed_scene(large_library, shift, n=16, seed=7)
    tomogram, labels, contested = reconstruct(crops, maps, grid, Background(0.2), order=order, chunks=(13, 40, 37),
                                              partial_volume=partial_volume)
    reference = _reference_render(crops, maps, grid, 0.2, partial_volume, order)
    assert contested == reference[2] > 0
    np.testing.assert_array_equal(labels, reference[1])
    assert len(np.unique(labels)) > 10
    np.testing.assert_allclose(tomogram, reference[0], rtol=0, atol=1e-5)


@pytest.mark.parametrize("device", ["cpu", pytest.param("cuda", marks=pytest.mark.skipif(
    not torch.cuda.is_available(), reason="no CUDA GPU"))])
@pytest.mark.parametrize("shift", [None, -0.4])
def test_the_torch_render_equals_the_numpy_render(large_library, shift, device):
    """The GPU path's arithmetic (run on the CPU without a GPU): labels equal, intensities within 1e-5."""
    crops, maps, grid, partial_volume = _mixed_scene(large_library, shift, n=10, seed=11)
    background = Background(0.2, 0.05, 0.5)  # pore texture and a wall
    arguments = dict(tube=(300.0, 330.0, -30.0), chunks=(13, 40, 37), partial_volume=partial_volume, seed=3)
    tomogram, labels, contested = reconstruct(crops, maps, grid, background, **arguments)
    renderer = TorchRenderer(device)
    on_device = reconstruct(crops, maps, grid, background, renderer=renderer, workers=1, **arguments)
    assert renderer.near_threshold < max(1, labels.size // 100_000)
    mismatch = np.count_nonzero(on_device[1] != labels)
    assert mismatch <= renderer.near_threshold and on_device[2] == contested > 0
    assert len(np.unique(labels)) > 10
    np.testing.assert_allclose(on_device[0], tomogram, rtol=0, atol=1e-5)


def test_a_gpu_device_without_a_gpu_is_an_input_error():
    assert resolve_device("cpu") is None
    assert resolve_device("auto", order=3) is None
    if not torch.cuda.is_available():
        assert resolve_device("auto") is None
        with pytest.raises(SynthpackInputError, match="torch sees no CUDA GPU here; use auto or cpu"):
            resolve_device("cuda")


def test_prepared_crop_replaces_the_rim_by_the_interior():
    mask = np.zeros((12, 12, 12), dtype=bool)
    mask[2:10, 2:10, 2:10] = True
    tomogram = np.where(mask, 0.8, 0.2).astype(np.float32)
    tomogram[mask & ~ndimage.binary_erosion(mask)] = 0.5  # a darkened (blurred) rim
    distance = VOXELS.distance(mask)
    assert distance[PAD + 2, PAD + 5, PAD + 5] == 0.5 and distance[PAD + 1, PAD + 5, PAD + 5] == -0.5
    intensity = PartialVolume(shift=0.0, rim=1.0).prepare(tomogram, distance)
    assert intensity.shape == distance.shape == tuple(n + 2 * PAD for n in mask.shape)
    np.testing.assert_array_equal(intensity, np.float32(0.8))  # rim and outside: the interior
    distance = np.array([-1.0, -0.5, 0.0, 0.25, 0.5, 1.0], dtype=np.float32)
    occupancy = PartialVolume(shift=0.25).occupancy(distance)
    assert occupancy.dtype == np.float32
    np.testing.assert_allclose(occupancy, [0, 0, 0.25, 0.5, 0.75, 1])
    # the torch render's occupancy is the same formula, to the bit
    on_torch = PartialVolume(shift=0.25).occupancy(torch.from_numpy(distance))
    assert on_torch.dtype == torch.float32 and on_torch.numpy().tobytes() == occupancy.tobytes()


def test_partial_volume_from_source_statistics():
    statistics = SourceStatistics(0.2, 0.01, 0.8, 0.02, edge_width=2.0, edge_shift=-0.1, edge_sigma=0.9)
    fitted = ReconstructConfig().partial_volume_of(statistics)
    assert fitted.shift == -0.1 and fitted.rim == pytest.approx(-0.1 + 1.645 * 0.9)
    assert ReconstructConfig(edge_shift=0.2, rim=2.0).partial_volume_of(statistics) == PartialVolume(0.2, 2.0)
    assert ReconstructConfig(partial_volume=False).partial_volume_of(statistics) is None
    assert PartialVolume.from_source(SourceStatistics(0.2, 0.01, 0.8, 0.02)) == PartialVolume(0.0, 1.0)
