import re
import subprocess
import sys
import tracemalloc

import numpy as np
import pytest
import tifffile

import synthpack
from synthpack.cli import main
from synthpack.io import write_tiff
from synthpack.library.core import ParticleLibrary


def test_library_build_from_sample_writes_library_and_preview(tmp_path, capsys):
    out, preview = tmp_path / "lib", tmp_path / "preview.png"
    code = main(["-q", "library", "build", "--sample", "large", "--out", str(out),
                 "--workers", "1", "--preview", str(preview)])
    assert code == 0
    library = ParticleLibrary.load(out)
    assert len(library) > 30
    assert preview.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert f"{len(library)} particles" in capsys.readouterr().out
    assert main(["library", "info", str(out)]) == 0


def test_library_build_from_tiff_files_with_voxel_size(tmp_path, blob_scan):
    write_tiff(tmp_path / "t.tif", blob_scan.tomogram, (1, 1, 1))
    write_tiff(tmp_path / "l.tif", blob_scan.labels, (1, 1, 1), labels=True)
    code = main(["-q", "library", "build", "--tomogram", str(tmp_path / "t.tif"), "--labels",
                 str(tmp_path / "l.tif"), "--voxel-size", "2", "1", "1", "--min-voxels", "100",
                 "--out", str(tmp_path / "lib"), "--workers", "1"])
    assert code == 0
    library = ParticleLibrary.load(tmp_path / "lib")
    assert library.voxel_size == (2.0, 1.0, 1.0)
    assert [p.label for p in library] == [1, 2, 3]


def test_library_build_can_exclude_the_test_block(tmp_path, blob_scan):
    # blob 1 spans z 5-14 and blob 2 z 9-21; the central 20% of 30 z-slices is 12-17
    np.save(tmp_path / "t.npy", blob_scan.tomogram)
    np.save(tmp_path / "l.npy", blob_scan.labels)
    code = main(["-q", "library", "build", "--tomogram", str(tmp_path / "t.npy"), "--labels",
                 str(tmp_path / "l.npy"), "--voxel-size", "1", "--min-voxels", "10",
                 "--exclude-test-block", "0", "--out", str(tmp_path / "lib"), "--workers", "1"])
    assert code == 0
    library = ParticleLibrary.load(tmp_path / "lib")
    assert [p.label for p in library] == [3]
    assert library.settings["exclude_slices"] == [12, 18]


def test_input_errors_are_one_line_with_exit_code_2(tmp_path):
    labels = np.zeros((8, 8, 8), dtype=np.float32)
    labels[2:5, 2:5, 2:5] = 1.5
    np.save(tmp_path / "labels.npy", labels)
    np.save(tmp_path / "tomo.npy", np.ones((8, 8, 8), dtype=np.float32))
    cases = [
        (["library", "info", str(tmp_path / "missing")], "does not exist"),
        (["library", "build", "--tomogram", str(tmp_path / "tomo.npy"), "--labels",
          str(tmp_path / "labels.npy"), "--out", str(tmp_path / "lib")], "fractional"),
        (["library", "build", "--tomogram", str(tmp_path / "tomo.npy"), "--out", str(tmp_path / "lib")],
         "no source scan"),
    ]
    for argv, phrase in cases:
        run = subprocess.run([sys.executable, "-m", "synthpack.cli", "-q", *argv], capture_output=True, text=True)
        assert run.returncode == 2, run.stderr
        assert "Traceback" not in run.stderr
        assert phrase in run.stderr
        assert len(run.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "lib").exists()


