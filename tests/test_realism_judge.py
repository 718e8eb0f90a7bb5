"""The stronger judge of the realism report: the floor, the CNN, edge half height, NPS ratios, full-band W,
the targets table, the worse-than-none line and the slices at one scale.

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

import dataclasses

import numpy as np
import pytest
import torch
from matplotlib import image
from scipy import ndimage, special

from synthpack.errors import SynthpackInputError
from synthpack.pipeline.config import PackConfig
from synthpack.realism import CnnConfig, RealismReport, Specimen
from synthpack.realism.appearance import noise_power_spectrum, nps_ratio
from synthpack.realism.discriminator import classifier_test, specimen_patches
from synthpack.realism.floor import floor_test, slab_parity
from synthpack.realism.markdown import report_markdown
from synthpack.realism.plots import save_slices_plot, slice_layout
from synthpack.realism.report import distances, measure
from synthpack.realism.targets import LOGISTIC_AUC_MARGIN, TARGETS, W_LIMIT, pour_key
from synthpack.measure.noise_estimate import estimate_spread
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
    # every ring of the 8x8 spectrum but ring 0 (the patch mean): from 1/8 cycles/voxel to the corner
    assert same["frequency"] == [0.125, 0.25, 0.375, 0.5, 0.625, 0.75]
    assert same["ratio"] == [1.0] * 6 and same["max_abs_log2"] == 0.0
    doubled = nps_ratio(noise_power_spectrum(2 * volume, mask), spectrum)
    np.testing.assert_allclose(doubled["ratio"], 4.0)
    assert doubled["max_abs_log2"] == pytest.approx(2.0)


def test_nps_ratio_sees_texture_in_the_lowest_and_in_the_corner_ring():
    white = _noise(7, blur=0.0)
    mask = np.ones(SHAPE, dtype=bool)
    reference = noise_power_spectrum(white, mask)
    x, z = np.arange(SHAPE[2]), np.arange(SHAPE[0])[:, None, None]
    # noise, not structure: a wave that changes from slice to slice (the NPS sees only what does).
    # A wave of 1/8 cycles/voxel along x whose phase steps by theta per slice, 2 - 2 cos theta = sqrt(6):
    # its normalised second difference across slices has power 1/2 in ring 1, where white noise of
    # variance 1 has 8/64
    phase = z * np.arccos(1.0 - np.sqrt(6.0) / 2.0)
    low = nps_ratio(noise_power_spectrum(white + np.sin(2 * np.pi * x / 8 + phase), mask), reference)
    assert low["worst_frequency"] == 0.125 and low["ratio"][0] == pytest.approx(5.0, rel=0.1)
    np.testing.assert_allclose(low["ratio"][1:], 1.0, atol=0.1)
    # a checkerboard (0.5, 0.5 cycles/voxel) whose sign flips from slice to slice: all in the corner
    # ring, the one frequency (4, 4) of ring 6
    y = np.arange(SHAPE[1])
    checker = 0.5 * (-1.0) ** (z + y[:, None] + x[None, :])
    high = nps_ratio(noise_power_spectrum(white + checker, mask), reference)
    assert high["worst_frequency"] == 0.75 and high["ratio"][-1] > 10
    np.testing.assert_allclose(high["ratio"][:-1], 1.0, atol=0.1)
    # structure, the same in every slice, is not noise: the same wave without its changing phase
    still = nps_ratio(noise_power_spectrum(white + np.sin(2 * np.pi * x / 8), mask), reference)
    assert still["max_abs_log2"] < 0.1


def _balls(seed: int, shading: float = 0.0) -> Specimen:
    """Rows of three touching balls (radius 9) in two layers, grains 1.0, pores 0.2, white noise 0.05, and a
    wave of `shading` amplitude (one period across the volume, along x)."""
    z, y, x = np.mgrid[:40, :64, :64]
    labels = np.zeros(z.shape, dtype=np.int32)
    centres = [(cz, cy, cx) for cz in (10, 30) for cy in (10, 32, 54) for cx in (10, 28, 46)]
    for label, (cz, cy, cx) in enumerate(centres, 1):
        labels[(z - cz) ** 2 + (y - cy) ** 2 + (x - cx) ** 2 <= 81] = label
    noise = np.random.default_rng(seed).normal(0.0, 0.05, z.shape)
    tomogram = np.where(labels > 0, 1.0, 0.2) + noise + shading * np.sin(2 * np.pi * x / 64)
    return Specimen(f"balls {seed}, shading {shading}", tomogram.astype(np.float32), labels,
                    np.ones(z.shape, dtype=bool), (1.0, 1.0, 1.0), "px")


@pytest.fixture(scope="module")
def balls():
    """Measurements of the ball volumes (the source, a pack of the same kind, the same pack shaded), the
    floor of the source and each pack's classifier test (logistic regression only)."""
    window = (0.0, 1.2)
    measured = {name: measure(specimen, window) for name, specimen in
                (("source", _balls(0)), ("plain", _balls(1)), ("shaded", _balls(1, shading=0.15)))}
    source = measured["source"]
    measured["floor"] = floor_test(source.patches, source.patch_corners, slab=5)
    measured["tests"] = {name: classifier_test(source.patches, measured[name].patches) for name in ("plain", "shaded")}
    return measured


