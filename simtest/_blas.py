"""One set of OpenBLAS kernels on every x86-64 CPU that runs them, so that a run repeats bit for bit (why:
:data:`simtest.constants.OPENBLAS_CORE`). Effective where OpenBLAS (numpy's and scipy's copies) has not loaded
yet: the command line, ``import simtest`` before numpy, and the processes they start."""

from __future__ import annotations

import os
import platform
from pathlib import Path

from simtest.constants import OPENBLAS_CORE, OPENBLAS_CORE_NEEDS

__all__ = ["pin_openblas_kernels", "vector_extension"]


def _cpu_flags() -> set[str]:
    """The first CPU's flags in ``/proc/cpuinfo`` (empty where there is none)."""
    try:
        text = Path("/proc/cpuinfo").read_text(encoding="ascii", errors="replace")
    except OSError:
        return set()
    return next((set(ln.split(":", 1)[1].split()) for ln in text.splitlines() if ln.startswith("flags")), set())


def vector_extension() -> str:
    """The widest x86 vector extension of this CPU: ``"avx512f"``, ``"avx2"`` or ``"none"`` (elsewhere).
    Dr.Jit's LLVM backend compiles renders for it (8 lanes with AVX2, 16 with AVX-512), which assigns
    the sampler's random numbers to other pixels: renders repeat bit for bit only on the same one."""
    flags = _cpu_flags()
    return next((f for f in ("avx512f", "avx2") if f in flags), "none")


def pin_openblas_kernels() -> str | None:
    """Set ``OPENBLAS_CORETYPE`` to :data:`~simtest.constants.OPENBLAS_CORE` where it is unset and the CPU
    is x86-64 with :data:`~simtest.constants.OPENBLAS_CORE_NEEDS` (read from ``/proc/cpuinfo``).

    Returns
    -------
    str or None
        The core type now asked for (the user's own where set), or None where none is.
    """
    if "OPENBLAS_CORETYPE" not in os.environ and platform.machine().lower() in ("x86_64", "amd64") \
            and OPENBLAS_CORE_NEEDS <= _cpu_flags():
        os.environ["OPENBLAS_CORETYPE"] = OPENBLAS_CORE
    return os.environ.get("OPENBLAS_CORETYPE")
