"""Settings dataclasses with their own checks: the one place every default is written.

Each stage owns a frozen dataclass of its settings (`synthpack.library.core.LibraryConfig`,
`synthpack.physics.PourConfig`, `synthpack.render.ReconstructConfig`), whose fields
are declared with :func:`setting`: a default, a check and a help text. The pack config
(`synthpack.pipeline.config.PackConfig`) nests them, :func:`build` validates a (partial) dict
against them, and the command line takes its defaults and help from the same fields
(:func:`default_of`, :func:`help_of`).
"""

from __future__ import annotations

import dataclasses
import math
import types
import typing
from collections.abc import Callable, Iterable
from typing import Any

from ..errors import SynthpackInputError

__all__ = [
    "setting", "finite", "positive", "non_negative", "in_range", "one_of", "build", "config_key", "option_name",
    "default_of", "help_of",
]

Check = Callable[[Any], bool]


def setting(default: Any, check: Check | None = None, help: str = "") -> Any:
    """A dataclass field with a default, a check and a help text.

    Parameters
    ----------
    default : Any
        The default value (a list or dict default is copied for each instance).
    check : callable, optional
        ``check(value) -> bool``; its ``__doc__`` says what is expected, for the
        error message. Not called for ``None``.
    help : str
        One line for ``--help`` and ``--print-config`` readers.
    """
    mutable = isinstance(default, (list, dict))
    factory = {"default_factory": lambda: type(default)(default)} if mutable else {"default": default}
    return dataclasses.field(**factory, metadata={"check": check, "help": help})


def _described(check: Check, text: str) -> Check:
    check.__doc__ = text
    return check


def _finite(value: Any) -> bool:
    return not isinstance(value, float) or math.isfinite(value)


finite = _described(_finite, "a finite number")
positive = _described(lambda value: _finite(value) and value > 0, "positive")
non_negative = _described(lambda value: _finite(value) and value >= 0, "zero or more")


def in_range(low: float, high: float) -> Check:
    """A check for ``low <= value <= high``."""
    return _described(lambda value: low <= value <= high, f"between {low} and {high}")


def one_of(choices: Iterable[Any]) -> Check:
    """A check for membership of `choices`."""
    choices = tuple(choices)
    return _described(lambda value: value in choices, "one of " + ", ".join(map(str, choices)))


def default_of(cls: type, name: str) -> Any:
    """The default of field `name` of settings dataclass `cls`."""
    field = {f.name: f for f in dataclasses.fields(cls)}[name]
    return field.default_factory() if field.default is dataclasses.MISSING else field.default


def help_of(cls: type, name: str) -> str:
    """The help text of field `name` of settings dataclass `cls`, with its default."""
    field = {f.name: f for f in dataclasses.fields(cls)}[name]
    default = default_of(cls, name)
    text = field.metadata["help"] if default is None else f"{field.metadata['help']} (default {default})"
    return text.replace("%", "%%")


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


def _type_name(annotation: Any) -> str:
    names = [getattr(a, "__name__", str(a)) for a in _alternatives(annotation)]
    return " or ".join("null" if n == "NoneType" else n for n in names)


def config_key(key: str) -> str:
    """How a setting is named in messages about a config file: ``config key 'pour.scale'``."""
    return f"config key {key!r}"


def option_name(key: str) -> str:
    """How a setting is named in messages about command-line options: ``--tube-radius``."""
    return "--" + key.rsplit(".", 1)[-1].replace("_", "-")


def build(cls: type, data: Any, prefix: str = "", name: Callable[[str], str] = config_key):
    """An instance of settings dataclass `cls` from a (partial) dict, every value checked.

    Parameters
    ----------
    cls : type
        A settings dataclass whose fields were declared with :func:`setting`.
    data : dict
        Values by field name; missing fields take their defaults.
    prefix : str
        Dotted path of this section in the whole config, for messages.
    name : callable
        ``name(key) -> str`` names a setting in messages (:func:`config_key`,
        :func:`option_name`).

    Raises
    ------
    SynthpackInputError
        For a section that is not a mapping, an unknown key, a wrong type or a
        value its check refuses; the message names the key.
    """
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
    for field_name, value in data.items():
        key, annotation = prefix + field_name, hints[field_name]
        if dataclasses.is_dataclass(annotation):
            values[field_name] = build(annotation, value, key + ".", name)
            continue
        if not _type_ok(value, annotation):
            raise SynthpackInputError(
                f"{name(key)} has the wrong type: got {value!r}, expected {_type_name(annotation)}"
            )
        check = fields[field_name].metadata.get("check")
        if check is not None and value is not None and not check(value):
            raise SynthpackInputError(
                f"{name(key)} is out of range: got {value!r}, "
                f"expected {check.__doc__ or fields[field_name].metadata['help']}"
            )
        values[field_name] = value
    return cls(**values)
