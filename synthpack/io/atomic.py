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

A folder output records what synthpack wrote in it: :data:`RECORD` (``.synthpack-files``,
JSON) lists its files and folders by relative POSIX path. Replacing an earlier output of
synthpack's own deletes only what that earlier output recorded; every other entry (a
file or folder the user added) is carried into the new folder (hard-linked, or copied
where the file system cannot link, so that it exists in the earlier folder until the new
one is renamed into place) and logged. When a new file would land where such an entry
is, the write is refused before anything is deleted, unless ``overwrite``. An earlier
output written before synthpack kept the record (or whose record is unreadable) loses
nothing: the new files replace those of the same names, every other entry is kept, and
a warning says that stale files of the earlier output may remain. A Zarr store (a folder
holding ``zarr.json``) is one volume: inside an output it is recorded, kept and
replaced whole, like a file, and an output that is a Zarr store gets no record (Zarr
warns about foreign files in a group) and is replaced whole.

Temporary siblings left by a killed process (its PID no longer runs) are removed the
next time the same output is written; an earlier output it had moved aside to replace
(``.NAME.tmp-old-PID-XXXXXXXX``) is put back first when nothing took its place.
:func:`check_output` runs the same checks up front, so a command can refuse a bad output
path before any work starts.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import re
import shutil
import tempfile
import uuid
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path, PurePosixPath

from ..errors import SynthpackInputError

__all__ = ["RECORD", "Output", "atomic_directory", "atomic_file", "check_output"]

logger = logging.getLogger(__name__)

#: The file in each folder output that lists what synthpack wrote there (relative POSIX paths).
RECORD = ".synthpack-files"

_STAGING = re.compile(r"^\.(?P<name>.+)\.tmp-(?P<retired>old-)?(?:(?P<pid>\d+)-)?[0-9a-f]{8}$")


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
    never_replaced : str, optional
        For an output that is never replaced unasked, even synthpack's own: why, for the
        message (``"it may have been corrected by hand since"``).
    """

    what: str
    folder: bool = True
    marker: str | None = None
    is_ours: Callable[[Path], bool] = _never
    never_replaced: str | None = None

    def owns(self, path: Path) -> bool:
        """Whether `path` holds synthpack's own earlier output of this kind."""
        if self.marker is not None and (path / self.marker).is_file():
            return True
        return self.is_ours(path)


#: A plain file or folder with no earlier version to recognise (callers that need more pass their own).
FILE = Output("file", folder=False)
FOLDER = Output("folder")


def _staging_name(final: Path, retired: bool = False) -> Path:
    """A temporary sibling of `final`; a `retired` one holds the earlier output while the new one is renamed in."""
    return final.with_name(f".{final.name}.tmp-{'old-' if retired else ''}{os.getpid()}-{uuid.uuid4().hex[:8]}")


