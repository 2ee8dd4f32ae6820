"""No command deletes what it did not write: an output folder is new, empty, or holds only what
that command writes (:func:`simtest._io.check_output_folder`), checked before any work.

Before this check, ``crb -o DIR`` left DIR with crb.json and crb.png only (a user's a.txt and
sub/b.txt gone), ``validate``/``nightly --run-id R`` replaced OUT/<suite>/R whatever it held, and
``view -o thesis.tex`` wrote PNG bytes over the text. Each refusal here happens before any fit or
render, so the tests are quick.
"""

from __future__ import annotations

from pathlib import Path

import pytest
from _cases import assert_one_error_line
from typer.testing import CliRunner

from simtest._io import OutputFolderError, check_output_folder, replace_output_folder
from simtest.cli import app

runner = CliRunner()


_one_line = assert_one_error_line


def _users_folder(path: Path) -> dict:
    """A folder holding a user's files; returns their contents, to compare afterwards."""
    (path / "sub").mkdir(parents=True)
    (path / "a.txt").write_text("mine")
    (path / "sub" / "b.txt").write_text("mine too")
    return _contents(path)


def _contents(path: Path) -> dict:
    return {str(p.relative_to(path)): p.read_bytes() for p in sorted(path.rglob("*")) if p.is_file()}


@pytest.mark.parametrize("command", [
    ["crb", "-n", "2"],
    ["render", "plane_fronto"],
    ["simreal"],
])
def test_a_folder_with_a_users_files_is_refused_and_kept(tmp_path, command):
    out = tmp_path / "out"
    before = _users_folder(out)
    res = runner.invoke(app, [*command, "-o", str(out)])
    _one_line(res, 4, "--out", "a.txt", "does not write")
    assert _contents(out) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]  # nothing beside it either


@pytest.mark.parametrize("command", [["validate", "quick"], ["nightly", "--quick"]])
def test_a_run_folder_with_a_users_file_is_refused_and_kept(tmp_path, command):
    run = tmp_path / "reports" / "quick" / "R"
    run.mkdir(parents=True)
    (run / "results.json").write_text("{}")  # a previous run's: that alone would be replaced
    (run / "thesis.tex").write_text("\\chapter{mine}")
    (run / "figures").mkdir()
    (run / "figures" / "mine.pdf").write_text("mine")
    before = _contents(run)
    res = runner.invoke(app, [*command, "-o", str(tmp_path / "reports"), "--run-id", "R"])
    _one_line(res, 4, "--out", "does not write", "figures/mine.pdf", "thesis.tex")
    assert _contents(run) == before


@pytest.mark.parametrize("command", [["crb"], ["render", "plane_fronto"], ["simreal"]])
def test_a_file_given_where_a_folder_is_expected_is_refused(tmp_path, command):
    f = tmp_path / "notes.txt"
    f.write_text("mine")
    res = runner.invoke(app, [*command, "-o", str(f)])
    _one_line(res, 4, "--out", "is a file")
    assert f.read_text() == "mine"


def test_view_never_overwrites_a_file_that_is_not_a_png(tmp_path):
    est = tmp_path / "estimates.json"
    est.write_text("{}")
    notes = tmp_path / "notes.txt"
    notes.write_text("mine")
    res = runner.invoke(app, ["view", str(est), "-o", str(notes)])
    _one_line(res, 2, "--out", "notes.txt", ".png")
    assert notes.read_text() == "mine"
    fake = tmp_path / "figure.png"  # a user's text under a .png name: not an image we wrote
    fake.write_text("mine")
    res = runner.invoke(app, ["view", str(est), "-o", str(fake)])
    _one_line(res, 4, "--out", "not a PNG image")
    assert fake.read_text() == "mine"


def test_owned_patterns_reach_into_sub_folders(tmp_path):
    owned = ("results.json", "figures/*.png")
    (tmp_path / "figures").mkdir()
    (tmp_path / "figures" / "a.png").write_bytes(b"")
    (tmp_path / "results.json").write_text("{}")
    assert check_output_folder(tmp_path, owned) == tmp_path
    (tmp_path / "figures" / "deeper").mkdir()
    with pytest.raises(OutputFolderError, match="figures/deeper"):
        check_output_folder(tmp_path, owned)
    (tmp_path / "figures" / "deeper").rmdir()
    (tmp_path / "results.json").unlink()
    (tmp_path / "results.json").mkdir()  # a folder under a file's name is not ours
    with pytest.raises(OutputFolderError, match="results.json"):
        check_output_folder(tmp_path, owned)


def test_a_file_put_there_during_the_run_is_kept(tmp_path):
    """Checked again under the folder's lock just before the swap: a file saved into the folder
    while a long run filled its temporary one is not swapped away."""
    out = tmp_path / "out"
    out.mkdir()
    (out / "crb.json").write_text("old")

    def fill(tmp: Path) -> None:
        (tmp / "crb.json").write_text("new")
        (out / "notes.txt").write_text("saved meanwhile")

    with pytest.raises(OutputFolderError, match="notes.txt"):
        replace_output_folder(out, fill, owned=("crb.json", "crb.png"))
    assert _contents(out) == {"crb.json": b"old", "notes.txt": b"saved meanwhile"}
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]  # the temporary folder removed
