"""Safe output: write under a temporary name, rename into place when complete, delete only our own.

Every file and folder synthpack writes goes through :func:`atomic_file` or
:func:`atomic_directory`: the content is written under a temporary sibling name
(``.NAME.tmp-PID-XXXXXXXX``) and renamed into place when complete, so a reader never
sees a half-written output. What is already at the path is replaced only when it is
synthpack's own output of the same kind (an :class:`Output` recognises it by a marker
file or a signature), or an empty folder. Anything else is refused with
:class:`~synthpack.errors.SynthpackInputError` before anything is deleted, unless
``overwrite=True``: then a folder receives synthpack's files next to what it holds
(files of the same names are replaced, nothing else is touched) and a file is replaced.

Temporary siblings left by a killed process (its PID no longer runs) are removed the
next time the same output is written. :func:`check_output` runs the same checks up
front, so a command can refuse a bad output path before any work starts.
"""

from __future__ import annotations

import contextlib
import os
import re
import shutil
import tempfile
import uuid
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

from .errors import SynthpackInputError

__all__ = ["Output", "atomic_directory", "atomic_file", "check_output"]

_STAGING = re.compile(r"^\.(?P<name>.+)\.tmp-(?:(?P<pid>\d+)-)?[0-9a-f]{8}$")


def _never(path: Path) -> bool:
    return False


@dataclass(frozen=True)
class Output:
    """A kind of output synthpack writes, and how to recognise an earlier one of its own.

    Attributes
    ----------
    what : str
        What it is, for messages: ``"particle library"``.
    folder : bool
        True for a folder, False for a single file.
    marker : str, optional
        For a folder: a file whose presence marks synthpack's own output of this kind.
    is_ours : callable, optional
        ``is_ours(path) -> bool`` for outputs that need more than a marker file.
    """

    what: str
    folder: bool = True
    marker: str | None = None
    is_ours: Callable[[Path], bool] = _never

    def owns(self, path: Path) -> bool:
        """Whether `path` holds synthpack's own earlier output of this kind."""
        if self.marker is not None and (path / self.marker).is_file():
            return True
        return self.is_ours(path)


#: A plain file or folder with no earlier version to recognise (callers that need more pass their own).
FILE = Output("file", folder=False)
FOLDER = Output("folder")


def _staging_name(final: Path) -> Path:
    return final.with_name(f".{final.name}.tmp-{os.getpid()}-{uuid.uuid4().hex[:8]}")


