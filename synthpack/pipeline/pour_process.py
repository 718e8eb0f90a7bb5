"""The pour in a second Python process, each batch handed to this one as it is locked, so the render can start on it.

A pour runs on one core, and its engine (pybullet) holds Python's GIL while it steps: a
render in a thread of the same process would slow every step. `pour_in_process` runs the
pour function in a new interpreter (``python -m synthpack.pipeline.pour_process``, which
imports nothing of the calling program: a script without a ``__main__`` guard is not run
twice, as it would be by `multiprocessing`'s spawn). The arguments go to it pickled through
its standard input; it sends back, pickled through a pipe of its own, each locked batch
(`~synthpack.physics.LockedGrains`), its log records and then the placements, or its error,
which is raised here. Its log records go to this process's loggers, so they show as the
pour's own; its progress bar writes to the same terminal. It ignores Ctrl-C: this process
stops it.
"""

from __future__ import annotations

import logging
import os
import pickle
import signal
import subprocess
import sys
import traceback
from collections.abc import Callable
from typing import Any, BinaryIO

from ..physics import LockedGrains, Placements

logger = logging.getLogger(__name__)

__all__ = ["pour_in_process", "can_start_pour_process"]

#: Seconds the pour's process may take to exit once it has sent its placements, before it is stopped.
_EXIT_WAIT = 10.0


def can_start_pour_process() -> bool:
    """Whether this process may start the pour's: Python's executable is known (not an embedded interpreter)."""
    return bool(sys.executable) and os.path.isfile(sys.executable)


class _ToParent(logging.Handler):
    """Sends each log record, its message formatted and its arguments dropped, to the parent process."""

    def __init__(self, send: Callable[[str, Any], None]) -> None:
        super().__init__()
        self.send = send

    def emit(self, record: logging.LogRecord) -> None:
        try:
            record.msg, record.args = record.getMessage(), None
            if record.exc_info:
                record.exc_text = logging.Formatter().formatException(record.exc_info)
            record.exc_info = None
            self.send("log", record)
        except Exception:  # a record that cannot be sent must not stop the pour
            self.handleError(record)


def _sender(stream: BinaryIO) -> Callable[[str, Any], None]:
    def send(kind: str, payload: Any) -> None:
        pickle.dump((kind, payload), stream, protocol=pickle.HIGHEST_PROTOCOL)
        stream.flush()
    return send


def _child(fd: int) -> None:
    """The pour's process: reads ``(pour, kwargs, level)`` from standard input, sends through `fd`."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the parent's to handle; it stops this process
    with os.fdopen(fd, "wb") as stream:
        send = _sender(stream)
        pour, kwargs, level = pickle.load(sys.stdin.buffer)
        root = logging.getLogger()
        root.handlers[:] = [_ToParent(send)]
        root.setLevel(logging.WARNING)
        logging.getLogger("synthpack").setLevel(level)
        try:
            placements = pour(**kwargs, on_lock=lambda grains: send("locked", grains))
        except BaseException as error:  # noqa: BLE001 - every failure goes to the parent
            trace = traceback.format_exc()
            try:
                send("error", (error, trace))
            except Exception:  # an error that does not pickle goes as its text
                send("error", (RuntimeError(f"{type(error).__name__}: {error}"), trace))
            return
        send("done", placements)


def _environment() -> dict[str, str]:
    """This process's environment, with its module search path: the pour's process imports what this one does."""
    environment = dict(os.environ)
    environment["PYTHONPATH"] = os.pathsep.join(path for path in sys.path if isinstance(path, str) and path)
    return environment


def pour_in_process(pour: Callable[..., Placements], on_lock: Callable[[LockedGrains], None],
                    **kwargs: Any) -> Placements:
    """``pour(**kwargs, on_lock=on_lock)`` run in a new Python process; `on_lock` is called here, in this thread.

    Parameters
    ----------
    pour : callable
        A module-level function taking `kwargs` and ``on_lock`` (e.g. `synthpack.physics.pour`)
        and returning the placements.
    on_lock : callable
        ``on_lock(grains)`` with each batch's `~synthpack.physics.LockedGrains` as it is locked.
    **kwargs
        Picklable arguments of `pour`.

    Returns
    -------
    Placements
        What `pour` returned.

    Raises
    ------
    Exception
        What `pour` raised (its traceback in the pour's process added as a note), or a
        RuntimeError when the process ended without a result.
    """
    read, write = os.pipe()
    try:
        process = subprocess.Popen(
            [sys.executable, "-m", __name__, str(write)], stdin=subprocess.PIPE, pass_fds=(write,),
            env=_environment(),
        )
    finally:
        os.close(write)  # this end now lives in the pour's process only: its exit ends the pipe
    ended = False  # the pour's process has sent its last message
    with os.fdopen(read, "rb") as stream:
        try:
            pickle.dump((pour, kwargs, logging.getLogger("synthpack").getEffectiveLevel()), process.stdin,
                        protocol=pickle.HIGHEST_PROTOCOL)
            process.stdin.close()
            while True:
                try:
                    kind, payload = pickle.load(stream)
                except EOFError:
                    process.wait(_EXIT_WAIT)
                    raise RuntimeError(f"the pour's process ended without a result (exit code {process.returncode}); "
                                         "set run.overlap: false to pour in this process") from None
                if kind == "log":
                    logging.getLogger(payload.name).handle(payload)
                elif kind == "locked":
                    on_lock(payload)
                else:
                    ended = True
                    if kind == "done":
                        return payload
                    error, trace = payload
                    error.add_note(f"in the pour's process:\n{trace}")
                    raise error
        finally:
            try:
                process.wait(_EXIT_WAIT if ended else 0)
            except subprocess.TimeoutExpired:  # stopped here (Ctrl-C, a render error), or hung at its exit
                process.kill()
                process.wait()


if __name__ == "__main__":
    _child(int(sys.argv[1]))