def test_pour_and_generate_with_the_same_settings_pour_the_same_pack_in_the_same_tube(tmp_path, large_library, capsys):
    """One PourConfig from the options of either command, one tube sizing (`PourConfig.tube`), one `pour`.

    A looser target than the default packing fraction sizes a taller tube; ``synthpack pour`` with a
    ``--tube-radius`` sized its tube without the target, so the two commands poured into different tubes.
    """
    from synthpack.physics import Placements, Tube
    from synthpack.pipeline.generate import pack_seed
    from synthpack.store.pack import open_pack

    library_dir = large_library.save(tmp_path / "lib")
    settings = ["--n-particles", "8", "--batch-size", "8", "--tube-radius", "400", "--target-solid-fraction", "0.4"]
    assert main(["-q", "pour", "--library", str(library_dir), "--out", str(tmp_path / "p.json"), *settings,
                 "--seed", str(pack_seed(0, 0))]) == 0
    poured = Placements.load(tmp_path / "p.json")
    assert len(poured) == 8 and poured.checks.n_outside == 0
    # 8 grains have no bulk: the summary says the target was not judged, not that it was missed
    assert poured.checks.target_reached is None and "(target 0.400: not judged, no bulk)" in capsys.readouterr().out
    config = tmp_path / "pack.yaml"
    config.write_text("postprocess: none\nreconstruct:\n  wall: false\n")
    assert main(["-q", "generate", "--library", str(library_dir), "--out", str(tmp_path / "packs"), *settings,
                 "--config", str(config), "--preview"]) == 0
    pack = open_pack(tmp_path / "packs" / "pack_0000")
    assert pack.manifest["config"]["pour"]["n_particles"] == 8
    assert pack.manifest["config"]["pour"]["tube_radius"] == 400.0
    assert (tmp_path / "packs" / "pack_0000" / "preview.png").is_file()
    generated = Placements.load(tmp_path / "packs" / "pack_0000" / "placements.json")
    assert generated.tube == poured.tube
    assert poured.tube.inner_radius == 400.0
    assert poured.tube.height > Tube.for_library(large_library, 8, inner_radius=400.0).height  # sized for 0.4
    np.testing.assert_array_equal(generated.indices, poured.indices)
    np.testing.assert_array_equal(generated.positions, poured.positions)
    bad = tmp_path / "bad.yaml"
    bad.write_text("pour:\n  n_particle: 8\n")
    assert main(["-q", "generate", "--library", str(library_dir), "--out", str(tmp_path / "x"),
                 "--config", str(bad)]) == 2


def test_a_pack_too_small_for_a_bulk_warns_once_per_step_with_the_grains_that_give_one(tmp_path, large_library,
                                                                                      capsys):
    """The pour's target and ``calibrated`` both need a bulk: both warnings name the same count, for the CLI and a config."""
    from synthpack.artefacts import recipes
    from synthpack.errors import SynthpackInputError
    from synthpack.realism.region import Specimen
    from synthpack.store.pack import open_pack

    recipes._warn_once.cache_clear()  # each warning is logged once per process
    library_dir = large_library.save(tmp_path / "lib")
    assert main(["generate", "--library", str(library_dir), "--out", str(tmp_path / "packs"),
                 "--n-particles", "8", "--batch-size", "8"]) == 0
    lines = capsys.readouterr().err.splitlines()
    (target,) = [line for line in lines if "not judged" in line]
    (fit,) = [line for line in lines if "calibrated cannot be fitted" in line]
    counts = {int(re.search(r"pour ~(\d+): --n-particles \1 \(pour\.n_particles\)",
                            line).group(1)) for line in (target, fit)}
    (count,) = counts
    assert count > 8
    assert "diameters deep, a bulk needs > 3" in target and "(no bulk region: " in fit
    pack = tmp_path / "packs" / "pack_0000"
    assert "no bulk region" in open_pack(pack).manifest["postprocess_fallback"]
    with pytest.raises(SynthpackInputError, match=rf"pack .*pack_0000: no bulk region: .*pour ~{count}:"):
        Specimen.from_pack(pack)  # what `synthpack compare` measures: the error names the pack


@pytest.mark.parametrize("values", [(4_000_000_000,), (3, 70_000, 4_000_000_000)])
def test_library_build_from_huge_sparse_labels_keeps_their_values(tmp_path, blob_scan, values):
    """Issue 13 case 8: label 4e9 made find_objects allocate for 4e9 labels (MemoryError)."""
    lookup = np.zeros(5, dtype=np.uint32)
    lookup[1:1 + len(values)] = values
    write_tiff(tmp_path / "t.tif", blob_scan.tomogram, (1, 1, 1))
    tifffile.imwrite(tmp_path / "l.tif", lookup[blob_scan.labels])
    tracemalloc.start()
    try:
        code = main(["-q", "library", "build", "--tomogram", str(tmp_path / "t.tif"), "--labels",
                     str(tmp_path / "l.tif"), "--min-voxels", "10", "--out", str(tmp_path / "lib"),
                     "--workers", "1"])
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert code == 0
    assert peak < 64e6
    assert [p.label for p in ParticleLibrary.load(tmp_path / "lib")] == sorted(values)


def test_python_dash_m_synthpack_is_the_command_line():
    run = subprocess.run([sys.executable, "-m", "synthpack", "--version"], capture_output=True, text=True)
    assert run.returncode == 0 and run.stdout.strip().endswith(synthpack.__version__)
