"""Worker processes that end with the command that started them.

The workers of a :func:`worker_pool` die with their parent, even one SIGKILLed (Linux
``prctl(PR_SET_PDEATHSIG)``), ignore SIGINT (the parent stops them; no traceback of theirs on the
caller's terminal) and take SIGTERM's default action. When the block is left by an exception (Ctrl-C and
SIGTERM included, :func:`simtest._exit.signals_interrupt`) the workers are terminated at once, not after
the queued tasks, and waited for.
"""

from __future__ import annotations

import contextlib
import ctypes
import multiprocessing
import os
import signal
import sys
from collections.abc import Callable, Iterator
from concurrent.futures import ProcessPoolExecutor

__all__ = ["STOP_WAIT_S", "new_pool", "stop_workers", "worker_pool"]

#: Seconds a terminated worker is given to exit before it is killed (within the 5 s stop the README promises)
STOP_WAIT_S = 2.0

#: Linux prctl option: the signal the kernel sends this process when its parent dies.
_PR_SET_PDEATHSIG = 1


def _die_with_parent(parent_pid: int) -> None:
    """Ask the kernel to SIGKILL this process when its parent dies (Linux); exit at once if it already did."""
    if not sys.platform.startswith("linux"):
        return
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(_PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0)
    except (OSError, AttributeError):  # no prctl: the parent's handlers still stop us
        return
    if os.getppid() != parent_pid:
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
