"""Finished samples are kept as they arrive (the spool), a resume uses them, and the result is the
uninterrupted dataset byte for byte; SIGTERM/SIGKILL leave no worker running (stand-in samples)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest
from _procs import alive, cmdline, descendants
from test_dataset_format import _cfg, _files, _make, standin_sample
from typer.testing import CliRunner

from simtest.cli import app
from simtest.dataset import cli as dataset_cli
from simtest.dataset.generate import SPOOL_DIR, Interrupted, SampleError, generate, spool_path
from simtest.dataset.shards import DatasetWriteError, shard_json_path
from simtest.dataset.verify import verify

REPO = Path(__file__).resolve().parents[1]


def _stop_at(index: int, exc: BaseException):
    def fn(config, i):  # not picklable, fine inline
        if i == index:
            raise exc
        return standin_sample(config, i)
    return fn


def _counting(calls: list):
    def fn(config, i):
        calls.append(i)
        return standin_sample(config, i)
    return fn


@pytest.mark.parametrize("stop", [RuntimeError("boom"), KeyboardInterrupt()], ids=["raise", "interrupt"])
def test_a_stop_mid_shard_keeps_the_finished_samples_and_the_resume_is_identical(tmp_path, stop):
    cfg, ref, _ = _make(tmp_path, "ref", count=10, shard_size=5)
    out = tmp_path / "out"
    cfg = _cfg(count=10, shard_size=5)
    with pytest.raises(SampleError if isinstance(stop, Exception) else Interrupted):
        generate(cfg, out, workers=1, sample_fn=_stop_at(8, stop), progress=False)
    # shard 0 complete; every finished sample of shard 1 kept in the spool (before: all lost):
    # 5, 6, 7, and 9 when it finished before 8's failure was seen
    assert shard_json_path(out, 0).exists() and not shard_json_path(out, 1).exists()
    kept = {int(p.name[:8]) for p in (out / SPOOL_DIR).iterdir()}
    assert {5, 6, 7} <= kept <= {5, 6, 7, 9}
    calls: list = []
    rep = generate(cfg, out, workers=1, sample_fn=_counting(calls), progress=False)
    assert calls == sorted({8, 9} - kept)
    assert (rep.written, rep.resumed, rep.skipped) == (len(calls), len(kept), 5)
    assert not (out / SPOOL_DIR).exists()
    assert _files(out) == _files(ref)  # byte-identical to the uninterrupted run
    assert verify(out).ok


def test_a_damaged_spool_file_is_rendered_again(tmp_path):
    cfg, ref, _ = _make(tmp_path, "ref", count=6, shard_size=6)
    out = tmp_path / "out"
    with pytest.raises(SampleError):
        generate(cfg, out, workers=1, sample_fn=_stop_at(4, RuntimeError("x")), progress=False)
    p = spool_path(out, 2)  # one value of an array changed, its hash kept
    with np.load(p) as z:
        entries = {k: z[k].copy() for k in z.files}
    entries["a_linear"].flat[0] += 1.0
    with open(p, "wb") as fh:
        np.savez(fh, **entries)
    spool_path(out, 3).write_bytes(spool_path(out, 3).read_bytes()[:100])  # truncated
    kept = {int(p.name[:8]) for p in (out / SPOOL_DIR).iterdir()}
    calls: list = []
    generate(cfg, out, workers=1, sample_fn=_counting(calls), progress=False)
    # the two damaged samples, and every sample the stopped run did not keep (4 failed; 5 may or
    # may not have finished before the stop reached the pool, so it is judged by the spool)
    assert 4 not in kept
    assert calls == sorted({2, 3} | (set(range(6)) - kept))
    assert _files(out) == _files(ref)


def test_the_spool_survives_a_full_disk_and_the_resume_completes(tmp_path, monkeypatch):
    import simtest.dataset.generate as gen

    cfg = _cfg(count=6, shard_size=6)
    real = gen._spool_write
    n = {"k": 0}

    def full_after_two(out, sample, fp):
        n["k"] += 1
        if n["k"] > 2:
            raise OSError(28, "No space left on device", str(spool_path(out, sample.index)))
        return real(out, sample, fp)

    monkeypatch.setattr(gen, "_spool_write", full_after_two)
    with pytest.raises(DatasetWriteError, match="no space left on device"):
        generate(cfg, tmp_path / "ds", workers=1, sample_fn=standin_sample, progress=False)
    monkeypatch.undo()
    kept = {int(p.name[:8]) for p in (tmp_path / "ds" / SPOOL_DIR).iterdir()}
    assert len(kept) == 2  # the two spooled before the disk filled (no temporary file left)
    calls: list = []
    generate(cfg, tmp_path / "ds", workers=1, sample_fn=_counting(calls), progress=False)
    assert calls == sorted(set(range(6)) - kept) and verify(tmp_path / "ds").ok


# ------------------------------------------------------------------------------------------------
# workers die with the parent

_SCRIPT = textwrap.dedent("""
    import sys, time
    sys.path.insert(0, {tests!r})

    def slow(config, index):  # imports here: a spawned worker imports this module too
        open({out!r} + f".running-{{index}}", "w").close()  # the worker is past its start-up
        time.sleep(90)  # (killed long before: only the test's start-up wait below must fit in it)
        from test_dataset_format import standin_sample
        return standin_sample(config, index)

    if __name__ == "__main__":
        import slowmod
        from test_dataset_format import _cfg
        from simtest.dataset.generate import Interrupted, generate
        try:
            generate(_cfg(count=8, shard_size=4), {out!r}, workers=2, sample_fn=slowmod.slow,
                     progress=False)
        except Interrupted:
            sys.exit(130)
