"""Reports of a suite run: ``results.json`` (versioned schema), ``report.md``, ``report.html``.

Layout: ``<out>/<suite>/<run id>/`` holds ``results.json``, ``report.md``, a self-contained
``report.html`` (plots inlined as base64 PNG) and ``figures/*.png``. Every file is written to a
temporary name and renamed into place.

``results.json`` (schema :data:`SCHEMA`, version :data:`SCHEMA_VERSION`)::

    {"schema": "simtest.validation", "schema_version": 1, "run_id": ..., "created_utc": ...,
     "suite": {"name", "description", "source", "sha256", "seed", "realisations", "estimators"},
     "seeding": "...", "provenance": {"git_commit", "git_dirty", "packages", "mitsuba_variants",
        "python", "machine", "workers", "wall_time_s", "realisations_per_s"},
     "open_parameters": {name: {"value", "why"}},
     "sweeps": [{"name", "protocol", "parameter", "label", "display_scale", "cases": [case keys],
                 "paper": {...} | null, "comparison": [...]}],
     "cases": [{"id" (<sweep>@<x>), "key" (seeds the case), "sweep", "protocol", "scene", "params", "x", "realisations",
                "metrics": {"estimators": {name: {n, n_ok, failure_rate, failures, mean, std,
                                                   median, p95, min, max}},
                            "diagnostics": {...}},
                "exceptions": [...]}]}

Angles in degrees. The numbers under ``cases`` depend only on the suite and the seed, never on the
number of workers; provenance (times, machine) of course differs between runs.
"""

from __future__ import annotations

import base64
import datetime as _dt
import html
import io
import json
import os
import platform
import subprocess
from pathlib import Path

import numpy as np

from simtest._io import atomic_write_bytes, atomic_write_json
from simtest.harness.metrics import case_metrics

__all__ = ["SCHEMA", "SCHEMA_VERSION", "PAPER_CHECKS", "build_results", "write_report",
           "provenance", "evaluate_paper_claim", "make_run_id"]

SCHEMA = "simtest.validation"
SCHEMA_VERSION = 1

SEEDING = ("realisation i of a case draws from numpy SeedSequence([root_seed, "
           "int.from_bytes(sha256(case_key)[:8], 'little'), i]); rendered cases take the render "
           "seed as the first 31-bit word of that sequence")

ESTIMATOR_TEXT = {
    "paper_oracle": "paper, closest of N+ and N- to the truth (oracle, as the paper reports)",
    "paper_selected": "paper, N+ or N- chosen without the truth (the one closer to the BP ray)",
    "cone_axis": "cone axis of C' (unique-sign eigenvector; as dam410/LightModel "
                 "vanishing_line_paper_co)",
    "joint_cone_axis": "joint cone axis of the nested isophotes",
    "bp_ray": "minus the viewing ray of the BP (baseline)",
}

COLOURS = {"paper_oracle": "#1f77b4", "paper_selected": "#9467bd", "cone_axis": "#d62728",
           "joint_cone_axis": "#ff7f0e", "bp_ray": "#7f7f7f"}


# ------------------------------------------------------------------------------------------------
# the paper's stated figures


def _series(sweep_cases: list[dict], estimator: str, stat: str = "mean"):
    xs, ys = [], []
    for c in sweep_cases:
        m = c["metrics"]["estimators"].get(estimator, {})
        v = m.get(stat)
        if v is not None:
            xs.append(c["x"])
            ys.append(v)
    return np.asarray(xs, float), np.asarray(ys, float)


def _chk_max_mean_below(cases, est, value):
    x, y = _series(cases, est)
    if not y.size:
        return None, "no successful realisation"
    i = int(np.argmax(y))
    return bool(y[i] < value), f"largest mean {y[i]:.3g} deg (at x = {x[i]:g})"


def _chk_max_max_below(cases, est, value):
    x, y = _series(cases, est, "max")
    if not y.size:
        return None, "no successful realisation"
    i = int(np.argmax(y))
    return bool(y[i] < value), f"largest single error {y[i]:.3g} deg (at x = {x[i]:g})"


