"""validate, nightly and crb: what can be checked before the work is checked before it.

An unusable --out (a file, a path under a file, a read-only folder) exits 4 with one line before
the suite runs, and leaves what was there; --run-id must be one plain name (exit 2); runaway
sizes (a suite file's or -n's realisations, crb's -n) and more workers than CPUs are refused
before anything is allocated (exit 2); one count of cases and realisations in the header, the
progress bar and the report; the console shows the report's statistic (medians).
"""

from __future__ import annotations

import errno
import json
import tempfile

import pytest
from typer.testing import CliRunner

import simtest.harness.cli as hcli
from simtest.cli import app
from simtest.harness.suite import MAX_TOTAL_REALISATIONS, SuiteError, load_suite

SHARED = """
[suite]
name = "shared"
realisations = 2
seed = 3
[base]
joint_isovalues = [0.1, 0.3, 0.5]
[[sweep]]
name = "a"
parameter = "sigma"
values = [0.0, 0.05]
[[sweep]]
name = "b"
parameter = "theta_deg"
values = [58.0, 20.0]
"""


def _invoke(*args):
    return CliRunner().invoke(app, [*map(str, args)])


def _one_error(r) -> str:
    lines = [ln for ln in r.output.splitlines() if ln.startswith("error:")]
    assert len(lines) == 1 and "Traceback" not in r.output, r.output
    return lines[0]


@pytest.fixture
def no_run(monkeypatch):
    def boom(*a, **k):
        raise AssertionError("the suite ran although the command had to stop before it")
    monkeypatch.setattr(hcli, "run_suite", boom)


@pytest.fixture
def earlier(tmp_path):
    """A report folder written before; it must survive every refusal."""
    old = tmp_path / "reports" / "quick" / "old"
    old.mkdir(parents=True)
    (old / "results.json").write_text("{}")
    return old


@pytest.mark.parametrize("cmd", [["validate", "quick"], ["nightly", "--quick"]])
@pytest.mark.parametrize("where", ["file", "under a file", "read-only"])
def test_an_unusable_out_exits_4_before_the_run(tmp_path, monkeypatch, no_run, earlier, cmd,
                                                where):
    target = {"file": tmp_path / "f", "under a file": tmp_path / "f" / "sub",
              "read-only": tmp_path / "reports"}[where]
    (tmp_path / "f").write_text("a file")
    if where == "read-only":  # the tests run as root, where chmod does not stop a write
        def ro(*a, **k):
            raise OSError(errno.EROFS, "Read-only file system")
        monkeypatch.setattr(tempfile, "mkstemp", ro)
    r = _invoke(*cmd, "-o", target, "-j", "1", "--no-progress")
    assert r.exit_code == 4, r.output
    line = _one_error(r)
    assert "--out" in line and ("is a file" in line or "read-only" in line), line
    assert (earlier / "results.json").read_text() == "{}"


@pytest.mark.parametrize("cmd", [["validate", "quick"], ["nightly", "--quick"]])
@pytest.mark.parametrize("rid", ["../..", "a/b", ".hidden", "-x"])
def test_a_run_id_that_leaves_out_is_refused(tmp_path, no_run, cmd, rid):
    r = _invoke(*cmd, "-o", tmp_path / "r", "--run-id", rid, "-j", "1", "--no-progress")
    assert r.exit_code == 2, r.output
    assert "--run-id" in _one_error(r)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("cmd", [["validate", "quick"], ["nightly", "--quick"]])
def test_more_workers_than_cpus_is_refused(tmp_path, monkeypatch, no_run, cmd):
    monkeypatch.setattr(hcli.os, "cpu_count", lambda: 2)
    r = _invoke(*cmd, "-o", tmp_path, "-j", "3", "--no-progress")
    assert r.exit_code == 2, r.output
    assert "-j/--workers: 3 workers on a machine with 2 CPUs" in _one_error(r)


@pytest.mark.parametrize("cmd", [["validate", "quick"], ["nightly", "--quick"]])
def test_workers_are_j_and_out_is_o(tmp_path, no_run, cmd):
    assert _invoke(*cmd, "-w", "1").exit_code == 2  # -w is gone: -j/--workers everywhere
    help_text = _invoke(cmd[0], "--help").output
    assert "-j" in help_text and "-o" in help_text


