"""`simtest bench --against REV`: the sections of this clone and of another commit, side by side."""

import subprocess
import textwrap

import pytest
from hypothesis import given, strategies as st
from typer.testing import CliRunner

from simtest.bench import CLONE_ROOT, load_benchmarks
from simtest.cli import app

load_benchmarks()
from benchmarks import side_by_side as sbs  # noqa: E402 - the clone's benchmarks/, put on sys.path above

costs = st.floats(min_value=1e-6, max_value=1e6, allow_nan=False)


def _row(name, value, unit="ms", section="s"):
    return {"section": section, "name": name, "unit": unit, "note": "", "value": value}


@given(costs, costs, st.sampled_from(["ms", "s", "MB", "1/s"]))
def test_the_ratio_says_how_many_times_slower_this_tree_is_and_flags_past_the_bar(ours, theirs, unit):
    (row,) = sbs.paired([[_row("x", ours, unit)]], [[_row("x", theirs, unit)]])
    slower = theirs / ours if unit == "1/s" else ours / theirs  # a rate: the larger is the faster
    assert row["ratio"] == pytest.approx(slower, rel=1e-12)
    assert row["slower"] == (slower > sbs.SLOWER_BAR)


def test_rows_pair_by_name_over_the_median_of_the_runs():
    ours = [[_row("a", 1.0), _row("b", 5.0), _row("note", None)], [_row("a", 3.0), _row("b", 7.0)],
            [_row("a", 2.0), _row("b", 6.0)]]
    theirs = [[_row("a", 1.0), _row("gone", 4.0)], [_row("a", 1.0), _row("gone", 4.0)]]
    rows = {r["name"]: r for r in sbs.paired(ours, theirs)}
    assert [r["name"] for r in sbs.paired(ours, theirs)] == ["a", "b", "note", "gone"]  # this tree's order first
    assert rows["a"]["ours"] == 2.0 and rows["a"]["theirs"] == 1.0 and rows["a"]["slower"]  # medians 2 / 1
    for name in ("b", "note", "gone"):  # a row one tree lacks, or a note, has no ratio and no flag
        assert rows[name]["ratio"] is None and not rows[name]["slower"]
    assert rows["b"]["ours"] == 6.0 and rows["gone"]["ours"] is None
    # the run-to-run spread: the larger tree's largest over smallest run figure
    assert rows["a"]["spread"] == 3.0 and rows["b"]["spread"] == pytest.approx(7.0 / 5.0)
    assert rows["gone"]["spread"] == 1.0 and rows["note"]["spread"] is None


@pytest.fixture(scope="module")
def head():
    try:
        return sbs.resolve_commit("HEAD")
    except LookupError as exc:
        pytest.skip(f"not a git clone: {exc}")


def test_each_tree_runs_its_own_code_in_a_fresh_interpreter(tmp_path, head):
    # a section outside both trees names the simtest it imported: each run's is its own tree's
    (tmp_path / "where_section.py").write_text(textwrap.dedent("""
        import simtest, simtest.bench as bench
        def bench_where(repeat):
            return [bench.BenchResult("where", "simtest", float(repeat), "ms", note=simtest.__file__)]
    """))
    with sbs.tree_at(head) as other:
        shown = subprocess.run(["git", "-C", str(CLONE_ROOT), "show", f"{head}:simtest/bench.py"],
                               capture_output=True, text=True, check=True).stdout
        assert (other / "simtest" / "bench.py").read_text() == shown  # the commit's files, not the work tree's
        for tree in (CLONE_ROOT, other):
            (row,) = sbs.run_tree(tree, ["where_section:bench_where"], 3, extra_path=[str(tmp_path)])
            assert row["note"] == str(tree / "simtest" / "__init__.py") and row["value"] == 3.0
    assert not other.exists()  # the extracted tree is removed
    with pytest.raises(RuntimeError, match="no_such_module"):
        sbs.run_tree(CLONE_ROOT, ["no_such_module:bench_x"], 1)


def test_against_a_name_that_is_no_commit_is_one_line(head):
    res = CliRunner().invoke(app, ["bench", "--only", "reconstruct", "--against", "no-such-rev"])
    assert res.exit_code == 2 and res.output.count("\n") == 1, res.output
    assert "--against no-such-rev: no such commit" in res.output and "Traceback" not in res.output


def test_against_prints_both_trees_and_marks_the_rows_past_the_bar(monkeypatch, head):
    calls = []

    def fake_run(tree, sections, repeat, variant=None, extra_path=()):
        calls.append((tree == CLONE_ROOT, tuple(sections), repeat))
        ours = tree == CLONE_ROOT
        return [_row("fit", 4.0 if ours else 2.0, section="reconstruct"),
                _row("frame", 1.0 if ours else 1.2, section="reconstruct")]

    monkeypatch.setattr(sbs, "run_tree", fake_run)
    res = CliRunner().invoke(app, ["bench", "--only", "reconstruct", "--against", "HEAD", "--repeat", "3",
                                   "--rounds", "3"], env={"COLUMNS": "250"})
    assert res.exit_code == 0, res.output
    # alternated, three runs each, this tree first
    assert [c[0] for c in calls] == [True, False, False, True, True, False]
    assert all(c[1:] == (("reconstruct",), 3) for c in calls)
    lines = {ln.split("│")[2].strip(): ln for ln in res.output.splitlines() if ln.count("│") > 6}
    assert "run spread" in res.output
    assert "2.00" in lines["fit"] and "NO" in lines["fit"]  # twice as slow: past x1.5
    assert "0.83" in lines["frame"] and "yes" in lines["frame"]
    assert head[:9] in res.output
