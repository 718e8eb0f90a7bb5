"""The machinery every artefact shares: parameters, seeded draws, records, configs.

A `Transform` is a small class that holds its parameters, each either a fixed
value or a ``(min, max)`` range, and a plain functional core. Calling it,
``transform(image, rng)``, draws the parameters that are ranges from `rng`, then
applies the core (which draws its noise from the same generator).
``transform.apply(image, rng)`` returns the output together with a record of what
was applied: a list of dicts such as ``[{"name": "gaussian_noise", "std": 0.031}]``
whose entries are themselves valid configs with every range replaced by the value
drawn, so a record can be stored, read and replayed (with the same generator state
it also reproduces the noise realisation).

`Compose` chains transforms; `from_config` builds a transform or a pipeline from
plain data (a dict or a list of dicts, as read from YAML or JSON) by registered name,
and `to_dict` writes it back.
"""

from __future__ import annotations

import logging
from abc import ABC, abstractmethod
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, ClassVar, Union

import numpy as np

from .._shared.arrays import as_image
from ..errors import SynthpackInputError
from ._param import Param

if TYPE_CHECKING:
    import torch

    from .torch_blocks import DeviceVolume

logger = logging.getLogger(__name__)

__all__ = [
    "BlockContext",
    "Compose",
    "RngLike",
    "Transform",
    "available_transforms",
    "from_config",
]

#: What a transform accepts as its random source: a seed (int), a
#: `numpy.random.Generator` (used and advanced in place) or None (fresh OS entropy,
#: not reproducible).
RngLike = Union[int, np.integer, np.random.Generator, None]

_REGISTRY: dict[str, type[Transform]] = {}


_P = Param("p", minimum=0.0, maximum=1.0, rangeable=False)


@dataclass(frozen=True)
class BlockContext:
    """Where a block sits in the volume, and its random sources: what a block step gets besides the block.

    Attributes
    ----------
    rng : numpy.random.Generator
        The block's own generator (its noise).
    call : numpy.random.SeedSequence
        The same for every block of a call: seeds what is drawn once per volume
        (e.g. ring radii), so that every block draws the same.
    origin : tuple of 3 int
        The global index (z, y, x) of the block's first voxel.
    shape : tuple of 3 int
        The whole volume's shape.
    """

    rng: np.random.Generator
    call: np.random.SeedSequence
    origin: tuple[int, int, int]
    shape: tuple[int, int, int]