def test_runaway_realisations_are_refused_before_allocating(tmp_path, no_run):
    big = 10 ** 11
    p = tmp_path / "s.toml"
    p.write_text(SHARED.replace("realisations = 2", f"realisations = {big}"))
    with pytest.raises(SuiteError, match=r"suite\.realisations: 100,000,000,000 realisations "
                                         r"exceed the maximum of 1,000,000"):
        load_suite(p)
    # many settings each under the bound, over it together
    per = MAX_TOTAL_REALISATIONS // 3 + 1
    p.write_text(SHARED.replace("realisations = 2", f"realisations = {per}"))
    with pytest.raises(SuiteError, match=r"realisations: 1,000,002 realisations over 3 distinct"):
        load_suite(p)
    r = _invoke("validate", p, "-o", tmp_path / "r", "--no-progress")
    assert r.exit_code == 2 and "exceed the maximum" in _one_error(r)
    r = _invoke("validate", "quick", "-n", big, "-o", tmp_path / "r", "--no-progress")
    assert r.exit_code == 2, r.output
    assert "-n/--realisations: 100,000,000,000 per case" in _one_error(r)
    assert not (tmp_path / "r").exists()


def test_crb_bounds_out_and_default(tmp_path, monkeypatch):
    r = _invoke("crb", "-n", 10 ** 9, "-o", tmp_path / "c")
    assert r.exit_code == 2 and "-n/--realisations" in _one_error(r)
    (tmp_path / "f").write_text("x")
    r = _invoke("crb", "-o", tmp_path / "f")
    assert r.exit_code == 4 and "is a file" in _one_error(r)
    import simtest.harness.crb as crb

    rows = crb.crb_study(eps_over_d=(0.2,), sigmas=(0.005,), realisations=2)
    monkeypatch.setattr(crb, "crb_study", lambda **k: rows)
    monkeypatch.chdir(tmp_path)
    old = tmp_path / "reports" / "crb"
    old.mkdir(parents=True)
    (old / "notes.txt").write_text("mine")
    # a file crb does not write is a user's: the folder is refused before any fit, not replaced
    r = _invoke("crb", "-n", 2)
    assert r.exit_code == 4 and "notes.txt" in _one_error(r)
    assert (old / "notes.txt").read_text() == "mine"
    (old / "notes.txt").unlink()
    (old / "crb.json").write_text("{}")  # a previous run's
    r = _invoke("crb", "-n", 2)
    assert r.exit_code == 0, r.output
    # the default is reports/crb under the current folder, replaced as a set
    assert sorted(p.name for p in old.iterdir()) == ["crb.json", "crb.png"]
    assert json.loads((old / "crb.json").read_text())["realisations"] == 2


def test_help_lists_every_file_written():
    for cmd, files in {"validate": ["results.json", "results.csv", "report.md", "report.html",
                                    "figures/*.png"],
                       "nightly": ["results.json", "results.csv", "report.md", "report.html",
                                   "figures/*.png", "history.jsonl", "baseline"],
                       "crb": ["crb.json", "crb.png"]}.items():
        out = " ".join(_invoke(cmd, "--help").output.split())
        for f in files:
            assert f in out, (cmd, f)
    out = " ".join(_invoke("nightly", "--help").output.split())
    for code in ("1 a regression", "2 bad usage", "3 the baseline", "4 OUT"):
        assert code in out, code


def test_one_count_in_header_progress_bar_and_report(tmp_path, monkeypatch):
    """Two sweeps share the setting sigma 0.05 / theta 58 (the defaults): 4 cases, 3 distinct
    settings run, 6 realisations (not 8)."""
    p = tmp_path / "s.toml"
    p.write_text(SHARED)
    s = load_suite(p)
    assert len(s.cases) == 4 and len(s.distinct_cases) == 3
    total = s.total_realisations
    assert total == 6
    import simtest.harness.runner as runner

    bars = []

    class Recorded(runner.Progress):
        def add_task(self, description, total=None, **kw):
            bars.append((description, total))
            return super().add_task(description, total=total, **kw)

    monkeypatch.setattr(runner, "Progress", Recorded)
    r = _invoke("validate", p, "-o", tmp_path / "r", "--run-id", "x", "-j", "1")
    assert r.exit_code == 0, r.output
    assert bars == [("shared: 3 distinct settings, 1 worker(s), realisations", total)]
    out = " ".join(r.output.split())
    assert f"4 cases = 3 distinct settings (1 shared by several sweeps run once), {total} " \
           "realisations" in out
    md = " ".join((tmp_path / "r" / "shared" / "x" / "report.md").read_text().split())
    assert f"4 cases = 3 distinct settings" in md and f"{total} realisations" in md
    res = json.loads((tmp_path / "r" / "shared" / "x" / "results.json").read_text())
    assert sum(v["realisations"] for v in res["provenance"]["realisations_per_s"].values()) \
        == total
    # the console's table shows the report's statistic: medians, labelled
    assert "median error (deg) per setting" in out
    med = res["cases"][0]["metrics"]["estimators"]["bp_ray"]["median"]
    assert hcli._fmt(med) in out