""")


def _pool_processes(pid: int) -> tuple[list[int], list[int]]:
    """The workers of ``pid``'s pool (spawned, or forked by a fork server) and its fork servers."""
    workers, servers = [], []
    for c in sorted(descendants(pid, depth=1)):
        cmd = cmdline(c)
        if b"spawn_main" in cmd:
            workers.append(c)
        elif b"forkserver" in cmd:
            servers.append(c)
            workers += sorted(descendants(c, depth=1))
    return workers, servers


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGKILL], ids=["SIGTERM", "SIGKILL"])
def test_killing_generate_leaves_no_worker_running(tmp_path, sig):
    src = _SCRIPT.format(tests=str(REPO / "tests"), out=str(tmp_path / "ds"))
    (tmp_path / "slowmod.py").write_text(src)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(tmp_path), str(REPO), str(REPO / "tests")])}
    proc = subprocess.Popen([sys.executable, str(tmp_path / "slowmod.py")], env=env, cwd=tmp_path)
    try:
        workers: list[int] = []
        servers: list[int] = []
        # the wait for both workers to run a sample: spawned workers import simtest, which on a 2-core
        # machine under load (another test run beside it) took over 18 s; the wait ends when they run
        deadline = time.monotonic() + 75
        while time.monotonic() < deadline:
            workers, servers = _pool_processes(proc.pid)
            if len(workers) == 2 and len(list(tmp_path.glob("ds.running-*"))) == 2:
                break
            time.sleep(0.1)
        assert len(workers) == 2, "the workers did not start"
        proc.send_signal(sig)
        rc = proc.wait(timeout=15)
        assert rc == (130 if sig == signal.SIGTERM else -signal.SIGKILL)
        deadline = time.monotonic() + 5
        while time.monotonic() < deadline and any(alive(w) for w in workers + servers):
            time.sleep(0.05)
        assert not [w for w in workers + servers if alive(w)], "workers outlived their parent"
    finally:
        if proc.poll() is None:
            proc.kill()


def test_cli_exit_codes_for_an_interrupt_and_a_full_disk(tmp_path, monkeypatch):
    cfg = tmp_path / "c.toml"
    cfg.write_text("count = 2\nseed = 1\n[families]\nplanes = 1\n")
    for exc, code in [(Interrupted("x: interrupted; rerun"), 130),
                      (DatasetWriteError("x: cannot write: no space left on device"), 4)]:
        def raising(*a, exc=exc, **k):
            raise exc
        monkeypatch.setattr(dataset_cli, "generate", raising)
        res = CliRunner().invoke(app, ["dataset", "generate", str(cfg), "-o", str(tmp_path / "ds"),
                                       "-j", "1", "--no-progress"])
        assert res.exit_code == code, res.output
        assert res.output.strip().splitlines() == [f"error: {exc}"]
