"""``simtest validate`` and ``simtest nightly`` (imported by :mod:`simtest.cli` only when they run).

Everything that can be checked before the suite runs is checked first (suite and bounds, ``-n``,
``-j``, ``--run-id``, output folder, baseline), so that minutes of work never end in a usage
error. Exit codes are :mod:`simtest._exit`'s.
"""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Optional

import typer
from rich.console import Console
from rich.table import Table

from simtest._dask import SchedulerError
from simtest._exit import BAD_BASELINE, BAD_INPUT, CANNOT_WRITE, CHECK_FAILED, fail, safe_name, writable_dir
from simtest._io import OutputFolderError
from simtest._outdir import check_out_folder
from simtest.harness.nightly import (CAPS, _listed, append_history, changes_table, check_section, compare,
                                     default_baseline_path, expected_metrics, gate_summary, history_line,
                                     load_baseline, metrics_of, noisy_headlines, read_history, uncovered,
                                     undetectable_doublings, update_baseline as write_baseline)
from simtest.harness.external import ExternalError, with_external
from simtest.harness.report import REPORT_FILES, build_results, make_run_id, write_report_files
from simtest.harness.runner import run_suite
from simtest.harness.suite import MAX_TOTAL_REALISATIONS, SuiteError, load_suite

__all__ = ["validate_command", "nightly_command", "check_workers", "load_checked_suite"]


def _fmt(deg: float) -> str:
    """Two significant digits, without exponents for errors of 10 deg and more."""
    return f"{deg:.0f}" if deg >= 10 else f"{deg:.2g}"


def check_workers(workers: int | None) -> int | None:
    """``workers`` if it is at most the machine's CPUs (``os.cpu_count()``), else exit 2.

    Parameters
    ----------
    workers : int or None
        ``-j/--workers`` (0 or None, the default: one per core).

    Returns
    -------
    int or None
        ``workers`` unchanged.

    Raises
    ------
    typer.Exit
        With exit code 2 and one line when ``workers`` exceeds ``os.cpu_count()`` (more
        processes than cores only slow a run down and multiply its memory).
    """
    cpus = os.cpu_count() or 1
    if workers is not None and workers > cpus:
        fail(f"-j/--workers: {workers} workers on a machine with {cpus} CPUs; use at most {cpus}", BAD_INPUT)
    return workers


def load_checked_suite(name: str, seed: int | None = None, realisations: int | None = None):
    """Load a suite with ``--seed`` / ``-n`` applied, or exit 2 with one line.

    Parameters
    ----------
    name : str
        Bundled suite name or path.
    seed, realisations : int or None
        Overrides (None keeps the suite's).

    Returns
    -------
    simtest.harness.suite.Suite

    Raises
    ------
    typer.Exit
        With exit code 2 on a bad suite, or when ``-n`` times the suite's distinct settings
        exceeds :data:`simtest.harness.suite.MAX_TOTAL_REALISATIONS` (checked before anything
        is allocated).
    """
    try:
        s = load_suite(name)
        if realisations is not None:
            n = len(s.distinct_cases)
            if realisations * n > MAX_TOTAL_REALISATIONS:
                fail(f"-n/--realisations: {realisations:,} per case x {n} distinct settings = "
                     f"{realisations * n:,} realisations exceed the maximum of "
                     f"{MAX_TOTAL_REALISATIONS:,} per run (about 2 KB of results each are held "
                     "until the report)", BAD_INPUT)
        if seed is not None or realisations is not None:
            s = s.with_overrides(seed=seed, realisations=realisations)
    except SuiteError as e:
        fail(e, BAD_INPUT)
    return s


def _run(s, *, workers, progress, console, scheduler):
    """:func:`run_suite`, a bad or silent ``--scheduler`` as one line (exit 2) before any work."""
    try:
        return run_suite(s, workers=workers, progress=progress, console=console, scheduler=scheduler)
    except SchedulerError as e:
        fail(e, BAD_INPUT)


#: ``--scheduler``, as ``dataset generate`` has it.
SCHEDULER_HELP = ("Address of a Dask scheduler (tcp://HOST:8786) whose workers run the "
                  "realisations instead of local processes (needs the dask extra); same results.")
WORKERS_HELP = "Worker processes (0, the default: one per core; 1: in process; at most the machine's CPUs)."
OUT_HELP = "Reports root folder; the run goes to OUT/<suite>/<run id>/."


