"""Run the builds of many packs as Dask tasks: on a local cluster, an existing cluster, or in this process.

One pack is one task (`dask.distributed`): the library is sent to every
worker once, each task builds and writes one pack, and a task that raises is
reported with its error while the others carry on. Where the tasks run:

- ``scheduler="tcp://host:8786"``: an existing Dask cluster (e.g. started by
  ``dask-jobqueue`` on SLURM or PBS, or by ``dask scheduler`` / ``dask worker``);
  its workers need synthpack installed and the output directory mounted at the
  same path.
- ``workers=W`` (W >= 1): a `distributed.LocalCluster` of W single-threaded
  worker processes, started here and closed at the end.
- ``workers=0``: in this process, one pack after the other (no Dask).
- neither (the default): a local cluster of one worker per CPU core (at most
  one per pack to build), or this process when there is only one pack to build.

A pack run by a Dask worker renders its chunks with one thread (the worker's
parallelism is over packs); in this process it uses every core. Neither changes
a single byte of the pack.

A local cluster is quiet: dask.distributed logs only warnings while it runs (as
`distributed.LocalCluster`'s ``silence_logs`` intends, also when the calling
program has configured logging) and nothing while it shuts down, when comms
closing in any order are expected (unless synthpack logs at DEBUG level). Its
workers' synthpack messages are forwarded to the calling process, which shows them
as its own: warnings and errors (`_worker_level`; all of them when it logs at DEBUG). Its
worker processes ignore Ctrl-C (:func:`dask_setup`): the calling process gets
the `KeyboardInterrupt`, and closing the cluster stops them (a pack still being
built is stopped after a few seconds, leaving its staging folder to the caller,
see `synthpack.io.atomic.remove_stale_staging`). A Ctrl-C while the cluster starts
(a few seconds) is ignored.
"""

from __future__ import annotations

import contextlib
import logging
import os
import signal
import threading
import traceback
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any

from tqdm.auto import tqdm
from tqdm.std import tqdm as std_tqdm

from .._shared.console import progress_bar
from ..errors import SynthpackInputError

logger = logging.getLogger(__name__)

__all__ = ["run_packs", "PackTask", "dask_setup"]

#: ``task(library, index, threads=...) -> Path``: builds and writes pack `index`.
PackTask = Callable[..., Path]


def _log_failure(index: int, error: BaseException, trace: str) -> None:
    """Log a failed pack: an error with its `trace`; an input error, whose message says what to do, as info.

    Every failure is reported again, in one line, by the run's error
    (`~synthpack.errors.PackBuildError`), so an input error shows as that one line.
    """
    text = f"{type(error).__name__}: {error}"
    if isinstance(error, SynthpackInputError):
        logger.info("pack %d failed: %s", index, text)
    else:
        logger.error("pack %d failed: %s\n%s", index, text, trace)


def _check(workers: int | None, scheduler: str | None) -> None:
    if scheduler is not None and workers is not None:
        raise SynthpackInputError(
            "give either workers (a local cluster) or scheduler (an existing cluster), not both"
        )
    if workers is not None and (isinstance(workers, bool) or not isinstance(workers, int) or workers < 0):
        raise SynthpackInputError(
            f"workers must be 0 (this process) or a positive number of worker processes, got {workers!r}"
        )
    if scheduler is not None and not (isinstance(scheduler, str) and scheduler.strip()):
        raise SynthpackInputError(
            f"scheduler must be the address of a Dask scheduler such as tcp://10.0.0.5:8786, got {scheduler!r}"
        )


def dask_setup(worker: Any) -> None:
    """Dask preload of the local cluster's worker processes: quiet, and Ctrl-C left to the calling process.

    A Ctrl-C in a terminal reaches every process of the foreground group, where each
    worker process would print a `KeyboardInterrupt` traceback. Workers ignore SIGINT
    (those a local cluster starts do so from their start-up, see `_local_client`; this
    covers a worker restarted later): the calling process stops the run and closes the
    cluster. Once a worker is closing, its dask.distributed log records are dropped:
    tasks cancelled and comms closed at shutdown are expected then. tqdm's lock
    becomes a thread lock: the default one holds a multiprocessing semaphore, which a
    worker killed mid-pack (an interrupted run) would leave to the resource tracker,
    which then warns at exit.

    Parameters
    ----------
    worker : distributed.Worker
        The worker starting.
    """
    from distributed.core import Status

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    std_tqdm.set_lock(threading.RLock())
    closing = {Status.closing, Status.closing_gracefully, Status.closed}

    def running(record: logging.LogRecord) -> bool:
        return worker.status not in closing

    for handler in logging.getLogger("distributed").handlers:
        handler.addFilter(running)


def _worker_level() -> int:
    """The level of synthpack's log lines in the local cluster's workers: this process's, but at most warnings at INFO.

    Workers build packs side by side: at INFO their lines would interleave, pack after
    pack; each pack's figures are in its manifest. ``--verbose`` shows them all.
    """
    level = logging.getLogger("synthpack").getEffectiveLevel()
    return logging.WARNING if level == logging.INFO else level


def _worker_logging(level: int) -> None:
    """In a worker process: synthpack logs at `level` (its records are forwarded to the calling process)."""
    logging.getLogger("synthpack").setLevel(level)


