"""One style across every subcommand of `simtest` (issue 37): workers are ``-j/--workers``, the
output is ``-o/--out``, ``--help`` answers, and a command's help names every file it writes.

Every subcommand is walked (:data:`simtest.cli.SUBCOMMANDS`, loaded with
:func:`simtest.cli.load_subcommand`, and the subcommands of each group); each test collects all
offenders and reports them in one assertion message, so one run lists everything to fix.
"""

from __future__ import annotations

import re

import pytest

import typer
from typer.testing import CliRunner

from simtest.cli import SUBCOMMANDS, app, load_subcommand

runner = CliRunner()

#: command path -> the files its help must name (what the command writes; a folder as "name/").
#: Commands that write no file (verify, params, bench, version) are listed with none.
WRITES: dict[str, tuple[str, ...]] = {
    "validate": ("results.json", "results.csv", "report.md", "report.html", "figures/"),
    "nightly": ("results.json", "results.csv", "report.md", "report.html", "history.jsonl"),
    "crb": ("crb.json", "crb.png"),
    "reconstruct": ("estimates.json", "overlay.png", "view.png", "estimates.parquet", "estimates.jsonl"),
    "view": (),  # one PNG, the file --out names
    "render": ("image.png", "frame.png", "intrinsics.json", "camera.json", "ground_truth.npz",
               "highlights.json"),
    "simreal": ("simreal.json", "simreal.md", "simreal.png"),
    "meshes build": ("colon.ply", "colon.json", "liver.ply", "liver.json"),
    "dataset generate": ("dataset.json", "manifest.jsonl", "shards/"),
    "dataset verify": (),
    "dataset export": ("export.json",),
    "dataset show": ("contact_sheet.png",),
    "dataset params": (),
    "evaluate c3vd": ("results.json", "report.html", "view_NNNN.png"),
    "evaluate detection": ("results.json", "report.md", "detection.png", "reliability.png"),
    "bench": (),
    "version": (),
}


# Typer 0.29 vendors its own Click (typer._click) and no longer installs Click: commands and
# options are recognised by what they have, not by class.


def _is_group(cmd) -> bool:
    return isinstance(getattr(cmd, "commands", None), dict)


def _commands() -> tuple[dict[str, object], list[str]]:
    """Every leaf command by its path ("dataset generate"), and the subcommands that fail to load."""
    found: dict[str, object] = {}
    broken: list[str] = []

    def walk(path: str, cmd) -> None:
        if _is_group(cmd):
            for name, sub in cmd.commands.items():
                walk(f"{path} {name}", sub)
        else:
            found[path] = cmd

    for name in SUBCOMMANDS:
        try:
            walk(name, load_subcommand(name))
        except Exception as exc:  # reported as an offender, not a crash of the walk
            broken.append(f"{name}: cannot be loaded ({type(exc).__name__}: {exc})")
    for name, cmd in typer.main.get_command(app).commands.items():
        if name not in SUBCOMMANDS:  # registered on the app itself (version)
            walk(name, cmd)
    return found, broken


def _options(cmd) -> list:
    return [p for p in cmd.params if getattr(p, "param_type_name", "") == "option"]


def _spellings(opt) -> set[str]:
    return set(opt.opts) | set(opt.secondary_opts)


def test_every_subcommand_is_walked():
    found, broken = _commands()
    missing = sorted(set(WRITES) - set(found))
    unknown = sorted(set(found) - set(WRITES))
    assert not (missing or unknown or broken), (
        f"not found: {missing}; not in WRITES (add what it writes): {unknown}; broken: {broken}")


def test_workers_are_j_workers_and_outputs_o_out():
    found, broken = _commands()
    offenders = list(broken)
    for path, cmd in sorted(found.items()):
        for opt in _options(cmd):
            names = _spellings(opt)
            if opt.name == "workers" or names & {"--workers", "-w", "-j"}:
                if names != {"-j", "--workers"}:
                    offenders.append(f"{path}: workers option spelled {sorted(names)}, not -j/--workers")
            if opt.name == "out" or names & {"--out", "-o", "--output"}:
                if names != {"-o", "--out"}:
                    offenders.append(f"{path}: output option spelled {sorted(names)}, not -o/--out")
    assert not offenders, "\n".join(offenders)


