"""Free-form deformation of the grains (synthpack.library.deform): identity at 0, volume, watertight meshes,
mesh and mask in agreement, recorded and reproducible placements."""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy import ndimage

from synthpack.cli import main
from synthpack.pipeline.config import PackConfig
from synthpack.library.deform import MIN_JACOBIAN, DeformConfig, LatticeFFD, deform_particle, draw_ffd, pack_grains, redo_grains
from synthpack.errors import SynthpackInputError
from synthpack.pipeline.generate import build_pack
from synthpack.physics import PourConfig, pour
from synthpack.physics.placements import Placements

CONFIG = PackConfig().replace(pour={"n_particles": 24, "batch_size": 12}, run={"chunks": [32, 64, 64]},
                              postprocess="none")
DEFORMED = CONFIG.replace(grains={"deform": {"strength": 0.3}})


@pytest.fixture(scope="module")
def deformed_pack(large_library):
    return build_pack(large_library, DEFORMED, 7, progress=False, threads=1)


def _mask_centroid_xyz(particle) -> np.ndarray:
    """The mask's centroid in the particle's local frame, (x, y, z), physical units."""
    centroid = np.array(ndimage.center_of_mass(particle.mask)) - (np.array(particle.mask.shape) - 1) / 2
    return (centroid * np.array(particle.voxel_size))[::-1]


def test_zero_displacements_are_the_identity(large_library):
    particle = large_library[5]
    ffd, factor = draw_ffd(particle, 0.0, 3, seed=1)
    points = np.asarray(particle.mesh.vertices)
    assert factor == 1.0
    assert np.array_equal(ffd.forward(points), points)
    same = deform_particle(particle, ffd, large_library.statistics.pore_mean)
    assert np.array_equal(same.mask, particle.mask)
    assert np.array_equal(same.tomogram, particle.tomogram)
    np.testing.assert_allclose(same.mesh.vertices, particle.mesh.vertices, atol=1e-9)
    assert pack_grains(large_library, 10, DeformConfig(strength=0.0), seed=1) is None


def test_strength_zero_pack_is_the_undeformed_pack(large_library):
    """grains.deform.strength 0 takes the code path of a config without deformation: no record, format 1."""
    pack = build_pack(large_library, CONFIG.replace(grains={"deform": {"strength": 0.0, "lattice": 4}}), 7,
                      progress=False, threads=1)
    reference = build_pack(large_library, CONFIG, 7, progress=False, threads=1)
    assert pack.placements.to_dict() == reference.placements.to_dict()
    assert pack.placements.to_dict()["version"] == 1 and "grains" not in pack.placements.to_dict()
    assert np.array_equal(pack.labels, reference.labels) and np.array_equal(pack.clean, reference.clean)
    assert "deform" not in pack.manifest["timings"]


@pytest.mark.parametrize("strength", [0.1, 0.3])
def test_deformed_grains_keep_their_volume_and_stay_watertight(large_library, strength):
    particles = large_library[:12]
    voxel = float(np.prod(large_library.voxel_size))
    for seed, particle in enumerate(particles):
        ffd, factor = draw_ffd(particle, strength, 3, seed)
        assert ffd.min_jacobian() >= MIN_JACOBIAN and 0 < factor <= 1
        assert np.abs(ffd.displacements).max() > 0.3 * strength * factor  # it did move
        grain = deform_particle(particle, ffd, large_library.statistics.pore_mean)
        assert grain.mesh.is_watertight and grain.mesh.volume > 0
        assert grain.volume == pytest.approx(particle.volume, rel=1e-9)
        assert grain.voxel_count == pytest.approx(particle.voxel_count, rel=0.05)
        # mesh and mask agree: volume, and place in the grain's frame
        assert grain.voxel_count * voxel == pytest.approx(grain.volume, rel=0.05)
        assert np.abs(_mask_centroid_xyz(grain) - grain.center_mass).max() < 0.5 * min(grain.voxel_size)
        assert not np.array_equal(grain.mask.shape, particle.mask.shape) or not np.array_equal(grain.mask, particle.mask)


