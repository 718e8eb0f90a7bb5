"""The grey-level grid a scan's values lie on (`synthpack.measure.grey_levels`), and a volume put on it
(the torch step: tests/test_blockwise_torch.py)."""

from __future__ import annotations

import numpy as np
import pytest

from synthpack.artefacts import RoundLevels
from synthpack.measure.grey_levels import grey_level_grid
from synthpack.source import SourceStatistics


def _counts(seed: int, shape=(40, 64, 64)) -> np.ndarray:
    """A 16-bit scan's counts: two phases and noise of a few hundred grey levels, with its extremes."""
    rng = np.random.default_rng(seed)
    counts = np.where(rng.random(shape) < 0.5, 20_000.0, 40_000.0) + rng.normal(0, 300, shape)
    counts.flat[:2] = (0, 65_535)
    return np.rint(counts).astype(np.uint16)


def test_integer_and_whole_float_scans_lie_on_whole_numbers():
    counts = _counts(0)
    assert grey_level_grid(counts) == (1.0, 0.0)
    assert grey_level_grid(counts.astype(np.float32)) == (1.0, 0.0)


@pytest.mark.parametrize("step, offset", [(2e-4, -0.005), (1 / 65_535, 0.0), (0.25, 3.1), (3e-5, -1.2)])
def test_a_float_scan_of_scaled_integers_gives_its_step_and_offset(step, offset):
    scan = (_counts(1).astype(np.float64) * step + offset).astype(np.float32)
    found = grey_level_grid(scan)
    assert found is not None
    assert found[0] == pytest.approx(step, rel=1e-6)
    shift = (found[1] - offset) / step  # the same grid: the offsets differ by whole steps
    assert abs(shift - round(shift)) < 0.01 and abs(found[1]) <= found[0] / 2


def test_continuous_floats_and_a_few_levels_lie_on_no_grid():
    rng = np.random.default_rng(2)
    assert grey_level_grid(rng.normal(0.5, 0.1, (40, 64, 64)).astype(np.float32)) is None
    few = rng.integers(0, 5, (40, 64, 64)) * 0.3 + 0.05  # five levels: a phantom's, not a scan's
    assert grey_level_grid(few.astype(np.float32)) is None


def test_round_levels_puts_a_volume_on_a_shifted_grid():
    rng = np.random.default_rng(3)
    image = rng.normal(0.0, 0.01, (8, 16, 16)).astype(np.float32)
    rounding = RoundLevels(step=2e-4, offset=-5e-5)
    out = rounding(image, 0)
    levels = (out.astype(np.float64) + 5e-5) / 2e-4
    assert np.abs(levels - np.round(levels)).max() < 1e-3 and np.abs(out - image).max() <= 1e-4 + 1e-7
    whole = RoundLevels()(image * 1000, 0)
    assert np.array_equal(whole, np.round(image * 1000))  # whole numbers: the bytes of a plain rounding


def test_statistics_of_an_older_synthpack_read_whole_levels_as_the_grid_of_whole_numbers():
    base = {"pore_mean": 40.0, "pore_std": 2.0, "grain_mean": 160.0, "noise_std": 2.0}
    assert SourceStatistics.from_dict({**base, "whole_levels": True}).grey_levels == (1.0, 0.0)
    assert SourceStatistics.from_dict({**base, "whole_levels": False}).grey_levels is None