def test_help_works_and_names_every_file_written():
    found, broken = _commands()
    offenders = list(broken)
    for path, _cmd in sorted(found.items()):
        res = runner.invoke(app, [*path.split(), "--help"], terminal_width=250,
                            env={"COLUMNS": "250", "TERM": "dumb", "NO_COLOR": "1"})
        if res.exit_code != 0:
            offenders.append(f"{path} --help: exit {res.exit_code}: {res.output[-200:]!r}")
            continue
        text = " ".join(re.sub(r"[│╭╮╰╯─]", " ", res.output).split())
        missing = [f for f in WRITES.get(path, ()) if f not in text]
        if missing:
            offenders.append(f"{path} --help does not name {', '.join(missing)} (it writes them)")
    assert not offenders, "\n".join(offenders)


# ---- issue 61: one line per usage error, results on stdout, readable at 80 columns -------------

try:  # Click before 8.2 mixes stderr into stdout unless told not to
    split_runner = CliRunner(mix_stderr=False)
except TypeError:  # Click 8.2 and later (and Typer's own copy) always keep them apart
    split_runner = CliRunner()


def _usage_error(args: list[str], env: dict | None = None) -> str:
    """'' when ``args`` exit 2 with exactly one stderr line ``error: ...`` and nothing on stdout,
    else what is wrong."""
    res = split_runner.invoke(app, args, env=env)
    lines = res.stderr.splitlines()
    if res.exit_code == 2 and len(lines) == 1 and lines[0].startswith("error: ") and not res.stdout:
        return ""
    return f"{' '.join(args)}: exit {res.exit_code}, stderr {res.stderr!r}, stdout {res.stdout[:200]!r}"


def _has_required(cmd) -> bool:
    return any(getattr(p, "required", False) for p in cmd.params)


def test_every_usage_error_is_one_error_line_and_exit_2():
    """An unknown flag, a missing required option or argument, a bad -j: one line, exit 2 (was
    Click's usage line, a hint and a rich box: 5 to 6 lines)."""
    found, broken = _commands()
    offenders = list(broken)
    for path, cmd in sorted(found.items()):
        cases = [[*path.split(), "--no-such-flag"]]
        if _has_required(cmd):
            cases.append(path.split())
        if any("-j" in _spellings(o) for o in _options(cmd)):
            cases += [[*path.split(), "-j", "-1"], [*path.split(), "-j", "many"]]
        offenders += [why for args in cases if (why := _usage_error(args))]
    for args in (["no-such-command"], ["dataset", "no-such-command"], ["evaluate", "nope"]):
        offenders += [why for why in [_usage_error(args)] if why]
    assert not offenders, "\n".join(offenders)


def test_a_usage_error_names_the_command_and_its_help():
    res = split_runner.invoke(app, ["reconstruct", "image.png"])
    assert res.exit_code == 2
    assert res.stderr == ("error: simtest reconstruct: Missing option '--intrinsics' / '-k'; "
                          "see simtest reconstruct --help\n")


def test_a_usage_error_is_one_line_in_a_real_process():
    """The console script's path (``simtest.cli.main``), not only the test runner's."""
    import subprocess
    import sys

    res = subprocess.run([sys.executable, "-m", "simtest.cli", "validate", "--bogus"],
                         capture_output=True, text=True, timeout=120,
                         env={**__import__("os").environ, "COLUMNS": "80"})
    assert res.returncode == 2 and res.stdout == ""
    assert res.stderr.startswith("error: simtest validate: No such option: --bogus")
    assert len(res.stderr.splitlines()) == 1, res.stderr


def test_off_a_terminal_stdout_holds_only_results(tmp_path):
    """The transient bars of reconstruct, evaluate and meshes draw on stderr and not at all off a
    terminal: a piped `simtest reconstruct` printed a blank line before its summary, a failed
    `simtest evaluate detection` one before its error line."""
    from pathlib import Path

    data = Path(__file__).parent / "data" / "real"
    res = split_runner.invoke(app, ["reconstruct", str(data / "hyperkvasir_tile_r1c7_mucosa.png"), "-k",
                                    str(data / "intrinsics_assumed_f140.json"), "-o", str(tmp_path / "r")])
    assert res.exit_code == 0, res.stderr
    assert res.stdout.splitlines()[0].split()[1] == "candidate(s),", res.stdout
    assert res.stderr == ""
    res = split_runner.invoke(app, ["evaluate", "detection", str(tmp_path / "nope.json"), "-o", str(tmp_path / "e")])
    assert res.exit_code == 2 and res.stdout == "" and res.stderr.startswith("error: "), (res.stdout, res.stderr)
    assert len(res.stderr.splitlines()) == 1


