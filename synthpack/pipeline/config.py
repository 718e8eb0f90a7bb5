"""The pack configuration: every parameter of ``synthpack generate``, validated.

A configuration is plain YAML (or a dict) with these sections; every key is
optional and falls back to the default shown by ``synthpack generate
--print-config``::

    seed: 0
    library: {min_voxels: 50, include_border: false, density: 2.65, target_faces: 500}
    grains: {deform: {strength: 0.0, lattice: 3}}
    pour: {n_particles: auto, batch_size: 50, engine: pybullet, scale: 1.0, ...}
    reconstruct: {view: auto, order: 1, wall: true, margin: 4, partial_volume: true, pore_texture: {...}}
    run: {chunks: [64, 256, 256], device: auto, threads: null}
    postprocess: calibrated       # or match_source, generic, randomised, none, or a list of artefact transforms

Each section is the settings dataclass of its stage, where its defaults and checks
are written once: :class:`~synthpack.library.core.LibraryConfig`, :class:`GrainsConfig` (with
:class:`~synthpack.library.deform.DeformConfig`), :class:`~synthpack.physics.PourConfig` and
:class:`~synthpack.render.config.ReconstructConfig` (with its sub-section
:class:`~synthpack.render.pore_texture.PoreTextureConfig`); :class:`RunConfig` says how a pack is
computed (chunk shape, device, threads). ``reconstruct.chunks`` and ``reconstruct.device``
(before synthpack 0.7.0) are still read, with a warning, as ``run.chunks`` and ``run.device``. What each ``postprocess`` value
means is resolved by :func:`~synthpack.artefacts.recipes.resolve_postprocessing`; the
default, ``calibrated``, fits the post-processing to the source scan of the
particle library, which every pack has. ``postprocess: default`` (the name of
``generic`` before synthpack 0.3.0) is still read, with a warning, as the
default. Unknown keys, wrong types and out-of-range values raise
:class:`~synthpack.errors.SynthpackInputError` naming the key.
"""

from __future__ import annotations

import dataclasses
import functools
import logging
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from .._shared.schema import build, default_of, non_negative, one_of, positive, setting
from ..artefacts import from_config
from ..library.deform import DeformConfig
from ..errors import SynthpackInputError
from ..library.core import LibraryConfig
from ..physics.config import PourConfig
from ..artefacts.recipes import POSTPROCESS_MODES
from ..render.config import ReconstructConfig

logger = logging.getLogger(__name__)

__all__ = [
    "PackConfig",
    "GrainsConfig",
    "LibraryConfig",
    "PourConfig",
    "ReconstructConfig",
    "RunConfig",
    "load_config",
]


#: The old name of ``postprocess: generic``, read as the default post-processing, with a warning.
_DEPRECATED_POSTPROCESS = "default"


def _valid_postprocess(value: str | list) -> bool:
    """'calibrated', 'match_source', 'generic', 'randomised', 'none' or a valid list of artefact transforms"""
    if isinstance(value, list):
        from_config(value)  # a bad pipeline raises with the transform's own message
        return True
    return value in POSTPROCESS_MODES or value == _DEPRECATED_POSTPROCESS


@functools.cache
def _warn_deprecated_postprocess(default: str) -> None:
    """Warn, once per process, that ``postprocess: default`` now means `default`."""
    logger.warning("postprocess: default is deprecated and now means the default, %s (fitted to the source "
                   "scan); the recipe it named before synthpack 0.3.0 is postprocess: generic", default)


def _chunk_shape(value: list) -> bool:
    """three positive whole numbers (z, y, x)"""
    return len(value) == 3 and all(isinstance(c, int) and not isinstance(c, bool) and c > 0 for c in value)


def _device(value: str) -> bool:
    """auto, cpu, cuda or cuda:N"""
    return isinstance(value, str) and (value in ("auto", "cpu", "cuda") or (
        value.startswith("cuda:") and value[5:].isdigit()))


#: Keys of ``run`` that were keys of ``reconstruct`` before synthpack 0.7.0 (read with a warning).
_MOVED_TO_RUN = ("chunks", "device")


#: ``run.overlap: auto`` renders while pouring from this many grains (a pour of about 40 s, a render of 10 s).
OVERLAP_MIN_GRAINS = 1000


@dataclass(frozen=True)
class RunConfig:
    """How a pack is computed: the ``run`` section (the render, the post-processing and the store read it).

    The chunk shape is part of the result (post-processing noise is drawn per chunk, and a Zarr
    pack's shards are its chunks); the device and the threads are not: a pack is the same
    voxel for voxel on the CPU with any number of threads, with or without `overlap`, and within
    float rounding on a GPU.
    """

    chunks: list = setting([64, 256, 256], _chunk_shape,
                           "chunk shape (z, y, x) of the chunk-by-chunk rendering and post-processing "
                           "(and the shards of Zarr packs)")
    device: str = setting("auto", _device, "where the render and the post-processing run: auto (the first CUDA "
                          "GPU torch sees, else the CPU), cpu, or cuda / cuda:N; only order 1 renders on a GPU")
    threads: int | None = setting(None, positive, "threads of one pack's chunked stages (default: the CPUs "
                                  "this process may use)")
    overlap: str = setting("auto", one_of(("auto", "on", "off")),
                           "render the tube's chunks that the locked batches bury while the pour goes on (the pour "
                           "in a second process; the same pack voxel for voxel), with 2 threads or more, on the CPU, "
                           f"for reconstruct.view tube: on; auto: for pours of {OVERLAP_MIN_GRAINS} grains or more "
                           "(the second process takes about a second to start); off")


