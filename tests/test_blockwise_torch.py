"""Post-processing on a torch device equals the NumPy path: the same draws, float32 rounding apart."""

from __future__ import annotations

import logging
import subprocess
import sys

import numpy as np
import pytest
import torch
from scipy import ndimage

from synthpack.artefacts import (
    BeamHardening,
    ColouredNoise,
    Compose,
    ContrastGamma,
    GaussianBlur,
    GaussianNoise,
    MotionBlur,
    PoissonNoise,
    RingArtefacts,
    RoundLevels,
    SpeckleNoise,
)
from synthpack.artefacts._base import BlockContext
from synthpack.artefacts.blockwise import apply_blockwise, device_for

CHUNKS = (8, 16, 13)  # cuts every axis unevenly; the blurs' halos cross block edges and the volume's border
PORE, GRAIN = 0.2, 1.0
DEVICES = ["cpu", pytest.param("cuda", marks=pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA GPU"))]


@pytest.fixture(scope="module")
def volume() -> np.ndarray:
    """Two phases (levels PORE and GRAIN) with soft edges and a little noise: float32, (29, 40, 46)."""
    rng = np.random.default_rng(1)
    grains = ndimage.gaussian_filter(rng.standard_normal((29, 40, 46)), 2.5) > 0
    clean = ndimage.gaussian_filter(np.where(grains, GRAIN, PORE), 0.8)
    return (clean + 0.02 * rng.standard_normal(clean.shape)).astype(np.float32)


def _calibrated() -> Compose:
    """The calibrated pipeline's transforms (`Calibration.pipeline`), with a source's fitted values."""
    return Compose([
        GaussianBlur(sigma=1.3),
        ColouredNoise(pore_power=[2e-4, 1e-4, 4e-5], grain_power=[3e-4, 2e-4, 1e-4], pore_level=PORE,
                      grain_level=GRAIN, pore_std=0.02, grain_std=0.03),
        BeamHardening(strength=0.08, keep="mean"),
        RingArtefacts(amplitude=0.03, n_rings=3, width=1.5, radii=[4.0, 9.5, 17.0], amplitudes=[0.03, -0.02, 0.01]),
    ])


def _both(pipeline, volume, device, seed=7):
    """The NumPy path's output and record, and those of `device`."""
    outputs = []
    for where in (None, device):
        out = np.empty_like(volume)
        record = apply_blockwise(pipeline, volume, out, seed, CHUNKS, threads=2,
                                 scratch=lambda: np.empty_like(volume), device=where)
        outputs.append((out, record))
    return outputs


@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.parametrize("pipeline", [
    _calibrated(),
    # every other torch step, drawn parameters and rings, and a blur after noise (two passes)
    Compose([MotionBlur(length=3.5, angle=(0.0, 180.0)), GaussianNoise(std=(0.02, 0.05)), SpeckleNoise(std=0.03),
             ContrastGamma(contrast=(0.8, 1.2), gamma=0.7, pore_level=PORE, grain_level=GRAIN),
             RingArtefacts(amplitude=0.05, n_rings=(3, 6)), GaussianBlur(sigma=(0.5, 1.0))]),
], ids=["calibrated", "other-steps"])
def test_the_device_path_equals_the_numpy_path(volume, pipeline, device):
    (numpy_out, numpy_record), (torch_out, torch_record) = _both(pipeline, volume, device)
    assert torch_record == numpy_record
    assert np.all(np.isfinite(torch_out))
    assert np.abs(torch_out - numpy_out).max() <= 1e-5 * np.ptp(numpy_out)
    assert np.abs(numpy_out - volume).max() > 100 * 1e-5 * np.ptp(numpy_out)  # the pipeline did change it


def test_a_pipeline_with_a_transform_without_a_torch_version_runs_on_the_cpu(volume, caplog):
    pipeline = Compose([GaussianBlur(sigma=1.0), PoissonNoise(photons=5000.0)])
    with caplog.at_level(logging.INFO, logger="synthpack.artefacts.blockwise"):
        (numpy_out, numpy_record), (torch_out, torch_record) = _both(pipeline, volume, "cpu")
    assert torch_record == numpy_record
    assert torch_out.tobytes() == numpy_out.tobytes()  # all of it the NumPy path, not the blur on the device
    assert "no torch version of poisson_noise" in caplog.text
    assert device_for(pipeline, "cpu") is None and device_for(_calibrated(), "cpu") == "cpu"


def test_the_numpy_path_does_not_import_torch():
    code = ("import sys, numpy as np\n"
            "from synthpack.artefacts import GaussianBlur\n"
            "from synthpack.artefacts.blockwise import apply_blockwise\n"
            "v = np.ones((6, 7, 8), np.float32)\n"
            "apply_blockwise(GaussianBlur(1.0), v, np.empty_like(v), 0, (3, 4, 4))\n"
            "assert 'torch' not in sys.modules\n")
    subprocess.run([sys.executable, "-c", code], check=True)


@pytest.mark.parametrize("transform", [
    GaussianBlur(sigma=1.3), MotionBlur(length=3.5, angle=30.0), _calibrated()[1], BeamHardening(strength=-0.1),
    RingArtefacts(amplitude=0.05, n_rings=4), GaussianNoise(std=0.05), SpeckleNoise(std=0.05),
    ContrastGamma(contrast=1.3, gamma=0.6, pore_level=PORE, grain_level=GRAIN), RoundLevels(step=0.05, offset=0.01),
], ids=lambda t: t.name)
def test_each_device_step_equals_its_numpy_block_step_over_the_whole_block(volume, transform):
    """Halo included: a blur mirrors beyond the block's edges as SciPy's "reflect" does."""
    from synthpack.artefacts.torch_blocks import DeviceVolume

    device = DeviceVolume("cpu")
    block = volume[3:20, 5:33, 2:40]  # a view: the device tensor on the CPU shares its memory
    before = block.copy()
    params = transform.sample(np.random.default_rng(0))

    def context() -> BlockContext:  # a fresh block generator for each path: the same draws
        return BlockContext(np.random.default_rng(1), np.random.SeedSequence(2), (3, 5, 2), volume.shape)

    expected = transform._transform_block(block, context(), **params)
    got = device.get(transform._transform_block_torch(device.put(block), context(), device, **params))
    assert got.shape == expected.shape
    assert np.abs(got - expected).max() <= 1e-5 * np.ptp(expected)
    assert np.array_equal(block, before)  # neither step modified its input


class _DarkRings(RingArtefacts):
    """A user's ring transform, every ring darker: the parent's name and block steps, its own map."""

    def _slice_map(self, shape, rng, **params):
        return -np.abs(super()._slice_map(shape, rng, **params))


def test_a_subclass_of_a_transform_gets_its_torch_step(volume):
    pipeline = Compose([GaussianBlur(sigma=0.8), _DarkRings(amplitude=0.05, n_rings=4)])
    assert all(t.has_torch_step for t in pipeline) and not PoissonNoise().has_torch_step
    assert device_for(pipeline, "cpu") == "cpu"
    (numpy_out, numpy_record), (torch_out, torch_record) = _both(pipeline, volume, "cpu")
    assert torch_record == numpy_record
    assert np.abs(torch_out - numpy_out).max() <= 1e-5 * np.ptp(numpy_out)
    # the device path ran the subclass's own map: every ring darkens what the blur left
    blurred = np.empty_like(volume)
    apply_blockwise(pipeline[0], volume, blurred, 7, CHUNKS)
    assert (torch_out <= blurred + 1e-6).all() and (torch_out < blurred - 1e-3).any()
