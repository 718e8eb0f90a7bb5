"""Artefacts applied block by block equal the whole-volume result where the maths allows it."""

from __future__ import annotations

import numpy as np
import pytest
import zarr
from scipy import ndimage

from synthpack._shared.seeds import generator
from synthpack.artefacts import (
    BeamHardening,
    Compose,
    CTSimulation,
    GaussianBlur,
    GaussianNoise,
    MotionBlur,
    RingArtefacts,
    generic_postprocessing,
)
from synthpack.artefacts.blockwise import apply_blockwise
from synthpack.errors import SynthpackInputError

CHUNKS = (8, 16, 13)  # cuts every axis unevenly


@pytest.fixture(scope="module")
def volume() -> np.ndarray:
    rng = np.random.default_rng(0)
    return ndimage.gaussian_filter(rng.standard_normal((37, 45, 51)), 2).astype(np.float32) + 0.05 * rng.standard_normal(
        (37, 45, 51)).astype(np.float32)


def _blockwise(pipeline, volume, threads=2, seed=5, chunks=CHUNKS):
    out = np.empty_like(volume)
    record = apply_blockwise(pipeline, volume, out, seed, chunks, threads=threads,
                             scratch=lambda: np.empty_like(volume))
    return out, record


@pytest.mark.parametrize("sigma", [0.5, 0.9, 2.3])
def test_chunked_gaussian_blur_equals_the_whole_volume_blur(volume, sigma):
    out, record = _blockwise(GaussianBlur(sigma=sigma), volume)
    whole = ndimage.gaussian_filter(volume, sigma, output=np.float32, mode="reflect")
    np.testing.assert_array_equal(out, whole)
    assert record == [{"name": "gaussian_blur", "sigma": sigma}]


def test_chunked_blur_with_drawn_sigma_and_motion_blur_equal_the_whole_volume(volume):
    out, record = _blockwise(GaussianBlur(sigma=(0.5, 1.5)), volume)
    np.testing.assert_array_equal(out, GaussianBlur(sigma=record[0]["sigma"])(volume, 0))
    out, record = _blockwise(MotionBlur(length=5, angle=(0, 180)), volume)
    np.testing.assert_array_equal(out, MotionBlur(length=5, angle=record[0]["angle"])(volume, 0))


def test_a_stored_volume_read_a_row_of_blocks_at_a_time_gives_the_same_bytes(volume, tmp_path):
    # a Zarr source is read with the halo as one strip per row of blocks (`_HaloReads`), a NumPy one block by block
    stored = zarr.create_array(store=str(tmp_path / "v.zarr"), shape=volume.shape, dtype=volume.dtype,
                               chunks=(1, *CHUNKS[1:]), shards=CHUNKS)
    stored[...] = volume
    pipeline = Compose([GaussianBlur(sigma=1.7), GaussianNoise(std=0.3), MotionBlur(length=5, angle=30.0)])
    for threads in (1, 3):
        out = np.empty_like(volume)
        apply_blockwise(pipeline, stored, out, 5, CHUNKS, threads=threads, scratch=lambda: np.empty_like(volume))
        np.testing.assert_array_equal(out, _blockwise(pipeline, volume)[0])


def test_a_blur_after_noise_sees_the_finished_noisy_volume(volume):
    noisy, _ = _blockwise(GaussianNoise(std=0.3), volume)
    out, _ = _blockwise(Compose([GaussianNoise(std=0.3), GaussianBlur(sigma=1.2)]), volume)
    np.testing.assert_array_equal(out, ndimage.gaussian_filter(noisy, 1.2, output=np.float32))


def test_rings_and_cupping_are_centred_on_the_whole_slice(volume):
    for transform in (RingArtefacts(amplitude=0.5, n_rings=4), BeamHardening(strength=0.3)):
        out, _ = _blockwise(transform, volume)
        # the per-volume draws come from the step's "transform_volume" stream: the whole-volume core with it
        params = transform.sample(generator(5, "transform_params", 0))
        whole = transform._transform(volume, generator(5, "transform_volume", 0), **params)
        np.testing.assert_array_equal(out, whole)


def test_result_depends_on_seed_and_blocks_not_on_threads(volume):
    pipeline = Compose([GaussianNoise(std=0.1), GaussianBlur(sigma=1.0), GaussianBlur(sigma=0.5),
                        generic_postprocessing(contrast=1.0)])
    one, record = _blockwise(pipeline, volume, threads=1)
    two, again = _blockwise(pipeline, volume, threads=2)
    np.testing.assert_array_equal(one, two)
    assert record == again and [r["name"] for r in record][:3] == ["gaussian_noise", "gaussian_blur", "gaussian_blur"]
    other, _ = _blockwise(pipeline, volume, seed=6)
    assert not np.array_equal(one, other)
    noise = _blockwise(GaussianNoise(std=1.0), np.zeros_like(volume))[0]
    assert abs(noise.std() - 1.0) < 0.02 and abs(noise.mean()) < 0.02  # white noise over the volume
    assert not np.array_equal(noise[:8, :16, :13], noise[:8, :16, 13:26])  # blocks draw their own noise


def test_ct_simulation_runs_on_slabs_of_whole_slices_with_one_set_of_gains():
    phantom = np.zeros((6, 21, 21), dtype=np.float32)
    phantom[:, 6:15, 6:15] = 1.0
    ct = CTSimulation(attenuation=0.05, photons=1e7, n_angles=24, gain_std=0.05)
    out, _ = _blockwise(ct, phantom, chunks=(2, 21, 21))  # three slabs of whole slices
    assert abs(out[:, 8:13, 8:13].mean() - 1.0) < 0.1
    # with negligible photon noise every slice is the same scan: the same gains in every slab
    np.testing.assert_allclose(out[0], out[5], atol=0.02)


def test_empty_pipeline_copies_and_bad_calls_are_rejected(volume):
    out, record = _blockwise(Compose([]), volume)
    np.testing.assert_array_equal(out, volume)
    assert record == []
    with pytest.raises(SynthpackInputError, match="scratch"):
        apply_blockwise(Compose([GaussianBlur(1.0), GaussianBlur(1.0)]), volume, np.empty_like(volume), 0, CHUNKS)
    with pytest.raises(SynthpackInputError, match="3D"):
        apply_blockwise(GaussianBlur(1.0), volume[0], np.empty_like(volume[0]), 0, CHUNKS)
    with pytest.raises(SynthpackInputError, match="chunks"):
        apply_blockwise(GaussianBlur(1.0), volume, np.empty_like(volume), 0, (8, 0, 8))