@contextlib.contextmanager
def _dask_logging_at_least(level: int) -> Iterator[None]:
    """Raise the level of dask.distributed's loggers to `level` inside the block, unless synthpack logs at DEBUG."""
    dask_logger = logging.getLogger("distributed")
    saved = dask_logger.level
    if not logger.isEnabledFor(logging.DEBUG):
        dask_logger.setLevel(max(level, dask_logger.getEffectiveLevel()))
    try:
        yield
    finally:
        dask_logger.setLevel(saved)


@contextlib.contextmanager
def _ctrl_c_ignored() -> Iterator[None]:
    """Ignore Ctrl-C inside the block (in the main thread, with a handler set from Python; else nothing changes).

    Processes started in the block inherit the setting from their first instruction,
    so a Ctrl-C cannot interrupt them halfway through their start-up.
    """
    previous = signal.getsignal(signal.SIGINT)
    if threading.current_thread() is not threading.main_thread() or previous is None:
        yield
        return
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


@contextlib.contextmanager
def _local_client(workers: int) -> Iterator[Any]:
    """A `distributed.Client` of a local cluster of `workers` processes, shut down quietly at the end of the block.

    Its worker processes start with Ctrl-C ignored, so a Ctrl-C while the cluster
    starts (a few seconds) is ignored; after that it stops the run.
    """
    from distributed import Client, LocalCluster

    with _dask_logging_at_least(logging.WARNING):
        cluster = client = None
        try:
            with _ctrl_c_ignored():
                cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                                       dashboard_address=":0", preload=[__name__])
            client = Client(cluster)
            level = _worker_level()
            client.run(_worker_logging, level)
            client.forward_logging("synthpack", level)
            yield client
        finally:
            with _dask_logging_at_least(logging.CRITICAL):
                if client is not None:
                    client.close()
                if cluster is not None:
                    cluster.close()


@contextlib.contextmanager
def _client(workers: int | None, scheduler: str | None) -> Iterator[Any]:
    """A `distributed.Client` of an existing cluster, or of a local cluster that lives as long as the block."""
    from distributed import Client

    if scheduler is not None:
        try:
            client = Client(scheduler)  # waits up to dask's distributed.comm.timeouts.connect
        except OSError as error:
            raise SynthpackInputError(
                f"cannot reach the Dask scheduler at {scheduler} ({error}): check the address, and that "
                "the scheduler is running and reachable from this machine"
            ) from error
        with client:
            yield client
        return
    with _local_client(workers) as client:
        yield client


def _run_here(task: PackTask, indices: Sequence[int], library: Any, bar: tqdm) -> dict[int, BaseException]:
    failures = {}
    for index in indices:
        try:
            task(library, index, threads=None)
        except Exception as error:  # one failing pack must not stop the others
            failures[index] = error
            _log_failure(index, error, traceback.format_exc())
        bar.update()
    return failures


def _run_on_dask(
    task: PackTask, indices: Sequence[int], library: Any, client: Any, bar: tqdm,
) -> dict[int, BaseException]:
    from distributed import as_completed

    shared = client.scatter(library, broadcast=True, hash=False)
    futures = {client.submit(task, shared, index, threads=1, pure=False, key=f"synthpack-pack-{index}-{os.getpid()}"):
               index for index in indices}
    failures = {}
    for future in as_completed(futures):
        index = futures[future]
        if future.status == "error":
            error = future.exception()
            failures[index] = error
            _log_failure(index, error, "".join(traceback.format_tb(future.traceback())))
        bar.update()
        future.release()
    return failures


def run_packs(
    task: PackTask,
    indices: Sequence[int],
    library: Any,
    *,
    n_packs: int | None = None,
    workers: int | None = None,
    scheduler: str | None = None,
    progress: bool = True,
) -> dict[int, BaseException]:
    """Run ``task(library, index, threads=...)`` for every index, each pack a Dask task.

    Parameters
    ----------
    task : callable
        Builds and writes one pack (e.g. `synthpack.pipeline.generate.generate_pack` with
        its other arguments bound); must be picklable for Dask.
    indices : sequence of int
        The packs to build.
    library : object
        Sent once to every worker and passed to every task.
    n_packs : int, optional
        Packs in the whole run, for the progress bar (the others are counted as
        done); default ``len(indices)``.
    workers : int, optional
        0: in this process; W >= 1: a local cluster of W worker processes;
        default: see the module docstring.
    scheduler : str, optional
        Address of an existing Dask scheduler (not with `workers`).
    progress : bool
        Show a progress bar over packs.

    Returns
    -------
    dict of int to BaseException
        Index of each failed pack -> its exception (empty when all succeeded).
        Each failure is also logged: an input error
        (`~synthpack.errors.SynthpackInputError`) as one line of info, any other
        as an error with its traceback.

    Raises
    ------
    SynthpackInputError
        For both `workers` and `scheduler`, a negative `workers`, or a
        scheduler that cannot be reached.
    """
    _check(workers, scheduler)
    n_packs = len(indices) if n_packs is None else n_packs
    with progress_bar(total=n_packs, initial=n_packs - len(indices), desc="packs", unit="pack",
              disable=not progress or n_packs == 1) as bar:
        if not indices:
            return {}
        if scheduler is None and workers is None:
            workers = min(os.cpu_count() or 1, len(indices))
            workers = 0 if workers == 1 else workers
        if workers == 0:
            return _run_here(task, indices, library, bar)
        where = scheduler or f"a local cluster of {workers} worker process(es)"
        logger.info("building %d pack(s) as Dask tasks on %s", len(indices), where)
        with _client(workers, scheduler) as client:
            return _run_on_dask(task, indices, library, client, bar)
