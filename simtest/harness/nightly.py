"""Nightly accuracy guard: run a fixed suite, compare with ``reports/baseline.json``.

The baseline holds, per suite (``nightly``, ``quick``), per case key and estimator, the metrics of
:data:`TRACKED` from a run whose numbers were accepted. A metric *regresses* when it gets worse
(errors and failure rates only get worse upwards) by more than ``abs + rel * |baseline|``; it
*improves* when it gets better by as much (reported, not fatal: rewrite the baseline on purpose
with ``--update-baseline``). A case or estimator that vanished is a regression; a new one is noted.

Tolerances (:data:`DEFAULT_TOLERANCES`; a suite file may override them in ``[tolerances]``). The
same code and seed reproduce the numbers exactly on one machine, so the tolerances only have to
absorb what differs between machines and library versions (OpenCV interpolation, LLVM codegen,
float summation order in BLAS): far below 0.05 deg on a mean over 20+ realisations. A real
regression of a few tenths of a degree, or one more failure in 50, is caught.

Baseline file::

    {"schema": "simtest.baseline", "schema_version": 1,
     "suites": {"quick": {"created_utc", "git_commit", "suite_sha256", "seed", "realisations",
                          "tolerances", "cases": {case id: {"sweep", "x", "estimators":
                                                  {name: {"mean", "median", "p95",
                                                          "failure_rate"}}}}}}}
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

from simtest.resources import bundled

__all__ = ["TRACKED", "DEFAULT_TOLERANCES", "Change", "baseline_entry", "compare",
           "load_baseline", "update_baseline", "default_baseline_path"]

#: Metrics compared, all "lower is better".
TRACKED = ("mean", "median", "p95", "failure_rate")

#: metric -> {"abs": ..., "rel": ...}; a change beyond abs + rel * |baseline| counts. Degrees for
#: the error statistics (p95 is noisier than the mean over few realisations: twice as wide);
#: failure rate in [0, 1] (0.02 = one failure more in 50).
DEFAULT_TOLERANCES = {
    "mean": {"abs": 0.05, "rel": 0.05},
    "median": {"abs": 0.05, "rel": 0.05},
    "p95": {"abs": 0.1, "rel": 0.1},
    "failure_rate": {"abs": 0.02, "rel": 0.0},
}

BASELINE_SCHEMA = "simtest.baseline"
BASELINE_VERSION = 1


def default_baseline_path() -> Path:
    """The committed baseline file, ``reports/baseline.json`` (:func:`simtest.resources.bundled`).

    Returns
    -------
    Path
        The path (the file may not exist yet).
    """
    return bundled("reports", "baseline.json")


@dataclass(frozen=True)
class Change:
    """One compared metric.

    Attributes
    ----------
    case : str
        Case id (``<sweep>@<x>``).
    label : str
        ``<sweep>[x=<x>]`` with x in display units.
    estimator : str
        Estimator name, ``"*"`` for a whole case that is new or missing.
    metric : str
        One of :data:`TRACKED` (degrees, or a fraction for ``failure_rate``), or ``"*"``.
    baseline, now : float or None
        Values in the baseline and in this run (None: the estimator never succeeded).
    tolerance : float or None
        ``abs + rel x |baseline|``, in the metric's unit; None where not compared.
    verdict : str
        ``"ok"``, ``"regression"``, ``"improved"``, ``"missing"`` or ``"new"``.
    """

    case: str
    label: str
    estimator: str
    metric: str
    baseline: float | None
    now: float | None
    tolerance: float | None
    verdict: str

    @property
    def name(self) -> str:
        """``<sweep>[x=<x>] <estimator> <metric>``: how messages name the metric."""
        return f"{self.label} {self.estimator} {self.metric}"


def tolerances_for(raw_suite: dict | None) -> dict:
    """Defaults updated with a suite file's ``[tolerances]`` table (validated).

    Parameters
    ----------
    raw_suite : dict or None
        The suite document as read (``Suite.raw``).

    Returns
    -------
    dict
        metric -> ``{"abs": float, "rel": float}`` for every metric of :data:`TRACKED`.

    Raises
    ------
    ValueError
        If the table names an untracked metric, a key other than abs/rel, or a negative or
        non-numeric value; the message names ``tolerances.<metric>.<key>``.
    """
    tol = {k: dict(v) for k, v in DEFAULT_TOLERANCES.items()}
    extra = (raw_suite or {}).get("tolerances", {}) or {}
    for metric, v in extra.items():
        if metric not in tol or not isinstance(v, dict) or set(v) - {"abs", "rel"}:
            raise ValueError(f"tolerances.{metric}: expected one of {TRACKED} with keys abs, rel")
        for k, x in v.items():
            if isinstance(x, bool) or not isinstance(x, (int, float)) or x < 0:
                raise ValueError(f"tolerances.{metric}.{k}: expected a number >= 0, got {x!r}")
        tol[metric].update({k: float(x) for k, x in v.items()})
    return tol


def baseline_entry(results: dict, tolerances: dict) -> dict:
    """The baseline section of one suite from its ``results.json`` document.

    Parameters
    ----------
    results : dict
        The run's ``results.json`` document.
    tolerances : dict
        As from :func:`tolerances_for`; stored with the section.

    Returns
    -------
    dict
        ``created_utc``, ``git_commit``, ``suite_sha256``, ``seed``, ``realisations``,
        ``tolerances`` and ``cases``: case id -> ``{"sweep", "x" (display units),
        "estimators": {name: {metric: value or None}}}``.
    """
    sweeps = {sw["name"]: sw for sw in results["sweeps"]}
    cases = {}
    for c in results["cases"]:
        sw = sweeps[c["sweep"]]
        cases[c["id"]] = {
            "sweep": c["sweep"],
            "x": c["x"] * sw["display_scale"],
            "estimators": {e: {m: v.get(m) for m in TRACKED}
                           for e, v in c["metrics"]["estimators"].items()},
        }
    prov = results["provenance"]
    return {"created_utc": results["created_utc"], "git_commit": prov.get("git_commit"),
            "suite_sha256": results["suite"]["sha256"], "seed": results["suite"]["seed"],
            "realisations": results["suite"]["realisations"], "tolerances": tolerances,
            "cases": cases}


def load_baseline(path: str | Path) -> dict:
    """Read a baseline file.

    Parameters
    ----------
    path : str or Path
        The baseline JSON.

    Returns
    -------
    dict
        ``{"schema", "schema_version", "suites": {name: section}}``.

    Raises
    ------
    ValueError
        If the file cannot be read, is not JSON, or has another schema; the message names it.
    """
    path = Path(path)
    try:
        d = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as e:
        raise ValueError(f"{path}: cannot read the baseline: {e}") from None
    if d.get("schema") != BASELINE_SCHEMA or d.get("schema_version") != BASELINE_VERSION:
        raise ValueError(f"{path}: schema: expected {BASELINE_SCHEMA} v{BASELINE_VERSION}, got "
                         f"{d.get('schema')} v{d.get('schema_version')}")
    return d


def update_baseline(path: str | Path, results: dict, tolerances: dict) -> Path:
    """Write (or replace) the section of ``results``' suite in the baseline file, atomically.

    Parameters
    ----------
    path : str or Path
        The baseline file (created if missing; other suites' sections are kept).
    results : dict
        The run's ``results.json`` document.
    tolerances : dict
        As from :func:`tolerances_for`.

    Returns
    -------
    Path
        ``path``.

    Raises
    ------
    ValueError
        If an existing file at ``path`` is not a baseline.
    """
    from simtest._io import atomic_write_json

    path = Path(path)
    d = load_baseline(path) if path.is_file() else {"schema": BASELINE_SCHEMA,
                                                     "schema_version": BASELINE_VERSION,
                                                     "suites": {}}
    d["suites"][results["suite"]["name"]] = baseline_entry(results, tolerances)
    return atomic_write_json(path, d, sort_keys=True)


def compare(base: dict, results: dict, tolerances: dict) -> list[Change]:
    """Compare a run's results with one suite's baseline section.

    Parameters
    ----------
    base : dict
        ``baseline["suites"][suite]``.
    results : dict
        The run's ``results.json`` document.
    tolerances : dict
        metric -> {"abs", "rel"}.

    Returns
    -------
    list of Change
        Every tracked metric of every case and estimator in either.
    """
    now = baseline_entry(results, tolerances)["cases"]
    out: list[Change] = []
    for key in sorted(set(base["cases"]) | set(now)):
        b, n = base["cases"].get(key), now.get(key)
        ref = b or n
        label = f"{ref['sweep']}[x={ref['x']:g}]"
        if b is None:
            out.append(Change(key, label, "*", "*", None, None, None, "new"))
            continue
        if n is None:
            out.append(Change(key, label, "*", "*", None, None, None, "missing"))
            continue
        for est in sorted(set(b["estimators"]) | set(n["estimators"])):
            be, ne = b["estimators"].get(est), n["estimators"].get(est)
            if be is None:
                out.append(Change(key, label, est, "*", None, None, None, "new"))
                continue
            if ne is None:
                out.append(Change(key, label, est, "*", None, None, None, "missing"))
                continue
            for m in TRACKED:
                bv, nv = be.get(m), ne.get(m)
                t = tolerances[m]
                if bv is None and nv is None:
                    verdict, tol = "ok", None
                elif bv is None:
                    verdict, tol = "improved", None  # never succeeded before, does now
                elif nv is None:
                    verdict, tol = "regression", None  # succeeded before, never now
                else:
                    tol = t["abs"] + t["rel"] * abs(bv)
                    d = nv - bv
                    verdict = "regression" if d > tol else "improved" if -d > tol else "ok"
                out.append(Change(key, label, est, m, bv, nv, tol, verdict))
    return out


def changes_table(changes: list[Change], title: str, show_all: bool = False):
    """A rich Table of the changes that moved (all of them with ``show_all``).

    Parameters
    ----------
    changes : list of Change
        From :func:`compare`.
    title : str
        Table title.
    show_all : bool
        Also list ``"ok"`` rows.

    Returns
    -------
    rich.table.Table
        One row per change: verdict (coloured), case label, estimator, metric, baseline, now,
        delta and tolerance (4 significant digits; degrees, or a fraction for failure_rate).
    """
    from rich.table import Table

    t = Table(title=title, show_lines=False)
    for col in ("verdict", "case", "estimator", "metric", "baseline", "now", "delta", "tolerance"):
        t.add_column(col, justify="right" if col in ("baseline", "now", "delta", "tolerance")
                     else "left")
    style = {"regression": "bold red", "missing": "bold red", "improved": "green", "new": "cyan",
             "ok": "dim"}

    def f(v):
        return "-" if v is None else f"{v:.4g}"

    for c in changes:
        if c.verdict == "ok" and not show_all:
            continue
        delta = None if c.baseline is None or c.now is None else c.now - c.baseline
        t.add_row(f"[{style[c.verdict]}]{c.verdict}[/]", c.label, c.estimator, c.metric,
                  f(c.baseline), f(c.now), "-" if delta is None else f"{delta:+.4g}", f(c.tolerance))
    return t
