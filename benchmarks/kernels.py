"""The compiled kernels' share of a frame: each timed in place.

The kernels are found, not listed: every numba-compiled function held by a loaded module of
``simtest`` (:func:`kernel_modules`). Numba is not imported here: where the package loaded none,
or holds no compiled kernel, there is nothing to time and a frame gets no kernel row.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from types import ModuleType

from benchmarks.timing import summary, wrapped


def _dispatcher_type() -> type | None:
    """numba's dispatcher class where the package has loaded numba, else None."""
    numba = sys.modules.get("numba")
    return getattr(getattr(getattr(numba, "core", None), "dispatcher", None), "Dispatcher", None)


def dispatchers(module: ModuleType) -> list[str]:
    """Names of the numba-compiled functions a module holds (those called from Python); none
    where numba is not loaded."""
    kind = _dispatcher_type()
    if kind is None:
        return []
    return sorted(n for n, f in vars(module).items() if isinstance(f, kind))


def kernel_modules() -> list[ModuleType]:
    """The loaded modules of ``simtest`` that hold compiled kernels, by name (run the code to time
    once first, so that its modules are loaded)."""
    mods = [m for name, m in sorted(sys.modules.items())
            if (name == "simtest" or name.startswith("simtest.")) and isinstance(m, ModuleType)]
    return [m for m in mods if dispatchers(m)]


@contextmanager
def kernel_times() -> Iterator[dict[str, float]]:
    """Time the reconstruction's compiled kernels in place, inside the block (a context manager).

    Every numba-compiled function of :func:`kernel_modules` is replaced in its module by a timer
    that calls it and adds its wall time to its entry of the yielded dict (name -> ms, summed over
    the calls), and put back on leaving the block, also when it raises. The pipeline calls its
    kernels as attributes of their modules, so each of its calls goes through a timer; a kernel
    that another kernel calls is timed as part of its caller. Unlike OpenCV's calls
    (:func:`benchmarks.opencv_replay.opencv_calls`), the kernels are not replayed: they run on the frame's own arrays and
    layouts. The timer's own cost (about a microsecond a call) is outside the sums. Not
    thread-safe (it patches the modules).
    """
    times: dict[str, float] = {}

    def timer(name: str, fn: Callable) -> Callable:
        def call(*args, **kwargs):
            t0 = time.perf_counter()
            try:
                return fn(*args, **kwargs)
            finally:
                times[name] = times.get(name, 0.0) + (time.perf_counter() - t0) * 1e3

        return call

    targets = [(mod, name) for mod in kernel_modules() for name in dispatchers(mod)]
    with wrapped(targets, timer):
        yield times


def kernel_ms(fn: Callable[[], object], repeat: int) -> tuple[float, float, dict[str, float]] | None:
    """The compiled kernels' time in ``fn()`` (:func:`kernel_times`) over ``repeat`` runs after
    one warm-up: median and minimum of the runs' sums, ms, and each kernel's mean per run, ms,
    largest first; None where ``fn`` calls no compiled kernel."""
    fn()
    totals: list[float] = []
    per: dict[str, float] = {}
    for _ in range(max(1, repeat)):
        with kernel_times() as times:
            fn()
        totals.append(sum(times.values()))
        for name, t in times.items():
            per[name] = per.get(name, 0.0) + t
    if not per:
        return None
    return summary(totals, per)

