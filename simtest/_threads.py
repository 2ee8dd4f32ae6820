"""One thread per process for the numerical libraries, where processes are the parallelism: in a pool on
every core, each worker's BLAS and OpenCV threads only spin on the cores other workers need."""

from __future__ import annotations

import contextlib
import os
import sys
from collections.abc import Iterator

from threadpoolctl import threadpool_limits

from simtest.constants import SINGLE_THREAD_ENV

__all__ = ["one_thread_each"]


@contextlib.contextmanager
def one_thread_each() -> Iterator[None]:
    """Within the block, this process and the worker processes it starts run BLAS, OpenMP and OpenCV on
    one thread each; on leaving, the previous limits and environment return.

    Forked workers inherit threadpoolctl's run-time limit (https://github.com/joblib/threadpoolctl) and
    OpenCV's thread count (set where OpenCV is loaded; its results do not depend on it); spawned ones
    read the environment :data:`simtest.constants.SINGLE_THREAD_ENV` when they import numpy.

    Yields
    ------
    None
    """
    saved = {k: os.environ.get(k) for k in SINGLE_THREAD_ENV}
    os.environ.update(SINGLE_THREAD_ENV)
    cv2 = sys.modules.get("cv2")  # (not imported here: a process without OpenCV does not load it)
    cv_threads = None if cv2 is None else cv2.getNumThreads()
    try:
        with threadpool_limits(limits=1):
            if cv2 is not None:
                cv2.setNumThreads(1)
            yield
    finally:
        if cv2 is not None:
            cv2.setNumThreads(cv_threads)
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v