def _counts(s) -> str:
    """The one count of a suite used by the header, the progress bar and the report."""
    n, d = len(s.cases), len(s.distinct_cases)
    shared = "" if n == d else (f" ({n - d} shared by several sweeps run once)")
    return (f"{len(s.sweeps)} sweeps, {n} cases = {d} distinct settings{shared}, {s.total_realisations} realisations")


def _write(results: dict, folder: Path, **kw) -> Path:
    """Write the report set, or exit 4 with one line (what was there before is kept)."""
    try:
        return write_report_files(results, folder, **kw)
    except OutputFolderError as e:  # a file put there while the suite ran: kept, nothing written
        fail(e, CANNOT_WRITE)
    except OSError as e:
        fail(f"--out: cannot write the report in {folder}: {e.strerror or e}", CANNOT_WRITE)


def _json_safe(doc):
    """``doc`` with every NaN or infinite float as None (the gate judged the original)."""
    if isinstance(doc, dict):
        return {k: _json_safe(v) for k, v in doc.items()}
    if isinstance(doc, list):
        return [_json_safe(v) for v in doc]
    return None if isinstance(doc, float) and not math.isfinite(doc) else doc


def _summary(results: dict, console) -> None:
    """The console table: one column per estimator where that fits the console's width, else one row
    per sweep and estimator.
    """
    ests = results["suite"]["estimators"]
    cases = {c["id"]: c for c in results["cases"]}
    cells = {}
    for sw in results["sweeps"]:
        for e in ests:
            ms = [cases[k]["metrics"]["estimators"][e] for k in sw["cases"]]
            meds = [m["median"] for m in ms if m["median"] is not None]
            fr = max(m["failure_rate"] for m in ms)
            cell = "-" if not meds else (f"{_fmt(min(meds))} to {_fmt(max(meds))}" if len(meds) > 1 else _fmt(meds[0]))
            cells[sw["name"], e] = cell + (f" [red]({fr:.0%})[/]" if fr > 0 else "")
    title = (f"{results['suite']['name']}: median error (deg) per setting, lowest to highest over "
             "the sweep's settings, as in the report; (worst failure rate)")
    # fold, never truncate: a number cut to "0.00099..." would be worse than none
    t = Table(title=title)
    t.add_column("sweep", overflow="fold")
    for e in ests:
        t.add_column(e, justify="right", overflow="fold")
    for sw in results["sweeps"]:
        t.add_row(sw["name"], *(cells[sw["name"], e] for e in ests))
    if console.measure(t, options=console.options.update(max_width=10**4)).maximum > console.width:
        t = Table(title=title)
        for col in ("sweep", "estimator", "median error (deg)"):
            t.add_column(col, justify="right" if col.startswith("median") else "left", overflow="fold")
        for sw in results["sweeps"]:
            for k, e in enumerate(ests):
                t.add_row(sw["name"] if k == 0 else "", e, cells[sw["name"], e], end_section=k == len(ests) - 1)
    console.print(t)


def validate_command(
    suite: str = typer.Argument("default", help="Bundled suite name (scenes/suites/<name>.toml) "
                                                "or a path to a suite TOML file."),
    workers: Optional[int] = typer.Option(None, "--workers", "-j", min=0, show_default=False, help=WORKERS_HELP),
    seed: Optional[int] = typer.Option(None, "--seed", min=0, help="Root seed (default: the suite's)."),
    out: Path = typer.Option(Path("reports"), "--out", "-o", help=OUT_HELP),
    realisations: Optional[int] = typer.Option(
        None, "--realisations", "-n", min=1,
        help=f"Realisations per case (default: the suite's; at most {MAX_TOTAL_REALISATIONS:,} in all per run)."),
    run_id: Optional[str] = typer.Option(None, "--run-id", help="Run folder name, one plain name "
                                         "(default: <UTC time>-local, git-ignored)."),
    progress: bool = typer.Option(True, "--progress/--no-progress", help="Show progress."),
    scheduler: Optional[str] = typer.Option(None, "--scheduler", help=SCHEDULER_HELP),  # noqa: UP045
    estimator: Optional[list[str]] = typer.Option(  # noqa: UP045
        None, "--estimator", metavar="[NAME=]MODULE:FUNCTION",
        help="Also score your own method, function(frame, camera, rig, response) -> {'bp_px': "
             "(N, 2), 'normal': (N, 3)}, beside the built-in estimators (repeatable; MODULE importable, from "
             "the current folder too, or a path/to/file.py)."),
) -> None:
    """Run a validation suite and write its report.

    With no argument: the bundled `default` suite (rendered bundled scenes and a small part of
    the paper's synthetic protocol).

    Writes OUT/<suite>/<run id>/: results.json (every statistic), results.csv (one row per case
    and estimator), report.md, report.html (self-contained) and figures/*.png, replaced as a set.

    A setting shared by two sweeps is two cases but runs once. The console table shows the median
    error per setting.

    Exit codes: 0 done; 2 bad usage or suite; 4 OUT cannot be written (both checked before
    running); 130 interrupted.
    """
    console = Console(stderr=True)
    workers = check_workers(workers) or None  # 0 and None: one per core
    s = load_checked_suite(suite, seed, realisations)
    if estimator:
        try:
            s = with_external(s, estimator)
        except ExternalError as e:
            fail(e, BAD_INPUT)
    run_id = safe_name(run_id or make_run_id(), "--run-id")
    folder = out / s.name / run_id
    check_out_folder(folder, REPORT_FILES)
    console.print(f"[bold]simtest validate[/] {s.name}: {_counts(s)}, seed {s.seed}")
    run = _run(s, workers=workers, progress=progress, console=console, scheduler=scheduler)
    results = build_results(run, run_id)
    folder = _write(results, folder)
    show = Console(soft_wrap=True)  # results on stdout (progress and errors on stderr)
    _summary(results, show)
    for k, v in results["provenance"]["realisations_per_s"].items():
        show.print(f"{k}: {v['realisations']} realisations, {v['per_s']} realisations/s with {run.workers} worker(s)")
    show.print(f"wall time {run.wall_s:.1f} s; report: {folder / 'report.html'}")


