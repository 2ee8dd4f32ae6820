"""``simtest bench --against REV``: the sections run on this clone and on another commit, side by side.

A speed change is judged against the commit before it on one machine in one run, not against a
figure written down another day (the shared 2-core VM's speed moves by up to a half between hours).
Here the other commit's tree is extracted with ``git archive`` into a temporary folder, and each
tree's sections run in a fresh interpreter whose ``import simtest`` and ``import benchmarks`` are
that tree's (``PYTHONPATH`` holds the tree alone; both use this environment's libraries), in the
order this tree, the other, the other, this tree, ... (:data:`ROUNDS` rounds), so that a drift of
the machine's speed over the run falls on both. A row's figure is the median of its rounds'
medians; rows pair by section and figure name.
"""

from __future__ import annotations

import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path

from rich.console import Console
from rich.table import Table

from simtest.bench import CLONE_ROOT, figure_text

#: Issue 64's bar on a rebuilt stage: no reconstruction row of ``simtest bench`` slower than this many
#: times the commit before the change, side by side in one run on one core ("a library call may
#: cost a little speed; the tables must win it back"). A ratio, not a measured threshold.
SLOWER_BAR = 1.5

#: Rounds of the two trees (this, other, other, this, ...): two cancel a linear drift of the machine.
ROUNDS = 2

#: Units whose larger figure is the faster (a rate); every other unit's figure is a cost (time, memory).
RATE_UNITS = frozenset({"1/s"})

# Runs in the tree's fresh interpreter: the sections by name (its ``benchmarks.SECTIONS``) or as
# "module:function", their rows written as JSON to argv[1]. It reads only simtest.bench's
# resolve_section and run_section, which every tree since the benchmarks left the package has.
_DRIVER = r"""
import importlib, json, math, sys
from simtest.bench import load_benchmarks, resolve_section, run_section
out, repeat, variant, names = sys.argv[1], int(sys.argv[2]), sys.argv[3] or None, sys.argv[4:]
load_benchmarks()
rows = []
for name in names:
    if ":" in name:
        mod, fn = name.split(":")
        label, fn = mod.rsplit(".", 1)[-1], getattr(importlib.import_module(mod), fn)
    else:
        label, fn = name, resolve_section(name)
    if isinstance(fn, str):
        sys.exit(f"section {name}: {fn}")
    for r in run_section(label, fn, repeat, variant):
        rows.append({"section": r.section, "name": r.name, "unit": r.unit, "note": r.note,
                     "value": None if math.isnan(r.value) else r.value})
json.dump(rows, open(out, "w"))
"""


def resolve_commit(rev: str, clone: Path = CLONE_ROOT) -> str:
    """The full hash of ``rev`` in the clone's git history.

    Raises
    ------
    LookupError
        Where the clone is no git work tree, git is missing, or ``rev`` names no commit.
    """
    try:
        got = subprocess.run(["git", "-C", str(clone), "rev-parse", "--verify", "--quiet", f"{rev}^{{commit}}"],
                             capture_output=True, text=True)
    except OSError as exc:
        raise LookupError(f"--against needs git: {exc}") from None
    if got.returncode != 0:
        if not (clone / ".git").exists():
            raise LookupError(f"--against needs a git clone; {clone} is none")
        raise LookupError(f"--against {rev}: no such commit in {clone}")
    return got.stdout.strip()


@contextmanager
def tree_at(commit: str, clone: Path = CLONE_ROOT) -> Iterator[Path]:
    """The files of ``commit`` (``git archive``) in a temporary folder, removed on leaving.

    Raises
    ------
    RuntimeError
        Where git or tar fails (tar's message).
    """
    folder = Path(tempfile.mkdtemp(prefix=f"simtest-bench-{commit[:9]}-"))
    try:  # git's tar stream straight into tar (about 100 MB with the reports: not held here)
        git = subprocess.Popen(["git", "-C", str(clone), "archive", "--format=tar", commit], stdout=subprocess.PIPE)
        tar = subprocess.run(["tar", "-x", "-C", str(folder)], stdin=git.stdout, capture_output=True)
        git.stdout.close()
        if git.wait() or tar.returncode:
            raise RuntimeError(f"could not extract {commit[:9]}: {tar.stderr.decode(errors='replace').strip()}")
        yield folder
    finally:
        shutil.rmtree(folder, ignore_errors=True)


def run_tree(tree: Path, sections: Sequence[str], repeat: int, variant: str | None = None,
             extra_path: Sequence[str] = ()) -> list[dict]:
    """Each section's rows as the tree's own code measures them, in a fresh interpreter.

    Parameters
    ----------
    tree : Path
        A folder holding ``simtest/`` and ``benchmarks/`` (a clone, or :func:`tree_at`'s).
    sections : sequence of str
        Names of the tree's ``benchmarks.SECTIONS``, or ``"module:function"``.
    repeat : int
        Timed runs per figure (``simtest bench --repeat``).
    variant : str, optional
        Mitsuba variant of the render section.
    extra_path : sequence of str
        Folders put after the tree on ``PYTHONPATH`` (a section module outside both trees).

    Returns
    -------
    list of dict
        ``{"section", "name", "unit", "note", "value"}`` per row (``value`` None for a note).

    Raises
    ------
    RuntimeError
        Where the interpreter fails: the last line it wrote to standard error.
    """
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "rows.json"
        env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(tree), *extra_path])}
        proc = subprocess.run([sys.executable, "-c", _DRIVER, str(out), str(int(repeat)), variant or "", *sections],
                              cwd=tree, env=env, capture_output=True, text=True)
        if proc.returncode != 0 or not out.is_file():
            last = (proc.stderr.strip().splitlines() or [f"exit status {proc.returncode}"])[-1]
            raise RuntimeError(f"the benchmarks of {tree} failed: {last}")
        return json.loads(out.read_text())


