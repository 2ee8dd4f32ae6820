"""``simtest bench``: run the clone's speed benchmarks and print them as one table.

The benchmarks live in a clone's ``benchmarks/`` folder (``benchmarks.SECTIONS``); a wheel ships none.
A section is ``f(repeat: int) -> list[BenchResult]`` (``repeat`` and ``variant`` passed when it takes
them); a ``dict`` result is flattened, one row per numeric leaf, the unit read from its suffix.
"""

from __future__ import annotations

import importlib
import inspect
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from importlib.resources import files
from types import ModuleType

import numpy as np
import typer
from rich.console import Console
from rich.table import Table

from simtest._exit import fail
from simtest.scene.spec import RENDER_VARIANTS

#: The folder that holds ``simtest/``: a clone's top, where ``benchmarks/`` lives (site-packages
#: for a wheel, which has none).
CLONE_ROOT = Path(str(files("simtest"))).resolve().parent


@dataclass(frozen=True)
class BenchResult:
    """One measured figure: median ``value`` in ``unit``, ``target`` (or None), ``best`` (minimum), a ``note``."""

    section: str
    name: str
    value: float
    unit: str
    target: float | None = None
    best: float | None = None
    note: str = ""

    @property
    def meets_target(self) -> bool | None:
        """True/False against the target, None without one."""
        return None if self.target is None else self.value <= self.target


SectionFn = Callable[..., "list[BenchResult] | dict"]


def load_benchmarks() -> ModuleType:
    """The clone's ``benchmarks`` package, its folder put on ``sys.path``.

    Raises
    ------
    LookupError
        Where there is no such folder (a wheel), or ``import benchmarks`` finds another package.
    """
    folder = CLONE_ROOT / "benchmarks"
    if not (folder / "__init__.py").is_file():
        raise LookupError(f"the benchmarks need a clone of simtest: no benchmarks/ beside the "
                          f"installed package in {CLONE_ROOT} (clone the repository and "
                          "`pip install -e .` it)")
    if str(CLONE_ROOT) not in sys.path:
        sys.path.insert(0, str(CLONE_ROOT))
    mod = importlib.import_module("benchmarks")
    if Path(inspect.getfile(mod)).resolve().parent != folder or not hasattr(mod, "SECTIONS"):
        raise LookupError(f"`import benchmarks` finds {inspect.getfile(mod)}, not the clone's {folder}")
    return mod


def resolve_section(name: str) -> SectionFn | str:
    """The function of a section of ``benchmarks.SECTIONS``, or why it cannot run (a string)."""
    spec = load_benchmarks().SECTIONS.get(name)
    if spec is None:
        return "unknown section"
    mod_name, fn_name = spec.split(":")
    try:
        return getattr(importlib.import_module(mod_name), fn_name)
    except (ImportError, AttributeError) as exc:
        return f"not available: {exc}"


def _unit_of(key: str) -> str:
    units = (("_per_s", "1/s"), ("_ms", "ms"), ("_s", "s"), ("_mib", "MiB"), ("_mb", "MB"))
    return next((unit for suffix, unit in units if key.endswith(suffix)), "")


def _flatten(section_name: str, obj, prefix: str = "") -> list[BenchResult]:
    rows = []
    if isinstance(obj, dict):
        for k, v in obj.items():
            rows += _flatten(section_name, v, f"{prefix}/{k}" if prefix else str(k))
    elif isinstance(obj, (int, float)) and not isinstance(obj, bool):
        rows.append(BenchResult(section_name, prefix, float(obj), _unit_of(prefix.rsplit("/", 1)[-1])))
    elif isinstance(obj, str):  # a name or an error: shown as a note (value NaN, printed blank)
        rows.append(BenchResult(section_name, prefix, float("nan"), "", note=obj))
    elif isinstance(obj, (list, tuple)) and all(isinstance(v, (str, int, float)) for v in obj):
        rows.append(BenchResult(section_name, prefix, float("nan"), "", note=" / ".join(map(str, obj))))
    return rows


def figure_text(value: float) -> str:
    """A figure as the table prints it: blank for a note's NaN, 3 significant digits below 1e-3."""
    if np.isnan(value):
        return ""
    return f"{value:.3g}" if 0 < abs(value) < 1e-3 else f"{value:.3f}"


def run_section(name: str, fn: SectionFn, repeat: int, variant: str | None = None) -> list[BenchResult]:
    """Call a section with ``repeat`` and ``variant`` where it takes them, and turn a dict result into rows."""
    try:
        params = inspect.signature(fn).parameters
    except (TypeError, ValueError):
        params = {"repeat": None}
    res = fn(**{k: v for k, v in (("repeat", repeat), ("variant", variant)) if k in params and v is not None})
    return _flatten(name, res) if isinstance(res, dict) else list(res)


def bench_command(
    only: list[str] = typer.Option(None, "--only", help="Run only these sections (repeatable)."),
    repeat: int = typer.Option(50, "--repeat", min=1, help="Timed runs per figure (median reported)."),
    variant: str = typer.Option(None, "--variant", help="Mitsuba variant for the render section: "
                                "llvm_ad_rgb (its default), cuda_ad_rgb or auto."),
    against: str = typer.Option(None, "--against", metavar="REV", help="Also run the sections on this git "
                                "commit's tree, alternately with this clone's, and print the two side by side."),
    rounds: int = typer.Option(2, "--rounds", min=1, help="With --against: runs of each tree, alternated."),
) -> None:
    """Run the speed benchmarks of a clone (benchmarks/) and print a table (median and min per
    figure, single core).

    Writes no file: the table goes to standard output."""
    if variant is not None and variant not in RENDER_VARIANTS:
        fail(f"--variant {variant!r} is not one of {list(RENDER_VARIANTS)}")
    try:
        names = list(load_benchmarks().SECTIONS)
    except LookupError as exc:
        fail(exc)
    chosen = names if not only else list(only)
    unknown = [n for n in chosen if n not in names]
    if unknown:
        fail(f"unknown bench section(s) {unknown}; known: {names}")
    if against is not None:  # the clone's benchmarks/side_by_side.py runs both trees and prints them
        try:
            return importlib.import_module("benchmarks.side_by_side").main(against, chosen, repeat, rounds, variant)
        except (LookupError, RuntimeError) as exc:
            fail(exc)
    table = Table(title="simtest bench (single core)")
    for col in ("section", "figure", "median", "min", "unit", "target", "ok", "note"):
        table.add_column(col)
    for name in chosen:
        fn = resolve_section(name)
        if isinstance(fn, str):
            table.add_row(name, f"(section {fn})", "", "", "", "", "", "")
            continue
        for r in run_section(name, fn, repeat, variant):
            ok = {None: "", True: "yes", False: "NO"}[r.meets_target]
            table.add_row(r.section, r.name, figure_text(r.value), "" if r.best is None else f"{r.best:.3f}",
                          r.unit, "" if r.target is None else f"<= {r.target:g}", ok, r.note)
    Console(width=max(160, Console().width)).print(table)
