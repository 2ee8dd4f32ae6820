"""tests/conftest.py's compile lock: of two processes that need the same cached numba kernel at
once (two pytest-xdist workers on a cold cache), one compiles and the other loads its result."""

from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

TESTS = Path(__file__).resolve().parent

KERNEL = textwrap.dedent("""
    import numba
    import numpy as np

    @numba.njit(cache=True)
    def inner(x):
        s = 0.0
        for i in range(50):
            s += np.sin(x * i) / (1 + i)
        return s

    @numba.njit(cache=True)
    def outer(x):
        return inner(x) + inner(2 * x)
""")

RUN = textwrap.dedent("""
    import os, sys, time
    from pathlib import Path
    sys.path[:0] = [sys.argv[1], sys.argv[2]]
    if sys.argv[3] == "lock":
        import conftest  # noqa: F401 - installs the lock, as pytest does in each worker
    import toykernel
    # both processes call the kernel at once: each waits for the other's "ready" file
    here = Path(sys.argv[2])
    (here / f"ready-{os.getpid()}").touch()
    while len(list(here.glob("ready-*"))) < 2:
        time.sleep(0.01)
    toykernel.outer(3.0)
    d = toykernel.outer
    print(sum(d._cache_misses.values()), sum(d._cache_hits.values()))
""")


def _misses_and_hits(folder, lock):
    """(misses, hits) of the outer kernel in each of two processes started together."""
    folder.mkdir()
    (folder / "toykernel.py").write_text(KERNEL)
    procs = [subprocess.Popen([sys.executable, "-c", RUN, str(TESTS), str(folder), lock], stdout=subprocess.PIPE,
                              stderr=subprocess.PIPE, text=True, cwd=folder) for _ in range(2)]
    outs = [p.communicate(timeout=300) for p in procs]
    assert all(p.returncode == 0 for p in procs), [err[-2000:] for _, err in outs]
    return sorted(tuple(int(v) for v in out.split()) for out, _ in outs)


def test_two_processes_compile_a_cached_kernel_once(tmp_path):
    # one process compiled it, the other loaded it
    assert _misses_and_hits(tmp_path / "locked", "lock") == [(0, 1), (1, 0)]
