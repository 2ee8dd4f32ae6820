"""Shared test fixtures."""

from __future__ import annotations

import compileall
import os
import sys
from pathlib import Path

import simtest  # noqa: F401 - first: it asks OpenBLAS for one set of kernels before numpy loads it (simtest._blas)

import matplotlib  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402

matplotlib.use("Agg")

# Point Dr.Jit at a suitable LLVM before any test imports Mitsuba.
from simtest._llvm import configure_llvm_env  # noqa: E402

configure_llvm_env()
os.environ.setdefault("SIMTEST_TEST", "1")

# Property tests explore new examples on every local run (that is how they find bugs); under CI
# (CI=true) they draw the same examples every time, so that a landing does not hang on luck.
from hypothesis import settings  # noqa: E402

settings.register_profile("ci", derandomize=True, print_blob=True)
if os.environ.get("CI", "").lower() in ("1", "true", "yes"):
    settings.load_profile("ci")


def pytest_configure(config):
    """Compile the package's bytecode once, before any worker starts, where the environment
    turns the cache off (``PYTHONDONTWRITEBYTECODE``, set on some CI images): else each of the
    run's processes (xdist workers, the command-line tests' subprocesses, the reconstruction's
    and the harness's worker pools) compiles every module it imports again, 0.3 to 0.7 s of CPU
    each. ``compileall`` writes the caches whatever that setting; Python then reads them."""
    if sys.flags.dont_write_bytecode and not hasattr(config, "workerinput"):
        compileall.compile_dir(Path(__file__).resolve().parents[1] / "simtest", quiet=2)
    if hasattr(config, "workerinput"):
        _one_library_thread_per_worker()


#: The xdist worker's thread limits (threadpoolctl's handle; kept for the process's life).
_WORKER_LIMITS = []


def _one_library_thread_per_worker():
    """One BLAS/OpenMP, one OpenCV and one Dr.Jit thread in each xdist worker (``-n auto``: a
    worker per core).

    Each library otherwise starts a thread per core in every worker: on the 2-core CI machine two
    busy workers run four threads of each, whose spinning and switching cost CPU the tests need.
    Measured on the 2-core machine under a load of 5 to 9 (noisy): tests/test_lightaware.py and
    test_harness_runner.py, -n 0, user CPU 77.0 and 89.7 s with two BLAS threads, 71.6 and 71.1 s
    with one; three colonoscope renders, 41.3 s CPU with two Dr.Jit threads, 34.0 s with one (the
    same image). Results do not depend on the thread count (test_render_tissue_sensor,
    test_dataset_generate and test_threads hold that); the processes a test starts (command lines,
    worker pools) keep their own settings, and ``-n 0`` runs keep the libraries' defaults.
    """
    import cv2
    import drjit as dr
    from threadpoolctl import threadpool_limits

    _WORKER_LIMITS.append(threadpool_limits(limits=1))
    cv2.setNumThreads(1)
    dr.set_thread_count(1)


def pytest_collection_modifyitems(config, items):
    """Modules holding a test marked ``slow`` run first in each worker's share, each module's tests
    kept together.

    Under ``--dist worksteal`` (pyproject's addopts) each of the N workers starts on a contiguous
    N-th of this order and takes tests from the end of another's when it runs out. The slow
    modules are dealt among the N shares (the module with the most slow tests to the share with
    the fewest so far) and each share starts with its own: every worker begins on long tests and
    ends on cheap ones, so that what is taken at the end, and the last test to run, is cheap. A
    long test left for the end would keep one core busy while the others idle.
    """
    order = _worker_share_order([getattr(getattr(item, "module", None), "__name__", None) for item in items],
                                [item.get_closest_marker("slow") is not None for item in items],
                                getattr(config, "workerinput", {}).get("workercount", 1))
    items[:] = [items[i] for i in order]


def _worker_share_order(modules, slow, workers):
    """The order of the items (indices) from their modules and slow marks, for ``workers`` shares
    of sizes as xdist's worksteal first sends them (the remaining count over the workers left)."""
    groups = {}
    for i, m in enumerate(modules):
        groups.setdefault(m, []).append(i)
    slow_mods = [m for m, idx in groups.items() if m is not None and any(slow[i] for i in idx)]
    cheap = [i for m, idx in groups.items() if m not in slow_mods for i in idx]
    weight = [0] * workers
    dealt = [[] for _ in range(workers)]
    for m in sorted(slow_mods, key=lambda m: -sum(slow[i] for i in groups[m])):  # stable: ties keep order
        k = weight.index(min(weight))
        dealt[k] += groups[m]
        weight[k] += sum(slow[i] for i in groups[m])
    order, left = [], len(modules)
    for k in range(workers):
        size = left // (workers - k)
        fill = max(0, size - len(dealt[k]))
        order += dealt[k] + cheap[:fill]
        cheap = cheap[fill:]
        left -= len(dealt[k]) + fill
    return order + cheap


@pytest.fixture(scope="module")
def shared_renders():
    """The harness's renders made once per (scene, seed, options) in the module that asks for it.

    For modules that run one suite many times to test what is done with its numbers (the nightly
    gate: a dozen runs of the quick suite at its seed, each rendering the same ten frames), not
    the renders themselves (tested by the render modules, determinism included). The harness
    calls ``simtest.harness.protocols.render_scene``; here it returns the first render of each
    key, its arrays made read-only so that a caller that wrote into one fails instead of changing
    the next test's frame. Yields the cache (key -> RenderResult).
    """
    import simtest.harness.protocols as protocols

    real, cache = protocols.render_scene, {}

    def render_once(spec, **kwargs):
        key = (spec, tuple(sorted(kwargs.items())))
        if key not in cache:
            res = real(spec, **kwargs)
            for value in vars(res).values():
                if isinstance(value, np.ndarray):
                    value.setflags(write=False)
            cache[key] = res
        return cache[key]

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(protocols, "render_scene", render_once)
        yield cache


@pytest.fixture(scope="module")
def without_end_to_end():
    """The rendered runner's rows without their end-to-end records (``row.e2e`` stays None).

    ``RenderedRunner.run`` scores the detections matched to the true highlights (their fits alone:
    ``protocols.fit_scored``), then runs the whole frame again as ``simtest reconstruct`` would
    (``end_to_end.frame_records``: light-aware fits of every candidate, 80 to 90 % of a run on the
    endoscope suite's frames). For tests that assert on the rows' errors and extras only; the
    records are tested in test_harness_end_to_end (against the command line) and by the
    end-to-end tests of test_rig_pairs and test_harness_dask. Module-scoped: the module's
    fixtures that run suites get the same runner."""
    import simtest.harness.protocols as protocols

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(protocols, "frame_records", lambda result, depth_errors: [])
        yield
