"""Worker processes that end with the command that started them.

The workers of a :func:`worker_pool` die with their parent, even one SIGKILLed (Linux
``prctl(PR_SET_PDEATHSIG)``), ignore SIGINT (the parent stops them; no traceback of theirs on the
caller's terminal) and take SIGTERM's default action. When the block is left by an exception (Ctrl-C and
SIGTERM included, :func:`simtest._exit.signals_interrupt`) the workers are terminated at once, not after
the queued tasks, and waited for. :func:`clean_context` starts workers that inherit no threads and no
Mitsuba state, forked from a server that has the workers' modules imported.
"""

from __future__ import annotations

import contextlib
import ctypes
import multiprocessing
import os
import select
import signal
import sys
import threading
from collections.abc import Callable, Iterator
from concurrent.futures import ProcessPoolExecutor
from multiprocessing import forkserver

from simtest._threads import one_thread_each

__all__ = ["CLEAN_PRELOAD", "STOP_WAIT_S", "clean_context", "new_pool", "stop_workers", "worker_pool"]

#: Seconds a terminated worker is given to exit before it is killed (within the 5 s stop the README promises)
STOP_WAIT_S = 2.0

#: Linux prctl option: the signal the kernel sends this process when its parent dies.
_PR_SET_PDEATHSIG = 1


#: Modules the fork server of :func:`clean_context` imports before it forks a worker: the harness's and the
#: dataset's worker code (numpy, scipy, OpenCV; not Mitsuba, whose threads a fork must not copy).
CLEAN_PRELOAD = ("simtest.harness.runner", "simtest.dataset.generate")


def clean_context():
    """The multiprocessing context of workers that inherit no threads and no renderer state: ``forkserver``
    (``spawn`` where the platform lacks it). One server per command, started here with :data:`CLEAN_PRELOAD`
    imported and one BLAS thread (:func:`~simtest._threads.one_thread_each`), forks each worker, which so
    skips the imports a spawned one makes. The server keeps the environment it started with; a worker
    gets the caller's ``sys.path`` and working directory."""
    if "forkserver" not in multiprocessing.get_all_start_methods():
        return multiprocessing.get_context("spawn")
    ctx = multiprocessing.get_context("forkserver")
    ctx.set_forkserver_preload(list(CLEAN_PRELOAD))
    with one_thread_each():  # the server imports numpy with one thread; its workers inherit it
        forkserver.ensure_running()
    return ctx


def _watch_owner(owner_pid: int) -> None:
    """End this process when the pool's owner ends (a pidfd, waited on by a daemon thread): a worker of
    :func:`clean_context` has for parent the fork server, which outlives the owner while any worker runs."""
    try:
        fd = os.pidfd_open(owner_pid)
    except ProcessLookupError:
        os._exit(1)
    except (OSError, AttributeError):  # no pidfd (not Linux >= 5.3): the owner's handlers still stop us
        return

    threading.Thread(target=lambda: (select.select([fd], [], []), os._exit(1)), daemon=True).start()


def _die_with_parent(parent_pid: int) -> None:
    """Ask the kernel to SIGKILL this process when its parent dies (Linux); exit at once if it already
    did. A worker whose parent is not the pool's owner (:func:`clean_context`) watches the owner."""
    if not sys.platform.startswith("linux"):
        return
    ppid = os.getppid()
    if ppid != parent_pid:  # the fork server's worker, or the owner has gone
        _watch_owner(parent_pid)
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(_PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0)
    except (OSError, AttributeError):  # no prctl: the parent's handlers still stop us
        return
    if os.getppid() != ppid:  # the parent died before the signal was asked for
        os._exit(1)


def _worker_start(parent_pid: int, initializer: Callable | None, initargs: tuple) -> None:
    """Each worker's initializer: the signal set-up of the module docstring, then the pool's own."""
    # the signals first: a SIGTERM from a pool being stopped ends the worker quietly
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    _die_with_parent(parent_pid)
    if initializer is not None:
        initializer(*initargs)


def new_pool(max_workers: int, *, mp_context=None, initializer: Callable | None = None,
             initargs: tuple = ()) -> ProcessPoolExecutor:
    """The pool of :func:`worker_pool` (same parameters), for a caller that holds it beyond one block.

    Returns
    -------
    ProcessPoolExecutor
        Its workers set up as the module docstring says; the caller shuts it down, or stops it
        with :func:`stop_workers`.
    """
    return ProcessPoolExecutor(max_workers=max_workers, mp_context=mp_context, initializer=_worker_start,
                               initargs=(os.getpid(), initializer, initargs))


@contextlib.contextmanager
def worker_pool(max_workers: int, *, mp_context=None, initializer: Callable | None = None,
                initargs: tuple = ()) -> Iterator[ProcessPoolExecutor]:
    """A :class:`~concurrent.futures.ProcessPoolExecutor` whose workers end with the command.

    Parameters
    ----------
    max_workers : int
    mp_context : multiprocessing context, optional
        How workers start (``fork``, ``spawn``); the platform's default if None.
    initializer : callable, optional
        Run in each worker after the signal set-up, with ``initargs``.
    initargs : tuple

    Yields
    ------
    ProcessPoolExecutor
        Shut down normally when the block ends normally; on an exception its workers are stopped at once
        (:func:`stop_workers`) and the exception goes on.
    """
    pool = new_pool(max_workers, mp_context=mp_context, initializer=initializer, initargs=initargs)
    try:
        yield pool
    except BaseException:
        stop_workers(pool)
        raise
    pool.shutdown(wait=True)


def stop_workers(pool: ProcessPoolExecutor | None = None) -> int:
    """Terminate a pool's workers (or, with no pool, every child process that multiprocessing
    started here), wait for them, and shut the pool down without running its queued tasks.

    Parameters
    ----------
    pool : ProcessPoolExecutor, optional
        The pool; None: :func:`multiprocessing.active_children`.

    Returns
    -------
    int
        The processes stopped.

    Notes
    -----
    A pool keeps its processes in the private ``_processes`` and its result pipe in
    ``_result_queue`` (CPython 3.9 to 3.13; 3.14 adds ``terminate_workers``). :mod:`simtest.dataset.generate` stops its own pool with it too.
    """
    procs = (multiprocessing.active_children() if pool is None
             else list((getattr(pool, "_processes", None) or {}).values()))
    for p in procs:
        with contextlib.suppress(OSError, AttributeError, ValueError):
            p.terminate()
    for p in procs:
        with contextlib.suppress(OSError, AttributeError, ValueError, AssertionError):
            p.join(STOP_WAIT_S)
            if p.is_alive():
                p.kill()
                p.join(STOP_WAIT_S)
    if pool is not None:
        # a worker stopped mid-result leaves the manager thread reading forever (this process holds
        # the pipe's other write end): closing it ends the read, and the pool shuts down broken
        writer = getattr(getattr(pool, "_result_queue", None), "_writer", None)
        if writer is not None:
            with contextlib.suppress(OSError):
                writer.close()
        pool.shutdown(wait=True, cancel_futures=True)
    return len(procs)
