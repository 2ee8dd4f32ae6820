"""Outputs replaced as a set: whatever stops `simtest reconstruct` (an exception, SIGKILL) at
whatever step, its ``--out`` folder holds the whole previous set or the whole new one, never a new
``estimates.json`` beside an old ``overlay.png``.

Two levels: the command, with a failure injected at each rename of the swap (the old writer renamed
file by file, so a failure between its two renames mixed the sets); and
:func:`~simtest._io.replace_output_folder` killed for real (``os._exit`` in a forked
child, so no clean-up runs) at each step, including between the two renames of the fallback swap
used where the file system has no atomic exchange.
"""

from __future__ import annotations

import hashlib
import os
from pathlib import Path

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from simtest.cli import app
from simtest.geometry import save_intrinsics
from simtest import _io as rio  # the set swap lives in the base module (reconstruct.io re-exports it)
from simtest.simulate.analytic import phong_plane_image

runner = CliRunner()
SIZE = 120


class Killed(BaseException):
    """Stands for a kill: not an Exception, so no ``except Exception`` handles it."""


def _digest(folder: Path) -> dict[str, str]:
    return {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(folder.iterdir())}


@pytest.fixture
def inputs(tmp_path):
    K = np.array([[150.0, 0, SIZE / 2 - 0.5], [0, 150.0, SIZE / 2 - 0.5], [0, 0, 1.0]])
    t = np.radians(12)
    img = phong_plane_image(K, (SIZE, SIZE), np.array([np.sin(t), 0.0, -np.cos(t)]), 250.0, 60)
    png = tmp_path / "plane.png"
    cv2.imwrite(str(png), np.round(img * 60000).astype(np.uint16))
    kjson = tmp_path / "K.json"
    save_intrinsics(kjson, K)
    return png, kjson


def _run(inputs, out, t):
    png, kjson = inputs
    return runner.invoke(app, ["reconstruct", str(png), "-k", str(kjson), "-o", str(out), "-t", str(t)])


def test_a_failure_at_any_rename_leaves_the_old_or_the_new_set(inputs, tmp_path, monkeypatch):
    # the two sets, made undisturbed (the outputs are deterministic: same bytes on a rerun)
    sets = {}
    for t in (0.3, 0.5):
        ref = tmp_path / f"ref{t}"
        assert _run(inputs, ref, t).exit_code == 0
        sets[t] = _digest(ref)
        assert set(sets[t]) == {"estimates.json", "overlay.png"}
    assert sets[0.3]["estimates.json"] != sets[0.5]["estimates.json"]
    assert sets[0.3]["overlay.png"] != sets[0.5]["overlay.png"]

    calls = {"n": 0, "fail_at": 0}

    def failing(fn):
        def wrapped(*args, **kwargs):
            if str(tmp_path) in str(args[-1]):
                calls["n"] += 1
                if calls["n"] == calls["fail_at"]:
                    raise Killed(f"rename {calls['n']}")
            return fn(*args, **kwargs)
        return wrapped

    monkeypatch.setattr(os, "rename", failing(os.rename))
    monkeypatch.setattr(os, "replace", failing(os.replace))
    monkeypatch.setattr(rio, "_exchange", failing(rio._exchange))
    seen_new = False
    for fail_at in range(1, 6):
        out = tmp_path / f"out{fail_at}"
        calls.update(n=0, fail_at=0)
        assert _run(inputs, out, 0.3).exit_code == 0
        assert _digest(out) == sets[0.3]
        calls.update(n=0, fail_at=fail_at)
        try:
            res = _run(inputs, out, 0.5)
            killed = False
            assert res.exit_code == 0, res.output
        except Killed:
            killed = True
        got = _digest(out)
        assert got in (sets[0.3], sets[0.5]), (fail_at, got)
        seen_new |= got == sets[0.5]
        if killed:  # nothing is left beside OUT but what the next run clears up
            assert _run(inputs, out, 0.5).exit_code == 0 and _digest(out) == sets[0.5]
            assert sorted(p.name for p in tmp_path.iterdir() if p.name.startswith(f".out{fail_at}")) == []
    assert seen_new