@pytest.mark.parametrize("args, words", [
    (["validate", "no_such_suite", "-j", "0"], "no_such_suite"),
    (["nightly", "--suite", "no_such_suite", "-j", "0"], "no_such_suite"),
    (["dataset", "generate", "no_such_config.toml", "-o", "ds", "-j", "0"], "no_such_config"),
])
def test_j_0_means_one_per_core_everywhere(args, words, tmp_path, monkeypatch):
    """-j 0 is accepted by every command with -j (one worker per core), as reconstruct's always
    was: the command goes on to its next check (the suite or config named here does not exist)."""
    monkeypatch.chdir(tmp_path)
    res = split_runner.invoke(app, args)
    assert res.exit_code == 2 and words in res.stderr and "workers" not in res.stderr, res.stderr


def test_validate_prints_its_table_on_stdout_readable_at_80_columns(tmp_path, monkeypatch):
    """`validate > log.txt` keeps the table (it went to stderr), and at 80 columns no estimator's
    name is broken across lines (it read 'paper_or / acle')."""
    from types import SimpleNamespace

    import simtest.harness.cli as hcli

    ests = ["paper_oracle", "paper_selected", "cone_axis", "joint_cone_axis", "bp_ray", "recommended"]
    med = {e: {"median": 0.0011, "failure_rate": 0.0} for e in ests}
    results = {"suite": {"name": "quick", "estimators": ests},
               "cases": [{"id": f"c{k}@{v}", "metrics": {"estimators": med}}
                         for k in range(3) for v in (1, 2)],
               "sweeps": [{"name": f"rendered_plane_{k}", "cases": [f"c{k}@1", f"c{k}@2"]}
                          for k in range(3)],
               "provenance": {"realisations_per_s": {"paper": {"realisations": 6, "per_s": 2.0}}}}
    monkeypatch.setattr(hcli, "run_suite", lambda *a, **k: SimpleNamespace(workers=1, wall_s=1.0))
    monkeypatch.setattr(hcli, "build_results", lambda run, run_id: results)
    monkeypatch.setattr(hcli, "write_report_files", lambda res, folder, **kw: folder)
    res = split_runner.invoke(app, ["validate", "quick", "-j", "1", "--no-progress",
                                    "-o", str(tmp_path)], env={"COLUMNS": "80"})
    assert res.exit_code == 0, res.stderr
    table = [ln for ln in res.stdout.splitlines() if ln[:1] in "┏┃┡│├└"]
    assert table and all(len(ln) <= 80 for ln in table), res.stdout
    assert all(e in res.stdout for e in ests), res.stdout
    assert "wall time" in res.stdout and "report:" in res.stdout
    assert not any(e in res.stderr for e in ests), res.stderr  # progress only there


def test_help_at_80_columns_wraps_sentences_and_shows_no_typer_placeholders():
    """Click's plain help: paragraphs rewrapped to 80 columns (Typer's panels kept the
    docstring's breaks and squeezed each option's help into a narrow column), flags without a
    ``<bool>`` metavar, usage lines naming IMAGE, not ``{image}``."""
    found, broken = _commands()
    offenders = list(broken)
    for path in ("reconstruct", "validate", "dataset generate", "simreal"):
        res = split_runner.invoke(app, [*path.split(), "--help"], env={"COLUMNS": "80"},
                                  terminal_width=80)
        text = res.stdout
        if res.exit_code != 0:
            offenders.append(f"{path} --help: exit {res.exit_code}")
        if "<bool>" in text or "{" in text.splitlines()[0] or "[[" in text.splitlines()[0]:
            offenders.append(f"{path} --help: Typer placeholders: {text.splitlines()[0]!r}")
        if re.search(r"[│╭╮╰╯]", text) or any(len(ln) > 80 for ln in text.splitlines()):
            offenders.append(f"{path} --help: wider than 80 columns or boxed")
    res = split_runner.invoke(app, ["reconstruct", "--help"], env={"COLUMNS": "80"}, terminal_width=80)
    assert "Usage: simtest reconstruct [OPTIONS] IMAGE" in res.stdout
    assert not offenders, "\n".join(offenders)
