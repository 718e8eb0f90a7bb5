import dataclasses
import json
import logging

import numpy as np
import pytest
import yaml
from scipy import ndimage

from synthpack.artefacts import recipes as postprocess
from synthpack.artefacts import calibrate
from synthpack.cli import main
from synthpack.pipeline.config import PackConfig
from synthpack.errors import SynthpackInputError
from synthpack.pipeline.generate import build_pack, generate_packs
from synthpack.library.core import ParticleLibrary
from synthpack.realism import CnnConfig, RealismReport, Specimen, compare
from synthpack.realism.appearance import measure_appearance, noise_levels, noise_power_spectrum
from synthpack.realism.discriminator import classifier_test
from synthpack.measure.lattice import patch_corners, take_patches
from synthpack.measure.contacts import coordination_numbers
from synthpack.realism.structure import grain_table, ks_distance
from synthpack.measure.noise_estimate import MIN_SAMPLES
from synthpack.measure.specimen import solid_fraction

# A pack narrow and deep enough to have a bulk region (radius ~17, height ~130 voxels).
PACK = PackConfig().replace(seed=1, pour={"n_particles": 60, "batch_size": 30, "tube_radius": 400.0})


def _specimen(tomogram, labels, region=None) -> Specimen:
    region = np.ones(labels.shape, dtype=bool) if region is None else region
    return Specimen("test", np.asarray(tomogram, dtype=np.float32), labels.astype(np.int32), region, (1.0, 1.0, 1.0), "px")


def test_solid_fraction_of_a_known_pack():
    labels = np.zeros((10, 20, 20), dtype=np.int32)
    labels[:, :, :5] = 1  # a quarter of every slice is grain
    assert solid_fraction(labels, np.ones(labels.shape, dtype=bool)) == 0.25
    region = np.zeros(labels.shape, dtype=bool)
    region[:, :, :10] = True
    assert solid_fraction(labels, region) == 0.5


def test_ks_distance_of_identical_and_shifted_samples():
    rng = np.random.default_rng(0)
    a = rng.normal(size=20000)
    assert ks_distance(a, a) == 0.0
    assert ks_distance(a, a + 100) == 1.0
    # N(0, 1) against N(0.5, 1): sup |F - G| = 2 Phi(0.25) - 1 = 0.197
    assert ks_distance(a, rng.normal(0.5, 1.0, 20000)) == pytest.approx(0.197, abs=0.02)


def test_grain_shape_size_orientation_and_contacts_of_known_grains():
    labels = np.zeros((40, 40, 90), dtype=np.int32)
    z, y, x = np.mgrid[:40, :40, :90]
    labels[(z - 20) ** 2 + (y - 20) ** 2 + (x - 15) ** 2 <= 81] = 1  # ball, radius 9
    labels[((z - 20) / 5) ** 2 + ((y - 20) / 5) ** 2 + ((x - 50) / 15) ** 2 <= 1] = 2  # cigar along x, 3:1
    labels[15:25, 15:25, 70:78] = 3
    labels[15:25, 15:25, 78:86] = 4  # touches 3 face to face
    table = grain_table(_specimen(np.zeros(labels.shape), labels))
    assert table.labels.tolist() == [1, 2, 3, 4]
    assert table.diameter[0] == pytest.approx(18.0, rel=0.03)
    assert table.sphericity[0] > 0.95 and table.sphericity[1] < table.sphericity[0]
    assert table.elongation[0] == pytest.approx(1.0, abs=0.03)
    assert table.elongation[1] == pytest.approx(1 / 3, rel=0.05)  # b/a of the cigar
    assert table.flatness[1] == pytest.approx(1.0, abs=0.03)
    np.testing.assert_allclose(np.abs(table.long_axis[1]), [0, 0, 1], atol=1e-6)  # long axis along x
    assert table.coordination.tolist() == [0, 0, 1, 1]
    assert coordination_numbers(labels)[3] == 1
    # the sections of 24 slices along z: discs, ellipses and rectangles (their corners are the roughest)
    assert len(table.roughness) > 24 and np.median(table.roughness) < 1.08
    assert np.all((table.roughness > 1.0) & (table.roughness < 1.15))


