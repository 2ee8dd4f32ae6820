"""Atomic writes: a failed or interrupted write leaves the previous file intact and no debris."""

from __future__ import annotations

import pytest

from simtest._io import atomic_write, atomic_write_bytes, atomic_write_text


def test_writes_and_replaces(tmp_path):
    p = atomic_write_text(tmp_path / "sub" / "a.json", "one")
    assert p.read_text() == "one"
    atomic_write_bytes(p, b"two")
    assert p.read_bytes() == b"two"
    assert sorted(x.name for x in p.parent.iterdir()) == ["a.json"]


def test_failed_write_keeps_old_content_and_removes_temporary(tmp_path):
    p = atomic_write_text(tmp_path / "a.txt", "old")

    def half_then_fail(tmp):
        with open(tmp, "w") as fh:
            fh.write("half")
        raise RuntimeError("disk full")

    with pytest.raises(RuntimeError, match="disk full"):
        atomic_write(p, half_then_fail)
    assert p.read_text() == "old"
    assert [x.name for x in tmp_path.iterdir()] == ["a.txt"]


def test_suffix_for_writers_that_infer_the_format(tmp_path):
    seen = []
    atomic_write(tmp_path / "x.png", lambda tmp: (seen.append(tmp), open(tmp, "wb").close()), suffix=".png")
    assert seen[0].endswith(".png") and (tmp_path / "x.png").exists()


def test_files_get_the_mode_of_an_ordinary_write(tmp_path):
    import os

    plain = tmp_path / "plain.txt"
    plain.write_text("x")
    p = atomic_write_text(tmp_path / "atomic.txt", "x")
    assert os.stat(p).st_mode == os.stat(plain).st_mode
