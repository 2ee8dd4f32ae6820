"""``validate`` and ``nightly`` on a Dask cluster: the same seeding, the same results."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from simtest.harness.runner import run_suite
from simtest.harness.suite import load_suite


def _errors(run) -> list:
    # the end-to-end records as JSON text: NaN == NaN there, so equal text is bit-for-bit equal
    return [(r.case.key, r.realisation.tolist(), {k: v.tolist() for k, v in sorted(r.errors.items())},
             (r.causes, json.dumps(r.e2e, sort_keys=True))) for r in run.results]


@pytest.mark.slow
def test_a_local_cluster_gives_the_results_of_local_processes():
    from distributed import LocalCluster

    # two realisations a case: each case still has one past its first (the per-realisation
    # seeding) and its own task, so both workers get several (CHUNK: one task a case here)
    suite = load_suite("quick").with_overrides(realisations=2)
    local = run_suite(suite, workers=2, progress=False)
    # worker processes, as on a real cluster: the chunks are pickled and set up per process
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                      dashboard_address=None) as cluster:
        remote = run_suite(suite, progress=False, scheduler=cluster.scheduler_address)
    assert remote.workers == 2
    a, b = _errors(local), _errors(remote)
    assert len(a) == len(b) and a  # every case ran
    for (ka, ia, ea, ca), (kb, ib, eb, cb) in zip(a, b):
        assert (ka, ia, ca) == (kb, ib, cb)
        for name in ea:  # bit for bit, NaN where the same realisation failed
            np.testing.assert_array_equal(np.asarray(ea[name]), np.asarray(eb[name]), err_msg=name)


@pytest.mark.parametrize("address, why", [("127.0.0.1:8786", "not a scheduler address"),
                                          ("tcp://127.0.0.1:9", "cannot connect")])
def test_a_bad_or_silent_scheduler_is_one_line_before_any_work(tmp_path, address, why):
    # port 9 (discard) on localhost: nothing listens there
    r = subprocess.run([sys.executable, "-m", "simtest.cli", "validate", "quick", "--no-progress",
                        "-o", str(tmp_path / "out"), "--scheduler", address],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 2, r.stderr
    lines = r.stderr.strip().splitlines()
    assert lines[-1].startswith("error: --scheduler") and why in lines[-1], r.stderr
    assert "Traceback" not in r.stderr
    assert not (tmp_path / "out" / "quick").exists()


def test_a_port_nothing_listens_on_is_refused_at_once_not_waited_for():
    # a port just freed on localhost refuses the connection: the error says so at once (Dask's client would retry
    # until CONNECT_TIMEOUT and say only that it timed out)
    import socket

    from simtest._dask import SchedulerError, connect
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    with pytest.raises(SchedulerError, match="cannot connect: the connection was refused"):
        connect(f"tcp://127.0.0.1:{port}")