def test_noise_level_and_spectrum_of_added_gaussian_noise():
    labels = np.zeros((48, 40, 40), dtype=np.int32)
    labels[:24] = 1
    rng = np.random.default_rng(1)
    tomogram = np.where(labels > 0, 1.0, 0.2) + rng.normal(0.0, 0.05, labels.shape)
    noise = noise_levels(_specimen(tomogram, labels))
    assert noise.grain_std == pytest.approx(0.05, rel=0.05)
    assert noise.pore_std == pytest.approx(0.05, rel=0.05)
    spectrum = noise_power_spectrum(tomogram, labels > 0)
    # the rings add up to the variance left after removing each 8x8 patch's mean
    assert spectrum.power.sum() == pytest.approx(0.05**2 * 63 / 64, rel=0.05)
    assert spectrum.power[0] == pytest.approx(0.0, abs=1e-12)
    assert spectrum.centroid > 0.35  # white noise: power at high frequencies


def test_pore_bands_read_a_pore_phase_brighter_and_calmer_near_its_grains():
    """A paste that is 30 brighter and half as variable within 2 voxels of its grains: the bands say so."""
    from synthpack.measure.edges import signed_distance
    from synthpack.measure.pore_bands import BANDS, pore_bands

    labels = np.zeros((40, 40, 40), np.int32)
    labels[8:14, 8:14, 8:14], labels[24:32, 20:30, 10:18] = 1, 2
    distance = signed_distance(labels)
    rng = np.random.default_rng(0)
    near = (distance < 0) & (distance >= -2)
    tomogram = np.where(labels > 0, 200.0, 100.0 + rng.normal(0, np.where(near, 10.0, 20.0), labels.shape))
    tomogram += np.where(near, 30.0, 0.0)
    bands = pore_bands(tomogram, distance, np.ones(labels.shape, bool))
    assert len(bands.median) == BANDS and bands.voxels.sum() == np.count_nonzero(labels == 0)
    np.testing.assert_allclose(bands.median, [130, 130, 100, 100, 100], atol=2)
    # the IQR of a normal distribution is 1.349 of its standard deviation
    np.testing.assert_allclose(bands.iqr, 1.349 * np.array([10, 10, 20, 20, 20]), rtol=0.1)
    assert bands.to_dict()["voxels"] == bands.voxels.tolist()


def test_patches_lie_inside_the_mask():
    mask = np.zeros((3, 30, 30), dtype=bool)
    mask[:, 5:25, 5:25] = True
    corners = patch_corners(mask, 8, 4)
    assert len(corners) == 3 * 9  # corners 8, 12, 16 in y and x (a 4-voxel lattice inside 5..24)
    patches = take_patches(np.where(mask, 1.0, 0.0), corners, 8)
    assert patches.shape == (27, 8, 8) and patches.min() == 1.0
    assert len(patch_corners(mask, 8, 4, max_patches=5)) == 5


def test_classifier_auc_near_half_for_one_distribution_and_near_one_for_two():
    rng = np.random.default_rng(2)

    def patches(n, noise):
        base = np.where(rng.uniform(size=(n, 1, 1)) < 0.5, 0.3, 0.7) * np.ones((n, 16, 16))
        return np.clip(base + rng.normal(0.0, noise, (n, 16, 16)), 0, 1)

    same = classifier_test(patches(300, 0.05), patches(300, 0.05), seed=0)
    assert abs(same.auc("logistic") - 0.5) < 0.1
    different = classifier_test(patches(300, 0.05), patches(300, 0.1), seed=0)
    assert different.auc("logistic") > 0.95 and different.n_per_class == 300
    assert different.auc("cnn") is None and different.cnn_scores is None  # the CNN only when asked for
    with pytest.raises(SynthpackInputError, match="patches per class"):
        classifier_test(patches(4, 0.05), patches(300, 0.05))


