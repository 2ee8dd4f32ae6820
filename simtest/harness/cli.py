"""``simtest validate`` and ``simtest nightly`` (registered in :mod:`simtest.cli`).

Cheap to import: typer only; the harness is imported when a command runs.
"""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

__all__ = ["validate_command", "nightly_command"]


def _fail(msg: str, code: int = 2):
    typer.echo(f"error: {msg}", err=True)
    raise typer.Exit(code)


def _fmt(deg: float) -> str:
    """Two significant digits, without exponents for errors of 10 deg and more."""
    return f"{deg:.0f}" if deg >= 10 else f"{deg:.2g}"


def _summary(results: dict, console) -> None:
    from rich.table import Table

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
    the paper's synthetic protocol), a few minutes on 2 cores.
    """
    from rich.console import Console

    from simtest.harness.report import write_report
    from simtest.harness.runner import run_suite
    from simtest.harness.suite import SuiteError, load_suite

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
    import json

    results = json.loads((folder / "results.json").read_text())
    _summary(results, console)
    for k, v in results["provenance"]["realisations_per_s"].items():
        console.print(f"{k}: {v['realisations']} realisations, {v['per_s']} realisations/s "
                      f"with {run.workers} worker(s)")
    console.print(f"wall time {run.wall_s:.1f} s; report: {folder / 'report.html'}")


def nightly_command(
    quick: bool = typer.Option(False, "--quick", help="Run the quick suite (< 2 minutes) instead "
                                                      "of the nightly one."),
    update_baseline: bool = typer.Option(False, "--update-baseline",
                                         help="Accept this run as the new baseline."),
    baseline: Optional[Path] = typer.Option(None, "--baseline", help="Baseline file (default: "
                                                                     "reports/baseline.json)."),
    workers: Optional[int] = typer.Option(None, "--workers", "-w", min=1),
    out: Path = typer.Option(Path("reports"), "--out", help="Reports root folder."),
    suite: Optional[str] = typer.Option(None, "--suite", help="Another suite (name or path)."),
    show_all: bool = typer.Option(False, "--all", help="List unchanged metrics too."),
    progress: bool = typer.Option(True, "--progress/--no-progress"),
) -> None:
    """Run the nightly (or --quick) suite and compare it with the committed baseline.

    Exits 1 on a regression, naming each metric that got worse beyond its tolerance.
    """
    import json

    from rich.console import Console

    from simtest.harness.nightly import (changes_table, compare, default_baseline_path,
                                         load_baseline, tolerances_for)
    from simtest.harness.nightly import update_baseline as write_baseline
    from simtest.harness.report import write_report
    from simtest.harness.runner import run_suite
    from simtest.harness.suite import SuiteError, load_suite

    console = Console(stderr=True)
    name = suite or ("quick" if quick else "nightly")
    path = baseline or default_baseline_path()
    try:
        s = load_suite(name)
        tol = tolerances_for(s.raw)
    except (SuiteError, ValueError) as e:
        _fail(str(e))
    base = None
    if not update_baseline:
        try:
            base = load_baseline(path)["suites"].get(s.name)
        except ValueError as e:
            _fail(str(e))
        if base is None:
            _fail(f"{path}: suites.{s.name}: no baseline for this suite; create it with "
                  f"`simtest nightly{' --quick' if quick else ''} --update-baseline`")
    run = run_suite(s, workers=workers, progress=progress, console=console)
    folder = write_report(run, out, run_id=None)
    results = json.loads((folder / "results.json").read_text())
    console.print(f"report: {folder / 'report.html'}")
    if update_baseline:
        write_baseline(path, results, tol)
        console.print(f"baseline for suite {s.name} written to {path}")
        return
    if base.get("suite_sha256") and base["suite_sha256"] != results["suite"]["sha256"]:
        console.print(f"[yellow]note: suite file {s.source} changed since the baseline[/]")
    changes = compare(base, results, tol)
    console.print(changes_table(changes, f"{s.name} vs baseline {path.name}", show_all))
    counts = {}
    for c in changes:
        counts[c.verdict] = counts.get(c.verdict, 0) + 1
    console.print(", ".join(f"{v}: {n}" for v, n in sorted(counts.items())))
    bad = [c for c in changes if c.verdict in ("regression", "missing")]
    if bad:
        for c in bad:
            if c.verdict == "missing":
                typer.echo(f"REGRESSION: {c.name}: missing from this run", err=True)
            else:
                typer.echo(f"REGRESSION: {c.name}: {c.baseline} -> {c.now} (tolerance "
                           f"{c.tolerance})", err=True)
        raise typer.Exit(1)
    console.print("[green]no regression[/]")
