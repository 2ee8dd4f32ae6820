"""Shared test fixtures."""

from __future__ import annotations

import os

import matplotlib
import pytest

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


#: The longest a process waits for another's compile of the same kernel, s: over three times the
#: whole set's cold compile (176 s of CPU in one process on the 2-core machine under load).
_COMPILE_WAIT_S = 600.0


def _compile_each_numba_kernel_once():
    """One process compiles a cached numba kernel, the others wait and load it from the cache.

    pytest-xdist's workers start together, and the first reconstruction in each compiled the same
    kernels side by side on a cold cache, as on a fresh clone (the reconstruction's set: 176 s of
    CPU in one process on the 2-core machine; the first test of each worker took 30 to 118 s in CI). A file lock per kernel (``fcntl.flock``, released when the compile returns)
    makes the second worker wait for the first's result in numba's on-disk cache, which numba's
    own ``Dispatcher.compile`` reads before compiling. Kernels without ``cache=True`` compile as
    before; so does every kernel where ``fcntl`` is missing (Windows) or numba changed its
    dispatcher.
    """
    try:
        import fcntl
        import hashlib
        import tempfile
        import threading
        import time
        from pathlib import Path

        from numba.core import sigutils
        from numba.core.caching import NullCache
        from numba.core.dispatcher import Dispatcher
    except ImportError:
        return
    if getattr(Dispatcher.compile, "_simtest_locked", False):
        return
    original = Dispatcher.compile
    locks = Path(tempfile.gettempdir()) / f"simtest-numba-compile-{os.getuid()}"
    held = threading.local()

    def compile(self, sig):
        cache = getattr(self, "_cache", None)
        if cache is None or isinstance(cache, NullCache):
            return original(self, sig)
        try:
            args, _ = sigutils.normalize_signature(sig)
            if self.overloads.get(tuple(args)) is not None:
                return original(self, sig)
            func = self.py_func
            key = hashlib.sha1(f"{func.__module__}.{func.__qualname__}:{args}".encode()).hexdigest()
        except Exception:  # noqa: BLE001 - an unforeseen dispatcher: compile as numba would
            return original(self, sig)
        mine = getattr(held, "keys", None)
        if mine is None:
            mine = held.keys = set()
        if key in mine:  # a recursive compile of the same kernel in this process
            return original(self, sig)
        locks.mkdir(exist_ok=True)
        with open(locks / key, "a") as fh:
            # wait for the other's compile, but never for ever (two kernels calling each other,
            # compiled from both ends at once, would each hold the lock the other waits for)
            deadline = time.monotonic() + _COMPILE_WAIT_S
            while True:
                try:
                    fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
                    break
                except BlockingIOError:
                    if time.monotonic() > deadline:
                        return original(self, sig)
                    time.sleep(0.05)
            mine.add(key)
            try:
                return original(self, sig)
            finally:
                mine.discard(key)
                fcntl.flock(fh, fcntl.LOCK_UN)

    compile._simtest_locked = True
    Dispatcher.compile = compile


_compile_each_numba_kernel_once()


def pytest_collection_modifyitems(config, items):
    """Modules holding a test marked ``slow`` run first, each module's tests kept together.

    Under ``--dist worksteal`` (pyproject's addopts) each worker starts on a contiguous half of
    this order and takes tests from the other when it runs out: a long test left for the end
    would keep one core busy while the other idles, whereas cheap tests at the end even out.
    """
    slow = {item.module.__name__ for item in items
            if item.get_closest_marker("slow") is not None and getattr(item, "module", None) is not None}
    if slow:
        items.sort(key=lambda item: getattr(getattr(item, "module", None), "__name__", None) not in slow)


@pytest.fixture(scope="session")
def numba_kernels_compiled():
    """The reconstruction's numba kernels compiled (or loaded from numba's cache) in this worker,
    for a test that then starts ``simtest`` processes.

    Those processes do not import this file, so they take no compile lock: on a cold cache (a
    fresh clone) each compiled the kernels it needed beside the workers. Reconstructing a real
    8-bit RGB tile and a float highlight here first, under the lock, leaves them to load what
    the workers compiled once.
    """
    import cv2
    import numpy as np

    from benchmarks.inputs import synthetic_roi_image
    from simtest.reconstruct import reconstruct, reconstruct_roi
    from simtest.resources import data_root

    tile = cv2.imread(str(data_root() / "tests" / "data" / "real" / "hyperkvasir_tile_r1c7_mucosa.png"))
    K = np.array([[140.0, 0, 139.5], [0, 140.0, 139.5], [0, 0, 1]])
    reconstruct(cv2.cvtColor(tile, cv2.COLOR_BGR2RGB), K)
    img, K, bp, _ = synthetic_roi_image()
    reconstruct(img, K, (0.1, 0.3, 0.5))
    reconstruct_roi(img, K, 0.1, bp_uv=bp)


@pytest.fixture(autouse=True)
def _kernels_before_a_slow_test(request):
    """A test marked ``slow`` starts with the kernels compiled (:func:`numba_kernels_compiled`).

    The modules holding one run first (:func:`pytest_collection_modifyitems`), on a cold cache
    in a fresh clone, and several start ``simtest`` processes that take no compile lock; the
    signal tests also bound how long a worker may take to end, which a kernel compile in
    progress would stretch.
    """
    if request.node.get_closest_marker("slow") is not None:
        request.getfixturevalue("numba_kernels_compiled")