def test_inverse_undoes_forward():
    rng = np.random.default_rng(0)
    ffd = LatticeFFD(np.array([-10.0, -20.0, -5.0]), np.array([20.0, 40.0, 10.0]),
                     rng.uniform(-0.1, 0.1, (3, 3, 3, 3)))
    points = ffd.lo + rng.uniform(0, 1, (500, 3)) * ffd.extent
    found, converged = ffd.inverse(ffd.forward(points))
    assert converged.all()
    np.testing.assert_allclose(found, points, atol=1e-4)
    numeric = (ffd.forward(points[:5] + [1e-6, 0, 0]) - ffd.forward(points[:5] - [1e-6, 0, 0])) / 2e-6
    np.testing.assert_allclose(ffd.jacobian(points[:5])[:, :, 0], numeric, atol=1e-6)


def test_rendered_grains_match_their_deformed_meshes(large_library, deformed_pack):
    placements = deformed_pack.placements
    grains = redo_grains(large_library, placements.indices, placements.grains)
    counts = np.bincount(deformed_pack.labels.ravel(), minlength=len(placements) + 1)[1:]
    voxel = float(np.prod(large_library.voxel_size))
    expected = np.array([g.volume for g in grains]) * placements.scales**3 / voxel
    # touching grains share a contested voxel now and then: every grain within 5%
    np.testing.assert_allclose(counts, expected, rtol=0.05)
    assert placements.checks.n_outside == 0


def test_placements_record_the_deformation_and_redo_it(large_library, deformed_pack, tmp_path):
    placements = deformed_pack.placements
    record = placements.grains
    assert record["method"] == "lattice-ffd" and record["strength"] == 0.3 and record["lattice"] == 3
    assert len(record["seeds"]) == len(record["factors"]) == len(placements)
    assert all(0 <= i < len(large_library) for i in placements.indices)
    saved = json.loads(placements.save(tmp_path / "placements.json").read_text())
    assert saved["version"] == 2 and saved["grains"] == record
    loaded = Placements.load(tmp_path / "placements.json")
    assert loaded.grains == record and np.array_equal(loaded.indices, placements.indices)
    made = pack_grains(large_library, len(placements), DeformConfig(strength=0.3), seed=7)
    again = redo_grains(large_library, loaded.indices, loaded.grains)
    for a, b in zip(made.particles, again):
        assert np.array_equal(a.mask, b.mask) and np.array_equal(a.tomogram, b.tomogram)
        assert np.array_equal(a.mesh.vertices, b.mesh.vertices)


def test_same_seed_same_placements_with_deformation(large_library, deformed_pack):
    again = build_pack(large_library, DEFORMED, 7, progress=False, threads=2)
    assert again.placements.to_dict() == deformed_pack.placements.to_dict()
    assert np.array_equal(again.labels, deformed_pack.labels)
    other = pack_grains(large_library, 24, DeformConfig(strength=0.3), seed=8)
    assert other.record["seeds"] != deformed_pack.placements.grains["seeds"]


def test_bad_settings_and_indices_are_refused(large_library):
    with pytest.raises(SynthpackInputError, match="'grains.deform.strength' is out of range"):
        PackConfig.from_dict({"grains": {"deform": {"strength": 0.8}}})
    with pytest.raises(SynthpackInputError, match="unknown config key 'grains.deform.amount'"):
        PackConfig.from_dict({"grains": {"deform": {"amount": 0.1}}})
    with pytest.raises(SynthpackInputError, match="indices must be 4 whole numbers"):
        pour(large_library, PourConfig(n_particles=4, batch_size=4), 0, indices=[0, 1, 2, len(large_library)],
             progress=False)


def test_cli_deform_strength_sets_the_config(capsys):
    assert main(["generate", "--out", "unused", "--print-config", "--deform-strength", "0.2"]) == 0
    printed = capsys.readouterr().out
    assert "deform:\n    strength: 0.2\n    lattice: 3" in printed
    assert main(["generate", "--out", "unused", "--print-config", "--deform-strength", "0.9"]) == 2