def test_the_feature_groups_alone_say_which_statistic_tells_two_sets_apart():
    rng = np.random.default_rng(3)
    smooth = ndimage.gaussian_filter(rng.normal(size=(300, 16, 16)), (0, 2, 2)).reshape(300, -1)
    # every patch holds the same 256 values: smooth in one set, the same values shuffled (white) in the other
    ranked = np.linspace(0.2, 0.8, 256)[np.argsort(np.argsort(smooth, axis=1), axis=1)]
    shuffled = rng.permuted(ranked, axis=1)
    test = classifier_test(ranked.reshape(300, 16, 16), shuffled.reshape(300, 16, 16), seed=0, feature_groups=True)
    groups = test.feature_auc
    assert list(groups) == ["intensities", "differences", "spectrum"]
    assert abs(groups["intensities"] - 0.5) < 0.1 and groups["differences"] > 0.95 and groups["spectrum"] > 0.95
    assert test.summary()["logistic_features"] == groups and test.auc("logistic") > 0.95
    alone = classifier_test(ranked.reshape(300, 16, 16), shuffled.reshape(300, 16, 16), seed=0)
    assert alone.feature_auc == {} and "logistic_features" not in alone.summary()  # only when asked for
    assert alone.auc("logistic") == test.auc("logistic")


@pytest.fixture(scope="module")
def packs(large_library, tmp_path_factory):
    """A generic and a default (calibrated) pack of the same pour, the latter by `generate` without options."""
    root = tmp_path_factory.mktemp("realism")
    (generic,) = generate_packs(large_library, root / "generic", 1, PACK.replace(postprocess="generic"),
                                progress=False)
    library_dir = large_library.save(root / "library")
    config = root / "pack.yaml"
    config.write_text("pour: {n_particles: 60, batch_size: 30, tube_radius: 400.0}\n")
    assert main(["-q", "generate", "--library", str(library_dir), "--out", str(root / "default"),
                 "--config", str(config), "--seed", "1"]) == 0
    return generic, root / "default" / "pack_0000"


def test_calibration_is_the_default_and_brings_noise_and_edges_to_the_source(packs, large_scan, large_library):
    generic, calibrated = packs
    manifest = json.loads((calibrated / "manifest.json").read_text())
    fit = manifest["calibration"]
    statistics = large_library.statistics
    assert manifest["config"]["postprocess"] == "calibrated" and manifest["postprocess_mode"] == "calibrated"
    assert (fit["target_sigma"], fit["target_shift"]) == (statistics.edge_sigma, statistics.edge_shift)
    assert fit["target_power"] == {"grains": list(statistics.nps_grains), "pores": list(statistics.nps_pores)}
    assert manifest["partial_volume"]["shift"] == statistics.edge_shift
    assert 0 < fit["blur_sigma"] < 2 and fit["edge_sigma"] == pytest.approx(fit["target_sigma"], abs=0.02)
    assert [step["name"] for step in manifest["postprocessing"]] == ["gaussian_blur", "coloured_noise"]
    source = measure_appearance(Specimen.from_scan(large_scan))
    before = measure_appearance(Specimen.from_pack(generic))
    after = measure_appearance(Specimen.from_pack(calibrated))
    for key in ("grain_std", "pore_std"):
        after_noise, before_noise, source_noise = (getattr(m.noise, key) for m in (after, before, source))
        assert abs(after_noise - source_noise) < 0.2 * abs(before_noise - source_noise)
        assert after_noise == pytest.approx(source_noise, rel=0.1)
    for phase in ("grains", "pores"):  # the noise power spectrum within a factor 2 in every ring to 0.5
        ratio = after.spectra[phase].power[1:5] / source.spectra[phase].power[1:5]
        assert np.all((ratio > 0.5) & (ratio < 2.0)), (phase, ratio)
    assert abs(after.edge_width - source.edge_width) < abs(before.edge_width - source.edge_width)
    assert after.edge_width == pytest.approx(source.edge_width, abs=0.15)
    # the fit is deterministic: the same clean volume gives the same parameters
    clean = Specimen.from_pack(calibrated, clean=True)
    targets = {"grains": fit["target_power"]["grains"], "pores": fit["target_power"]["pores"]}
    again = calibrate(clean.tomogram, clean.labels, clean.region, target_sigma=fit["target_sigma"],
                      target_shift=fit["target_shift"], target_power=targets,
                      target_phase_noise=fit["target_phase_noise"], target_edge_width=fit["target_edge_width"],
                      target_noise=fit["target_noise"],
                      pore_level=fit["pore_level"], grain_level=fit["grain_level"])
    assert again.blur_sigma == pytest.approx(fit["blur_sigma"]) and again.added_power == fit["added_power"]