def test_w_is_full_band_so_low_frequency_shading_shows(balls):
    plain, shaded = distances(balls["source"], balls["plain"]), distances(balls["source"], balls["shaded"])
    for phase in ("grains", "pores", "edges"):
        assert plain[f"wasserstein_{phase}"] < 0.01
        assert shaded[f"wasserstein_{phase}"] > W_LIMIT  # 0.15 of the 0.8 contrast: W about 0.06
    # the noise estimate, a high-pass figure, does not see the shading
    for key in ("grain_std", "pore_std"):
        assert getattr(balls["shaded"].appearance.noise, key) == pytest.approx(
            getattr(balls["plain"].appearance.noise, key), rel=0.02)


def _report(balls: dict, packs: list[str], modes: list[str], pours: list[str] | None = None) -> dict:
    """``to_dict`` of a report of the measured balls, as `compare` would make of packs of one pour."""
    source, measured = balls["source"], [balls[name] for name in packs]
    infos = [{"path": m.specimen.name, "postprocess": mode, "mode": mode, "calibration": None, "pour": pour}
             for m, mode, pour in zip(measured, modes, pours or ["one pour"] * len(packs))]
    settings = {"source": "balls", "window": [0.0, 1.2], "patch": 16, "seed": 0, "slab": 5, "cnn": None,
                "packs": infos}
    return RealismReport(source, measured, [distances(source, m) for m in measured], balls["floor"],
                         [balls["tests"][name] for name in packs], settings).to_dict()


def test_targets_table_reads_the_measured_figures(balls):
    report = _report(balls, ["plain", "shaded"], ["none", "calibrated"])
    source, floor = report["source"]["figures"], report["floor"]
    for pack in report["packs"]:
        rows = {row["figure"]: row for row in pack["targets"]}
        assert list(rows) == [target.figure for target in TARGETS]
        for row in rows.values():
            assert row["pass"] is None or row["pass"] == (row["deviation"] <= row["limit"])
        assert rows["CNN AUC"]["pass"] is None  # the CNN did not run
        assert rows["logistic AUC"]["limit"] == pytest.approx(floor["logistic"]["auc"] + LOGISTIC_AUC_MARGIN)
        assert rows["logistic AUC"]["deviation"] == pack["distances"]["classifier"]["logistic"]["auc"]
        for phase in ("grains", "pores", "edges"):
            assert rows[f"W {phase}"]["deviation"] == pack["distances"][f"wasserstein_{phase}"]
        assert rows["noise std in pores"]["deviation"] == pytest.approx(
            abs(pack["figures"]["noise_pore"] / source["noise_pore"] - 1))
        assert rows["noise std in pores"]["pass"] is True  # the same noise level
        assert rows["NPS in pores, every ring"]["deviation"] == pack["distances"]["nps_ratio"]["pores"]["max_abs_log2"]
        assert rows["solid fraction"]["deviation"] == pytest.approx(0.0, abs=1e-9)  # the same labels
        assert rows["mean coordination"]["pass"] is True and source["coordination_mean"] > 0
    plain, shaded = ({row["figure"]: row["pass"] for row in p["targets"]} for p in report["packs"])
    assert plain["W pores"] is True and shaded["W pores"] is False
    markdown = report_markdown(report)
    assert "## Targets" in markdown and "**FAIL**" in markdown
    w_pores = report["packs"][0]["distances"]["wasserstein_pores"]
    assert f"| W pores | <= {W_LIMIT} of the contrast | {w_pores:.3f}: pass |" in markdown


def test_the_noise_rows_show_a_noise_level_in_any_intensity_unit():
    # a float scan's noise (0.0116) was shown as "0.0 (source 0.0, -6.9%)"
    noise = {target.figure: target for target in TARGETS}["noise std in grains"]
    for source, pack, cell in ((0.0116, 0.0108, "0.0108 (source 0.0116, -6.9%)"),
                               (1100.0, 1234.4, "1234 (source 1100, +12.2%)"),
                               (0.5, 0.52, "0.520 (source 0.500, +4.0%)")):
        reading = noise.read({"figures": {"noise_grain": source}}, {"figures": {"noise_grain": pack}})
        assert reading.cell == cell
        assert reading.deviation == pytest.approx(abs(pack / source - 1))