def _running(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def remove_stale_staging(final: Path) -> None:
    """Remove temporary siblings of `final` left by processes that no longer run."""
    parent = final.parent
    if not parent.is_dir():
        return
    for entry in parent.iterdir():
        match = _STAGING.match(entry.name)
        if match is None or match["name"] != final.name:
            continue
        pid = match["pid"]
        if pid is not None and _running(int(pid)):
            continue
        if entry.is_dir() and not entry.is_symlink():
            shutil.rmtree(entry, ignore_errors=True)
        else:
            entry.unlink(missing_ok=True)


def _writable_parent(final: Path) -> None:
    """Refuse a path whose folder cannot be created or written, before any work (and without creating it)."""
    ancestor = final.parent
    while not ancestor.exists() and not ancestor.is_symlink() and ancestor != ancestor.parent:
        ancestor = ancestor.parent
    if not ancestor.is_dir():
        raise SynthpackInputError(f"cannot write {final}: {ancestor} is not a folder; choose another path")
    try:
        with tempfile.NamedTemporaryFile(dir=ancestor, prefix=".synthpack-probe-"):
            pass
    except OSError as error:
        reason = error.strerror or type(error).__name__
        raise SynthpackInputError(
            f"cannot write {final}: {reason} in {ancestor}; choose a folder you can write to"
        ) from error


def check_output(path: str | os.PathLike, output: Output, *, overwrite: bool = False) -> Path:
    """Check that `output` may be written at `path`, before any work starts.

    Parameters
    ----------
    path : path-like
        Where the output goes.
    output : Output
        What is written there.
    overwrite : bool
        Write into (a folder) or replace (a file) what is there even when it is
        not synthpack's own output of this kind.

    Returns
    -------
    Path

    Raises
    ------
    SynthpackInputError
        If the path is a file where a folder goes or the other way round, if it
        holds something that is not synthpack's own output of this kind (and not
        `overwrite`), or if its folder cannot be created or written.
    """
    final = Path(path)
    if final.is_symlink() and not final.exists():
        raise SynthpackInputError(f"{final} is a broken symbolic link: remove it or choose another path")
    if final.exists():
        if output.folder and not final.is_dir():
            raise SynthpackInputError(
                f"{final} is a file, but the {output.what} is a folder: give a folder path (new or empty)"
            )
        if not output.folder and final.is_dir():
            raise SynthpackInputError(f"{final} is a folder, but the {output.what} is a file: give a file name")
        if not (overwrite or _replaceable(final, output)):
            kept = "write into it (files of other names in it are kept)" if output.folder else "replace it"
            raise SynthpackInputError(
                f"{final} exists and is not a {output.what} written by synthpack: choose a new "
                f"{'or empty folder' if output.folder else 'file name'}, or pass --overwrite to {kept}"
            )
    _writable_parent(final)
    return final


def _replaceable(final: Path, output: Output) -> bool:
    if output.folder and final.is_dir() and not final.is_symlink() and not any(final.iterdir()):
        return True
    return output.owns(final)


def _merge(staging: Path, final: Path) -> None:
    """Move every entry of `staging` into the existing folder `final`, replacing entries of the same names."""
    for entry in sorted(staging.iterdir()):
        target = final / entry.name
        if target.is_dir() and not target.is_symlink():
            if not entry.is_dir():
                raise SynthpackInputError(f"cannot write {target}: a folder of that name is in the way")
            _merge(entry, target)
        else:
            os.replace(entry, target)
    staging.rmdir()


@contextlib.contextmanager
def atomic_directory(path: str | os.PathLike, output: Output = FOLDER, *, overwrite: bool = False) -> Iterator[Path]:
    """Yield a temporary folder that replaces `path` only if the block succeeds.

    On an exception, or when the final rename fails, the temporary folder is removed
    and `path` is left as it was. An earlier output at `path` is replaced only if
    `output` recognises it as synthpack's own (or it is an empty folder); with
    `overwrite` a foreign folder receives the new files instead, its other files kept.

    Raises
    ------
    SynthpackInputError
        From :func:`check_output`, before the block runs.
    """
    final = check_output(path, output, overwrite=overwrite)
    final.parent.mkdir(parents=True, exist_ok=True)
    remove_stale_staging(final)
    staging = _staging_name(final)
    staging.mkdir()
    try:
        yield staging
        if final.exists() and not _replaceable(final, output):
            _merge(staging, final)  # overwrite=True on a foreign folder: never delete its files
        elif final.exists():
            retired = _staging_name(final)
            os.replace(final, retired)
            try:
                os.replace(staging, final)
            except OSError:
                os.replace(retired, final)
                raise
            shutil.rmtree(retired, ignore_errors=True)
        else:
            os.replace(staging, final)
    finally:
        if staging.exists():
            shutil.rmtree(staging, ignore_errors=True)


@contextlib.contextmanager
def atomic_file(path: str | os.PathLike, output: Output = FILE, *, overwrite: bool = True) -> Iterator[Path]:
    """Yield a temporary file path that is renamed to `path` only if the block succeeds.

    Files inside an output folder of synthpack's own are replaced freely
    (``overwrite=True``, the default); a file the user names directly passes its
    `output` kind and ``overwrite`` from the command line, so a foreign file is
    refused before anything is written.
    """
    final = check_output(path, output, overwrite=overwrite)
    final.parent.mkdir(parents=True, exist_ok=True)
    remove_stale_staging(final)
    staging = _staging_name(final)
    try:
        yield staging
        os.replace(staging, final)
    finally:
        staging.unlink(missing_ok=True)