def _chk_slope_in_range(cases, est, value):
    x, y = _series(cases, est)
    if y.size < 2:
        return None, "fewer than 2 points"
    slope = float(np.polyfit(x, y, 1)[0])
    lo, hi = value
    return bool(lo <= slope <= hi), f"least-squares slope of the mean {slope:.3g} deg per unit"


def _chk_argmin_in_range(cases, est, value):
    x, y = _series(cases, est)
    if not y.size:
        return None, "no successful realisation"
    i = int(np.argmin(y))
    lo, hi = value
    interior = 0 < i < y.size - 1
    return bool(lo <= x[i] <= hi and interior), \
        f"smallest mean {y[i]:.3g} deg at x = {x[i]:g} ({'interior' if interior else 'at an end'})"


def _chk_stable_up_to(cases, est, value):
    x, y = _series(cases, est)
    if not y.size:
        return None, "no successful realisation"
    base = y[np.argmin(x)]
    sel = x <= value
    worst = float(np.max(y[sel]))
    allowed = base + max(0.25, 0.5 * base)
    return bool(worst <= allowed), (f"mean {base:.3g} deg at x = {x.min():g}, at most {worst:.3g} "
                                    f"deg for x <= {value:g} (stable: within max(0.25 deg, 50 %))")


def _chk_increasing(cases, est, value):
    x, y = _series(cases, est)
    if y.size < 2:
        return None, "fewer than 2 points"
    rho = float(np.corrcoef(np.argsort(np.argsort(x)), np.argsort(np.argsort(y)))[0, 1])
    return bool(rho >= value), f"rank correlation of mean error with x {rho:.2f}"


#: Checks of a sweep against the paper's statement: name -> f(cases, estimator, value) ->
#: (holds or None, what we measured).
PAPER_CHECKS = {
    "max_mean_below": _chk_max_mean_below,
    "max_max_below": _chk_max_max_below,
    "slope_in_range": _chk_slope_in_range,
    "argmin_in_range": _chk_argmin_in_range,
    "stable_up_to": _chk_stable_up_to,
    "increasing": _chk_increasing,
}


def evaluate_paper_claim(paper: dict, sweep_cases: list[dict]) -> list[dict]:
    """Evaluate the checks of a sweep's ``[sweep.paper]`` table on its cases' metrics.

    Parameters
    ----------
    paper : dict
        The sweep's ``paper`` table: ``check`` (a key of :data:`PAPER_CHECKS` or a list of them),
        ``value`` (one per check; degrees for error bounds), optional ``estimator`` (default
        ``"paper_oracle"``).
    sweep_cases : list of dict
        The sweep's case documents of ``results.json`` (with ``metrics``), in sweep order.

    Returns
    -------
    list of dict
        ``{"check", "value", "estimator", "holds" (bool or None), "ours" (str)}`` per check;
        empty if the table has no ``check``. ``holds`` is None when the metrics cannot decide.

    Raises
    ------
    KeyError
        If a check name is not in :data:`PAPER_CHECKS` (suite validation refuses those first).
    """
    est = paper.get("estimator", "paper_oracle")
    out = []
    checks = paper.get("check")
    values = paper.get("value")
    if checks is None:
        return out
    if isinstance(checks, str):
        checks, values = [checks], [values]
    for chk, val in zip(checks, values):
        holds, ours = PAPER_CHECKS[chk](sweep_cases, est, val)
        out.append({"check": chk, "value": val, "estimator": est, "holds": holds, "ours": ours})
    return out


# ------------------------------------------------------------------------------------------------
# provenance


def _git(*args) -> str | None:
    root = Path(__file__).resolve().parents[2]
    try:
        r = subprocess.run(["git", *args], cwd=root, capture_output=True, text=True, timeout=10)
    except (OSError, subprocess.SubprocessError):
        return None
    return r.stdout.strip() if r.returncode == 0 else None


def _versions() -> dict:
    from importlib import metadata

    out = {}
    for name in ("simtest", "numpy", "scipy", "scikit-image", "opencv-python-headless", "mitsuba",
                 "drjit", "trimesh", "matplotlib", "rich", "typer"):
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            out[name] = None
    return out


