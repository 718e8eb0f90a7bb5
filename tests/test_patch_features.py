"""Tests of synthpack.measure.patch_features: a scan's classifier patches, its floor, and a logistic AUC against it."""

from __future__ import annotations

import logging

import numpy as np
import pytest

from synthpack.artefacts import GaussianBlur, GaussianNoise
from synthpack.artefacts.guard import guard_steps
from synthpack.measure.lattice import patch_corners
from synthpack.measure.patch_features import DEFAULT_PATCH, MAX_PATCHES, PatchReference, logistic_auc, patch_features
from synthpack.errors import SynthpackInputError


@pytest.fixture(scope="module")
def noisy(phantom):
    """The phantom with white noise of std 0.03 (its source), another draw of it, and the labels."""
    clean, labels = phantom
    return GaussianNoise(std=0.03)(clean, 1), GaussianNoise(std=0.03)(clean, 2), labels


def test_a_scan_is_told_from_a_blurred_copy_not_from_another_noise_draw(noisy):
    source, other_draw, _ = noisy
    region = np.ones(source.shape, dtype=bool)
    reference = PatchReference.measure(source, region)
    assert reference.features.shape == (MAX_PATCHES, 32 + DEFAULT_PATCH // 2 + 1)
    # the floor: a homogeneous scan's slabs look alike, the phantom's differ (its balls lie at other depths)
    white = PatchReference.measure(np.random.default_rng(0).normal(size=source.shape).astype(np.float32), region)
    assert white.floor < 0.65 < reference.floor
    corners = patch_corners(region, DEFAULT_PATCH, DEFAULT_PATCH // 2, MAX_PATCHES)
    same = reference.auc(other_draw, corners)
    blurred = reference.auc(GaussianBlur(sigma=1.5)(other_draw, 0), corners)
    assert same < 0.7 and blurred > 0.95, (same, blurred)


def test_too_few_patches_give_no_figure(noisy):
    source, _, _ = noisy
    region = np.zeros(source.shape, dtype=bool)
    region[:2, :20, :20] = True  # one 16x16 patch per slice: 2 patches
    assert PatchReference.measure(source, region) is None
    assert PatchReference.measure(source, np.zeros_like(region)) is None  # no patch at all
    reference = PatchReference.measure(source, np.ones_like(region))
    assert reference.auc(source, np.zeros((0, 3), dtype=np.int64)) is None
    features = patch_features(np.zeros((3, 16, 16)))
    with pytest.raises(SynthpackInputError, match="patches per class"):
        logistic_auc(features, features)


def test_the_guard_records_the_logistic_auc_and_warns_where_the_steps_raise_it(noisy, caplog):
    """The AUC is recorded, not a figure the steps are chosen by: with no other figure to judge by, the blur stays."""
    source, clean, labels = noisy
    region = np.ones(labels.shape, dtype=bool)
    reference = PatchReference.measure(source, region)
    figures = {"histograms": {}, "noise": {}, "contrast": 0.6}

    def build(kept):
        return [GaussianBlur(sigma=1.5)] if kept else []

    kept, record = guard_steps(build, ("blur",), clean, labels, region, **figures)
    assert kept == ("blur",) and "logistic" not in record
    with caplog.at_level(logging.WARNING, logger="synthpack.artefacts.guard"):
        kept, record = guard_steps(build, ("blur",), clean, labels, region, **figures, patches=reference)
    auc = record["logistic"]
    assert kept == ("blur",) and auc["applied"] == auc["fitted"] > auc["none"] + 0.2
    assert "look less like the source's with the steps applied" in caplog.text
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="synthpack.artefacts.guard"):
        _, record = guard_steps(lambda kept: [GaussianNoise(std=0.0)] if kept else [], ("idle",), clean, labels,
                                region, **figures, patches=reference)
    assert record["logistic"]["applied"] == record["logistic"]["none"] and "look less like" not in caplog.text
