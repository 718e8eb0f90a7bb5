"""pybullet, connected without its C-level chatter on stdout.

pybullet prints a "pybullet build time: ..." banner when the first physics server
starts, and V-HACD prints its progress; both come from C ``printf`` (buffered), which
would end up in the middle of a command-line tool's output.
"""

from __future__ import annotations

import contextlib
import ctypes
import os
import sys
from collections.abc import Iterator

import pybullet

__all__ = ["pybullet", "silenced_stdout", "connect"]

_LIBC = ctypes.CDLL(None)


@contextlib.contextmanager
def silenced_stdout() -> Iterator[None]:
    """Send file descriptor 1 (C-level stdout) to /dev/null inside the block."""
    sys.stdout.flush()
    _LIBC.fflush(None)
    saved = os.dup(1)
    try:
        with open(os.devnull, "wb") as devnull:
            os.dup2(devnull.fileno(), 1)
        yield
    finally:
        _LIBC.fflush(None)  # C's buffered output goes to /dev/null, not to the terminal
        os.dup2(saved, 1)
        os.close(saved)


def connect() -> int:
    """Start a headless (``DIRECT``) physics server; its client id.

    Raises
    ------
    RuntimeError
        If pybullet cannot start one.
    """
    with silenced_stdout():
        client = pybullet.connect(pybullet.DIRECT)
    if client < 0:
        raise RuntimeError("pybullet could not start a physics server")
    return client
