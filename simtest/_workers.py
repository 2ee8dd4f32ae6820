"""Worker processes that end with the command that started them.

Every process pool of simtest (a suite's realisations, a video's frames, a frame's light-aware
fits) is a :func:`worker_pool`. Its workers

- die with their parent, even one killed by SIGKILL, which no handler sees (Linux
  ``prctl(PR_SET_PDEATHSIG)``; elsewhere the parent's handlers below still stop them);
- ignore SIGINT: a Ctrl-C reaches the terminal's whole process group, and a worker that raised
  KeyboardInterrupt would print its own traceback on the caller's standard error; the parent
  stops them instead;
- take SIGTERM's default action (a forked worker would otherwise inherit the parent's handler).

When the block around the pool is left by an exception (an error, or the KeyboardInterrupt that
SIGINT or SIGTERM raises in the command, :func:`simtest._exit.signals_interrupt`), the workers
are terminated at once, not after the tasks they hold, and waited for; so is every child process
left when the command line stops on a signal (:func:`stop_workers` with no pool). A pool's own
``shutdown`` would instead run every task already queued before returning.
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

#: Seconds a terminated worker is given to exit before it is killed (SIGKILL). A worker in a
#: compiled kernel still ends on SIGTERM at once (its default action needs no Python); the wait
#: only covers the kernel's scheduling, and keeps the whole stop within the 5 s the command line
#: promises (README, "Exit codes").
STOP_WAIT_S = 2.0

#: Linux prctl option: the signal the kernel sends this process when its parent dies.
_PR_SET_PDEATHSIG = 1


def _die_with_parent(parent_pid: int) -> None:
    """Ask the kernel to SIGKILL this process when its parent dies (Linux; elsewhere a no-op).

    If the parent died before the request was made (the race the man page names), exit at once.
    """
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
        Worker processes.
    mp_context : multiprocessing context, optional
        How workers start (``fork``, ``spawn``); the platform's default if None.
    initializer : callable, optional
        Run in each worker after the signal set-up, with ``initargs``.
    initargs : tuple
        Arguments of ``initializer``.

    Yields
    ------
    ProcessPoolExecutor
        Shut down normally (every submitted task run) when the block ends normally; on an
        exception, its workers are stopped at once (:func:`stop_workers`) and the exception
        goes on.
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
    if pool is None:
        procs = multiprocessing.active_children()
    else:
        procs = list((getattr(pool, "_processes", None) or {}).values())
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
        # A worker stopped while it sent a result leaves the pool's manager thread reading the
        # rest of that message, which never comes: this process holds the result pipe's other
        # write end, so the read sees no end of file, and ``shutdown`` would wait for that
        # thread forever. With every worker gone, closing it ends the read; the pool marks
        # itself broken and shuts down.
        writer = getattr(getattr(pool, "_result_queue", None), "_writer", None)
        if writer is not None:
            with contextlib.suppress(OSError):
                writer.close()
        pool.shutdown(wait=True, cancel_futures=True)
    return len(procs)
