"""Timing helpers of the benchmarks: one core, medians after a warm-up, CPU time beside wall time."""

from __future__ import annotations

import os
import resource
import statistics
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager, suppress
from pathlib import Path

import cv2
from threadpoolctl import threadpool_limits

from simtest.constants import SINGLE_THREAD_ENV
from simtest.reconstruct.lightaware.plane_solve import forget_solves

#: The clone's top folder, which holds ``benchmarks/`` and ``simtest/``.
ROOT = Path(__file__).resolve().parents[1]


def clone_env(**extra: str) -> dict[str, str]:
    """This process's environment for a child Python that imports ``benchmarks``: the clone's top
    folder first on ``PYTHONPATH``, and ``extra``."""
    path = os.pathsep.join(p for p in (str(ROOT), os.environ.get("PYTHONPATH", "")) if p)
    return {**os.environ, "PYTHONPATH": path, **extra}


def single_core() -> None:
    """Ask numerical libraries and OpenCV for one thread, for the rest of this process: the
    environment for libraries not yet loaded, threadpoolctl's limit for the BLAS already loaded
    (numpy's OpenBLAS reads its environment only when it loads)."""
    os.environ.update(SINGLE_THREAD_ENV)
    threadpool_limits(limits=1)
    cv2.setNumThreads(1)


def time_ms(fn: Callable[[], object], repeat: int) -> tuple[float, float]:
    """(median, min) wall time of ``fn()`` in ms over ``repeat`` runs after one warm-up."""
    return time_ms_cpu(fn, repeat)[:2]


def runs(repeat: int, share: int, floor: int) -> int:
    """Timed runs of a costly figure: ``repeat // share``, at least ``floor`` (a median of two runs is
    the mean of a slow and a quick one on a machine whose speed moves), but never more than the
    ``repeat`` asked for: ``simtest bench --repeat 1`` times every figure once, as its help says."""
    return min(max(1, int(repeat)), max(floor, int(repeat) // share))


def time_ms_cpu(fn: Callable[[], object], repeat: int) -> tuple[float, float, float]:
    """(median, min) wall time and median CPU time of this process (``time.process_time``) of
    ``fn()`` in ms over ``repeat`` runs after one warm-up.

    On a machine that other processes load, the wall time counts the time the process waits for
    a core; the CPU time does not (it still grows somewhat with the load: shared caches). Each run
    starts with the light-aware fits' memory of solves empty, as a user's first run of a frame does.
    """
    fn()
    wall, cpu = [], []
    for _ in range(max(1, repeat)):
        forget_solves()
        t0, c0 = time.perf_counter(), time.process_time()
        fn()
        c1, t1 = time.process_time(), time.perf_counter()
        wall.append((t1 - t0) * 1e3)
        cpu.append((c1 - c0) * 1e3)
    return statistics.median(wall), min(wall), statistics.median(cpu)


@contextmanager
def wrapped(targets: list[tuple[object, str]], wrap: Callable[[str, Callable], Callable]) -> Iterator[None]:
    """Replace each function ``getattr(namespace, name)`` of ``targets`` by ``wrap(name, fn)`` for
    the block, and put the originals back on leaving it, also when it raises (the mechanism of
    :func:`benchmarks.opencv_replay.opencv_calls`; not thread-safe)."""
    originals = [(ns, name, getattr(ns, name)) for ns, name in targets]
    for ns, name, fn in originals:
        setattr(ns, name, wrap(name, fn))
    try:
        yield
    finally:
        for ns, name, fn in originals:
            setattr(ns, name, fn)


def summary(totals: list[float], per: dict[str, float]) -> tuple[float, float, dict[str, float]]:
    """Median and minimum of runs' totals, ms, and each function's summed time over the runs as
    its mean per run, largest first (the results of
    :func:`benchmarks.opencv_replay.replay_opencv_ms`)."""
    n = len(totals)
    per = {name: t / n for name, t in sorted(per.items(), key=lambda kv: -kv[1])}
    return statistics.median(totals), min(totals), per


@contextmanager
def every_core() -> Iterator[None]:
    """Within the block this process (and the workers it forks) may run on every core of the
    machine, whatever ``taskset`` pinned it to; the pinning returns after. Where the process may
    not widen its affinity (a container's cpuset), it stays as it is."""
    get, put = getattr(os, "sched_getaffinity", None), getattr(os, "sched_setaffinity", None)
    saved = get(0) if get is not None else None
    try:
        if put is not None:
            with suppress(OSError):
                put(0, range(os.cpu_count() or 1))
        yield
    finally:
        if saved is not None:
            with suppress(OSError):
                put(0, saved)


def cpu_s_with_workers() -> float:
    """CPU time, s, of this process and of its ended children (the video's worker processes,
    counted once the pool has joined them)."""
    own, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + kids.ru_utime + kids.ru_stime
