"""A full disk during ``dataset export``: one line, exit 4, no temporary folder, earlier export intact."""

from __future__ import annotations

import errno
import os

import h5py
import pytest
from test_dataset_format import _files, _make
from typer.testing import CliRunner

from simtest.cli import app
from simtest.dataset import export as export_mod
from simtest.dataset.shards import DatasetWriteError


def _full_after(n: int):
    real = export_mod._write_file
    state = {"k": 0}

    def write(path, data):
        state["k"] += 1
        if state["k"] > n:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(path))
        return real(path, data)
    return write


def test_a_full_disk_during_the_hdf5_export_is_one_line_exit_4_and_leaves_nothing(tmp_path, monkeypatch):
    _, ds, _ = _make(tmp_path)
    out = tmp_path / "exp"
    res = CliRunner().invoke(app, ["dataset", "export", str(ds), "-f", "hdf5", "-o", str(out)])
    assert res.exit_code == 0, res.output
    before = _files(out)
    monkeypatch.setattr(export_mod, "_write_file", _full_after(3))  # the disk fills mid-way
    res = CliRunner().invoke(app, ["dataset", "export", str(ds), "-f", "hdf5", "-o", str(out)])
    assert res.exit_code == 4, res.output
    lines = res.output.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and "no space left on device" in lines[0]
    assert "Traceback" not in res.output and "HDF5" not in res.output
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ds", "exp"]  # no .exp.<pid>.tmp left
    assert _files(out) == before  # the earlier export is intact
    with h5py.File(out / "3.hdf5", "r") as f:
        assert f["normals"].shape[-1] == 3


def test_the_api_raises_dataset_write_error_and_removes_a_dead_exports_temp_folder(tmp_path, monkeypatch):
    _, ds, _ = _make(tmp_path)
    out = tmp_path / "exp"
    stale = tmp_path / ".exp.999999999.tmp"  # left by an export whose process died (no such pid)
    stale.mkdir()
    (stale / "0.hdf5").write_bytes(b"x" * 1000)
    monkeypatch.setattr(export_mod, "_write_file", _full_after(0))
    with pytest.raises(DatasetWriteError, match="no space left on device") as err:
        export_mod.export(ds, "hdf5", out)
    assert "\n" not in str(err.value)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ds"]
