"""Locate an LLVM shared library that Dr.Jit's llvm variants accept (LLVM 16 or newer).

Dr.Jit reads ``DRJIT_LIBLLVM_PATH`` when it first loads; Debian's libllvm15 crashes at the first kernel
and libllvm14 is refused, so simtest points it at the newest LLVM >= 16 found unless the user set it.
"""

from __future__ import annotations

import glob
import os
import re

#: Minimum LLVM major version the llvm_ad_* variants run with on these machines.
MIN_LLVM_MAJOR = 16

#: What to tell a user whose machine lacks a suitable LLVM.
LLVM_FIX = ("install LLVM 16 or newer, e.g. `apt-get install libllvm19` on Debian, or set "
            "DRJIT_LIBLLVM_PATH to a libLLVM-16+ shared library")

_SEARCH = ("/usr/lib/x86_64-linux-gnu/libLLVM-*.so*", "/usr/lib/aarch64-linux-gnu/libLLVM-*.so*",
           "/usr/lib/llvm-*/lib/libLLVM*.so*", "/usr/lib/libLLVM-*.so*", "/usr/local/lib/libLLVM*.so*")


def _major(path: str) -> int | None:
    m = re.search(r"(?:libLLVM-|llvm-)(\d+)", path)
    return int(m.group(1)) if m else None


def find_libllvm() -> str | None:
    """Return the path of the newest LLVM >= 16 shared library found, or None.

    Returns
    -------
    str or None
        An absolute path such as ``/usr/lib/x86_64-linux-gnu/libLLVM-19.so``.
    """
    found: list[tuple[int, str]] = []
    for pattern in _SEARCH:
        for path in glob.glob(pattern):
            major = _major(path)
            if major is not None and major >= MIN_LLVM_MAJOR and os.path.isfile(path):
                found.append((major, path))
    if not found:
        return None
    found.sort(key=lambda mp: (mp[0], -len(mp[1])))
    return found[-1][1]


def configure_llvm_env() -> str | None:
    """Set ``DRJIT_LIBLLVM_PATH`` if unset and a suitable LLVM exists; return the path in force.

    Must run before Dr.Jit is imported. A user's own setting is never overridden.
    """
    current = os.environ.get("DRJIT_LIBLLVM_PATH")
    if current:
        return current
    path = find_libllvm()
    if path is not None:
        os.environ["DRJIT_LIBLLVM_PATH"] = path
    return path