class Transform(ABC):
    """Base of every artefact: validated parameters, a seeded draw and a record.

    Subclasses set `name` (the config name), `params` (their `Param` specs, in
    constructor order) and implement `_transform`. Every transform also has `p`,
    the probability in [0, 1] that it is applied at a call (default 1).

    Call it as ``out = transform(image, rng)`` or, to also get the record,
    ``out, record = transform.apply(image, rng)``.
    """

    name: ClassVar[str]
    params: ClassVar[tuple[Param, ...]] = ()
    #: What one output voxel depends on, for block-by-block application
    #: (`synthpack.artefacts.blockwise`): ``"voxel"``: its own input voxel and its
    #: position; ``"neighbourhood"``: the input within `halo` voxels; ``"slice"``:
    #: whole slices (Y, X).
    locality: ClassVar[str] = "voxel"

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        if "name" in cls.__dict__:
            _REGISTRY[cls.name] = cls

    def __init__(self, *, p: float = 1.0, **values: Any) -> None:
        self._values: dict[str, Any] = {
            spec.name: spec.validate(self.name, values[spec.name]) for spec in self.params
        }
        self.p: float = float(_P.validate(self.name, p))

    def __getattr__(self, item: str) -> Any:
        values = self.__dict__.get("_values", {})
        if item in values:
            return values[item]
        raise AttributeError(f"{type(self).__name__!r} object has no attribute {item!r}")

    def sample(self, rng: np.random.Generator) -> dict[str, Any]:
        """Draw the parameters given as ranges; return all parameters as fixed values."""
        return {spec.name: spec.draw(self._values[spec.name], rng) for spec in self.params}

    @abstractmethod
    def _transform(self, image: np.ndarray, rng: np.random.Generator, **params: Any) -> np.ndarray:
        """The functional core: `image` (float32) with the drawn `params` applied, a new array."""

    def halo(self, **params: Any) -> tuple[int, int, int]:
        """Voxels of input ``(z, y, x)`` on each side that one output voxel depends on.

        Zero except for ``"neighbourhood"`` transforms; `params` are the drawn values.
        """
        return (0, 0, 0)

    def _transform_block(self, block: np.ndarray, context: BlockContext, **params: Any) -> np.ndarray:
        """The core on one block of a larger volume (see `synthpack.artefacts.blockwise`).

        Parameters
        ----------
        block : ndarray of float32, shape (z, y, x)
            The input box whose first voxel is ``context.origin`` in a volume of
            ``context.shape`` (with the halo for ``"neighbourhood"`` transforms, whole
            slices for ``"slice"`` ones). Never modified.
        context : BlockContext
            Where the block sits and its random sources.
        **params
            The drawn parameter values.

        Returns
        -------
        ndarray of float32, the shape of `block`
            A new array.

        The default applies `_transform` to the block, with the block's generator:
        right for transforms whose only draws are per-voxel noise and for
        neighbourhood filters.
        """
        return self._transform(block, context.rng, **params)

    def _transform_block_torch(
        self, block: torch.Tensor, context: BlockContext, device: DeviceVolume, **params: Any
    ) -> torch.Tensor:
        """`_transform_block` in torch, on `block`'s device: the same values within float32 rounding.

        Every random draw and table is made on the CPU by the NumPy code of the
        transform's module, from the same generators as `_transform_block`; only the
        arithmetic runs on the device. `device` moves arrays there and keeps what is
        made once per volume (`~synthpack.artefacts.torch_blocks.DeviceVolume`).
        `block` (float32, shape (z, y, x), on ``device.device``) is never modified;
        returns a new float32 tensor of its shape there.

        A transform that has a torch step overrides this in its own module (importing
        torch there, inside the method), and its subclasses inherit it; this default
        has none (`has_torch_step` is False), and a pipeline holding such a transform
        runs on the CPU.
        """
        raise NotImplementedError(f"{type(self).__name__} ({self.name!r}) has no torch block step")

    @property
    def has_torch_step(self) -> bool:
        """Whether the transform, or a class it derives from, defines `_transform_block_torch`."""
        return type(self)._transform_block_torch is not Transform._transform_block_torch

    def record_entry(self, params: Mapping[str, Any]) -> dict[str, Any]:
        """One entry of a record: ``{"name": ..., <parameter>: <value drawn>, ...}``, JSON/YAML-ready."""
        return {"name": self.name, **_plain(params)}

    def apply(self, image: Any, rng: RngLike) -> tuple[np.ndarray, list[dict[str, Any]]]:
        """Apply the transform and return ``(output, record)``.

        Parameters
        ----------
        image : array_like, shape (Z, Y, X) or (H, W)
            Intensities (any real dtype). Never modified.
        rng : int, numpy.random.Generator or None
            Seed or generator of every random draw (parameters and noise). The same
            seed gives the same output; a Generator is advanced in place.

        Returns
        -------
        output : ndarray of float32, same shape as `image`
            A new array, except when the transform was skipped (``p < 1``): then
            `image` itself (as float32) comes back.
        record : list of dict
            ``[{"name": ..., <parameter>: <value drawn>, ...}]``, or ``[]`` when
            skipped. Each entry is a valid config of a fixed transform.
        """
        array = as_image(image)
        generator = np.random.default_rng(rng)
        if self.p < 1.0 and generator.random() >= self.p:
            logger.debug("%s skipped (p=%g)", self.name, self.p)
            return array, []
        drawn = self.sample(generator)
        logger.debug("%s %s on shape %s", self.name, drawn, array.shape)
        out = self._transform(array, generator, **drawn)
        return out, [self.record_entry(drawn)]

    def __call__(self, image: Any, rng: RngLike) -> np.ndarray:
        """Apply the transform; see `apply`, which also returns the record."""
        return self.apply(image, rng)[0]

    def to_dict(self) -> dict[str, Any]:
        """The config of this transform: ``{"name": ..., <parameter>: value or [min, max], "p": ...}``."""
        return {"name": self.name, **_plain(self._values), "p": self.p}

    def __eq__(self, other: object) -> bool:
        return type(other) is type(self) and other.to_dict() == self.to_dict()  # type: ignore[attr-defined]

    __hash__ = None  # type: ignore[assignment]

    def __repr__(self) -> str:
        args = ", ".join(f"{k}={v!r}" for k, v in self._values.items())
        return f"{type(self).__name__}({args}, p={self.p:g})"


def _plain(values: Mapping[str, Any]) -> dict[str, Any]:
    """JSON/YAML-ready copy: tuples become lists."""
    return {k: list(v) if isinstance(v, tuple) else v for k, v in values.items()}