def test_a_failing_writer_leaves_the_previous_set(inputs, tmp_path, monkeypatch):
    out = tmp_path / "out"
    assert _run(inputs, out, 0.3).exit_code == 0
    before = _digest(out)
    from simtest.reconstruct import cli as rcli

    def broken(*args, **kwargs):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(rcli, "draw_overlay", broken)  # estimates.json is written, overlay.png fails
    res = _run(inputs, out, 0.5)
    lines = [ln for ln in res.output.splitlines() if ln.strip()]
    assert res.exit_code == 4 and len(lines) == 1, res.output
    assert lines[0].startswith("error: --out: cannot write") and "No space left on device" in lines[0]
    assert _digest(out) == before
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".out")] == []


def _fill(tag):
    def fill(folder):
        (folder / "a.txt").write_text(tag)
        (folder / "b.txt").write_text(tag)
    return fill


def _state(out: Path):
    if not out.exists():
        return None
    files = {p.name: p.read_text() for p in out.iterdir()}
    assert files in ({"a.txt": "old", "b.txt": "old"}, {"a.txt": "new", "b.txt": "new"}), files
    return files["a.txt"]


def _killed_child(out: Path, step: str, exchange: bool) -> None:
    """Fork; the child replaces OUT's set and dies (``os._exit``, no clean-up) at ``step``."""
    pid = os.fork()
    if pid == 0:  # the child never returns into pytest
        try:
            def die(*_a, **_k):
                os._exit(9)

            real_rename = os.rename
            if not exchange:
                rio._exchange = lambda a, b: False
            if step == "fill":
                fill = _fill("new")
                rio.replace_output_folder(out, lambda f: (fill(f), die()))
            elif step == "swap":  # at the exchange, or at the fallback's first rename
                if exchange:
                    rio._exchange = die
                else:
                    os.rename = die
            elif step == "after_swap":
                rio.shutil.rmtree = die
            elif step == "between_renames":
                n = {"k": 0}

                def second_dies(a, b):
                    n["k"] += 1
                    if n["k"] == 2:
                        die()
                    real_rename(a, b)

                os.rename = second_dies
            rio.replace_output_folder(out, _fill("new"))
            os._exit(0)
        finally:
            os._exit(1)
    _, status = os.waitpid(pid, 0)
    assert os.waitstatus_to_exitcode(status) == 9, (step, status)  # it died where meant to


@pytest.mark.parametrize("exchange", [True, False], ids=["renameat2", "two-renames"])
def test_a_kill_at_any_step_leaves_a_whole_set(tmp_path, exchange):
    steps = ["fill", "swap", "after_swap"] + ([] if exchange else ["between_renames"])
    for step in steps:
        out = tmp_path / f"out-{step}"
        rio.replace_output_folder(out, _fill("old"))
        _killed_child(out, step, exchange)
        state = _state(out)
        if state is None:  # killed between the two renames: the previous set waits beside OUT
            assert step == "between_renames"
            assert rio.recover_output_folder(out)
            assert _state(out) == "old"
        # the next write clears what the kill left and succeeds
        rio.replace_output_folder(out, _fill("new"))
        assert _state(out) == "new"
        assert [p.name for p in tmp_path.iterdir() if p.name.startswith(f".{out.name}")] == []


def test_renameat2_exchange_is_used_here(tmp_path):
    """On this machine the swap is the atomic exchange (the fallback is tested above)."""
    a, b = tmp_path / "a", tmp_path / "b"
    a.mkdir()
    b.mkdir()
    (a / "x").write_text("a")
    assert rio._exchange(a, b) is True
    assert (b / "x").read_text() == "a" and not (a / "x").exists()
