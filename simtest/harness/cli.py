"""``simtest validate`` and ``simtest nightly`` (registered in :mod:`simtest.cli`).

Imported by :mod:`simtest.cli` only when one of these commands runs (``simtest --help`` stays fast).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Optional

import typer
from rich.console import Console
from rich.table import Table

from simtest.harness.nightly import (
    append_history,
    changes_table,
    check_section,
    compare,
    default_baseline_path,
    gate_summary,
    history_line,
    load_baseline,
    read_history,
    undetectable_doublings,
    update_baseline as write_baseline,
)
from simtest.harness.report import build_results, make_run_id, write_report, write_report_files
from simtest.harness.runner import run_suite
from simtest.harness.suite import SuiteError, load_suite

__all__ = ["validate_command", "nightly_command"]


def _fail(msg: str, code: int = 2):
    typer.echo(f"error: {msg}", err=True)
    raise typer.Exit(code)


def _fmt(deg: float) -> str:
    """Two significant digits, without exponents for errors of 10 deg and more."""
    return f"{deg:.0f}" if deg >= 10 else f"{deg:.2g}"


def _summary(results: dict, console) -> None:
    ests = results["suite"]["estimators"]
    t = Table(title=f"{results['suite']['name']}: mean error (deg), min-max over the sweep; "
                    "failure rate")
    # fold, never truncate: a number cut to "0.00099..." would be worse than none
    t.add_column("sweep", overflow="fold")
    for e in ests:
        t.add_column(e, justify="right", overflow="fold")
    cases = {c["id"]: c for c in results["cases"]}
    for sw in results["sweeps"]:
        row = [sw["name"]]
        for e in ests:
            ms = [cases[k]["metrics"]["estimators"][e] for k in sw["cases"]]
            means = [m["mean"] for m in ms if m["mean"] is not None]
            fr = max(m["failure_rate"] for m in ms)
            cell = "-" if not means else (f"{_fmt(min(means))} to {_fmt(max(means))}"
                                          if len(means) > 1 else _fmt(means[0]))
            row.append(cell + (f" [red]({fr:.0%})[/]" if fr > 0 else ""))
        t.add_row(*row)
    console.print(t)


def validate_command(
    suite: str = typer.Argument("default", help="Bundled suite name (scenes/suites/<name>.toml) "
                                                "or a path to a suite TOML file."),
    workers: Optional[int] = typer.Option(None, "--workers", "-w", min=1,
                                          help="Worker processes (default: all cores; 1: in "
                                               "process)."),
    seed: Optional[int] = typer.Option(None, "--seed", min=0, help="Root seed (default: the "
                                                                   "suite's)."),
    out: Path = typer.Option(Path("reports"), "--out", help="Reports root folder."),
    realisations: Optional[int] = typer.Option(None, "--realisations", "-n", min=1,
                                               help="Realisations per case (default: the "
                                                    "suite's)."),
    run_id: Optional[str] = typer.Option(None, "--run-id", help="Run folder name (default: "
                                                                "<UTC time>-local, git-ignored)."),
    progress: bool = typer.Option(True, "--progress/--no-progress", help="Show progress."),
) -> None:
    """Run a validation suite and write its report (results.json, report.md, report.html).

    With no argument: the bundled `default` suite (rendered bundled scenes and a small part of
    the paper's synthetic protocol). The report's provenance records the run's wall time.
    """

    console = Console(stderr=True)
    try:
        s = load_suite(suite)
        if seed is not None or realisations is not None:
            s = s.with_overrides(seed=seed, realisations=realisations)
    except SuiteError as e:
        _fail(str(e))
    console.print(f"[bold]simtest validate[/] {s.name}: {len(s.sweeps)} sweeps, {len(s.cases)} "
                  f"cases, {s.total_realisations} realisations, seed {s.seed}")
    run = run_suite(s, workers=workers, progress=progress, console=console)
    folder = write_report(run, out, run_id=run_id)

    results = json.loads((folder / "results.json").read_text())
    _summary(results, console)
    for k, v in results["provenance"]["realisations_per_s"].items():
        console.print(f"{k}: {v['realisations']} realisations, {v['per_s']} realisations/s "
                      f"with {run.workers} worker(s)")
    console.print(f"wall time {run.wall_s:.1f} s; report: {folder / 'report.html'}")


def nightly_command(
    quick: bool = typer.Option(False, "--quick", help="Run the quick suite (seconds) instead "
                                                      "of the nightly one."),
    update_baseline: bool = typer.Option(False, "--update-baseline",
                                         help="Accept this code as the new baseline: run the "
                                              "suite --repeats times with seeds seed, seed + 1, "
                                              "... and store values, spreads and tolerances."),
    repeats: int = typer.Option(4, "--repeats", min=1, help="Seed-varied runs that measure the "
                                                            "spread (with --update-baseline)."),
    seed: Optional[int] = typer.Option(None, "--seed", min=0, help="Root seed of this run "
                                                                   "(default: the suite's)."),
    baseline: Optional[Path] = typer.Option(None, "--baseline", help="Baseline file (default: "
                                                                     "reports/baseline.json)."),
    history: Optional[Path] = typer.Option(None, "--history", help="History file, one JSON "
                                                                   "line per run (default: "
                                                                   "<out>/<suite>/history.jsonl)."),
    workers: Optional[int] = typer.Option(None, "--workers", "-w", min=1),
    out: Path = typer.Option(Path("reports"), "--out", help="Reports root folder."),
    run_id: Optional[str] = typer.Option(None, "--run-id", help="Run folder name (default: "
                                                                "<UTC time>-local)."),
    suite: Optional[str] = typer.Option(None, "--suite", help="Another suite (name or path)."),
    show_all: bool = typer.Option(False, "--all", help="List unchanged metrics too."),
    progress: bool = typer.Option(True, "--progress/--no-progress"),
) -> None:
    """Run the nightly (or --quick) suite and gate it against the committed baseline.

    Exits 1 when a metric regressed beyond its tolerance (measured seed spread plus a relative
    floor) or is NaN, infinite, non-numeric or missing, naming each; 2 on a bad baseline file.
    """

    console = Console(stderr=True)
    name = suite or ("quick" if quick else "nightly")
    path = baseline or default_baseline_path()
    try:
        s = load_suite(name)
        if seed is not None:
            s = s.with_overrides(seed=seed)
    except SuiteError as e:
        _fail(str(e))
    section = None
    if not update_baseline:
        try:
            section = load_baseline(path)["suites"].get(s.name)
        except ValueError as e:
            _fail(str(e))
        if section is None:
            _fail(f"{path}: suites.{s.name}: no baseline for this suite; create it with "
                  f"`simtest nightly{' --quick' if quick else ''} --update-baseline`")
        bad = check_section(section, f"{path}: suites.{s.name}")
        if bad:
            _fail(bad)
    run_id = run_id or make_run_id()
    folder = out / s.name / run_id
    run = run_suite(s, workers=workers, progress=progress, console=console)
    results = build_results(run, run_id)
    if update_baseline:
        runs = [results]
        for k in range(1, repeats):
            sk = s.with_overrides(seed=s.seed + k)
            console.print(f"repeat {k + 1} of {repeats}: seed {sk.seed}")
            runs.append(build_results(run_suite(sk, workers=workers, progress=progress,
                                                console=console), f"{run_id}-seed{sk.seed}"))
        try:
            write_baseline(path, runs)
        except ValueError as e:
            _fail(str(e))
        sec = load_baseline(path)["suites"][s.name]
        weak = undetectable_doublings(sec)
        write_report_files(results, folder)
        console.print(f"report: {folder / 'report.html'}")
        console.print(f"baseline for suite {s.name} written to {path} ({len(sec['metrics'])} "
                      f"metrics from seeds {sec['seeds']}; {len(weak)} could double unnoticed: "
                      "too noisy at this many realisations)")
        return
    if section.get("suite_sha256") and section["suite_sha256"] != results["suite"]["sha256"]:
        console.print(f"[yellow]note: suite file {s.source} changed since the baseline[/]")
    changes = compare(section, results)
    passed, lines, counts = gate_summary(changes)
    hist_path = history or (out / s.name / "history.jsonl")
    append_history(hist_path, history_line(results, passed, counts))
    summary = ", ".join(f"{v}: {n}" for v, n in sorted(counts.items()))
    write_report_files(results, folder, history=read_history(hist_path),
                       nightly={"verdict": "pass" if passed else "FAIL",
                                "baseline": str(path), "summary": summary, "problems": lines})
    console.print(changes_table(changes, f"{s.name} vs baseline {path.name}", show_all))
    console.print(summary)
    console.print(f"report: {folder / 'report.html'}; history: {hist_path}")
    if not passed:
        for ln in lines:
            typer.echo(ln, err=True)
        raise typer.Exit(1)
    console.print("[green]no regression[/]")
