"""simtest._threads.one_thread_each: one BLAS thread here and in the workers started within, the
previous state back after."""

import multiprocessing as mp
import os

import numpy as np  # noqa: F401  (loads the BLAS whose threads are limited)
import pytest
from threadpoolctl import threadpool_info, threadpool_limits

from simtest._threads import one_thread_each
from simtest.constants import SINGLE_THREAD_ENV


def _blas_threads() -> list[int]:
    return [d["num_threads"] for d in threadpool_info() if d["user_api"] == "blas"]


def _in_worker(_):
    return _blas_threads(), {k: os.environ.get(k) for k in SINGLE_THREAD_ENV}


def test_limits_this_process_and_restores(monkeypatch):
    monkeypatch.setenv("OPENBLAS_NUM_THREADS", "7")
    monkeypatch.delenv("OMP_NUM_THREADS", raising=False)
    # two threads before (an xdist worker runs one, conftest), so that a limit left behind shows
    with threadpool_limits(limits=2):
        before = _blas_threads()
        with one_thread_each():
            assert all(n == 1 for n in _blas_threads())
            assert {k: os.environ[k] for k in SINGLE_THREAD_ENV} == SINGLE_THREAD_ENV
        assert _blas_threads() == before
    assert os.environ["OPENBLAS_NUM_THREADS"] == "7"  # put back, not dropped
    assert "OMP_NUM_THREADS" not in os.environ  # dropped, as it was absent


@pytest.mark.parametrize("method", ["fork", "spawn"])
def test_workers_started_within_get_one_thread(method):
    # a forked worker inherits the run-time limit, a spawned one reads the environment
    # two threads outside: in an xdist worker (one thread, conftest) a fork would get one anyway
    with threadpool_limits(limits=2), one_thread_each(), mp.get_context(method).Pool(1) as pool:
        threads, env = pool.map(_in_worker, [0])[0]
    assert all(n == 1 for n in threads)
    assert env == SINGLE_THREAD_ENV


def _cv_threads_in_worker(_):
    import cv2

    return cv2.getNumThreads()


def test_opencv_runs_on_one_thread_here_and_in_forked_workers_and_is_restored():
    # two OpenCV threads outside (an xdist worker runs one, conftest), so that a limit left behind
    # or one a forked worker does not inherit shows
    import cv2

    before = cv2.getNumThreads()
    cv2.setNumThreads(2)
    try:
        with one_thread_each():
            assert cv2.getNumThreads() == 1
            with mp.get_context("fork").Pool(1) as pool:
                assert pool.map(_cv_threads_in_worker, [0]) == [1]
        assert cv2.getNumThreads() == 2
    finally:
        cv2.setNumThreads(before)


def test_the_light_aware_step_runs_every_stage_on_one_blas_thread(monkeypatch):
    # the whole light-aware step of `simtest reconstruct -k camera.json` (its last stage here), not only the fits'
    # pool: a stage on two BLAS threads (the lone lobes' refits once were) sums in another order, so a pinned
    # sensor-like frame's depth sigma differed in its last bit with the thread count, at 1.6 times the CPU
    import simtest.reconstruct.rig_centroid as rc

    seen = []
    monkeypatch.setattr(rc, "lone_lobe_rows", lambda image, out, *a, **k: seen.append(_blas_threads()) or out)
    with threadpool_limits(limits=2):
        assert rc.light_aware_with_rig(np.zeros((8, 8)), [], np.eye(3), None) == []
        assert all(n == 2 for n in _blas_threads())  # (restored after)
    assert seen and all(n == 1 for n in seen[0])


def test_a_suite_on_one_worker_runs_on_one_blas_thread(monkeypatch):
    # `simtest validate --workers 1` runs the cases in this process: on one BLAS thread, as its workers do
    import simtest.harness.runner as runner
    from simtest.harness.suite import suite_from_dict

    seen, real = [], runner.run_case_chunk
    monkeypatch.setattr(runner, "run_case_chunk", lambda *a, **k: seen.append(_blas_threads()) or real(*a, **k))
    suite = suite_from_dict({"suite": {"name": "one", "realisations": 1, "seed": 3},
                             "sweep": [{"name": "theta", "parameter": "theta_deg", "values": [20.0]}]})
    with threadpool_limits(limits=2):
        runner.run_suite(suite, workers=1, progress=False)
    assert seen and all(n == 1 for s in seen for n in s)
