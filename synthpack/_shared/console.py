"""What synthpack shows on the terminal: its log lines and its progress bars.

Log lines go to stderr as ``synthpack: message``, at the level the command line
chose (`show_logs`: INFO by default, DEBUG with ``--verbose``, WARNING with
``--quiet``). A progress bar is information, like an INFO message: it is hidden
when the ``synthpack`` logger is set above INFO (``--quiet``, or a program that
calls ``logging.getLogger("synthpack").setLevel(logging.WARNING)``), whatever the
``progress`` argument of the function drawing it. A logger left unset (a library
user's default) keeps the bars.
"""

from __future__ import annotations

import contextlib
import logging
import re
from collections.abc import Iterator
from typing import Any

from tqdm.auto import tqdm

__all__ = ["LOG_FORMAT", "log_to_stderr", "progress_bar", "show_logs"]

#: How a synthpack log line reads on the terminal.
LOG_FORMAT = "synthpack: %(message)s"

_PACKAGE = logging.getLogger("synthpack")


def progress_bar(*args: Any, disable: bool = False, **kwargs: Any) -> tqdm:
    """`tqdm.auto.tqdm` with `args` and `kwargs`, disabled also when the ``synthpack`` logger is set above INFO."""
    return tqdm(*args, disable=disable or _PACKAGE.level > logging.INFO, **kwargs)


class _WarnOnce(logging.Filter):
    """Drops a warning of a kind already shown by this handler: packs built side by side (each by its
    own Dask worker, whose records are forwarded here) warn of the same thing once each, often with
    their own figures ("1.6 diameters deep ... pour ~50" and "... pour ~51"). A kind is the message
    with its numbers taken out (`_kind`); the first of a kind is shown."""

    def __init__(self) -> None:
        super().__init__()
        self._shown: set[str] = set()

    def filter(self, record: logging.LogRecord) -> bool:
        if record.levelno != logging.WARNING:
            return True
        kind = _kind(record.getMessage())
        if kind in self._shown:
            return False
        self._shown.add(kind)
        return True


def _kind(message: str) -> str:
    """`message` with every number in it replaced by ``#``."""
    return _NUMBER.sub("#", message)


_NUMBER = re.compile(r"[-+]?\d+(?:\.\d+)?(?:e[-+]?\d+)?")


def log_to_stderr(level: int) -> logging.Handler:
    """Show synthpack's messages of `level` and above on stderr as `LOG_FORMAT`; returns the handler added.

    Only the ``synthpack`` logger is set: other libraries' messages keep their own
    levels (Python's default shows their warnings). A warning is shown once, however
    many times it is logged (by as many packs, each with its own figures: the first is shown).
    """
    handler = logging.StreamHandler()
    handler.setFormatter(logging.Formatter(LOG_FORMAT))
    handler.addFilter(_WarnOnce())
    _PACKAGE.addHandler(handler)
    _PACKAGE.setLevel(level)
    return handler


@contextlib.contextmanager
def show_logs(level: int) -> Iterator[None]:
    """`log_to_stderr` inside the block; the logger's handlers and level as they were after it."""
    saved = _PACKAGE.level
    handler = log_to_stderr(level)
    try:
        yield
    finally:
        _PACKAGE.removeHandler(handler)
        _PACKAGE.setLevel(saved)
