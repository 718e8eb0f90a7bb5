"""The pack configuration: every parameter of ``synthpack generate``, validated.

A configuration is plain YAML (or a dict) with four sections; every key is
optional and falls back to the default shown by ``synthpack generate
--print-config``::

    seed: 0
    library: {min_voxels: 50, include_border: false, density: 2.65, target_faces: 500}
    pour: {n_particles: 150, batch_size: 50, engine: pybullet, scale: 1.0, ...}
    reconstruct: {order: 1, wall: true, margin: 4, chunks: [64, 256, 256]}
    postprocess: default          # or none, match_source, calibrated, or a list of artefact transforms

Unknown keys, wrong types and out-of-range values raise
:class:`~synthpack.errors.SynthpackInputError` naming the key.
"""

from __future__ import annotations

import dataclasses
import os
import types
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from .errors import SynthpackInputError

__all__ = [
    "PackConfig",
    "LibraryConfig",
    "PourConfig",
    "ReconstructConfig",
    "load_config",
]


def _valid_pipeline(transforms: list) -> bool:
    """Build the artefact pipeline once, so a bad one fails when the config is read."""
    from .artefacts import from_config

    from_config(transforms)
    return True


def _positive(value) -> bool:
    return value > 0


def _non_negative(value) -> bool:
    return value >= 0


def _range(low: float, high: float):
    def check(value) -> bool:
        return low <= value <= high

    check.__doc__ = f"between {low} and {high}"
    return check


_positive.__doc__ = "positive"
_non_negative.__doc__ = "zero or more"


def _spec(default: Any, check=None, help: str = "") -> Any:
    factory = {"default_factory": lambda: list(default)} if isinstance(default, list) else {"default": default}
    return field(**factory, metadata={"check": check, "help": help})


@dataclass(frozen=True)
class LibraryConfig:
    """Particle extraction and meshing (paper 3.1-3.2)."""

    min_voxels: int = _spec(50, _positive, "drop particles smaller than this many voxels")
    include_border: bool = _spec(False, None, "keep particles cut by the scan border")
    density: float = _spec(2.65, _positive, "grain density for masses (paper eq. 1)")
    target_faces: int = _spec(500, lambda v: v >= 8, "faces per mesh after decimation")


@dataclass(frozen=True)
class PourConfig:
    """Batched rigid-body pouring (paper 3.3)."""

    n_particles: int = _spec(150, _positive, "grains poured into the tube")
    batch_size: int = _spec(50, _positive, "grains per batch; each batch settles and is locked")
    engine: str = _spec("pybullet", lambda v: v in ("pybullet", "blender"), "pybullet or blender")
    scale: float | list = _spec(1.0, None, "grain scale factor, or [min, max] drawn per grain")
    tube_radius: float | None = _spec(None, _positive, "inner tube radius (physical units); default from the scan")
    tube_height: float | None = _spec(None, _positive, "tube height (physical units); default from n_particles")
    friction: float = _spec(0.6, _non_negative, "friction coefficient")
    restitution: float = _spec(0.1, _range(0.0, 1.0), "restitution (bounciness)")


@dataclass(frozen=True)
class ReconstructConfig:
    """Rebuilding the tomogram from the placements (paper 3.4)."""

    order: int = _spec(1, lambda v: v in (0, 1, 3), "interpolation of intensities: 0, 1 (linear) or 3 (cubic)")
    wall: bool = _spec(True, None, "draw the tube wall")
    wall_intensity: float | None = _spec(None, None, "wall intensity; default between pores and grains")
    margin: int = _spec(4, _non_negative, "voxels of margin around the tube")
    chunks: list = _spec([64, 256, 256], lambda v: len(v) == 3 and all(isinstance(c, int) and c > 0 for c in v),
                         "chunk shape (z, y, x) of the chunk-by-chunk rendering and post-processing "
                         "(and the shards of Zarr packs)")


@dataclass(frozen=True)
class PackConfig:
    """Everything that defines a synthetic pack; the same config gives the same pack."""

    seed: int = _spec(0, _non_negative, "run seed; pack k uses a seed derived from it and k")
    library: LibraryConfig = field(default_factory=LibraryConfig)
    pour: PourConfig = field(default_factory=PourConfig)
    reconstruct: ReconstructConfig = field(default_factory=ReconstructConfig)
    postprocess: str | list = _spec(
        "default",
        lambda v: _valid_pipeline(v) if isinstance(v, list) else v in ("default", "none", "match_source", "calibrated"),
        "'default', 'none', 'match_source' (Gaussian noise up to the source scan's noise level), "
        "'calibrated' (blur and noise fitted to the source's edge width and noise level) "
        "or a list of artefact transforms",
    )

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
        return _build(cls, data or {}, "")


def _alternatives(annotation: Any) -> tuple:
    if typing.get_origin(annotation) in (typing.Union, types.UnionType):
        return typing.get_args(annotation)
    return (annotation,)


def _type_ok(value: Any, annotation: Any) -> bool:
    for kind in _alternatives(annotation):
        if kind is type(None) and value is None:
            return True
        if kind is float and isinstance(value, (int, float)) and not isinstance(value, bool):
            return True
        if kind is int and isinstance(value, int) and not isinstance(value, bool):
            return True
        if kind in (bool, str, list, dict) and isinstance(value, kind):
            return True
    return False


def _build(cls: type, data: Any, prefix: str):
    if not isinstance(data, dict):
        raise SynthpackInputError(f"config section {prefix or 'top level'!r} must be a mapping, got {data!r}")
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls)}
    unknown = sorted(set(data) - set(fields))
    if unknown:
        raise SynthpackInputError(
            f"unknown config key {prefix + unknown[0]!r}; valid keys here: {', '.join(fields)}"
        )
    values = {}
    for name, value in data.items():
        key, annotation = prefix + name, hints[name]
        if dataclasses.is_dataclass(annotation):
            values[name] = _build(annotation, value, key + ".")
            continue
        if not _type_ok(value, annotation):
            raise SynthpackInputError(
                f"config key {key!r} has the wrong type: got {value!r}, expected {_type_name(annotation)}"
            )
        check = fields[name].metadata.get("check")
        if check is not None and value is not None and not check(value):
            raise SynthpackInputError(
                f"config key {key!r} is out of range: got {value!r}, expected {check.__doc__ or fields[name].metadata['help']}"
            )
        values[name] = value
    return cls(**values)


def _type_name(annotation: Any) -> str:
    names = [getattr(a, "__name__", str(a)) for a in _alternatives(annotation)]
    return " or ".join("null" if n == "NoneType" else n for n in names)


def load_config(path: str | os.PathLike | None) -> PackConfig:
    """Read and validate a YAML config file (None gives the defaults)."""
    if path is None:
        return PackConfig()
    path = Path(path)
    if not path.is_file():
        raise SynthpackInputError(f"config file {path} does not exist")
    try:
        data = yaml.safe_load(path.read_text())
    except yaml.YAMLError as error:
        raise SynthpackInputError(f"config file {path} is not valid YAML: {error}") from error
    return PackConfig.from_dict(data)