class Compose:
    """Apply transforms in order, passing one generator through all of them.

    Parameters
    ----------
    transforms : sequence of Transform or Compose
        Applied first to last.

    Examples
    --------
    >>> pipeline = Compose([GaussianBlur(sigma=(0.5, 1.0)), GaussianNoise(std=0.05)])
    >>> out, record = pipeline.apply(volume, rng=7)
    >>> pipeline.to_config()
    [{'name': 'gaussian_blur', 'sigma': [0.5, 1.0], 'p': 1.0}, {'name': 'gaussian_noise', 'std': 0.05, 'p': 1.0}]
    """

    name: ClassVar[str] = "compose"

    def __init__(self, transforms: Sequence[Transform | Compose]) -> None:
        if isinstance(transforms, (Transform, Compose)) or not isinstance(transforms, Sequence):
            raise SynthpackInputError(
                "Compose takes a list of transforms, e.g. Compose([GaussianNoise(0.05)])"
            )
        for t in transforms:
            if not isinstance(t, (Transform, Compose)):
                raise SynthpackInputError(
                    f"Compose got {t!r}, which is not an artefact transform: build it with "
                    "a transform class or from_config"
                )
        self.transforms: list[Transform | Compose] = list(transforms)

    def apply(self, image: Any, rng: RngLike) -> tuple[np.ndarray, list[dict[str, Any]]]:
        """Apply every transform in order; return ``(output, record)``.

        The record lists what was applied, in order (see `Transform.apply`);
        ``from_config(record)`` rebuilds those transforms with the drawn values.
        """
        generator = np.random.default_rng(rng)
        out = as_image(image)
        record: list[dict[str, Any]] = []
        for transform in self.transforms:
            out, applied = transform.apply(out, generator)
            record.extend(applied)
        return out, record

    def __call__(self, image: Any, rng: RngLike) -> np.ndarray:
        """Apply every transform in order; see `apply`, which also returns the record."""
        return self.apply(image, rng)[0]

    def to_config(self) -> list[dict[str, Any]]:
        """The pipeline as a list of transform configs (what `from_config` reads)."""
        return [t.to_dict() for t in self.transforms]

    def to_dict(self) -> dict[str, Any]:
        """``{"name": "compose", "transforms": [...]}``, for nesting in another pipeline."""
        return {"name": self.name, "transforms": self.to_config()}

    def __len__(self) -> int:
        return len(self.transforms)

    def __iter__(self) -> Iterator[Transform | Compose]:
        return iter(self.transforms)

    def __getitem__(self, index: int) -> Transform | Compose:
        return self.transforms[index]

    def __eq__(self, other: object) -> bool:
        return isinstance(other, Compose) and other.to_dict() == self.to_dict()

    __hash__ = None  # type: ignore[assignment]

    def __repr__(self) -> str:
        inner = ",\n    ".join(repr(t) for t in self.transforms)
        return f"Compose([\n    {inner},\n])" if self.transforms else "Compose([])"


def available_transforms() -> list[str]:
    """The names `from_config` accepts, sorted."""
    return sorted([*_REGISTRY, Compose.name])


def from_config(config: Mapping[str, Any] | Sequence[Mapping[str, Any]]) -> Transform | Compose:
    """Build a transform or pipeline from plain data (e.g. read from YAML or JSON).

    Parameters
    ----------
    config : dict or list of dict
        A dict ``{"name": <name>, <parameter>: value, ...}`` builds one transform
        (``{"name": "compose", "transforms": [...]}`` a pipeline); a list of such
        dicts builds a `Compose`. Values are numbers, ``[min, max]`` ranges drawn
        per call, or (for some parameters) strings, lists or null. Parameters left
        out take their defaults. Example::

            [{"name": "gaussian_blur", "sigma": [0.5, 1.0]},
             {"name": "gaussian_noise", "std": 0.05}]

    Returns
    -------
    Transform or Compose

    Raises
    ------
    SynthpackInputError
        For an unknown name (the message lists the valid ones), an unknown
        parameter (it lists the valid ones), a value of the wrong type or out of range.
    """
    if isinstance(config, Sequence) and not isinstance(config, (str, bytes)):
        return Compose([from_config(entry) for entry in config])
    if not isinstance(config, Mapping):
        raise SynthpackInputError(
            f"an artefact config must be a mapping such as {{'name': 'gaussian_noise', 'std': 0.05}} "
            f"or a list of them, got {config!r}"
        )
    if "name" not in config:
        raise SynthpackInputError(
            f"the artefact config {dict(config)!r} has no 'name': add one of "
            f"{', '.join(available_transforms())}"
        )
    name = config["name"]
    rest = {k: v for k, v in config.items() if k != "name"}
    if name == Compose.name:
        unknown = set(rest) - {"transforms"}
        if unknown or "transforms" not in rest:
            raise SynthpackInputError(
                f"a 'compose' config takes exactly one key 'transforms' (a list), got {sorted(rest)}"
            )
        return Compose([from_config(entry) for entry in rest["transforms"]])
    cls = _REGISTRY.get(name) if isinstance(name, str) else None
    if cls is None:
        raise SynthpackInputError(
            f"unknown artefact transform {name!r}: valid names are {', '.join(available_transforms())}"
        )
    valid = [spec.name for spec in cls.params] + ["p"]
    unknown = sorted(str(k) for k in rest if k not in valid)
    if unknown:
        raise SynthpackInputError(
            f"unknown parameter(s) {', '.join(map(repr, unknown))} for {name!r}: valid parameters "
            f"are {', '.join(valid)}"
        )
    return cls(**rest)