def test_calibrate_option_is_accepted_and_overrides_the_config(tmp_path, capsys):
    config = tmp_path / "pack.yaml"
    config.write_text("postprocess: generic\n")
    for extra, expected in (([], "generic"), (["--calibrate"], "calibrated")):
        assert main(["-q", "generate", "--sample", "large", "--out", str(tmp_path / "packs"), "--config",
                     str(config), "--print-config", *extra]) == 0
        assert yaml.safe_load(capsys.readouterr().out)["postprocess"] == expected


def test_without_the_source_edge_width_packs_get_match_source_with_a_warning(large_library, caplog):
    statistics = dataclasses.replace(large_library.statistics, edge_width=None)
    unmeasured = ParticleLibrary(large_library.particles, voxel_size=large_library.voxel_size,
                                 unit=large_library.unit, density=large_library.density, statistics=statistics,
                                 source_shape=large_library.source_shape)
    postprocess._warn_once.cache_clear()
    with caplog.at_level(logging.WARNING, logger="synthpack.artefacts.recipes"):
        pack = build_pack(unmeasured, PACK.replace(pour={"n_particles": 12, "batch_size": 12}), seed=0,
                          progress=False)
    assert "calibrated cannot be fitted" in caplog.text and "rebuild the library" in caplog.text
    assert pack.manifest["postprocess_mode"] == "match_source" and "calibration" not in pack.manifest
    assert "edge width" in pack.manifest["postprocess_fallback"]
    assert pack.manifest["noise_match"]["target_noise"] == statistics.noise_std


def test_compare_measures_the_floor_and_the_cnn_and_shows_its_picks(packs, large_scan, tmp_path):
    report = compare(large_scan, [packs[1]], cnn=CnnConfig(epochs=1, width=4))
    paths = report.write(tmp_path / "report")
    assert "cnn_patches.png" in paths and paths["cnn_patches.png"].stat().st_size > 0
    figures = json.loads(paths["realism.json"].read_text())
    floor, classifier = figures["floor"], figures["packs"][0]["distances"]["classifier"]
    assert floor["slab"] == 10 and floor["n_per_class"] >= 500  # twice a pack's patches, split in two
    for name in ("logistic", "cnn"):
        assert 0 <= floor[name]["auc"] <= 1 and floor[name]["seconds"] > 0
        assert classifier[name]["margin"] == pytest.approx(classifier[name]["auc"] - floor[name]["auc"])
    assert figures["settings"]["cnn"]["epochs"] == 1
    # the source's edge is centred on its labels; the pack's sits inside the grains (clean crops end at the mask)
    source_half, pack_half = (f["figures"]["edge_half_height"] for f in (figures["source"], figures["packs"][0]))
    assert abs(source_half) < 0.1 and pack_half > source_half
    nps = figures["packs"][0]["distances"]["nps_ratio"]
    assert nps["grains"]["frequency"] == [0.125, 0.25, 0.375, 0.5, 0.625, 0.75] and len(nps["pores"]["ratio"]) == 6
    markdown = paths["realism.md"].read_text()
    assert "**The floor**" in markdown and "## Classifiers" in markdown and "(cnn_patches.png)" in markdown
    assert "CNN AUC (source: its floor)" in markdown and "edge half height" in markdown
    assert f"{floor['cnn']['auc']:.3f} +- {floor['cnn']['auc_std']:.3f}" in markdown
    # the ablation: both classifiers again on the patches with phases made flat, shown as its own section
    ablation = figures["packs"][0]["distances"]["ablation"]
    assert list(ablation) == ["grains flat", "pores flat", "edges only", "labels only"]
    for name, summary in ablation.items():
        assert 0 <= summary["logistic"]["auc"] <= 1 and 0 <= summary["cnn"]["auc"] <= 1
        assert f"| {name} | {summary['logistic']['auc']:.3f} / {summary['cnn']['auc']:.3f} |" in markdown
    assert "## Where the classifiers see the difference" in markdown