def ratio(ours: float, theirs: float, unit: str) -> float:
    """How many times slower (or larger in memory) this tree's figure is than the other's: the cost
    ``ours / theirs``, or for a rate (:data:`RATE_UNITS`) ``theirs / ours``; above 1 this tree is slower."""
    return theirs / ours if unit in RATE_UNITS else ours / theirs


def paired(ours_runs: Sequence[list[dict]], theirs_runs: Sequence[list[dict]]) -> list[dict]:
    """The rows of the two trees side by side, in this tree's order (then those only the other has).

    Each figure is the median over the runs; a row is ``{"section", "name", "unit", "ours", "theirs",
    "ratio", "slower", "spread"}`` (:func:`ratio`; ``slower``: the ratio exceeds :data:`SLOWER_BAR`;
    ``spread``: the larger of the two trees' largest over smallest run figure, the run-to-run noise a
    ratio must stand out of), None where a tree lacks the row or has no figure for it (a note), or
    (``spread``) where neither tree has two positive run figures."""
    def medians(runs):
        vals: dict[tuple[str, str], list] = {}
        units: dict[tuple[str, str], str] = {}
        for rows in runs:
            for r in rows:
                key = (r["section"], r["name"])
                units.setdefault(key, r["unit"])
                if r["value"] is not None:
                    vals.setdefault(key, []).append(float(r["value"]))
        spreads = {k: max(v) / min(v) for k, v in vals.items() if len(v) > 1 and min(v) > 0}
        return {k: (statistics.median(vals[k]) if vals.get(k) else None) for k in units}, units, spreads

    ours, units, our_spreads = medians(ours_runs)
    theirs, their_units, their_spreads = medians(theirs_runs)
    out = []
    for key in [*ours, *(k for k in theirs if k not in ours)]:
        a, b = ours.get(key), theirs.get(key)
        unit = units.get(key, their_units.get(key, ""))
        r = ratio(a, b, unit) if a is not None and b is not None and a > 0 and b > 0 else None
        spread = [x for x in (our_spreads.get(key), their_spreads.get(key)) if x is not None]
        out.append({"section": key[0], "name": key[1], "unit": unit, "ours": a, "theirs": b, "ratio": r,
                    "slower": r is not None and r > SLOWER_BAR, "spread": max(spread) if spread else None})
    return out


def side_by_side(rev: str, sections: Sequence[str], repeat: int, rounds: int = ROUNDS,
                 variant: str | None = None, clone: Path = CLONE_ROOT, extra_path: Sequence[str] = (),
                 on_run=None) -> tuple[str, list[dict]]:
    """The sections on ``clone`` and on commit ``rev``, alternately (:data:`ROUNDS`): ``(commit, rows)``
    with :func:`paired`'s rows. ``on_run(label)`` is called before each tree's run (progress).

    Raises
    ------
    LookupError
        ``rev`` is no commit of the clone (:func:`resolve_commit`).
    RuntimeError
        ``rev``'s files could not be extracted (:func:`tree_at`), or a tree's benchmarks failed (:func:`run_tree`).
    """
    commit = resolve_commit(rev, clone)
    ours_runs: list[list[dict]] = []
    theirs_runs: list[list[dict]] = []
    with tree_at(commit, clone) as other:
        for i in range(max(1, int(rounds))):
            order = [("this tree", clone, ours_runs), (commit[:9], other, theirs_runs)]
            for label, tree, runs in order if i % 2 == 0 else order[::-1]:
                if on_run is not None:
                    on_run(f"round {i + 1}: {label}")
                runs.append(run_tree(tree, sections, repeat, variant, extra_path))
    return commit, paired(ours_runs, theirs_runs)


def main(rev: str, sections: Sequence[str], repeat: int, rounds: int = ROUNDS, variant: str | None = None) -> None:
    """``simtest bench --against REV``: :func:`side_by_side` with a status line, then its rows as a table,
    those over :data:`SLOWER_BAR` marked. Raises as :func:`side_by_side` does."""
    console = Console(width=max(160, Console().width))
    with console.status("benchmarks") as status:
        commit, rows = side_by_side(rev, sections, repeat, rounds, variant,
                                    on_run=lambda label: status.update(f"benchmarks, {label}"))
    table = Table(title=f"simtest bench (single core): this tree against {commit[:9]}, {rounds} run(s) each, "
                        "alternated; ratio > 1 where this tree is slower; run spread: largest over smallest run")
    for col in ("section", "figure", "this tree", commit[:9], "unit", "ratio", "run spread", f"within x{SLOWER_BAR:g}"):
        table.add_column(col)
    for r in rows:
        table.add_row(r["section"], r["name"], *("" if v is None else figure_text(v) for v in (r["ours"], r["theirs"])),
                      r["unit"], *("" if r[k] is None else f"{r[k]:.2f}" for k in ("ratio", "spread")),
                      "" if r["ratio"] is None else "NO" if r["slower"] else "yes")
    console.print(table)
