"""One thread per process for the numerical libraries, where processes are the parallelism.

In a pool on every core, each worker's BLAS threads only spin on the cores other workers need.
:func:`one_thread_each` covers forked workers (threadpoolctl's run-time limit, inherited) and spawned ones
(the environment, read when they import numpy).
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator

from threadpoolctl import threadpool_limits

from simtest.constants import SINGLE_THREAD_ENV

__all__ = ["one_thread_each"]


@contextlib.contextmanager
def one_thread_each() -> Iterator[None]:
    """Within the block, this process and the worker processes it starts (forked or spawned) run
    BLAS and OpenMP on one thread each; on leaving, the previous limits and environment return.

    Yields
    ------
    None

    Notes
    -----
    The run-time limit is threadpoolctl's (https://github.com/joblib/threadpoolctl), the
    environment :data:`simtest.constants.SINGLE_THREAD_ENV`.
    """
    saved = {k: os.environ.get(k) for k in SINGLE_THREAD_ENV}
    os.environ.update(SINGLE_THREAD_ENV)
    try:
        with threadpool_limits(limits=1):
            yield
    finally:
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v
