"""Nightly accuracy gate: a fixed suite compared with ``reports/baseline.json``.

Metrics are named ``<scope>:<name>:<estimator>:<statistic>``: ``family:<family>:<estimator>:median|failure_rate``
and ``family:<family>:*:false_positives_per_image`` (the report's summary table; family medians are
the *headline* metrics) and ``case:<case id>:<estimator>:median|failure_rate``. Errors are in degrees,
rates are fractions; lower is better.

The baseline is made from ``repeats`` runs with root seeds ``seed, seed + 1, ...``: its value is the
run at the suite's own seed, its spread the sample standard deviation over the repeats, its tolerance
``min(k_spread x spread + rel_floor x |value| + abs_floor, cap)``. The caps (:data:`CAPS`): 0.4 deg on
headline metrics (a 0.5 deg bias fails), 10 deg on per-case medians, 0.1 on rates. A metric regresses
when it grows by more than its tolerance. Baselines with unusable entries are refused
(:func:`check_section`), and run metrics the baseline lacks are named (:func:`uncovered`): a gate
that cannot judge a metric is no pass. Noisy headline metrics (:func:`noisy_headlines`) call for more
realisations, never a larger cap (``docs/decisions/nightly-gate.md``).

Baseline file::

    {"schema": "simtest.baseline", "schema_version": 2,
     "suites": {"<suite>": {"created_utc", "git_commit", "machine", "suite_sha256", "seed",
                            "seeds", "realisations", "policy": {"k_spread", "rel_floor",
                            "abs_floor": {"deg", "rate"}},
                            "metrics": {name: {"value", "spread", "tolerance"}}}}}

:func:`append_history` adds one JSON line per nightly run to ``<reports>/<suite>/history.jsonl``.
"""

from __future__ import annotations

import fcntl
import json
import math
from collections import Counter
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from rich.table import Table

from simtest._io import atomic_write_json
from simtest.resources import bundled
from simtest.harness.report.results import case_family  # the reports' family rule

__all__ = ["POLICY", "CAPS", "Change", "metrics_of", "metric_class", "baseline_section",
           "check_section", "uncovered", "expected_metrics", "noisy_headlines", "compare",
           "gate_summary", "load_baseline", "update_baseline", "default_baseline_path",
           "history_line", "append_history", "read_history", "undetectable_doublings", "changes_table",
           "BASELINE_SCHEMA", "BASELINE_VERSION"]

BASELINE_SCHEMA = "simtest.baseline"
BASELINE_VERSION = 2

#: Default tolerance policy: k_spread standard deviations of seed noise; rel_floor 0.25, half the
#: doubling that must fail, leaves room for platform rounding; abs_floor for values near 0 (1e-6 deg,
#: one failure more in 50 for rates). The caps per :func:`metric_class` also bound any baseline.
CAPS = {"headline_deg": 0.4, "deg": 10.0, "rate": 0.1}
POLICY = {"k_spread": 3.0, "rel_floor": 0.25, "abs_floor": {"deg": 1e-6, "rate": 0.02}, "cap": dict(CAPS)}

