"""The stronger judge of the realism report: the floor, the CNN, edge half height, NPS ratios.

Tolerances of the classifier tests. With n patches per class and k folds, the AUC of
one held-out fold of a classifier that cannot tell the sets apart has a spread of
about sqrt((2m + 1) / (12 m^2)) for m = n / k test patches per class (the Mann-Whitney
statistic): 0.065 for n = 200, k = 5, so about 0.03 for the mean over the folds. A
tolerance of 0.1 around 0.5 is three of those: a classifier that learnt something
where there is nothing to learn fails, and the seeded draw does not. "Clearly
different" pairs differ by a factor 2 in noise or by a blur that halves the noise
standard deviation at unchanged variance; any working classifier separates those
almost perfectly, so > 0.95 is asked.
"""

import numpy as np
import pytest
import torch
from scipy import ndimage, special

from synthpack.errors import SynthpackInputError
from synthpack.realism import CnnConfig, Specimen
from synthpack.realism.appearance import noise_power_spectrum, nps_ratio
from synthpack.realism.discriminator import classifier_test, specimen_patches
from synthpack.realism.floor import floor_test, slab_parity
from synthpack.measure.edges import EdgeProfile, edge_profile, half_height, signed_distance

# Tiny CNN for tests: a second or two per cross-validation on 2 cores.
TINY = CnnConfig(epochs=8, width=8)
# Big enough that the noise of one slab of 5 slices hardly differs from another's: on 40 x 48 x 48
# the floor of pure noise is about 0.63 for the logistic regression (every slab's own finite-sample
# statistics are learnt), on 60 x 96 x 96 about 0.5.
SHAPE = (60, 96, 96)


def _patches(volume: np.ndarray, window: tuple[float, float] | None = None,
             max_patches: int = 400) -> tuple[np.ndarray, np.ndarray]:
    """16x16 patches of a whole volume and their corners; default window: the volume's 0.5-99.5 %."""
    specimen = Specimen("test", volume.astype(np.float32), np.zeros(volume.shape, dtype=np.int32),
                        np.ones(volume.shape, dtype=bool), (1.0, 1.0, 1.0), "px")
    window = tuple(np.percentile(volume, [0.5, 99.5])) if window is None else window
    return specimen_patches(specimen, window, max_patches=max_patches)


def _noise(seed: int, blur: float = 1.0, std: float = 1.0) -> np.ndarray:
    """Gaussian noise blurred by `blur` voxels (0: white), scaled to standard deviation `std`."""
    field = np.random.default_rng(seed).normal(size=SHAPE)
    field = ndimage.gaussian_filter(field, blur) if blur else field
    return field / field.std() * std


def test_floor_of_a_homogeneous_volume_is_chance_for_both_classifiers():
    patches, corners = _patches(_noise(0))
    floor = floor_test(patches, corners, slab=5, cnn=TINY)
    assert 190 <= floor.n_per_class <= 200  # the even and odd slabs hold about half the patches each
    for classifier in ("logistic", "cnn"):
        assert abs(floor.auc(classifier) - 0.5) < 0.1, (classifier, floor.auc(classifier))
    summary = floor.summary()
    assert set(summary) == {"n_per_class", "folds", "logistic", "cnn"} and summary["folds"] == 5
    assert summary["cnn"]["seconds"] > 0 and "margin" not in summary["cnn"]


@pytest.mark.parametrize("other", [dict(blur=1.0, std=2.0), dict(blur=0.0, std=1.0)],
                         ids=["noise doubled", "unblurred"])
def test_both_classifiers_tell_clearly_different_volumes_apart(other):
    first = _noise(1)
    window = tuple(np.percentile(first, [0.5, 99.5]))  # one window for both, as the report does: the source's
    test = classifier_test(_patches(first, window)[0], _patches(_noise(2, **other), window)[0], cnn=TINY)
    for classifier in ("logistic", "cnn"):
        assert test.auc(classifier) > 0.95, (classifier, test.auc(classifier))
    margins = test.summary(floor=test)
    assert margins["logistic"]["margin"] == 0.0 and margins["cnn"]["margin"] == 0.0


