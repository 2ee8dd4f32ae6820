"""Regenerate every committed report, optionally the nightly baseline, then the README section.

``python -m simtest.harness.regenerate`` re-runs each suite with a committed run folder under
``reports/``, writes ``reports/<suite>/<UTC date>/``, removes that suite's older committed run
folders (not ``-local`` ones) and rewrites the README section. ``--baseline`` also rebuilds
``reports/baseline.json``.
"""

from __future__ import annotations

import argparse
import datetime as _dt
import shutil
import sys
from pathlib import Path

from rich.console import Console

from simtest.harness import readme
from simtest.harness.nightly import default_baseline_path, update_baseline
from simtest.harness.report import build_results, write_report
from simtest.harness.runner import run_suite
from simtest.harness.suite import SuiteError, load_suite
from simtest.resources import data_root

__all__ = ["main", "BASELINE_REPEATS"]

#: Seed-varied runs per baseline suite (the quick suite's few renders need more for a usable spread).
BASELINE_REPEATS = {"nightly": 3, "quick": 5}


def _baseline(name: str, repeats: int, path: Path, workers, console) -> None:
    s = load_suite(name)
    runs = []
    for k in range(repeats):
        sk = s.with_overrides(seed=s.seed + k)
        console.print(f"baseline {name}: seed {sk.seed} ({k + 1} of {repeats})")
        runs.append(build_results(run_suite(sk, workers=workers, console=console), f"baseline-seed{sk.seed}"))
    update_baseline(path, runs)
    console.print(f"baseline {name} written to {path}")


def main(argv: list[str] | None = None) -> int:
    """Command line (see the module docstring).

    Parameters
    ----------
    argv : list of str, optional
        Arguments (default ``sys.argv[1:]``).

    Returns
    -------
    int
        0 on success; 2 on a bad suite name or README (one line on stderr).
    """
    root = data_root()
    ap = argparse.ArgumentParser(prog="python -m simtest.harness.regenerate", description=__doc__.splitlines()[0])
    ap.add_argument("--suite", action="append",
                    help="suite to run (repeatable; default: every suite with a committed report)")
    ap.add_argument("--out", type=Path, default=root / "reports", help="reports root")
    ap.add_argument("--run-id", default=_dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%d"))
    ap.add_argument("-j", "--workers", type=int, default=None)
    ap.add_argument("--readme", type=Path, default=root / "README.md")
    ap.add_argument("--no-readme", action="store_true", help="leave the README alone")
    ap.add_argument("--baseline", action="store_true",
                    help="also rebuild the nightly baseline (nightly and quick suites)")
    ap.add_argument("--baseline-path", type=Path, default=None)
    a = ap.parse_args(argv)
    console = Console(stderr=True)
    names = a.suite or [p.parent.name for p in readme.committed_runs(a.out)]
    try:
        suites = [load_suite(n) for n in names]
    except SuiteError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    for s in suites:
        console.print(f"[bold]{s.name}[/]: {len(s.cases)} cases = {len(s.distinct_cases)} "
                      f"distinct settings, {s.total_realisations} realisations")
        run = run_suite(s, workers=a.workers, console=console)
        folder = write_report(run, a.out, run_id=a.run_id)
        for old in (a.out / s.name).iterdir():
            if old.is_dir() and old != folder and not old.name.endswith("-local") \
                    and not old.name.startswith(".") and (old / "results.json").is_file():
                shutil.rmtree(old)
        console.print(f"{s.name}: {folder} ({run.wall_s:.0f} s)")
    if a.baseline:
        for name, reps in BASELINE_REPEATS.items():
            _baseline(name, reps, a.baseline_path or default_baseline_path(), a.workers, console)
    return 0 if a.no_readme else readme.main(["--readme", str(a.readme), "--reports", str(a.out)])


if __name__ == "__main__":
    raise SystemExit(main())