@dataclass(frozen=True)
class GrainsConfig:
    """How the grains of a pack are made from the library's: the ``grains`` section.

    ``deform`` is a sub-section: the free-form deformation of each placed grain
    (:class:`~synthpack.library.deform.DeformConfig`; off by default).
    """

    deform: DeformConfig = field(default_factory=DeformConfig)


@dataclass(frozen=True)
class PackConfig:
    """Everything that defines a synthetic pack; the same config gives the same pack."""

    seed: int = setting(0, non_negative, "run seed; pack k uses a seed derived from it and k")
    library: LibraryConfig = field(default_factory=LibraryConfig)
    grains: GrainsConfig = field(default_factory=GrainsConfig)
    pour: PourConfig = field(default_factory=PourConfig)
    reconstruct: ReconstructConfig = field(default_factory=ReconstructConfig)
    run: RunConfig = field(default_factory=RunConfig)
    postprocess: str | list = setting(
        "calibrated", _valid_postprocess,
        "'calibrated' (blur and noise fitted to the source scan's edge width and noise level; where that "
        "cannot be fitted, match_source with a warning), 'match_source' (Gaussian noise up to the source's "
        "noise level), 'generic' (light blur, weak rings and noise of 3-8% of the contrast, fitted to nothing), "
        "'randomised' (blur, noise level and colour, cupping, rings, contrast and gamma drawn per pack within "
        "wide ranges about the calibrated values), 'none', or a list of artefact transforms",
    )

    def __post_init__(self) -> None:
        if self.postprocess == _DEPRECATED_POSTPROCESS:
            default = default_of(PackConfig, "postprocess")
            _warn_deprecated_postprocess(default)
            object.__setattr__(self, "postprocess", default)

    def to_dict(self) -> dict:
        """A plain, YAML/JSON-able dict of every value."""
        return dataclasses.asdict(self)

    def replace(self, **sections: dict | Any) -> PackConfig:
        """A copy with some values changed, e.g. ``cfg.replace(pour={"n_particles": 50})``."""
        merged = self.to_dict()
        for key, value in sections.items():
            if isinstance(value, dict) and isinstance(merged.get(key), dict):
                merged[key] = {**merged[key], **value}
            else:
                merged[key] = value
        return PackConfig.from_dict(merged)

    @classmethod
    def from_dict(cls, data: dict | None) -> PackConfig:
        """Validate a (possibly partial) dict against the schema."""
        return build(cls, _moved_keys(data or {}))


def _moved_keys(data: Any) -> Any:
    """`data` with ``reconstruct.chunks`` / ``reconstruct.device`` moved to ``run`` (with a warning)."""
    if not isinstance(data, dict) or not isinstance(data.get("reconstruct"), dict):
        return data
    moved = {key: data["reconstruct"][key] for key in _MOVED_TO_RUN if key in data["reconstruct"]}
    if not moved:
        return data
    run = data.get("run") or {}
    if not isinstance(run, dict):
        return data  # build names the bad section
    both = sorted(set(moved) & set(run))
    if both:
        raise SynthpackInputError(f"config keys 'reconstruct.{both[0]}' and 'run.{both[0]}' both given: "
                                  f"keep run.{both[0]} only")
    for key in moved:
        _warn_moved(key)
    reconstruct = {key: value for key, value in data["reconstruct"].items() if key not in moved}
    return {**data, "reconstruct": reconstruct, "run": {**run, **moved}}


@functools.cache
def _warn_moved(key: str) -> None:
    logger.warning("config key reconstruct.%s is now run.%s (read as run.%s); rename it", key, key, key)


def load_config(path: str | os.PathLike | None) -> PackConfig:
    """Read and validate a YAML config file (None gives the defaults)."""
    if path is None:
        return PackConfig()
    path = Path(path)
    if path.is_dir():
        raise SynthpackInputError(f"config file {path} is a folder, not a file: give the path of a YAML config file")
    if not path.is_file():
        raise SynthpackInputError(f"config file {path} does not exist")
    try:
        data = yaml.safe_load(path.read_text(encoding="utf-8"))
    except UnicodeDecodeError as error:
        raise SynthpackInputError(
            f"config file {path} is not UTF-8 text (byte {error.start}): save it as a plain UTF-8 YAML file"
        ) from error
    except yaml.YAMLError as error:
        raise SynthpackInputError(f"config file {path} is not valid YAML: {_yaml_problem(error)}") from error
    return PackConfig.from_dict(data)


def _yaml_problem(error: yaml.YAMLError) -> str:
    """One line: what the YAML parser found and where (line and column, 1-based)."""
    mark = getattr(error, "problem_mark", None)
    problem = getattr(error, "problem", None) or str(error).splitlines()[0]
    where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark is not None else ""
    return f"{problem}{where}"