def _running(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def remove_stale_staging(final: Path) -> None:
    """Remove temporary siblings of `final` left by processes that no longer run.

    A retired earlier output whose process was killed before the new one took its
    place is renamed back to `final` instead (when nothing is there).
    """
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
        if match["retired"] and not os.path.lexists(final):
            os.replace(entry, final)
            logger.warning("put back %s: a killed run had moved it aside to replace it", final)
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
        if not overwrite and output.never_replaced is not None:
            raise SynthpackInputError(
                f"{final} exists, and {_a(output.what)} is never replaced unasked ({output.never_replaced}): "
                "choose a new file name, or pass --overwrite (overwrite=True in Python) to replace it"
            )
        if not (overwrite or _replaceable(final, output)):
            kept = "write into it (files of other names in it are kept)" if output.folder else "replace it"
            raise SynthpackInputError(
                f"{final} exists and is not {_a(output.what)} written by synthpack: choose a new "
                f"{'or empty folder' if output.folder else 'file name'}, or pass --overwrite (overwrite=True in Python) to {kept}"
            )
    _writable_parent(final)
    return final


def _a(what: str) -> str:
    """``"an evaluation report"``, ``"a pack"``: `what` with its indefinite article."""
    return f"{'an' if what[:1].lower() in 'aeiou' else 'a'} {what}"


def _replaceable(final: Path, output: Output) -> bool:
    if output.folder and final.is_dir() and not final.is_symlink() and not any(final.iterdir()):
        return True
    return output.owns(final)


def _is_unit(path: Path) -> bool:
    """Whether `path` is recorded, kept and replaced whole: a file, a link, or a Zarr store."""
    return not path.is_dir() or path.is_symlink() or (path / "zarr.json").is_file()


def _contents(root: Path) -> dict[str, list[str]]:
    """What `root` holds, but its record: ``files`` (Zarr stores too) and ``folders``, relative POSIX paths."""
    record: dict[str, list[str]] = {"files": [], "folders": []}

    def walk(folder: Path, prefix: str) -> None:
        for entry in sorted(folder.iterdir()):
            relative = prefix + entry.name
            if relative == RECORD:
                continue
            if _is_unit(entry):
                record["files"].append(relative)
            else:
                record["folders"].append(relative)
                walk(entry, relative + "/")

    walk(root, "")
    return record


def _read_record(folder: Path) -> dict[str, list[str]] | None:
    """The record of an earlier output in `folder`, or None when it has none (older synthpack) or it is unreadable."""
    try:
        record = json.loads((folder / RECORD).read_text())
    except (OSError, ValueError):
        return None
    if not isinstance(record, dict):
        return None
    lists = [record.get(key) for key in ("files", "folders")]
    if not all(isinstance(value, list) and all(isinstance(v, str) for v in value) for value in lists):
        return None
    return {"files": lists[0], "folders": lists[1]}


@dataclass
class _Plan:
    """What happens to the entries of an earlier folder (relative POSIX paths) when a new output replaces it."""

    kept: list[str]  # not written by synthpack: carried into the new output
    replaced: list[str]  # not written by synthpack, replaced by a new file of the same name (allowed)
    clashes: list[str]  # not written by synthpack, in the way of a new file or folder (refused)


def _plan(old: Path, new: Path, record: dict[str, list[str]] | None, *, replace: bool) -> _Plan:
    """Sort the entries of the earlier folder `old` that `record` does not list, against the new folder `new`.

    With `replace`, an unrecorded file where the new output has a file of the same
    name is replaced; otherwise it is a clash. A file where a folder goes (or the
    other way round) is always a clash.
    """
    ours = set(record["files"]) if record else set()
    under = set(record["folders"]) if record else set()  # folders holding (or being) something recorded
    for path in ours:
        under.update(str(parent) for parent in PurePosixPath(path).parents if str(parent) != ".")
    plan = _Plan([], [], [])

    def walk(folder: Path, target_folder: Path, prefix: str, blocked: bool) -> None:
        for entry in sorted(folder.iterdir()):
            relative = prefix + entry.name
            if relative == RECORD:
                continue
            target = target_folder / entry.name
            present = not blocked and os.path.lexists(target)
            if _is_unit(entry):
                if relative in ours:
                    continue
                if blocked or (present and not (replace and _is_unit(target))):
                    plan.clashes.append(relative)
                else:
                    (plan.replaced if present else plan.kept).append(relative)
            elif relative not in under and (blocked or not present or _is_unit(target)):
                (plan.kept if not (blocked or present) else plan.clashes).append(relative)  # the user's, whole
            else:
                walk(entry, target, relative + "/", blocked or (present and _is_unit(target)))

    walk(old, new, "", False)
    return plan


def _link(source: str | os.PathLike, target: str | os.PathLike) -> None:
    """Hard-link `source` (a link itself, not what it points to) at `target`; copy it where links are impossible."""
    try:
        os.link(source, target, follow_symlinks=False)
    except OSError:
        shutil.copy2(source, target, follow_symlinks=False)


def _carry(old: Path, new: Path, kept: list[str]) -> None:
    """Link the `kept` entries of `old` into `new` at the same relative paths (folders link their files)."""
    for relative in kept:
        source, target = old / relative, new / relative
        target.parent.mkdir(parents=True, exist_ok=True)
        if source.is_dir() and not source.is_symlink():
            shutil.copytree(source, target, symlinks=True, copy_function=_link)
        else:
            _link(source, target)


def _merge(staging: Path, final: Path) -> None:
    """Move every entry of `staging` into the existing folder `final`, replacing files of the same names."""
    for entry in sorted(staging.iterdir()):
        target = final / entry.name
        if not _is_unit(entry) and target.is_dir() and not _is_unit(target):
            _merge(entry, target)
            continue
        if target.is_dir() and not target.is_symlink():  # a Zarr store of the same name (checked by _plan)
            shutil.rmtree(target)
        os.replace(entry, target)
    staging.rmdir()


def _swap(staging: Path, final: Path) -> None:
    """Rename `staging` to `final`, replacing the folder there; on any failure `final` is put back."""
    retired = _staging_name(final, retired=True)
    os.replace(final, retired)
    try:
        os.replace(staging, final)
    except BaseException:
        os.replace(retired, final)
        raise
    shutil.rmtree(retired, ignore_errors=True)


def _listing(paths: list[str], folder: Path) -> tuple[str, str]:
    """``("1 file and 1 folder", "my_notes.txt, runs/")``: how many of `paths` (in `folder`), and at most 5 names."""
    names = [f"{p}/" if (folder / p).is_dir() and not (folder / p).is_symlink() else p for p in paths]
    n_folders = sum(name.endswith("/") for name in names)
    counts = [f"{n} {word}{'s' if n > 1 else ''}" for n, word in ((len(names) - n_folders, "file"),
                                                                   (n_folders, "folder")) if n]
    shown = ", ".join(names[:5]) + (f" and {len(names) - 5} more" if len(names) > 5 else "")
    return " and ".join(counts), shown


def _clash_error(final: Path, output: Output, clashes: list[str]) -> SynthpackInputError:
    first = clashes[0] + (f" (and {len(clashes) - 1} more)" if len(clashes) > 1 else "")
    return SynthpackInputError(
        f"cannot write the {output.what} {final}: {first} was not written by synthpack, and the new "
        f"{output.what} writes there; nothing was changed: move it out of {final}, or pass --overwrite (overwrite=True in Python) "
        "to replace files of the same names"
    )


def _commit(staging: Path, final: Path, output: Output, overwrite: bool) -> None:
    """Put the complete folder `staging` at `final` by the rules of the module docstring."""
    whole = _is_unit(staging)  # a Zarr store: one volume
    if not whole:
        (staging / RECORD).write_text(json.dumps(_contents(staging), indent=1))
    if not final.exists():
        os.replace(staging, final)
        return
    ours = _replaceable(final, output)
    if whole and ours:
        _swap(staging, final)
        return
    record = _read_record(final) if ours else None
    plan = _plan(final, staging, record, replace=overwrite or record is None)
    if plan.clashes:
        raise _clash_error(final, output, plan.clashes)
    if not ours:  # overwrite=True on a folder that is not synthpack's: write into it, delete nothing
        _merge(staging, final)
        if plan.replaced:
            logger.info("replaced %d file(s) of the same names in %s", len(plan.replaced), final)
        return
    _carry(final, staging, plan.kept)
    _swap(staging, final)
    counts, names = _listing(plan.kept, final)
    if record is None and plan.kept:
        logger.warning("%s was written by a synthpack that did not record its files: the new files replaced "
                       "those of the same names and %s of other names were kept (%s); delete those that are "
                       "stale files of the earlier output", final, counts, names)
    elif plan.kept:
        logger.info("kept %s not written by synthpack in %s: %s", counts, final, names)
    if record is not None and plan.replaced:
        logger.info("replaced %d file(s) not written by synthpack in %s (--overwrite): %s",
                    len(plan.replaced), final, ", ".join(plan.replaced[:5]))


@contextlib.contextmanager
def atomic_directory(path: str | os.PathLike, output: Output = FOLDER, *, overwrite: bool = False) -> Iterator[Path]:
    """Yield a temporary folder that replaces `path` only if the block succeeds.

    On an exception, or when the final rename fails, the temporary folder is removed
    and `path` is left as it was. An earlier output at `path` is replaced only if
    `output` recognises it as synthpack's own (or it is an empty folder), and then
    only what it recorded is deleted: other entries are carried into the new folder
    (see the module docstring). With `overwrite` a foreign folder receives the new
    files instead, its other files kept.

    Raises
    ------
    SynthpackInputError
        From :func:`check_output`, before the block runs; after it, when an entry
        that synthpack did not write is where the new output puts a file (nothing
        is changed then).
    """
    final = check_output(path, output, overwrite=overwrite)
    final.parent.mkdir(parents=True, exist_ok=True)
    remove_stale_staging(final)
    staging = _staging_name(final)
    staging.mkdir()
    try:
        yield staging
        _commit(staging, final, output, overwrite)
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
