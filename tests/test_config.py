import logging

import pytest

from synthpack.pipeline import config as config_module
from synthpack.pipeline.config import PackConfig, load_config
from synthpack.errors import SynthpackInputError


def test_defaults_and_partial_override(tmp_path):
    path = tmp_path / "pack.yaml"
    path.write_text("seed: 7\npour:\n  n_particles: 40\n  scale: [0.9, 1.1]\npostprocess: []\n")
    config = load_config(path)
    assert config.seed == 7
    assert config.pour.n_particles == 40 and config.pour.scale == [0.9, 1.1]
    assert config.pour.batch_size == PackConfig().pour.batch_size
    assert config.postprocess == []
    assert PackConfig.from_dict(config.to_dict()) == config


def test_replace_merges_sections():
    config = PackConfig().replace(pour={"n_particles": 12}, seed=3)
    assert config.pour.n_particles == 12 and config.seed == 3
    assert config.pour.engine == "pybullet"


def test_pore_texture_is_a_sub_section_of_reconstruct():
    assert PackConfig().to_dict()["reconstruct"]["pore_texture"] == {
        "model": "measured", "cutoff": 0.1, "rolloff": 0.1, "sigma": 0.8, "tile": 256, "histogram": True}
    config = PackConfig().replace(reconstruct={"pore_texture": {"sigma": 1.5}})
    assert (config.reconstruct.pore_texture.sigma, config.reconstruct.pore_texture.tile) == (1.5, 256)
    assert PackConfig.from_dict(config.to_dict()) == config


@pytest.mark.parametrize(
    "data, phrase",
    [
        ({"pour": {"n_partcles": 5}}, "unknown config key 'pour.n_partcles'"),
        ({"colour": 1}, "unknown config key 'colour'"),
        ({"pour": {"n_particles": "many"}}, "'pour.n_particles' is out of range: got 'many', expected a whole number > 0, or 'auto'"),
        ({"pour": {"n_particles": 2.5}}, "'pour.n_particles' has the wrong type"),
        ({"library": {"include_border": 1}}, "'library.include_border' has the wrong type"),
        ({"pour": {"n_particles": 0}}, "'pour.n_particles' is out of range"),
        ({"pour": {"engine": "havok"}}, "'pour.engine' is out of range"),
        ({"pour": {"engine_options": {"warp": 1}}}, "unknown config key 'pour.engine_options.warp'"),
        ({"pour": {"engine_options": {"max_hull_vertices": 3}}},
         "'pour.engine_options.max_hull_vertices' is out of range"),
        ({"pour": {"engine_options": {"allow_sleeping": "yes"}}},
         "'pour.engine_options.allow_sleeping' has the wrong type"),
        ({"pour": {"engine": "blender", "engine_options": {"convex_decomposition": True}}},
         "unknown config key 'pour.engine_options.convex_decomposition'"),
        ({"pour": {"engine_options": None}}, "'pour.engine_options' has the wrong type"),
        ({"pour": {"restitution": 1.5}}, "'pour.restitution' is out of range"),
        ({"run": {"chunks": [64, 0, 64]}}, "'run.chunks' is out of range"),
        ({"reconstruct": {"pore_texture": {"sigma": -0.5}}}, "'reconstruct.pore_texture.sigma' is out of range"),
        ({"reconstruct": {"pore_texture": {"rolloff": 0.0}}}, "'reconstruct.pore_texture.rolloff' is out of range"),
        ({"reconstruct": {"pore_texture": {"tile": 6.5}}}, "'reconstruct.pore_texture.tile' has the wrong type"),
        ({"reconstruct": {"pore_texture": {"size": 8}}}, "unknown config key 'reconstruct.pore_texture.size'"),
        ({"reconstruct": {"pore_texture": {"model": "fractal"}}}, "'reconstruct.pore_texture.model'"),
        ({"run": {"device": "gpu"}}, "'run.device' is out of range"),
        ({"reconstruct": {"view": "box"}}, "'reconstruct.view' is out of range"),
        ({"pour": 3}, "must be a mapping"),
    ],
)
def test_bad_key_type_or_value_is_named(data, phrase):
    with pytest.raises(SynthpackInputError, match=phrase.replace("(", r"\(")):
        PackConfig.from_dict(data)


