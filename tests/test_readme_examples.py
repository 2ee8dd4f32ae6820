"""Every example of the README runs as written, in order, from the root of a copy of the clone.

The README is a user's document: its shell blocks (```bash) are run one line at a time from a
temporary copy of the repository (so ``out/`` and the reports they write land there), then its
Python blocks (```python) are executed in the same folder. A ``simtest ...`` line (after its
``NAME=value`` assignments, if any) goes through the command line's app in this process, from that
folder, with those variables set (CliRunner, as the command-line tests run it: a Python start
and the package's imports, 1 to 2.5 s of CPU a line, saved; the console script itself is tested by
the tests that run it in a real process); every other line runs with ``bash -e``. Two kinds of
lines are not run here, and why:

- the two set-up commands (``apt-get ... && pip install ...``): they install the system; CI runs
  them, and ``test_ci_runs_the_set_up_commands`` checks that ``.ci/run`` runs both;
- a block whose first line is ``# needs: ...`` (data simtest cannot ship, such as a C3VD
  sequence): each of its ``simtest`` lines is parsed by the command line itself (every option and
  argument checked, nothing run), so a renamed flag still fails here.
"""

from __future__ import annotations

import json
import os
import re
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import typer
from test_harness_external import check_external_run
from typer.testing import CliRunner

from simtest.cli import app
from simtest.resources import data_root

ROOT = data_root()
README = (ROOT / "README.md").read_text(encoding="utf-8")
BLOCKS = re.findall(r"^```(\w+)\n(.*?)^```", README, re.S | re.M)
SETUP = "apt-get update && apt-get install"


def _bash_blocks():
    return [b for lang, b in BLOCKS if lang == "bash"]


def _run_lines():
    return [ln for b in _bash_blocks() if not b.startswith("# needs:")
            for ln in b.splitlines() if ln.strip() and not ln.startswith(SETUP)]


def test_the_readme_is_a_users_document():
    lines = README.splitlines()
    assert len(lines) <= 350, f"README.md has {len(lines)} lines (at most 350)"
    long = [i + 1 for i, ln in enumerate(lines) if len(ln) > 300]
    assert not long, f"README.md lines over 300 characters: {long}"
    setup = [b.strip() for b in _bash_blocks()[:2]]
    assert all(s.startswith(SETUP) for s in setup), "the README starts with the two set-up commands"
    assert setup[0].endswith("simtest validate") and setup[1].endswith("python -m pytest")


def test_ci_runs_the_set_up_commands():
    ci = (ROOT / ".ci" / "run").read_text(encoding="utf-8")
    first, second = (b.strip() for b in _bash_blocks()[:2])
    packages = first.split("apt-get install -y ", 1)[1].split(" &&", 1)[0]
    assert packages in ci, ".ci/run installs other system packages than the README"
    assert 'pip install -q -e ".[test]"' in ci and "python -m pytest" in ci
    assert re.search(r"^simtest validate\b", ci, re.M), ".ci/run does not run the main job"


def _copy_of_the_clone(tmp: Path) -> Path:
    """The files the examples read by relative path (scenes, the real frames), in a fresh folder.

    The code itself is this checkout's (``PYTHONPATH``): the examples run what the tests test.
    """
    repo = tmp / "clone"
    (repo / "tests" / "data").mkdir(parents=True)
    shutil.copytree(ROOT / "scenes", repo / "scenes")
    for data in ("real", "external"):
        shutil.copytree(ROOT / "tests" / "data" / data, repo / "tests" / "data" / data)
    for name in ("pyproject.toml", "README.md"):
        shutil.copy2(ROOT / name, repo / name)
    return repo


def _user_env(tmp_path: Path) -> dict:
    """The environment of a user of this interpreter: ``simtest`` and ``python`` on PATH run
    ``sys.executable`` (inside a venv, the venv's), with this checkout's code."""
    env = dict(os.environ, MPLBACKEND="Agg", PYTHONPATH=str(ROOT))
    shim = tmp_path / "bin"
    shim.mkdir()
    (shim / "simtest").write_text(f"#!/bin/sh\nexec {sys.executable} -m simtest.cli \"$@\"\n")
    (shim / "simtest").chmod(0o755)
    # a script, not a symlink: Python started through a symlink outside a venv finds no
    # pyvenv.cfg beside it and runs as the base interpreter, without the venv's packages
    (shim / "python").write_text(f"#!/bin/sh\nexec {sys.executable} \"$@\"\n")
    (shim / "python").chmod(0o755)
    env["PATH"] = f"{shim}{os.pathsep}{env['PATH']}"
    return env


