"""A pybullet physics client, imported and connected without its C-level chatter.

pybullet prints a "pybullet build time: ..." banner on stderr when it is imported
(once in every Dask worker process), and V-HACD prints its progress on stdout; both
come from C, which would end up in the middle of a command-line tool's output.

:class:`Client` binds one headless physics server's id to pybullet's functions once,
as Kubric's pybullet simulator does, so callers write ``client.stepSimulation()``
rather than passing ``physicsClientId`` to every call.
"""

from __future__ import annotations

import contextlib
import ctypes
import functools
import os
import sys
from collections.abc import Iterator
from typing import Any

__all__ = ["Client", "silenced_stdout"]

_LIBC = ctypes.CDLL(None)


@contextlib.contextmanager
def _silenced(fd: int) -> Iterator[None]:
    """Send file descriptor `fd` (1: C-level stdout, 2: stderr) to /dev/null inside the block."""
    sys.stdout.flush()
    sys.stderr.flush()
    _LIBC.fflush(None)
    saved = os.dup(fd)
    try:
        with open(os.devnull, "wb") as devnull:
            os.dup2(devnull.fileno(), fd)
        yield
    finally:
        _LIBC.fflush(None)  # C's buffered output goes to /dev/null, not to the terminal
        os.dup2(saved, fd)
        os.close(saved)


def silenced_stdout() -> contextlib.AbstractContextManager[None]:
    """Send file descriptor 1 (C-level stdout) to /dev/null inside the block."""
    return _silenced(1)


with _silenced(2):  # the import-time banner
    import pybullet


class Client:
    """A headless (``DIRECT``) pybullet physics server of its own.

    ``client.f(...)`` is ``pybullet.f(..., physicsClientId=client.id)`` for every
    pybullet function; pybullet's constants are attributes too (``client.GEOM_MESH``).
    Used as a context manager, it disconnects on exit.

    Raises
    ------
    RuntimeError
        If pybullet cannot start a physics server.
    """

    def __init__(self) -> None:
        with silenced_stdout():
            self.id: int = pybullet.connect(pybullet.DIRECT)
        if self.id < 0:
            raise RuntimeError("pybullet could not start a physics server")

    def __getattr__(self, name: str) -> Any:
        value = getattr(pybullet, name)
        if callable(value):
            value = functools.partial(value, physicsClientId=self.id)
        self.__dict__[name] = value  # bound once
        return value

    def close(self) -> None:
        """Disconnect from the physics server."""
        pybullet.disconnect(physicsClientId=self.id)

    def __enter__(self) -> Client:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()