def _baseline_section(path: Path, s, quick: bool):
    """The suite's baseline section, sound and covering the suite's cases and families; else 3."""
    try:
        section = load_baseline(path)["suites"].get(s.name)
    except ValueError as e:
        fail(e, BAD_BASELINE)
    if section is None:
        fail(f"{path}: suites.{s.name}: no baseline for this suite; create it with "
             f"`simtest nightly{' --quick' if quick else ''} --update-baseline`", BAD_BASELINE)
    where = f"{path}: suites.{s.name}"
    bad = check_section(section, where)
    if bad:
        fail(bad, BAD_BASELINE)
    _covers(section, expected_metrics(s), where)
    return section


def _covers(section: dict, names, where: str) -> None:
    miss = uncovered(section, names)
    if miss:
        fail(f"{where}: does not cover {len(miss)} metric(s) of this run: {_listed(miss)} (rewrite it with "
             "--update-baseline)", BAD_BASELINE)


def nightly_command(
    quick: bool = typer.Option(False, "--quick", help="Run the quick suite instead of the nightly one."),
    update_baseline: bool = typer.Option(False, "--update-baseline",
                                         help="Accept this code as the new baseline: run the "
                                              "suite --repeats times with seeds seed, seed + 1, "
                                              "... and store values, spreads and tolerances."),
    repeats: int = typer.Option(4, "--repeats", min=1, help="Seed-varied runs that measure the spread "
                                "(with --update-baseline)."),
    seed: Optional[int] = typer.Option(None, "--seed", min=0, help="Root seed of this run (default: the suite's)."),
    baseline: Optional[Path] = typer.Option(None, "--baseline", help="Baseline file (default: reports/baseline.json)."),
    history: Optional[Path] = typer.Option(None, "--history", help="History file, one JSON line per run "
                                           "(default: OUT/<suite>/history.jsonl)."),
    workers: Optional[int] = typer.Option(None, "--workers", "-j", min=0, show_default=False, help=WORKERS_HELP),
    out: Path = typer.Option(Path("reports"), "--out", "-o", help=OUT_HELP),
    run_id: Optional[str] = typer.Option(None, "--run-id", help="Run folder name, one plain name "
                                         "(default: <UTC time>-local)."),
    suite: Optional[str] = typer.Option(None, "--suite", help="Another suite (name or path)."),
    show_all: bool = typer.Option(False, "--all", help="List unchanged metrics too."),
    progress: bool = typer.Option(True, "--progress/--no-progress"),
    scheduler: Optional[str] = typer.Option(None, "--scheduler", help=SCHEDULER_HELP),  # noqa: UP045
) -> None:
    """Run the nightly (or --quick) suite and gate it against the committed baseline.

    Each metric may grow by its tolerance: its measured seed spread plus a relative floor, capped
    at 0.4 deg on family medians, 10 deg on case medians and 0.1 on rates.

    Writes OUT/<suite>/<run id>/ (results.json, results.csv, report.md, report.html with the
    gate's verdict, figures/*.png) and appends one line to OUT/<suite>/history.jsonl (or
    --history). With --update-baseline: the report of the first repeat and the suite's section of
    the baseline file (--baseline); no history line.

    Exit codes: 0 no regression; 1 a regression: a metric grew beyond its tolerance, or is NaN,
    infinite or missing (each named); 2 bad usage (flag, suite, run id); 3 the baseline is
    unusable: missing, malformed, or not covering this run's metrics; 4 OUT, the history or the
    baseline cannot be written (checked before running); 130 interrupted.
    """
    console = Console(stderr=True)
    name = suite or ("quick" if quick else "nightly")
    path = baseline or default_baseline_path()
    workers = check_workers(workers) or None  # 0 and None: one per core
    s = load_checked_suite(name, seed)
    run_id = safe_name(run_id or make_run_id(), "--run-id")
    folder = out / s.name / run_id
    check_out_folder(folder, REPORT_FILES)
    hist_path = history or (out / s.name / "history.jsonl")
    if update_baseline:
        writable_dir(path.parent, "--baseline")
        section = None
    else:
        if hist_path.is_dir():
            fail(f"--history: {hist_path} is a folder, not a file", CANNOT_WRITE)
        writable_dir(hist_path.parent, "--history")
        section = _baseline_section(path, s, quick)
    run = _run(s, workers=workers, progress=progress, console=console, scheduler=scheduler)
    results = build_results(run, run_id)
    if update_baseline:
        runs = [results]
        for k in range(1, repeats):
            sk = s.with_overrides(seed=s.seed + k)
            console.print(f"repeat {k + 1} of {repeats}: seed {sk.seed}")
            runs.append(build_results(_run(sk, workers=workers, progress=progress, console=console,
                                           scheduler=scheduler), f"{run_id}-seed{sk.seed}"))
        try:
            write_baseline(path, runs)
        except ValueError as e:
            fail(e, BAD_INPUT)
        except OSError as e:
            fail(f"--baseline: cannot write {path}: {e.strerror or e}", CANNOT_WRITE)
        sec = load_baseline(path)["suites"][s.name]
        weak = undetectable_doublings(sec)
        noisy = noisy_headlines(sec)
        _write(results, folder)
        show = Console(soft_wrap=True)  # results on stdout
        show.print(f"report: {folder / 'report.html'}")
        show.print(f"baseline for suite {s.name} written to {path} ({len(sec['metrics'])} "
                   f"metrics from seeds {sec['seeds']}; {len(weak)} could double unnoticed: "
                   "too noisy at this many realisations)")
        if noisy:
            console.print(f"[yellow]warning: {len(noisy)} headline metric(s) have seed noise "
                          f"(k_spread spreads) above their {CAPS['headline_deg']} deg cap and "
                          "may fail a good run at another seed; give their sweeps more "
                          f"realisations: {', '.join(noisy)}[/]")
        return
    if section.get("suite_sha256") and section["suite_sha256"] != results["suite"]["sha256"]:
        console.print(f"[yellow]note: suite file {s.source} changed since the baseline[/]")
    where = f"{path}: suites.{s.name}"
    miss = uncovered(section, metrics_of(results))
    if miss:
        _write(_json_safe(results), folder,
               nightly={"verdict": "NO VERDICT (the baseline does not cover this run)",
                        "baseline": str(path),
                        "summary": f"{len(miss)} metric(s) not in the baseline",
                        "problems": miss[:20]})
        _covers(section, miss, where)
    changes = compare(section, results)
    passed, lines, counts = gate_summary(changes)
    results = _json_safe(results)  # judged; what is written keeps a NaN as null
    try:
        append_history(hist_path, history_line(results, passed, counts))
    except OSError as e:
        fail(f"--history: cannot append to {hist_path}: {e.strerror or e}", CANNOT_WRITE)
    summary = ", ".join(f"{v}: {n}" for v, n in sorted(counts.items()))
    _write(results, folder, history=read_history(hist_path),
           nightly={"verdict": "pass" if passed else "FAIL", "baseline": str(path),
                    "summary": summary, "problems": lines})
    show = Console(soft_wrap=True)  # results on stdout (progress and errors on stderr)
    show.print(changes_table(changes, f"{s.name} vs baseline {path.name}", show_all))
    show.print(summary)
    show.print(f"report: {folder / 'report.html'}; history: {hist_path}")
    if not passed:
        for ln in lines:
            typer.echo(ln, err=True)
        raise typer.Exit(CHECK_FAILED)
    show.print("[green]no regression[/]")