def test_missing_or_invalid_yaml_file(tmp_path):
    with pytest.raises(SynthpackInputError, match="does not exist"):
        load_config(tmp_path / "nope.yaml")
    bad = tmp_path / "bad.yaml"
    bad.write_text("pour: [unclosed\n")
    with pytest.raises(SynthpackInputError, match="not valid YAML"):
        load_config(bad)


def test_postprocess_pipeline_is_validated_when_read():
    config = PackConfig.from_dict({"postprocess": [{"name": "gaussian_noise", "std": 0.05}]})
    assert config.postprocess[0]["std"] == 0.05
    with pytest.raises(SynthpackInputError, match="gaussian_nois"):
        PackConfig.from_dict({"postprocess": [{"name": "gaussian_nois", "std": 0.05}]})
    with pytest.raises(SynthpackInputError, match="'postprocess' is out of range"):
        PackConfig.from_dict({"postprocess": "fancy"})


def test_the_default_post_processing_is_calibrated_and_default_is_a_deprecated_alias(tmp_path, caplog):
    assert PackConfig().postprocess == "calibrated"
    path = tmp_path / "old.yaml"
    path.write_text("postprocess: default\n")
    config_module._warn_deprecated_postprocess.cache_clear()
    with caplog.at_level(logging.WARNING, logger="synthpack.pipeline.config"):
        old = load_config(path)
        again = PackConfig.from_dict({"postprocess": "default"}).replace(seed=2)
    assert old == PackConfig() and again.postprocess == "calibrated"
    (warning,) = caplog.records  # once per process
    assert "postprocess: default is deprecated" in warning.getMessage() and "generic" in warning.getMessage()
    for mode in ("calibrated", "match_source", "generic", "none"):
        assert PackConfig.from_dict({"postprocess": mode}).postprocess == mode


def test_engine_options_are_read_from_yaml_and_checked_against_the_engine(tmp_path):
    path = tmp_path / "pack.yaml"
    path.write_text("pour:\n  engine: blender\n  engine_options: {max_hull_vertices: 32, fixed_steps: 200}\n")
    config = load_config(path)
    assert config.pour.engine_options == {"max_hull_vertices": 32, "fixed_steps": 200}
    assert PackConfig.from_dict(config.to_dict()) == config
    assert PackConfig().pour.engine_options == {}
    with pytest.raises(SynthpackInputError, match="'pour.engine_options.blend_file'"):
        config.replace(pour={"engine": "pybullet", "engine_options": {"blend_file": "a.blend"}})


def test_engine_names_come_from_the_registry():
    from synthpack import cli
    from synthpack.physics.registry import ENGINES

    assert cli._ENGINE_CHOICES == tuple(ENGINES) == ("pybullet", "blender")
    assert PackConfig.from_dict({"pour": {"engine": "blender"}}).pour.engine == "blender"


def test_chunks_and_device_are_run_settings_and_their_old_keys_still_read(tmp_path, caplog):
    path = tmp_path / "old.yaml"
    path.write_text("reconstruct:\n  order: 3\n  chunks: [16, 32, 32]\n  device: cpu\n")
    config_module._warn_moved.cache_clear()
    with caplog.at_level(logging.WARNING, logger="synthpack.pipeline.config"):
        old = load_config(path)
    assert old == PackConfig.from_dict({"reconstruct": {"order": 3}, "run": {"chunks": [16, 32, 32], "device": "cpu"}})
    assert sorted(r.getMessage() for r in caplog.records) == [
        "config key reconstruct.chunks is now run.chunks (read as run.chunks); rename it",
        "config key reconstruct.device is now run.device (read as run.device); rename it"]
    assert "chunks" not in old.to_dict()["reconstruct"] and old.run.threads is None
    with pytest.raises(SynthpackInputError, match="'reconstruct.chunks' and 'run.chunks' both given"):
        PackConfig.from_dict({"reconstruct": {"chunks": [8, 8, 8]}, "run": {"chunks": [8, 8, 8]}})
    with pytest.raises(SynthpackInputError, match="'run.threads' is out of range"):
        PackConfig.from_dict({"run": {"threads": 0}})
