"""Lazy re-exports for a package's ``__init__`` (PEP 562): each public name is imported on first use.

A stage package re-exports the public names of its modules without importing them, so that
``import synthpack`` and the command line's help stay fast and free of the heavy libraries
(torch, pybullet, Zarr) until a name that needs one is used.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Mapping
from typing import Any


def lazy_exports(package: str, names: Mapping[str, str]) -> tuple[Callable[[str], Any], Callable[[], list[str]], list[str]]:
    """The ``__getattr__``, ``__dir__`` and ``__all__`` of a package that re-exports names lazily.

    Parameters
    ----------
    package : str
        The package's ``__name__``.
    names : mapping of str to str
        Public name -> the module that defines it, relative to `package` (``".core"``) or absolute.

    Returns
    -------
    __getattr__, __dir__ : callable
        Module-level hooks: ``__getattr__(name)`` imports the defining module on first use.
    __all__ : list of str
        The public names, sorted.
    """
    module_globals = importlib.import_module(package).__dict__

    def __getattr__(name: str) -> Any:
        if name in names:
            value = getattr(importlib.import_module(names[name], package), name)
            module_globals[name] = value
            return value
        raise AttributeError(f"module {package!r} has no attribute {name!r}")

    def __dir__() -> list[str]:
        return sorted(set(module_globals) | set(names))

    return __getattr__, __dir__, sorted(names)
