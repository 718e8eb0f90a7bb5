"""Matplotlib for the pictures synthpack writes: one place for the headless backend."""

from __future__ import annotations

from typing import Any

__all__ = ["pyplot"]


def pyplot() -> Any:
    """``matplotlib.pyplot`` on the non-interactive Agg backend (PNG files, no display needed).

    Imported on first use, so ``import synthpack`` does not load matplotlib.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt
