"""Parameters of artefact transforms: a fixed value or a (min, max) range, validated."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np

from ..errors import SynthpackInputError

__all__ = ["IntRange", "Param", "Range"]

#: A real parameter: a fixed number or a (min, max) pair drawn uniformly per call.
Range = float | Sequence[float]
#: An integer parameter: a fixed integer or a (min, max) pair, both ends included.
IntRange = int | Sequence[int]


def _is_number(value: Any) -> bool:
    return isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, (bool, np.bool_))


@dataclass(frozen=True)
class Param:
    """One parameter of a transform: its kind, allowed values and whether it may be a range.

    Attributes
    ----------
    name : str
        The keyword of the transform's constructor and the key in its config.
    kind : {"float", "int", "choice", "floats"}
        A real number, an integer, one string of `choices`, or a list of reals.
    minimum, maximum : float or None
        Bounds of the allowed values (inclusive unless `exclusive_minimum`).
    exclusive_minimum : bool
        Whether `minimum` itself is not allowed (e.g. a photon count must be > 0).
    rangeable : bool
        Whether a ``(min, max)`` pair may be given, drawn uniformly per call.
    optional : bool
        Whether None is allowed (meaning "derive it from the image").
    choices : tuple of str
        The allowed strings of a "choice" parameter.
    """

    name: str
    kind: Literal["float", "int", "choice", "floats"] = "float"
    minimum: float | None = None
    maximum: float | None = None
    exclusive_minimum: bool = False
    rangeable: bool = True
    optional: bool = False
    choices: tuple[str, ...] = ()

    def _where(self, owner: str) -> str:
        return f"parameter {self.name!r} of {owner!r}"

    def _domain(self) -> str:
        parts = []
        if self.minimum is not None:
            parts.append(f"{'>' if self.exclusive_minimum else '>='} {self.minimum:g}")
        if self.maximum is not None:
            parts.append(f"<= {self.maximum:g}")
        return " and ".join(parts) or "finite"

    def _expected(self) -> str:
        what = {"float": "a number", "int": "an integer", "floats": "a list of numbers"}.get(
            self.kind, f"one of {', '.join(map(repr, self.choices))}"
        )
        if self.rangeable:
            what += f" or a [min, max] pair of {'integers' if self.kind == 'int' else 'numbers'}"
        if self.optional:
            what += " or null"
        return what

    def _scalar(self, owner: str, value: Any) -> float | int:
        if not _is_number(value):
            hint = ""
            if isinstance(value, str):
                try:
                    float(value)
                    hint = " (YAML reads numbers such as 1e4 as text: write 1.0e4 or 10000)"
                except ValueError:
                    pass
            raise SynthpackInputError(
                f"{self._where(owner)} must be {self._expected()}, got {value!r} "
                f"({type(value).__name__}){hint}"
            )
        number = float(value)
        if not math.isfinite(number):
            raise SynthpackInputError(f"{self._where(owner)} must be finite, got {value!r}")
        if self.kind == "int":
            if number != round(number):
                raise SynthpackInputError(
                    f"{self._where(owner)} must be a whole number, got {value!r}: round it"
                )
            number = int(round(number))
        low, high = self.minimum, self.maximum
        if (
            (low is not None and (number < low or (self.exclusive_minimum and number == low)))
            or (high is not None and number > high)
        ):
            raise SynthpackInputError(
                f"{self._where(owner)} must be {self._domain()}, got {value!r}: "
                "give a value in that range"
            )
        return number

    def validate(self, owner: str, value: Any) -> Any:
        """Check `value` for the transform named `owner` and return it normalised.

        Numbers come back as Python floats or ints, ranges as a ``(min, max)``
        tuple, lists of numbers as a tuple of floats.

        Raises
        ------
        SynthpackInputError
            If `value` has the wrong type or lies outside the allowed values; the
            message names the transform, the parameter and what is allowed.
        """
        if value is None:
            if self.optional:
                return None
            raise SynthpackInputError(f"{self._where(owner)} must be {self._expected()}, got null")
        if self.kind == "choice":
            if value not in self.choices:
                raise SynthpackInputError(
                    f"{self._where(owner)} must be {self._expected()}, got {value!r}"
                )
            return str(value)
        if self.kind == "floats":
            if isinstance(value, (str, bytes)) or not isinstance(value, (Sequence, np.ndarray)):
                raise SynthpackInputError(
                    f"{self._where(owner)} must be {self._expected()}, got {value!r}"
                )
            return tuple(float(self._scalar(owner, v)) for v in value)
        if isinstance(value, (Sequence, np.ndarray)) and not isinstance(value, (str, bytes)):
            if not self.rangeable:
                raise SynthpackInputError(
                    f"{self._where(owner)} must be a single value, not a range: got {value!r}"
                )
            if len(value) != 2:
                raise SynthpackInputError(
                    f"{self._where(owner)} must be {self._expected()}, got {len(value)} values {value!r}"
                )
            low, high = (self._scalar(owner, v) for v in value)
            if low > high:
                raise SynthpackInputError(
                    f"{self._where(owner)} is the range {list(value)!r} whose minimum exceeds its "
                    "maximum: write it as [min, max]"
                )
            return (low, high)
        return self._scalar(owner, value)

    def draw(self, value: Any, rng: np.random.Generator) -> Any:
        """Return `value` itself, or a uniform draw from it when it is a range."""
        if not isinstance(value, tuple) or self.kind == "floats":
            return value
        low, high = value
        if self.kind == "int":
            return int(rng.integers(low, high + 1))
        return float(low + (high - low) * rng.random())
