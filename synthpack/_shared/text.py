"""Numbers as a person reads them in a log line: rounded by their meaning, with their unit.

One place for how synthpack writes a measured figure into a message, so that a
log line never shows ``179.05899047851562``:

- `sig`: intensities, noise levels, lengths: significant figures (3 by default);
- `fraction`: fractions and other figures of a fixed scale: decimals;
- `voxel_size`: a voxel size with its unit, one number when isotropic.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

__all__ = ["sig", "fraction", "voxel_size"]


def sig(value: float | None, digits: int = 3) -> str:
    """`value` to `digits` significant figures, e.g. ``179.0589 -> '179'``, ``0.000522144 -> '0.000522'``.

    Parameters
    ----------
    value : float or None
        Any real number; None (not measured) reads ``"n/a"``, NaN and infinities as Python writes them.
    digits : int
        Significant figures kept.

    Returns
    -------
    str
        The shortest form of `value` rounded to `digits` figures (``%g``: exponent notation
        below 1e-4, e.g. ``'5.2e-05'``, and from 1e6 up, ``'4.12e+06'``); from ``10**digits``
        to 1e6 rounded to a whole number (``'3523'``).
    """
    if value is None:
        return "n/a"
    value = float(value)
    if not math.isfinite(value):
        return str(value)
    if 10**digits <= abs(value) < 1e6:
        return f"{value:.0f}"  # 3523, not 3.52e+03
    return f"{value:.{digits}g}"


def fraction(value: float | None, decimals: int = 2) -> str:
    """A fraction or other figure of a fixed scale to `decimals` decimals, e.g. ``0.5843 -> '0.58'``; None: ``"n/a"``."""
    if value is None or not math.isfinite(float(value)):
        return "n/a" if value is None else str(float(value))
    return f"{float(value):.{decimals}f}"


def voxel_size(size: Sequence[float], unit: str) -> str:
    """``'10 um'`` for an isotropic voxel size ``(10, 10, 10)``, ``'2 x 1 x 1 um'`` (z, y, x) otherwise."""
    figures = [sig(v, 4) for v in size]
    return f"{figures[0] if len(set(figures)) == 1 else ' x '.join(figures)} {unit}"
