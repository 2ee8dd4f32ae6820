"""simtest._workers: a pool stopped at any moment ends, and takes its workers with it.

The hang this guards against: a worker terminated while it wrote a large result left the pool's
manager thread reading the rest of that message for ever (this process held the pipe's other
write end), and ``stop_workers`` waited for that thread: ``simtest reconstruct <folder> -j 2``
did not end on Ctrl-C about one time in eight on a loaded machine.
"""

from __future__ import annotations

import multiprocessing
import sys
import threading
import time
from pathlib import Path

import pytest

from simtest._workers import new_pool, stop_workers

pytestmark = pytest.mark.skipif(
    not sys.platform.startswith("linux") or "fork" not in multiprocessing.get_all_start_methods(),
    reason="reads the worker's kernel wait channel in /proc; forks")

#: A result far larger than a pipe's 64 KiB buffer, so that its worker blocks in the write while
#: the pool's manager thread reads it in pieces.
RESULT_BYTES = 256 << 20
#: How long a stop may take: terminate, join (``STOP_WAIT_S`` each) and a shutdown; generous for a
#: loaded 2-core machine. The hang it detects lasts for ever.
STOP_WITHIN_S = 30.0


def _large_result() -> bytes:
    return b"\0" * RESULT_BYTES


def _wait_channel(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/wchan").read_text()
    except OSError:
        return ""


def test_a_pool_stopped_while_a_worker_sends_its_result_ends():
    pool = new_pool(1, mp_context=multiprocessing.get_context("fork"))
    fut = pool.submit(_large_result)
    deadline = time.monotonic() + 120.0
    while not getattr(pool, "_processes", None):
        assert time.monotonic() < deadline, "no worker started"
        time.sleep(0.01)
    (pid,) = list(pool._processes)
    # the worker blocks in the pipe's write while the manager thread is mid-message
    while "pipe_write" not in _wait_channel(pid):
        if fut.done() or time.monotonic() > deadline:
            stop_workers(pool)
            pytest.skip("never saw the worker block in its result pipe's write (no wchan?)")
    stopper = threading.Thread(target=stop_workers, args=(pool,), daemon=True)
    stopper.start()
    stopper.join(STOP_WITHIN_S)
    assert not stopper.is_alive(), f"stop_workers did not return within {STOP_WITHIN_S} s"
    assert not any(p.is_alive() for p in multiprocessing.active_children() if p.pid == pid)


def test_a_pool_stopped_when_idle_ends_and_its_worker_is_gone():
    pool = new_pool(2, mp_context=multiprocessing.get_context("fork"))
    assert pool.submit(len, "abc").result() == 3
    procs = list(pool._processes.values())
    assert stop_workers(pool) == len(procs) > 0
    assert not any(p.is_alive() for p in procs)


def _worker_view(_):
    import os

    from threadpoolctl import threadpool_info
    return (sorted(m for m in ("simtest.harness.runner", "mitsuba", "drjit") if m in sys.modules),
            max((i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"), default=1),
            os.getcwd(), list(sys.path))


def test_a_clean_workers_modules_threads_and_paths(tmp_path, monkeypatch):
    # a worker of clean_context() is forked from a server that imported the workers' modules (not
    # the renderer) with one BLAS thread, and it still sees the caller's working directory and
    # sys.path as they are when the pool starts (a spawned worker's contract)
    from simtest._workers import clean_context
    monkeypatch.chdir(tmp_path)
    monkeypatch.syspath_prepend(str(tmp_path / "mine"))
    pool = new_pool(1, mp_context=clean_context())
    try:
        mods, blas, cwd, path = pool.submit(_worker_view, 0).result(timeout=120)
    finally:
        pool.shutdown()
    assert mods == ["simtest.harness.runner"] and blas == 1
    assert cwd == str(tmp_path) and path[0] == str(tmp_path / "mine")
