"""One style across every subcommand of `simtest` (issue 37): workers are ``-j/--workers``, the
output is ``-o/--out``, ``--help`` answers, and a command's help names every file it writes.

Every subcommand is walked (:data:`simtest.cli.SUBCOMMANDS`, loaded with
:func:`simtest.cli.load_subcommand`, and the subcommands of each group); each test collects all
offenders and reports them in one assertion message, so one run lists everything to fix.
"""

from __future__ import annotations

import re

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
    "reconstruct": ("estimates.json", "overlay.png", "view.png", "estimates.jsonl"),
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