def test_the_examples_python_is_the_users_interpreter(tmp_path):
    """`python` in an example runs with the test's own prefix (a venv's packages, not the base's)."""
    env = _user_env(tmp_path)
    r = subprocess.run(["bash", "-c", "python -c 'import sys; print(sys.prefix)'"], env=env,
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == sys.prefix


def _run_line(line: str, repo: Path, env: dict, monkeypatch) -> tuple[int, str]:
    """One README line from ``repo``: its exit status and what it printed on error.

    ``[NAME=value ...] simtest ARGS`` (no other shell syntax) through the command line's app in
    this process: the assignments set in the environment for the line (a ``PYTHONPATH`` one also
    on ``sys.path``, where this process's imports look), the environment restored after it. Any
    other line with ``bash -e`` in the user's environment ``env``."""
    words = shlex.split(line)
    sets = words[:next((i for i, w in enumerate(words) if "=" not in w), len(words))]
    rest = words[len(sets):]
    if rest[:1] != ["simtest"] or any(c in line for c in "|;&<>$`()"):
        r = subprocess.run(["bash", "-e", "-c", line], cwd=repo, env=env, capture_output=True,
                           text=True, timeout=300)
        return r.returncode, r.stderr
    saved = dict(os.environ)
    try:
        with monkeypatch.context() as mp:
            mp.chdir(repo)
            # the clone's example is the one a line names; pytest's doctest collection imported the checkout's
            ours = (ROOT / "tests" / "data" / "external").resolve()
            mp.setattr(sys, "path", [p for p in sys.path if Path(p or ".").resolve() != ours])
            for example in ours.glob("*.py"):
                mp.delitem(sys.modules, example.stem, raising=False)
            for name, value in (w.split("=", 1) for w in sets):
                mp.setenv(name, value)
                if name == "PYTHONPATH":
                    mp.syspath_prepend(str(repo / value))
            res = CliRunner().invoke(app, rest[1:], prog_name="simtest")
    finally:  # what a command leaves in os.environ reaches neither the next line nor test
        os.environ.clear()
        os.environ.update(saved)
    return res.exit_code, res.output + (repr(res.exception) if res.exception else "")


@pytest.mark.slow
def test_every_readme_example_runs(tmp_path, monkeypatch):
    repo = _copy_of_the_clone(tmp_path)
    env = _user_env(tmp_path)
    for line in _run_lines():
        code, err = _run_line(line, repo, env, monkeypatch)
        assert code == 0, f"README example failed ({code}): {line}\n{err[-2000:]}"
    # the external estimator's run (README_LINE): test_harness_external's checks, on this run
    runs = [p.parent for p in (repo / "out" / "reports" / "quick").glob("*/results.json")
            if "bp_ray_cv" in json.loads(p.read_text())["suite"]["estimators"]]
    assert len(runs) == 1, runs
    check_external_run(runs[0])
    for lang, block in BLOCKS:
        if lang == "python":
            r = subprocess.run([sys.executable, "-c", block], cwd=repo, env=env,
                               capture_output=True, text=True, timeout=300)
            assert r.returncode == 0, f"README Python example failed:\n{block}\n{r.stderr[-2000:]}"


def test_lines_that_need_outside_data_still_parse():
    needs = [b for b in _bash_blocks() if b.startswith("# needs:")]
    assert needs, "the README's C3VD example is a '# needs:' block"
    top = typer.main.get_command(app)
    for block in needs:
        for line in block.splitlines()[1:]:
            args = shlex.split(line)
            assert args[0] == "simtest", line
            cmd, rest, ctx = top, args[1:], typer.Context(top, info_name="simtest")
            while hasattr(cmd, "get_command"):  # a group (Typer's own Click: no click import)
                name, rest = rest[0], rest[1:]
                cmd = cmd.get_command(ctx, name)
                assert cmd is not None, f"{line}: no command {name!r}"
            cmd.make_context(cmd.name, list(rest))  # raises on an unknown option or argument