def test_compare_command_writes_the_report(packs, tmp_path, capsys):
    out = tmp_path / "report"
    assert main(["-q", "compare", "--sample", "large", "--packs", str(packs[0]), str(packs[1]),
                 "--out", str(out), "--patch", "12", "--no-cnn", "--no-ablation"]) == 0
    assert sorted(p.name for p in out.iterdir()) == [
        ".synthpack-files", "appearance.png", "realism.json", "realism.md", "slices.png", "structure.png"]
    report = json.loads((out / "realism.json").read_text())
    assert [p["name"] for p in report["packs"]] == ["generic/pack_0000", "default/pack_0000"]
    assert [p["mode"] for p in report["settings"]["packs"]] == ["generic", "calibrated"]
    figures = report["packs"][0]["figures"]
    # the labels' solid fraction of the bulk agrees with the pour's Monte-Carlo estimate from the meshes
    assert figures["solid_fraction"] == pytest.approx(figures["pour_packing_fraction"], abs=0.03)
    assert report["source"]["figures"]["solid_fraction"] == pytest.approx(0.61, abs=0.02)
    for pack in report["packs"]:
        assert 0.5 <= pack["distances"]["classifier"]["logistic"]["auc"] <= 1.0
        assert "cnn" not in pack["distances"]["classifier"]
        assert 0 <= pack["distances"]["ks_diameter"] <= 1 and 0 <= pack["distances"]["ks_roughness"] <= 1
        assert 1.0 < pack["figures"]["roughness_median"] < pack["figures"]["roughness_p90"] < 1.5
    assert report["floor"]["slab"] == 10 and "cnn" not in report["floor"] and report["settings"]["cnn"] is None
    assert report["settings"]["ablation"] is False and all("ablation" not in p["distances"] for p in report["packs"])
    markdown = (out / "realism.md").read_text()  # no ablation table; the logistic's feature groups still shown
    assert "| labels only |" not in markdown and "logistic AUC on one feature group alone" in markdown
    for name, group in (("intensity histogram", "intensities"), ("power spectrum", "spectrum")):
        auc = report["packs"][1]["distances"]["classifier"]["logistic_features"][group]
        assert 0.0 <= auc <= 1.0 and f"| {name} | " in markdown
    assert "logistic AUC" in markdown
    # the two packs are of one pour (the same seed and config but the post-processing); no none pack: no flag
    assert report["settings"]["packs"][0]["pour"] == report["settings"]["packs"][1]["pour"]
    assert report["worse_than_none"] == [] and "worse than none" not in (out / "realism.md").read_text()
    assert [row["figure"] for row in report["packs"][0]["targets"]][:2] == ["logistic AUC", "CNN AUC"]
    assert "median section roughness" in (out / "realism.md").read_text()
    counts = [(f["figures"]["noise_grain_voxels"], f["figures"]["noise_pore_voxels"])
              for f in (report["source"], *report["packs"])]
    assert all(n >= MIN_SAMPLES for pair in counts for n in pair)  # each noise level says what it rests on
    assert f"| {counts[0][0]} / {counts[0][1]} |" in (out / "realism.md").read_text()
    for specimen in (report["source"], *report["packs"]):
        assert specimen["figures"]["pore_width_median"] >= 1 and 0 <= specimen["figures"]["pore_narrow_share"] <= 1
    assert all(0 <= pack["distances"]["ks_pore_width"] <= 1 for pack in report["packs"])
    assert "median pore half-width" in (out / "realism.md").read_text()
    source_bands = report["source"]["figures"]["pore_bands"]
    assert len(source_bands["median"]) == 5 and sum(source_bands["voxels"]) > 0
    assert "## Pore phase against distance from the grains" in (out / "realism.md").read_text()
    printed = capsys.readouterr().out
    assert "floor (source against itself, slabs of 10): logistic AUC" in printed and "cnn AUC" not in printed
    # without packs: the source and its floor only
    floor_only = tmp_path / "floor"
    assert main(["-q", "compare", "--sample", "large", "--out", str(floor_only), "--no-cnn", "--slab", "16"]) == 0
    report = json.loads((floor_only / "realism.json").read_text())
    assert report["packs"] == [] and report["floor"]["slab"] == 16
    assert (floor_only / "realism.md").read_text().startswith("# Realism report: the floor of sample:large")
    assert main(["-q", "compare", "--sample", "large", "--out", str(tmp_path / "y"), "--slab", "0"]) == 2
    assert "slab thickness" in capsys.readouterr().err
    assert main(["-q", "compare", "--sample", "large", "--packs", str(tmp_path / "missing"),
                 "--out", str(tmp_path / "x")]) == 2
    with pytest.raises(SynthpackInputError, match="not a realism report written by synthpack"):
        RealismReport(None, [], []).write(packs[0])  # never replaces a folder that is not a report
