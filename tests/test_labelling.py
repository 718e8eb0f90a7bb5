"""`synthpack label`: starting instance labels for a scan that has none (synthpack.scan.labelling)."""

import logging

import numpy as np
import pytest

from synthpack.cli import main
from synthpack.errors import SynthpackInputError
from synthpack.io import read_volume, write_tiff
from synthpack.scan.labelling import STARTING_POINT, LabelConfig, label_scan
from synthpack.metrics import dice_stats


@pytest.fixture(scope="module")
def large_labelling(large_scan):
    return label_scan(large_scan.tomogram)


def _inverted(tomogram: np.ndarray) -> np.ndarray:
    return tomogram.max() + tomogram.min() - tomogram


def test_large_sample_reaches_matched_instance_dice_0_8(large_scan, large_labelling):
    stats = dice_stats(large_labelling.labels, large_scan.labels)
    assert large_labelling.contrast == "bright"  # auto: the grains are the thicker phase
    assert large_labelling.labels.dtype == np.int32
    assert stats.instance_dice_micro >= 0.8
    assert stats.f1 >= 0.8  # most grains found one to one (IoU >= 0.5)
    assert 0.75 * large_scan.n_particles <= large_labelling.n_grains <= 1.1 * large_scan.n_particles


@pytest.mark.parametrize("contrast", ["auto", "dark"])
def test_inverted_contrast_finds_the_grains(large_scan, large_labelling, contrast):
    result = label_scan(_inverted(large_scan.tomogram), LabelConfig(contrast=contrast))
    assert result.contrast == "dark"
    assert dice_stats(result.labels, large_scan.labels).instance_dice_micro >= 0.8
    assert abs(result.n_grains - large_labelling.n_grains) <= 0.05 * large_labelling.n_grains


def test_wrong_contrast_labels_the_pores_instead(large_scan):
    result = label_scan(large_scan.tomogram, LabelConfig(contrast="dark"))
    assert dice_stats(result.labels, large_scan.labels).dice < 0.1  # the pore phase, not the grains


def test_every_labelling_warns_it_is_a_starting_point(blob_scan, caplog):
    with caplog.at_level(logging.WARNING, logger="synthpack"):
        result = label_scan(blob_scan.tomogram, LabelConfig(threshold=0.5, contrast="bright"))
    assert STARTING_POINT in caplog.text
    assert result.threshold == 0.5 and result.n_grains >= 1


def test_a_threshold_outside_the_grey_values_is_refused(blob_scan):
    with pytest.raises(SynthpackInputError, match="give a --threshold between them"):
        label_scan(blob_scan.tomogram, LabelConfig(threshold=float(blob_scan.tomogram.max()) + 1))


def test_cli_writes_labels_and_preview_and_refuses_to_overwrite(tmp_path, large_scan, large_labelling, capsys):
    write_tiff(tmp_path / "scan.tif", large_scan.tomogram, large_scan.voxel_size, large_scan.unit)
    out = tmp_path / "labels.tif"
    assert main(["-q", "label", "--tomogram", str(tmp_path / "scan.tif"), "--out", str(out), "--preview"]) == 0
    labels, voxel_size, unit = read_volume(out)
    np.testing.assert_array_equal(labels, large_labelling.labels)
    assert (voxel_size, unit) == (large_scan.voxel_size, large_scan.unit)
    assert (tmp_path / "labels.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    quiet = capsys.readouterr()  # -q: the warning alone, no summary and no INFO line
    assert quiet.out == "" and quiet.err == f"synthpack: {STARTING_POINT}\n"

    before = out.read_bytes()
    assert main(["-q", "label", "--tomogram", str(tmp_path / "scan.tif"), "--out", str(out)]) == 2
    error = capsys.readouterr().err  # synthpack's own labels too: they may have been corrected by hand
    assert "never replaced unasked" in error and "--overwrite" in error and "not a label volume" not in error
    assert out.read_bytes() == before

    assert main(["label", "--tomogram", str(tmp_path / "scan.tif"), "--out", str(out), "--overwrite"]) == 0
    shown = capsys.readouterr()  # without -q: the summary, and the warning once
    assert shown.out == f"{large_labelling.n_grains} grains labelled in {out}\n"
    assert f"synthpack: labelled {large_labelling.n_grains} grains" in shown.err
    assert shown.err.count("not ground truth") == 1


@pytest.mark.parametrize("option, message", [
    (["--contrast", "sideways"], "invalid choice"),
    (["--min-distance", "0"], "--min-distance is out of range"),
    (["--sigma", "-1"], "--sigma is out of range"),
])
def test_cli_bad_options_are_one_line_errors(tmp_path, blob_scan, capsys, option, message):
    np.save(tmp_path / "scan.npy", blob_scan.tomogram)
    argv = ["label", "--tomogram", str(tmp_path / "scan.npy"), "--out", str(tmp_path / "labels.tif"), *option]
    if option[0] == "--contrast":  # argparse refuses it: exit 2 by SystemExit
        with pytest.raises(SystemExit) as exit_:
            main(argv)
        assert exit_.value.code == 2
    else:
        assert main(argv) == 2
    assert message in capsys.readouterr().err
    assert not (tmp_path / "labels.tif").exists()


def test_cli_refuses_a_non_tiff_output_before_reading(tmp_path, capsys):
    assert main(["label", "--tomogram", str(tmp_path / "missing.tif"), "--out", str(tmp_path / "l.npy")]) == 2
    assert "name ending in .tif" in capsys.readouterr().err