def test_cnn_is_deterministic_for_a_seed_and_leaves_torch_as_it_was():
    first, second = _patches(_noise(3), max_patches=200)[0], _patches(_noise(4, std=1.3), max_patches=200)[0]
    torch.manual_seed(123)
    state, threads = torch.get_rng_state(), torch.get_num_threads()
    runs = [classifier_test(first, second, seed=seed, cnn=TINY) for seed in (0, 0, 1)]
    np.testing.assert_array_equal(runs[0].cnn_scores, runs[1].cnn_scores)
    assert runs[0].auc("cnn") == runs[1].auc("cnn")
    assert not np.array_equal(runs[0].cnn_scores, runs[2].cnn_scores)  # the seed matters
    assert torch.equal(torch.get_rng_state(), state) and torch.get_num_threads() == threads
    assert not torch.are_deterministic_algorithms_enabled()


def test_floor_splits_interleaved_slabs_and_refuses_one_parity():
    assert slab_parity(np.arange(7), 2).tolist() == [0, 0, 1, 1, 0, 0, 1]
    patches, corners = _patches(_noise(5), max_patches=100)
    with pytest.raises(SynthpackInputError, match="one parity only"):
        floor_test(patches, corners, slab=SHAPE[0])
    with pytest.raises(SynthpackInputError, match="slab thickness"):
        floor_test(patches, corners, slab=0)


def _step_edge(shift: float, sigma: float = 1.0, dark_grains: bool = False) -> EdgeProfile:
    """Edge profile of a plane boundary (grains at x >= 16) whose intensity step, a Gaussian-blurred
    edge of `sigma` voxels, sits `shift` voxels into the grains."""
    labels = np.zeros((12, 12, 32), dtype=np.int32)
    labels[..., 16:] = 1
    x = np.arange(32, dtype=np.float64)
    step = 0.5 * (1 + special.erf((x - 15.5 - shift) / (np.sqrt(2) * sigma)))
    tomogram = np.broadcast_to(0.2 + 0.6 * step, labels.shape)
    profile = edge_profile(tomogram, signed_distance(labels))
    if dark_grains:  # the same edge with the contrast reversed
        profile = EdgeProfile(profile.distance, 1.0 - profile.intensity, 1.0 - profile.pore_level,
                              1.0 - profile.grain_level, profile.count)
    return profile


@pytest.mark.parametrize("dark_grains", [False, True], ids=["bright grains", "dark grains"])
def test_half_height_of_a_blurred_step_edge_is_its_position(dark_grains):
    assert half_height(_step_edge(0.0, dark_grains=dark_grains)) == pytest.approx(0.0, abs=0.1)
    for shift in (1.0, -1.5, 0.6):
        assert half_height(_step_edge(shift, dark_grains=dark_grains)) == pytest.approx(shift, abs=0.1)
    assert half_height(_step_edge(0.6, sigma=0.7)) == pytest.approx(0.6, abs=0.1)


def test_nps_ratio_of_a_volume_against_itself_is_one():
    volume = _noise(6, blur=0.7)
    mask = np.ones(SHAPE, dtype=bool)
    spectrum = noise_power_spectrum(volume, mask)
    same = nps_ratio(spectrum, spectrum)
    assert same["frequency"] == [0.125, 0.25, 0.375, 0.5]  # the 8x8 rings from 0.1 to 0.5 cycles/voxel
    assert same["ratio"] == [1.0] * 4 and same["max_abs_log2"] == 0.0
    doubled = nps_ratio(noise_power_spectrum(2 * volume, mask), spectrum)
    np.testing.assert_allclose(doubled["ratio"], 4.0)
    assert doubled["max_abs_log2"] == pytest.approx(2.0)