#: Statistics gated, per case and per family: medians and failure rates (robust at a nightly's few
#: realisations).
_STATS = ("median", "failure_rate")


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
    metric : str
        ``<scope>:<name>:<estimator>:<statistic>``.
    baseline, now : float or None
        Value in the baseline and in this run (None: absent or never succeeded).
    tolerance : float or None
        Allowed growth in the metric's unit; None where not compared.
    verdict : str
        ``"ok"``, ``"regression"``, ``"improved"``, ``"missing"``, ``"new"`` or ``"invalid"``.
    """

    metric: str
    baseline: float | None
    now: float | None
    tolerance: float | None
    verdict: str


def _unit(metric: str) -> str:
    return "rate" if metric.endswith(("failure_rate", "false_positives_per_image")) else "deg"


def metric_class(metric: str) -> str:
    """The tolerance class of a metric: ``"headline_deg"``, ``"deg"`` or ``"rate"``.

    Parameters
    ----------
    metric : str
        ``<scope>:<name>:<estimator>:<statistic>``.

    Returns
    -------
    str
        ``"rate"`` for failure rates and false positives per image; ``"headline_deg"`` for a
        family median (an estimator's headline metric); ``"deg"`` for the other errors.
    """
    if _unit(metric) == "rate":
        return "rate"
    return "headline_deg" if metric.startswith("family:") and metric.endswith(":median") else "deg"


def metrics_of(results: dict) -> dict:
    """The gate's metrics of a ``results.json`` document.

    Parameters
    ----------
    results : dict
        A results document (schema 2, with ``families``).

    Returns
    -------
    dict of str to object
        Metric name -> value as found (float, None where an estimator never succeeded, or
        whatever the document holds: :func:`_bad` names the bad ones).
    """
    out = {}
    for fam, f in results.get("families", {}).items():
        for e, m in f["estimators"].items():
            for s in _STATS:
                out[f"family:{fam}:{e}:{s}"] = m.get(s)
        if f.get("false_positives_per_image") is not None:
            out[f"family:{fam}:*:false_positives_per_image"] = f["false_positives_per_image"]
    for c in results["cases"]:
        for e, m in c["metrics"]["estimators"].items():
            for s in _STATS:
                out[f"case:{c['id']}:{e}:{s}"] = m.get(s)
    return out


def _bad(v) -> str | None:
    """Why a stored value is not a usable number (None is allowed: 'never succeeded')."""
    if v is None:
        return None
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        return f"non-numeric {v!r}"
    if math.isnan(v):
        return "NaN"
    return "infinite" if math.isinf(v) else None


def baseline_section(runs: list[dict], policy: dict | None = None) -> dict:
    """The baseline section of one suite from repeated runs with different root seeds.

    Parameters
    ----------
    runs : list of dict
        ``results.json`` documents of the same suite; ``runs[0]`` gives the values, all of them the
        spread (with one run, spread 0).
    policy : dict, optional
        Default :data:`POLICY`.

    Returns
    -------
    dict
        ``created_utc``, ``git_commit``, ``machine``, ``suite_sha256``, ``seed``, ``seeds``,
        ``realisations``, ``policy`` and ``metrics``: name -> ``{"value", "spread", "tolerance"}``.

    Raises
    ------
    ValueError
        If ``runs`` is empty, a run holds a NaN, infinite or non-numeric metric, or the policy's caps
        exceed :data:`CAPS`.
    """
    if not runs:
        raise ValueError("baseline_section: no runs")
    pol = json.loads(json.dumps(policy or POLICY))
    pol.setdefault("cap", dict(CAPS))
    over = {k: v for k, v in pol["cap"].items() if not (0 <= v <= CAPS.get(k, -1))}
    if over:
        raise ValueError(f"baseline policy: cap {over} above the ceilings {CAPS}")
    per = [metrics_of(r) for r in runs]
    for r, m in zip(runs, per):
        bad = {k: _bad(v) for k, v in m.items() if _bad(v)}
        if bad:
            raise ValueError(f"run with seed {r['suite']['seed']}: {_name_list(bad)}")
    metrics = {}
    for name, v in per[0].items():
        vals = [m.get(name) for m in per]
        vals = [float(x) for x in vals if x is not None]
        spread = float(np.std(vals, ddof=1)) if len(vals) >= 2 else 0.0
        cap = pol.get("cap", CAPS)[metric_class(name)]
        tol = None if v is None else min(pol["k_spread"] * spread + pol["rel_floor"] * abs(v)
                                         + pol["abs_floor"][_unit(name)], cap)
        metrics[name] = {"value": None if v is None else float(v), "spread": spread, "tolerance": tol}
    prov = runs[0].get("provenance", {})
    mach = prov.get("machine", {})
    return {"created_utc": runs[0].get("created_utc"), "git_commit": prov.get("git_commit"),
            "git_dirty": prov.get("git_dirty"),
            "machine": f"{mach.get('platform', '?')}, {mach.get('cpu_count', '?')} CPUs",
            "suite_sha256": runs[0]["suite"]["sha256"], "seed": runs[0]["suite"]["seed"],
            "seeds": [r["suite"]["seed"] for r in runs],
            "realisations": runs[0]["suite"]["realisations"], "policy": pol, "metrics": metrics}


def _listed(names: list[str], limit: int = 8) -> str:
    """The first ``limit`` names, comma-separated, and how many more there are."""
    return ", ".join(names[:limit]) + (f" and {len(names) - limit} more" if len(names) > limit else "")


def _name_list(bad: dict) -> str:
    return f"{len(bad)} bad metric(s): " + _listed([f"{k} ({why})" for k, why in sorted(bad.items())])


def _never_succeeded(metrics: dict, name: str) -> bool:
    """Whether the baseline says the estimator of median ``name`` never succeeded there."""
    if not name.endswith(":median"):
        return False
    fr = metrics.get(name[: -len("median")] + "failure_rate")
    return isinstance(fr, dict) and fr.get("value") == 1.0


def check_section(section: dict, where: str) -> str | None:
    """One line naming every unusable entry of a baseline section, or None if it is sound.

    Unusable: a missing or empty ``metrics`` table; an entry without a value; a NaN, infinite or
    non-numeric value; a null value other than the median of an estimator with failure rate 1; a
    tolerance that is missing, non-finite, negative, below its unit's floor (:data:`POLICY`) or above
    its class's cap (:data:`CAPS`).

    Parameters
    ----------
    section : dict
        ``baseline["suites"][suite]``.
    where : str
        Prefix of the message (file and suite).

    Returns
    -------
    str or None
        ``"<where>: N bad metric(s): name (why), ..."``.
    """
    metrics = section.get("metrics") if isinstance(section, dict) else None
    if not isinstance(metrics, dict) or not metrics:
        return f"{where}: no metrics table (rewrite it with --update-baseline)"
    bad = {}
    for name, m in metrics.items():
        if not isinstance(m, dict) or "value" not in m:
            bad[name] = "missing value"
            continue
        why = _bad(m["value"])
        if why is None and m["value"] is None:
            if not _never_succeeded(metrics, name):
                why = ("null value (only the median of an estimator that never succeeded, failure rate 1, may be null)")
        elif why is None:
            t = m.get("tolerance")
            cap = CAPS[metric_class(name)]
            if t is None:
                why = "missing tolerance"
            elif _bad(t):
                why = f"tolerance {_bad(t)}"
            elif t < 0:
                why = f"negative tolerance {t:g}"
            elif t < POLICY["abs_floor"][_unit(name)] * (1 - 1e-9):
                why = (f"tolerance {t:g} below the floor {POLICY['abs_floor'][_unit(name)]:g} "
                       "(platform rounding alone would fail it)")
            elif t > cap * (1 + 1e-9):
                why = f"tolerance {t:g} above the ceiling {cap:g} of its class {metric_class(name)}"
        if why:
            bad[name] = why
    return f"{where}: {_name_list(bad)}" if bad else None


def uncovered(section: dict, names) -> list[str]:
    """The metrics among ``names`` that the baseline section has no entry for.

    Parameters
    ----------
    section : dict
        A baseline section (checked by :func:`check_section`).
    names : iterable of str
        The run's metrics (:func:`metrics_of`) or the suite's (:func:`expected_metrics`).

    Returns
    -------
    list of str
        Sorted; empty when the baseline covers them all.
    """
    have = section.get("metrics") or {}
    return sorted(n for n in set(names) if n not in have)


def expected_metrics(suite) -> set[str]:
    """The metrics a run of ``suite`` will have, known before it runs.

    Every case's and every family's median and failure rate per estimator (the families'
    false positives per image, present only where the protocol detects, are checked after the
    run), so that ``simtest nightly`` refuses a baseline that does not cover the suite before
    spending minutes on it.

    Parameters
    ----------
    suite : simtest.harness.suite.Suite
        The suite about to run.

    Returns
    -------
    set of str
        Metric names as :func:`metrics_of` writes them.
    """
    out = set()
    for c in suite.cases:
        fam = case_family(c)[0]
        for e in suite.estimators:
            for st in _STATS:
                out.update((f"case:{c.id}:{e}:{st}", f"family:{fam}:{e}:{st}"))
    return out


def noisy_headlines(section: dict) -> list[str]:
    """Headline metrics whose seed noise alone reaches their cap: a good run may fail on them.

    Parameters
    ----------
    section : dict
        A baseline section (with the measured ``spread`` of each metric).

    Returns
    -------
    list of str
        Names of the family medians with ``k_spread x spread >= cap``; the remedy is more
        realisations for the sweeps of that family, never a larger cap.
    """
    pol = section.get("policy", POLICY)
    k = pol.get("k_spread", POLICY["k_spread"])
    return sorted(n for n, m in section["metrics"].items()
                  if metric_class(n) == "headline_deg" and m.get("value") is not None
                  and k * (m.get("spread") or 0.0) >= CAPS["headline_deg"])


def compare(section: dict, results: dict) -> list[Change]:
    """Compare a run with one suite's baseline section (checked by :func:`check_section`).

    Parameters
    ----------
    section : dict
        ``baseline["suites"][suite]``.
    results : dict
        The run's ``results.json`` document.

    Returns
    -------
    list of Change
        One per metric of either, sorted by name. A NaN, infinite or non-numeric value in the
        run is ``"invalid"``; a metric of the baseline absent from the run ``"missing"``; a
        value that became None (never succeeds now) a ``"regression"``; a metric of the run that
        the baseline lacks ``"new"`` (:func:`gate_summary` refuses to pass it: see
        :func:`uncovered`).
    """
    now = metrics_of(results)
    base = section["metrics"]
    out = []
    for name in sorted(set(base) | set(now)):
        b = base.get(name)
        if b is None:
            out.append(Change(name, None, now[name] if not _bad(now[name]) else None, None,
                              "invalid" if _bad(now[name]) else "new"))
            continue
        if name not in now:
            out.append(Change(name, b["value"], None, None, "missing"))
            continue
        v, t, n = b["value"], b.get("tolerance"), now[name]
        if _bad(n):
            out.append(Change(name, v, None, t, "invalid"))
        elif v is None and n is None:
            out.append(Change(name, None, None, None, "ok"))
        elif v is None:
            out.append(Change(name, None, float(n), None, "improved"))  # succeeds now
        elif n is None:
            out.append(Change(name, v, None, t, "regression"))  # succeeded before, not now
        else:
            d = float(n) - v
            verdict = "regression" if d > t else "improved" if -d > t else "ok"
            out.append(Change(name, v, float(n), t, verdict))
    return out


def gate_summary(changes: list[Change]) -> tuple[bool, list[str], dict]:
    """Verdict, problem lines and counts of a comparison.

    Parameters
    ----------
    changes : list of Change
        From :func:`compare`.

    Returns
    -------
    (bool, list of str, dict)
        ``passed``; one line per problem (``REGRESSION: <metric>: <baseline> -> <now> (tolerance
        <t>)``, one ``INVALID:`` line naming every NaN, infinite or non-numeric metric of the
        run, one ``MISSING:`` line naming the metrics the run lacks, one ``UNCOVERED:`` line
        naming the run's metrics the baseline lacks); counts per verdict.
    """
    lines = [f"REGRESSION: {c.metric}: {_f(c.baseline)} -> {_f(c.now)} (tolerance "
             f"{_f(c.tolerance)})" for c in changes if c.verdict == "regression"]
    for verdict, what in (("invalid", "INVALID: {} NaN, infinite or non-numeric metric(s) in this run"),
                          ("missing", "MISSING: {} metric(s) of the baseline absent from this run"),
                          ("new", "UNCOVERED: {} metric(s) of this run absent from the baseline")):
        names = [c.metric for c in changes if c.verdict == verdict]
        if names:
            lines.append(what.format(len(names)) + ": " + _listed(names))
    return not lines, lines, dict(Counter(c.verdict for c in changes))


def _f(v) -> str:
    return "none" if v is None else f"{v:.4g}"


def undetectable_doublings(section: dict) -> list[str]:
    """Metrics whose tolerance is not below their value: doubling them would pass the gate.

    Parameters
    ----------
    section : dict
        A baseline section.

    Returns
    -------
    list of str
        Names of metrics with a positive value and ``tolerance >= value`` (too noisy for the
        suite's realisations, or exactly 0).
    """
    return sorted(k for k, m in section["metrics"].items()
                  if m["value"] is not None and m["value"] > 0 and m["tolerance"] >= m["value"])


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
        If the file cannot be read, is not JSON, or has another schema or version; the message
        names the file.
    """
    path = Path(path)
    try:
        d = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError, UnicodeDecodeError) as e:
        raise ValueError(f"{path}: cannot read the baseline: {e}") from None
    if not isinstance(d, dict) or d.get("schema") != BASELINE_SCHEMA \
            or d.get("schema_version") != BASELINE_VERSION or not isinstance(d.get("suites"), dict):
        got = (d.get("schema"), d.get("schema_version")) if isinstance(d, dict) else type(d)
        raise ValueError(f"{path}: schema: expected {BASELINE_SCHEMA} v{BASELINE_VERSION} with a "
                         f"suites table, got {got} (rewrite it with --update-baseline)")
    return d


def update_baseline(path: str | Path, runs: list[dict]) -> Path:
    """Write (or replace) the section of the runs' suite in the baseline file, atomically.

    Parameters
    ----------
    path : str or Path
        The baseline file (created if missing; other suites' sections are kept; a file of an
        older schema is replaced).
    runs : list of dict
        As for :func:`baseline_section` (with the default :data:`POLICY`).

    Returns
    -------
    Path
        ``path``.
    """
    path = Path(path)
    try:
        d = load_baseline(path)
    except ValueError:
        d = {"schema": BASELINE_SCHEMA, "schema_version": BASELINE_VERSION, "suites": {}}
    d["suites"][runs[0]["suite"]["name"]] = baseline_section(runs)
    return atomic_write_json(path, d, sort_keys=True, allow_nan=False)


def history_line(results: dict, passed: bool, counts: dict) -> dict:
    """One line of the nightly history.

    Parameters
    ----------
    results : dict
        The run's results document.
    passed : bool
        The gate's verdict.
    counts : dict
        Verdict counts of :func:`gate_summary`.

    Returns
    -------
    dict
        ``run_id``, ``created_utc``, ``git_commit``, ``suite``, ``seed``, ``verdict``
        (``"pass"`` or ``"fail"``), ``counts``, ``families``: {family: {estimator: median
        error in degrees or None}} and ``n``: {family: {estimator: highlights it succeeded on}}
        (the trend figure shows it).
    """
    return {"run_id": results["run_id"], "created_utc": results["created_utc"],
            "git_commit": results["provenance"].get("git_commit"),
            "suite": results["suite"]["name"], "seed": results["suite"]["seed"],
            "verdict": "pass" if passed else "fail", "counts": counts,
            "families": {fam: {e: m.get("median") for e, m in f["estimators"].items()}
                         for fam, f in results.get("families", {}).items()},
            "n": {fam: {e: m.get("n_ok") for e, m in f["estimators"].items()}
                  for fam, f in results.get("families", {}).items()}}


def append_history(path: str | Path, line: dict) -> Path:
    """Append one JSON line to a history file, under an exclusive lock.

    Parameters
    ----------
    path : str or Path
        ``history.jsonl`` (created with its folder if missing).
    line : dict
        From :func:`history_line`.

    Returns
    -------
    Path
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "a", encoding="utf-8") as fh:
        fcntl.flock(fh, fcntl.LOCK_EX)  # released when the file closes, after the line is flushed
        fh.write(json.dumps(line, sort_keys=True, allow_nan=False) + "\n")
    return path


def read_history(path: str | Path) -> list[dict]:
    """The last 60 lines of a history file (oldest first); unreadable lines are skipped.

    Parameters
    ----------
    path : str or Path
        ``history.jsonl``; a missing file gives an empty list.

    Returns
    -------
    list of dict
    """
    path = Path(path)
    if not path.is_file():
        return []
    out = []
    for ln in path.read_text(encoding="utf-8").splitlines():
        try:
            d = json.loads(ln)
        except json.JSONDecodeError:
            continue
        if isinstance(d, dict):
            out.append(d)
    return out[-60:]


def changes_table(changes: list[Change], title: str, show_all: bool = False):
    """A rich Table of the metrics that moved (all of them with ``show_all``).

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
        Verdict (coloured), metric, baseline, now, delta, tolerance (4 significant digits).
    """
    t = Table(title=title, show_lines=False)
    for col in ("verdict", "metric", "baseline", "now", "delta", "tolerance"):
        # at 80 columns only the metric's name folds: headers and numbers stay whole
        t.add_column(col, justify="right" if col in ("baseline", "now", "delta", "tolerance")
                     else "left", overflow="fold", no_wrap=col != "metric")
    style = {"regression": "bold red", "missing": "bold red", "invalid": "bold red",
             "improved": "green", "new": "cyan", "ok": "dim"}
    for c in changes:
        if c.verdict == "ok" and not show_all:
            continue
        delta = None if c.baseline is None or c.now is None else c.now - c.baseline
        t.add_row(f"[{style[c.verdict]}]{c.verdict}[/]", c.metric, _f(c.baseline), _f(c.now),
                  "-" if delta is None else f"{delta:+.4g}", _f(c.tolerance))
    return t