def test_a_noise_level_on_few_voxels_is_not_told_apart_from_none_s_by_its_spread():
    # the concrete block: the calibrated pack's grain noise 41.5 % off, none's 36.3 %, each on 216 voxels
    noise = {target.figure: target for target in TARGETS}["noise std in grains"]
    source = {"figures": {"noise_grain": 106.0}}

    def worse(count: int | None) -> bool:
        mine, theirs = (noise.read(source, {"figures": {"noise_grain": v, "noise_grain_voxels": count}})
                        for v in (150.0, 144.5))
        return mine.deviation > theirs.deviation + max(mine.resolution, theirs.resolution)

    assert not worse(216)  # 5 points apart, within 2 / sqrt(216) = 14 % of each estimate
    assert worse(100_000)  # on 100,000 voxels the estimates are 0.6 % apart in spread: told apart
    assert worse(None)  # a report without the counts: as before
    cell = noise.read({"figures": {"noise_grain": 106.0, "noise_grain_voxels": 267}},
                      {"figures": {"noise_grain": 150.0, "noise_grain_voxels": 216}}).cell
    assert cell == "150 (source 106, +41.5% ± 25.9%)"  # both estimates' spreads, on the ratio 1.415
    assert estimate_spread(279) == pytest.approx(0.12, abs=0.001)


def test_a_mode_worse_than_none_is_flagged_and_only_then(balls):
    plain, shaded = balls["plain"], balls["shaded"]
    worse = _report(balls, ["plain", "shaded"], ["none", "calibrated"])
    (flag,) = worse["worse_than_none"]
    assert (flag["mode"], flag["pack"], flag["none"]) == ("calibrated", shaded.specimen.name, plain.specimen.name)
    figures = [w["figure"] for w in flag["worse"]]
    assert {"W grains", "W pores", "W edges"} <= set(figures)
    assert "solid fraction" not in figures and "mean coordination" not in figures  # the same labels
    w_pores = worse["packs"][1]["distances"]["wasserstein_pores"], worse["packs"][0]["distances"]["wasserstein_pores"]
    assert f"W pores ({w_pores[0]:.3f} > {w_pores[1]:.3f})" in report_markdown(worse)
    assert "is worse than none (" in report_markdown(worse)
    # the other way round: the mode takes the shading away, so it is nowhere worse
    better = _report(balls, ["shaded", "plain"], ["none", "calibrated"])
    assert better["worse_than_none"][0]["worse"] == []
    assert "is worse than" not in report_markdown(better) and "is nowhere worse than none (" in report_markdown(better)
    # a none pack of another pour is no reference
    other = _report(balls, ["plain", "shaded"], ["none", "calibrated"], pours=["a", "b"])
    assert other["worse_than_none"] == [] and "worse than" not in report_markdown(other)


def test_pour_key_ignores_only_the_post_processing_and_the_run():
    manifest = {"seed": 3, "library_source": "scan.tif", "config": PackConfig().to_dict()}
    again = {**manifest, "config": PackConfig().replace(postprocess="none", run={"threads": 1}).to_dict()}
    assert pour_key(manifest) == pour_key(again)
    for other in ({**manifest, "seed": 4}, {**manifest, "config": PackConfig().replace(seed=2).to_dict()},
                  {**manifest, "config": PackConfig().replace(pour={"n_particles": 12}).to_dict()}):
        assert pour_key(other) != pour_key(manifest)


def test_slices_are_laid_out_at_one_scale_and_drawn_so(balls, tmp_path):
    shapes = [(100, 100), (109, 109), (60, 200)]
    scale, size, boxes = slice_layout(shapes)
    assert scale == int(scale) and scale >= 1
    for (rows, columns), (left, bottom, width, height) in zip(shapes, boxes):
        assert (width, height) == (scale * columns, scale * rows)  # the same pixels per voxel in every panel
        assert bottom + height == boxes[0][1] + boxes[0][3]  # tops aligned
    assert all(a[0] + a[2] < b[0] for a, b in zip(boxes, boxes[1:])) and boxes[-1][0] + boxes[-1][2] <= size[0]
    # wider than the picture at 1 pixel per voxel: one scale below 1, the panels still in the picture
    scale, size, boxes = slice_layout([(50, 3000), (50, 1500)], width=1000)
    assert scale < 1 and boxes[1][2] == pytest.approx(boxes[0][2] / 2) and boxes[-1][0] + boxes[-1][2] <= size[0]
    # the picture: the source and two packs, one of them cut smaller; its size is the layout's
    source, plain = balls["source"], balls["plain"]
    cut = dataclasses.replace(plain.specimen, name="smaller", tomogram=plain.specimen.tomogram[:, :40, :50],
                              labels=plain.specimen.labels[:, :40, :50], region=plain.specimen.region[:, :40, :50])
    smaller = dataclasses.replace(plain, specimen=cut)
    path = save_slices_plot(source, [plain, smaller], (0.0, 1.2), tmp_path / "slices.png")
    _, size, _ = slice_layout([(64, 64), (64, 64), (40, 50)])
    assert image.imread(path).shape[:2] == (size[1], size[0])