def provenance(run) -> dict:
    """Git commit, package versions, Mitsuba variant(s), machine, workers, wall time, speed.

    Parameters
    ----------
    run : simtest.harness.runner.SuiteRun
        The finished run.

    Returns
    -------
    dict
        JSON-ready: ``git_commit``, ``git_dirty`` and ``git_dirty_files`` (None outside a git
        checkout), ``packages`` (version or None), ``mitsuba_variants``, ``python``, ``machine``,
        ``workers``, ``started_utc``, ``wall_time_s`` (seconds) and ``realisations_per_s`` per
        protocol (realisations per CPU-second x workers).
    """
    # reports/ holds outputs (earlier reports, the baseline), not code: a run that rewrites them is
    # still a run of the committed code.
    dirty = _git("status", "--porcelain", "--untracked-files=no", "--", ".", ":(exclude)reports")
    rates = {}
    for proto, n in run.realisations_by_protocol.items():
        cpu = run.cpu_s_by_protocol.get(proto, 0.0)
        rates[proto] = {
            "realisations": n,
            "cpu_s": round(cpu, 3),
            # per worker-second x workers: the rate this protocol runs at with this many workers
            "per_s": round(n / cpu * run.workers, 3) if cpu > 0 else None,
        }
    return {
        "git_commit": _git("rev-parse", "HEAD"),
        "git_dirty": None if dirty is None else bool(dirty),
        # tracked files modified against that commit (the code that ran is HEAD plus these)
        "git_dirty_files": None if dirty is None else sorted(
            ln.split(None, 1)[1] for ln in dirty.splitlines() if len(ln.split(None, 1)) == 2),
        "packages": _versions(),
        "mitsuba_variants": run.variants,
        "python": platform.python_version(),
        "machine": {"node": platform.node(), "platform": platform.platform(),
                    "processor": platform.processor() or platform.machine(),
                    "cpu_count": os.cpu_count()},
        "workers": run.workers,
        "started_utc": run.started_utc,
        "wall_time_s": round(run.wall_s, 3),
        "realisations_per_s": rates,
    }


def _open_parameters(suite) -> dict:
    """Parameters the paper leaves open, with the values this suite used."""
    paper_cases = [c for c in suite.cases if c.protocol == "paper"]
    out = {}
    if paper_cases:
        p = paper_cases[0].params

        def vals(name):
            return [json.loads(v) for v in sorted({json.dumps(c.params[name]) for c in paper_cases})]

        out["smoothing_px"] = {
            "value": vals("smoothing_px"),
            "why": "standard deviation of the Gaussian smoothing (cv2.GaussianBlur, +-4 sigma "
                   "kernel, reflected border); the paper does not give it"}
        out["camera_distance_px"] = {
            "value": vals("camera_distance_px"),
            "why": "distance D of the slanted camera to the BP (null: D = V_Z, the paper's "
                   "'camera to scene plane distance': at theta = 0 the camera is the viewer, and "
                   "the t = 0.1, n = 50 isophote is a circle of about 62 px radius); sets the "
                   "ellipse size in pixels, which the paper does not give"}
        out["texture"] = {"value": p.get("texture_px") or p.get("image_px"),
                          "why": "texture is M x M (paper), bilinear warp, zero outside"}
        out["noise"] = {"value": "additive N(0, sigma^2), float, no clipping or quantisation",
                        "why": "the paper states white Gaussian noise of variance sigma^2 only"}
        out["normalisation"] = {"value": "smoothed intensity at the true BP pixel",
                                "why": "the paper says 'intensity at the BP is 1'"}
        out["roi"] = {"value": "bounding box of the noiseless image above t_min / 2, + 10 px",
                      "why": "the paper uses 'a given region of interest containing the "
                             "specularity' without its size"}
        out["joint_isovalues"] = {"value": vals("joint_isovalues"),
                                  "why": "beyond the paper: nested isovalues of the joint axis"}
        out["statistics"] = {"value": "std with ddof = 0; p95 by linear interpolation",
                             "why": "the paper gives mean, std and min-max bars"}
    return out


def make_run_id(suffix: str = "local") -> str:
    """A run id from the current UTC time.

    Parameters
    ----------
    suffix : str
        Appended after a dash (``-local`` runs are ignored by git); empty for none.

    Returns
    -------
    str
        ``YYYYmmddTHHMMSSZ-<suffix>``.
    """
    now = _dt.datetime.now(_dt.timezone.utc).strftime("%Y%m%dT%H%M%SZ")
    return f"{now}-{suffix}" if suffix else now


