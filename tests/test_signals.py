"""SIGTERM and SIGINT end a command with exit status 130, one line, and no process of its own.

Before, ``validate -j 2`` and ``reconstruct -j 2`` died with -15 on SIGTERM and left their two
workers running (still alive minutes later, holding the caller's standard error); SIGINT on
``validate`` printed nothing. Each test starts the command in its own process, waits until its
workers run, sends the signal and checks the exit status, standard error and that every process
the command started is gone 5 s later (the bound the issue states; /proc, Linux).
"""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from _procs import alive, cmdline, descendants

pytestmark = [pytest.mark.slow,
              pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="reads /proc")]

ROOT = Path(__file__).resolve().parents[1]
#: The bound on how long a worker may outlive the signal (the issue's "no worker alive 5 s after").
GONE_WITHIN_S = 5.0
#: How long a cold start may take before the workers run (imports on a busy VM).
START_S = 300.0


def _workers(pid: int) -> set[int]:
    """The command's worker processes (not multiprocessing's resource tracker)."""
    return {c for c in descendants(pid) if b"resource_tracker" not in cmdline(c)}


def _interrupt(args: list[str], sig: int, cwd: Path, *, group: bool = False) -> None:
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")])))
    err = cwd / "stderr.txt"
    with open(err, "wb") as fh:
        p = subprocess.Popen([sys.executable, "-m", "simtest.cli", *args], cwd=cwd, env=env,
                             stdout=subprocess.DEVNULL, stderr=fh, start_new_session=True)
    seen: set[int] = set()
    try:
        deadline = time.monotonic() + START_S
        while len(_workers(p.pid)) < 2:
            assert p.poll() is None, f"ended before its workers started: {err.read_text()}"
            assert time.monotonic() < deadline, "no workers started"
            time.sleep(0.2)
        time.sleep(1.0)  # the workers now hold tasks
        assert p.poll() is None, "the command ended before the signal: give it more work"
        seen = descendants(p.pid)
        if group:  # Ctrl-C in a terminal: the whole process group gets SIGINT
            os.killpg(p.pid, sig)
        else:
            p.send_signal(sig)
        code = p.wait(timeout=60)
        deadline = time.monotonic() + GONE_WITHIN_S
        while any(alive(c) for c in seen) and time.monotonic() < deadline:
            time.sleep(0.1)
        left = [c for c in seen if alive(c)]
        text = err.read_text()
        assert code == 130, text
        assert "Traceback" not in text and "leaked" not in text, text
        errors = [ln for ln in text.splitlines() if ln.startswith("error:")]
        assert len(errors) == 1 and text.splitlines()[-1] == errors[0], text
        assert f"interrupted by {signal.Signals(sig).name}" in errors[0]
        assert left == [], f"processes left {GONE_WITHIN_S} s after the signal: {left}"
    finally:
        for c in seen | {p.pid}:
            if alive(c):
                os.kill(c, signal.SIGKILL)
        p.wait(timeout=10)


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_validate_with_workers_ends_130_and_leaves_no_process(tmp_path, sig):
    _interrupt(["validate", "quick", "-j", "2", "-o", str(tmp_path / "reports"), "--no-progress"],
               sig, tmp_path)
    assert not (tmp_path / "reports" / "quick").exists() or not any(
        (tmp_path / "reports" / "quick").iterdir())  # no run folder, no temporary folder


@pytest.mark.parametrize("group", [False, True])
def test_reconstruct_of_frames_with_workers_ends_130_and_leaves_no_process(tmp_path, group):
    frames = tmp_path / "frames"
    frames.mkdir()
    tile = ROOT / "tests" / "data" / "real" / "hyperkvasir_tile_r2c3_polyp.png"
    for i in range(400):  # far more than the signal lets run
        shutil.copy(tile, frames / f"f{i:03d}.png")
    out = tmp_path / "out"
    _interrupt(["reconstruct", str(frames), "-k", str(ROOT / "tests" / "data" / "real" /
                                                       "intrinsics_assumed_f140.json"),
                "-o", str(out), "-j", "2"],
               signal.SIGINT if group else signal.SIGTERM, tmp_path, group=group)
    assert not out.exists()
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []  # no temporaries
