"""The compiled render kernel (`synthpack.render.kernel`) draws what the SciPy render draws."""

import functools
import logging

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from synthpack.cli import main
from synthpack.render import Background, Grid, PartialVolume, Surface, pose_maps, reconstruct, resolve_kernel
from synthpack.render.numpy_render import render_chunk
from synthpack.store.pack import open_pack

logger = logging.getLogger(__name__)


def _scene(library, shift, n=14, seed=5):
    """`n` rotated placements of 4 library grains at scales 0.7-1.8, some overlapping, and their partial volume."""
    rng = np.random.default_rng(seed)
    crops = [(p.tomogram, p.mask) for p in library]
    rotations = Rotation.random(n, random_state=seed).as_matrix()
    positions = rng.uniform(-200, 200, size=(n, 3))
    grid = Grid.covering(400.0, -300.0, 300.0, library.voxel_size)
    partial_volume = None if shift is None else PartialVolume(shift=shift, rim=1.5)
    maps = pose_maps([c[1] for c in crops], rng.integers(0, 4, n), rotations, positions, rng.uniform(0.7, 1.8, n),
                     grid, reach=Surface().reach(partial_volume))
    return crops, maps, grid, partial_volume


def test_auto_is_the_compiled_kernel_where_numba_is_installed():
    assert resolve_kernel("auto") == resolve_kernel("numba") == "numba"
    assert resolve_kernel("scipy") == "scipy"


@pytest.mark.parametrize("shift, order", [(None, 1), (None, 3), (None, 0), (0.0, 1), (-0.4, 1), (0.3, 3)])
def test_the_kernel_draws_the_scipy_render(large_library, shift, order):
    # chunks of 13 x 40 x 37 voxels cut most grains; the grains overlap (contested voxels)
    crops, maps, grid, partial_volume = _scene(large_library, shift)
    background = Background(0.2, wall=0.5)
    rendered = {
        kernel: reconstruct(crops, maps, grid, background, tube=(300.0, 330.0, -30.0), order=order,
                            chunks=(13, 40, 37), partial_volume=partial_volume, workers=1,
                            renderer=functools.partial(render_chunk, kernel=kernel))
        for kernel in ("scipy", "numba")
    }
    (tomogram, labels, contested), expected = rendered["numba"], rendered["scipy"]
    np.testing.assert_array_equal(labels, expected[1])
    assert contested == expected[2] > 0
    assert len(np.unique(labels)) > 10
    contrast = float(np.ptp(expected[0]))
    logger.info("kernel vs scipy, shift %s order %d: max |difference| %g", shift, order,
                np.abs(tomogram - expected[0]).max())
    np.testing.assert_allclose(tomogram, expected[0], rtol=1e-5, atol=1e-4 * contrast)


def test_a_generated_pack_is_the_same_with_either_kernel(large_library, tmp_path):
    library_dir = large_library.save(tmp_path / "lib")
    packs = {}
    for kernel in ("scipy", "numba"):
        config = tmp_path / f"{kernel}.yaml"
        config.write_text(f"postprocess: none\nreconstruct:\n  kernel: {kernel}\n")
        assert main(["-q", "generate", "--library", str(library_dir), "--out", str(tmp_path / kernel),
                     "--n-particles", "10", "--batch-size", "10", "--config", str(config)]) == 0
        packs[kernel] = open_pack(tmp_path / kernel / "pack_0000")
        assert packs[kernel].manifest["config"]["reconstruct"]["kernel"] == kernel
        assert packs[kernel].manifest["devices"]["render_kernel"] == kernel
    scipy_pack, numba_pack = packs["scipy"], packs["numba"]
    assert len(np.unique(numba_pack.labels)) > 5
    np.testing.assert_array_equal(numba_pack.labels, scipy_pack.labels)
    assert numba_pack.manifest["contested_voxels"] == scipy_pack.manifest["contested_voxels"]
    clean = np.asarray(scipy_pack.clean)
    np.testing.assert_allclose(numba_pack.clean, clean, rtol=1e-5, atol=1e-4 * float(np.ptp(clean)))