def build_results(run, run_id: str) -> dict:
    """The ``results.json`` document of a suite run (schema in the module docstring).

    Parameters
    ----------
    run : simtest.harness.runner.SuiteRun
        The finished run.
    run_id : str
        Id written in the document (see :func:`make_run_id`).

    Returns
    -------
    dict
        JSON-ready document (angles in degrees); the ``cases`` numbers depend only on the suite
        and its seed.
    """
    suite = run.suite
    cases = []
    for r in run.results:
        d = r.case.to_dict()
        d["metrics"] = case_metrics(r)
        d["samples"] = int(r.realisation.size)
        d["exceptions"] = list(r.exceptions)
        cases.append(d)
    sweeps = []
    for sw in suite.sweeps:
        sc = [c for c in cases if c["sweep"] == sw.name]
        entry = {"name": sw.name, "protocol": sw.protocol, "parameter": sw.parameter,
                 "label": sw.label, "display_scale": sw.display_scale,
                 "description": sw.description,
                 "cases": [c["id"] for c in sc], "paper": sw.paper, "comparison": []}
        if sw.paper:
            entry["comparison"] = evaluate_paper_claim(sw.paper, sc)
        sweeps.append(entry)
    return {
        "schema": SCHEMA,
        "schema_version": SCHEMA_VERSION,
        "run_id": run_id,
        "created_utc": _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ"),
        "suite": {"name": suite.name, "description": suite.description,
                  "source": _relative(suite.source), "sha256": suite.sha256, "seed": suite.seed,
                  "realisations": suite.realisations, "estimators": list(suite.estimators)},
        "seeding": SEEDING,
        "estimators": {k: ESTIMATOR_TEXT[k] for k in suite.estimators},
        "provenance": provenance(run),
        "open_parameters": _open_parameters(suite),
        "sweeps": sweeps,
        "cases": cases,
    }


def _relative(path: str) -> str:
    try:
        return str(Path(path).resolve().relative_to(Path(__file__).resolve().parents[2]))
    except ValueError:
        return str(path)


# ------------------------------------------------------------------------------------------------
# writing


def _fig_png(fig) -> bytes:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=100, bbox_inches="tight")
    return buf.getvalue()


