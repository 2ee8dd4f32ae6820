"""The one lazy-import helper: a missing optional back-end is one line naming what to install."""

from __future__ import annotations

import subprocess
import sys

import pytest

from simtest import _lazy


def test_a_present_backend_is_imported_and_cached():
    mod = _lazy.require("dask")
    assert mod is sys.modules["dask"]


def test_a_missing_backend_names_the_extra_to_install(monkeypatch):
    monkeypatch.setitem(_lazy.BACKENDS, "simtest_no_such_backend", "nothere")
    with pytest.raises(_lazy.MissingBackend) as info:
        _lazy.require("simtest_no_such_backend.sub", purpose="the 3D view")
    msg = str(info.value)
    assert "\n" not in msg
    assert msg.startswith("the 3D view needs simtest_no_such_backend")
    assert 'pip install "simtest[nothere]"' in msg


def test_a_missing_default_dependency_says_reinstall(monkeypatch):
    monkeypatch.setitem(_lazy.BACKENDS, "simtest_no_such_backend", None)
    with pytest.raises(_lazy.MissingBackend, match="reinstall"):
        _lazy.require("simtest_no_such_backend")


def test_only_the_optional_backends_go_through_it():
    with pytest.raises(ValueError, match="not one of the optional back-ends"):
        _lazy.require("numpy")


def test_a_backend_missing_its_own_dependency_shows_that_one(monkeypatch, tmp_path):
    pkg = tmp_path / "simtest_fake_backend"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("import simtest_fake_dependency_that_is_missing\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setitem(_lazy.BACKENDS, "simtest_fake_backend", "x")
    with pytest.raises(ModuleNotFoundError) as info:
        _lazy.require("simtest_fake_backend")
    assert not isinstance(info.value, _lazy.MissingBackend)
    assert info.value.name == "simtest_fake_dependency_that_is_missing"


def test_a_command_needing_a_missing_extra_is_one_line(monkeypatch, tmp_path):
    # Dask is the [dask] extra: without it, --scheduler says what to install, exit 2
    from typer.testing import CliRunner

    from simtest.cli import app
    from simtest.resources import data_root

    for mod in ("distributed", "distributed.comm", "distributed.comm.addressing"):
        monkeypatch.setitem(sys.modules, mod, None)  # as if it were not installed
    res = CliRunner().invoke(app, ["dataset", "generate",
                                   str(data_root() / "scenes" / "datasets" / "small.toml"),
                                   "-o", str(tmp_path / "ds"), "--scheduler", "tcp://127.0.0.1:9"])
    assert res.exit_code == 2, res.output
    lines = [ln for ln in res.output.splitlines() if ln.strip()]
    assert len(lines) == 1 and 'pip install "simtest[dask]"' in lines[0], res.output


def test_the_reconstruction_imports_no_scipy_until_a_step_needs_it():
    # importing scipy is 0.2 to 0.5 s of a command's start on the 2-core VM: the reconstruction's
    # modules take it through require() where a step needs it (the light-aware fits, the contours'
    # linking), never at import, so that a command that needs none of it does not pay for it
    code = ("import sys, simtest.cli, simtest.reconstruct.cli, simtest.reconstruct.pipeline; "
            "print(sorted(m for m in sys.modules if m.split('.')[0] == 'scipy'))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]", out
