"""Strict JSON for every file synthpack writes: NaN and infinities become null, never a bare ``NaN``.

Python's :func:`json.dumps` writes ``NaN``, ``Infinity`` and ``-Infinity`` by default,
which is not JSON (RFC 8259): strict parsers (JavaScript's ``JSON.parse``, jq,
Rust's serde_json) refuse the file. :func:`dumps` turns every non-finite float into
``null`` (the value is unknown or undefined) and dumps with ``allow_nan=False``, so a
value that slipped through would raise instead of writing a broken file.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["dumps", "plain"]


def plain(value: Any) -> Any:
    """`value` with NumPy scalars and arrays as Python ones, paths as strings, and non-finite floats as None.

    Dicts, lists and tuples are converted recursively; anything else is returned as it is.
    """
    if isinstance(value, dict):
        return {key: plain(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [plain(item) for item in value]
    if isinstance(value, np.ndarray):
        return plain(value.tolist())
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, Path):
        return str(value)
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def dumps(value: Any, **kwargs: Any) -> str:
    """Strict JSON text of `value` (see :func:`plain`); `kwargs` go to :func:`json.dumps` (``indent``, ...).

    Raises
    ------
    TypeError
        For a value JSON cannot hold (after :func:`plain`).
    """
    return json.dumps(plain(value), allow_nan=False, **kwargs)