def _plots(results: dict) -> dict[str, bytes]:
    """Figure-3-style bar plots and error curves per sweep -> {file name: PNG bytes}."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    cases = {c["id"]: c for c in results["cases"]}
    ests = results["suite"]["estimators"]
    out = {}
    for sw in results["sweeps"]:
        sc = [cases[k] for k in sw["cases"]]
        if not sc:
            continue
        scale = sw["display_scale"]
        xs = np.array([c["x"] for c in sc]) * scale
        # (1) the paper's figure 3 style: mean bars, black std bars, cyan [mean-min, max-mean].
        fig, axes = plt.subplots(1, len(ests), figsize=(3.1 * len(ests), 2.8), squeeze=False)
        width = 0.6 * (np.min(np.diff(np.unique(xs))) if np.unique(xs).size > 1 else 1.0)
        for ax, est in zip(axes[0], ests):
            ms = [c["metrics"]["estimators"][est] for c in sc]
            ok = np.array([m["mean"] is not None for m in ms])
            mean = np.array([m["mean"] if m["mean"] is not None else np.nan for m in ms])
            std = np.array([m["std"] if m["std"] is not None else np.nan for m in ms])
            mn = np.array([m["min"] if m["min"] is not None else np.nan for m in ms])
            mx = np.array([m["max"] if m["max"] is not None else np.nan for m in ms])
            ax.bar(xs[ok], mean[ok], width=width, color=COLOURS.get(est, "C0"), alpha=0.8)
            ax.errorbar(xs[ok], mean[ok], yerr=np.clip([mean[ok] - mn[ok], mx[ok] - mean[ok]], 0, None), fmt="none",
                        ecolor="c", elinewidth=4, alpha=0.6, capsize=0)
            ax.errorbar(xs[ok], mean[ok], yerr=std[ok], fmt="none", ecolor="k", elinewidth=1.2,
                        capsize=3)
            ax.set_title(est, fontsize=9)
            ax.set_xlabel(sw["label"], fontsize=8)
            ax.tick_params(labelsize=7)
        axes[0][0].set_ylabel("normal error (deg)", fontsize=8)
        fig.suptitle(f"{sw['name']}: mean (bars), std (black), [min, max] (cyan)", fontsize=9, y=1.04)
        out[f"{sw['name']}_bars.png"] = _fig_png(fig)
        plt.close(fig)
        # (2) curves: mean and median vs the parameter, one line per estimator, log scale.
        fig, ax = plt.subplots(figsize=(5.2, 3.4))
        floor = 1e-4  # log axis: errors below (exact zeros of bp_ray) are drawn at the floor
        any_fail = False
        for est in ests:
            ms = [c["metrics"]["estimators"][est] for c in sc]
            mean = np.array([m["mean"] if m["mean"] is not None else np.nan for m in ms])
            med = np.array([m["median"] if m["median"] is not None else np.nan for m in ms])
            fr = np.array([m["failure_rate"] for m in ms])
            mean, med = np.maximum(mean, floor), np.maximum(med, floor)
            ax.plot(xs, mean, "o-", color=COLOURS.get(est), label=est, ms=3)
            ax.plot(xs, med, ":", color=COLOURS.get(est), lw=1)
            bad = fr > 0
            if bad.any():
                any_fail = True
                ax.plot(xs[bad], mean[bad], "x", color="k", ms=6)
        ax.set_yscale("log")
        ax.set_xlabel(sw["label"])
        ax.set_ylabel("error (deg): mean -, median ..")
        ax.set_title(sw["name"] + (" (x: some realisations failed)" if any_fail else "")
                     + f"; floor {floor:g} deg", fontsize=9)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=7)
        out[f"{sw['name']}_curves.png"] = _fig_png(fig)
        plt.close(fig)
    # (3) error against dimensionless curvature (rendered cases): case means, log-log.
    rc = [c for c in results["cases"]
          if (c["metrics"]["diagnostics"].get("r_k1") or 0) > 0]
    if rc:
        from matplotlib.ticker import NullFormatter

        fig, axes = plt.subplots(1, 2, figsize=(10, 3.6))
        for ax, key, lab in ((axes[0], "anisotropy", "r |k1 - k2| (isophote radius x anisotropy)"),
                             (axes[1], "r_k1", "r k1 (isophote radius x largest curvature)")):
            for est in ests:
                pts = [(c["metrics"]["diagnostics"].get(key), c["metrics"]["estimators"][est]["mean"])
                       for c in rc]
                pts = [(x, y) for x, y in pts if x is not None and y is not None and x > 0]
                if pts:
                    x, y = np.array(pts).T
                    ax.scatter(x, np.maximum(y, 1e-4), s=12, color=COLOURS.get(est), label=est)
            ax.set_xscale("log")
            ax.set_yscale("log")
            ax.xaxis.set_minor_formatter(NullFormatter())
            ax.set_xlabel(lab, fontsize=8)
            ax.grid(True, which="both", alpha=0.3)
        axes[0].set_ylabel("mean error per case (deg)")
        axes[0].legend(fontsize=7)
        fig.suptitle("Rendered curved cases: error against dimensionless curvature (DESIGN.md 1.4)",
                     fontsize=9)
        out["curvature_scatter.png"] = _fig_png(fig)
        plt.close(fig)
    return out


def _fmt(v, nd=3):
    if v is None:
        return "-"
    if isinstance(v, float):
        return f"{v:.{nd}g}"
    return str(v)


def _md(results: dict, figures: list[str]) -> str:
    s = results["suite"]
    p = results["provenance"]
    cases = {c["id"]: c for c in results["cases"]}
    L = [f"# Validation report: {s['name']}", ""]
    if s["description"]:
        L += [s["description"], ""]
    L += [f"- run id: `{results['run_id']}` ({results['created_utc']}), suite file "
          f"`{s['source']}` (sha256 {s['sha256'][:12]})",
          f"- git commit `{p['git_commit']}`"
          + (f" plus uncommitted changes to {', '.join(p.get('git_dirty_files') or [])}"
             if p["git_dirty"] else "") + ", "
          + 
          f"Mitsuba variant(s): {', '.join(p['mitsuba_variants']) or 'none (no render)'}",
          f"- machine: {p['machine']['platform']}, {p['machine']['cpu_count']} CPUs; "
          f"{p['workers']} worker(s), wall time {p['wall_time_s']:.1f} s",
          "- speed: " + "; ".join(f"{k}: {v['realisations']} realisations, "
                                  f"{_fmt(v['per_s'])} realisations/s"
                                  for k, v in p["realisations_per_s"].items()),
          f"- root seed {s['seed']}; {results['seeding']}",
          "- errors: angle between the estimated and true normals, atan2(|a x b|, a . b), "
          "degrees; statistics over the realisations where the estimator succeeded, failures "
          "counted by cause", ""]
    L += ["## Estimators", ""] + [f"- `{k}`: {v}" for k, v in results["estimators"].items()] + [""]
    comp = [sw for sw in results["sweeps"] if sw.get("paper")]
    if comp:
        L += ["## The paper's figures beside ours", "",
              "| sweep | paper (figure 3) | ours | holds | note |", "|---|---|---|---|---|"]
        for sw in comp:
            ours = "; ".join(c["ours"] for c in sw["comparison"]) or "-"
            holds = ", ".join({True: "yes", False: "no", None: "n/a"}[c["holds"]]
                              for c in sw["comparison"]) or "-"
            note = sw["paper"].get("note", "").replace("\n", " ")
            L.append(f"| {sw['name']} | {sw['paper'].get('claim', '')} | {ours} | {holds} | "
                     f"{note} |")
        L.append("")
    if "curvature_scatter.png" in figures:
        L += ["## Error against dimensionless curvature", "",
              "Each point is one rendered case with curvature at the BP (mean over its "
              "highlights): the isophote radius r on the surface (estimated from the fitted "
              "ellipse) times the anisotropy |k1 - k2| or the largest curvature k1. DESIGN.md 1.4 "
              "predicts the cone axis unbiased to second order while N+ and N- tilt as the "
              "anisotropy grows.", "", "![curvature_scatter.png](figures/curvature_scatter.png)",
              ""]
    if results.get("open_parameters"):
        L += ["## Parameters the paper leaves open (our choices)", ""]
        for k, v in results["open_parameters"].items():
            L.append(f"- `{k}` = {json.dumps(v['value'])}: {v['why']}")
        L.append("")
    for sw in results["sweeps"]:
        L += [f"## Sweep `{sw['name']}` ({sw['protocol']}): {sw['label']}", ""]
        if sw.get("description"):
            L += [sw["description"], ""]
        ests = s["estimators"]
        L.append("| " + sw["label"] + " | " + " | ".join(ests) + " | failures |")
        L.append("|---" * (len(ests) + 2) + "|")
        for key in sw["cases"]:
            c = cases[key]
            cells = []
            fails = {}
            for e in ests:
                m = c["metrics"]["estimators"][e]
                cells.append("-" if m["mean"] is None else
                             f"{m['mean']:.3g} ± {m['std']:.2g} (med {m['median']:.3g}, "
                             f"p95 {m['p95']:.3g}, max {m['max']:.3g})")
                for cause, n in m["failures"].items():
                    fails[cause] = max(fails.get(cause, 0), n)
            n = c["metrics"]["estimators"][ests[0]]["n"]
            ftxt = ", ".join(f"{k}: {v}" for k, v in sorted(fails.items())) or "0"
            L.append(f"| {c['x'] * sw['display_scale']:g} | " + " | ".join(cells)
                     + f" | {ftxt} (n = {n}) |")
        L.append("")
        diag = [cases[k]["metrics"]["diagnostics"] for k in sw["cases"]]
        if any(diag):
            keys = sorted({k for d in diag for k in d})
            L.append("Diagnostics, means over the scored highlights (eigenvalue gap: 0 for a right "
                     "circular cone; pose_split_deg: angle between N+ and N-; anisotropy, r_k1, "
                     "r_k2: curvature times the isophote radius iso_radius_mm):")
            L.append("")
            L.append("| " + sw["label"] + " | " + " | ".join(keys) + " |")
            L.append("|---" * (len(keys) + 1) + "|")
            for key, d in zip(sw["cases"], diag):
                L.append(f"| {cases[key]['x'] * sw['display_scale']:g} | "
                         + " | ".join(_fmt(d.get(k)) for k in keys) + " |")
            L.append("")
        for f in figures:
            if f.startswith(sw["name"] + "_"):
                L.append(f"![{f}](figures/{f})")
        L.append("")
        exc = [(cases[k]["x"], e) for k in sw["cases"] for e in cases[k]["exceptions"]]
        if exc:
            L += ["Exceptions (first of each case):", ""] + [f"- x = {x:g}: `{e}`" for x, e in exc]
            L.append("")
    return "\n".join(L) + "\n"


_CSS = """body{font-family:system-ui,sans-serif;max-width:1200px;margin:2em auto;padding:0 1em;
color:#222}table{border-collapse:collapse;font-size:12px;margin:0.5em 0}td,th{border:1px solid
#ccc;padding:3px 6px;text-align:right}th{background:#f0f0f0}td:first-child{text-align:left}
code{background:#f5f5f5;padding:0 3px}img{max-width:100%}.no{color:#b00}.yes{color:#070}"""


def _md_to_html(md: str, images: dict[str, bytes]) -> str:
    """A small converter for the markdown this module writes (headings, lists, tables, images)."""
    out, table = [], []

    def inline(t: str) -> str:
        t = html.escape(t)
        parts = t.split("`")
        return "".join(f"<code>{p}</code>" if i % 2 else p for i, p in enumerate(parts))

    def flush():
        if table:
            rows = [r for r in table if not set(r.replace("|", "").strip()) <= set("-")]
            h = "".join(f"<th>{inline(c.strip())}</th>" for c in rows[0].strip("|").split("|"))
            body = "".join("<tr>" + "".join(f"<td>{inline(c.strip())}</td>"
                                            for c in r.strip().strip("|").split("|")) + "</tr>"
                           for r in rows[1:])
            out.append(f"<table><tr>{h}</tr>{body}</table>")
            table.clear()

    in_list = False
    for line in md.splitlines():
        if line.startswith("|"):
            table.append(line)
            continue
        flush()
        if in_list and not line.startswith("- "):
            out.append("</ul>")
            in_list = False
        if line.startswith("#"):
            n = len(line) - len(line.lstrip("#"))
            out.append(f"<h{n}>{inline(line[n:].strip())}</h{n}>")
        elif line.startswith("- "):
            if not in_list:
                out.append("<ul>")
                in_list = True
            out.append(f"<li>{inline(line[2:])}</li>")
        elif line.startswith("![") and "](figures/" in line:
            name = line.split("](figures/")[1].rstrip(")")
            b64 = base64.b64encode(images[name]).decode("ascii")
            out.append(f'<p><img alt="{html.escape(name)}" src="data:image/png;base64,{b64}"></p>')
        elif line.strip():
            out.append(f"<p>{inline(line)}</p>")
    flush()
    if in_list:
        out.append("</ul>")
    return ("<!DOCTYPE html><html><head><meta charset='utf-8'><title>simtest report</title>"
            f"<style>{_CSS}</style></head><body>" + "\n".join(out) + "</body></html>\n")


def write_report(run, out_dir: str | Path = "reports", run_id: str | None = None,
                 plots: bool = True) -> Path:
    """Write ``results.json``, ``report.md``, ``report.html`` and figures of a suite run.

    Parameters
    ----------
    run : SuiteRun
        The finished run.
    out_dir : path
        Reports root; the files go to ``<out_dir>/<suite name>/<run id>/``.
    run_id : str or None
        Default :func:`make_run_id` (``<UTC time>-local``, ignored by git).
    plots : bool
        Draw the figures (matplotlib, Agg).

    Returns
    -------
    Path
        The run folder.
    """
    run_id = run_id or make_run_id()
    folder = Path(out_dir) / run.suite.name / run_id
    results = build_results(run, run_id)
    figures = _plots(results) if plots else {}
    for name, png in figures.items():
        atomic_write_bytes(folder / "figures" / name, png)
    atomic_write_json(folder / "results.json", results, allow_nan=False)
    md = _md(results, sorted(figures))
    atomic_write_bytes(folder / "report.md", md.encode())
    atomic_write_bytes(folder / "report.html", _md_to_html(md, figures).encode())
    return folder
