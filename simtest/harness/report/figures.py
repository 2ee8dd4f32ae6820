"""Report figures (matplotlib, Agg): per-sweep error curves, figure-3 bars, rho, nightly trend.

Each axis is labelled with its unit, each estimator has its own colour, marker, size and fill,
points sit at their true values, every statistic names its n, and no interval is drawn from fewer
than :data:`MIN_N_INTERVAL` values. :func:`takeaways` gives one sentence per figure.
"""

from __future__ import annotations

import io
import itertools
from collections import Counter

import matplotlib
import numpy as np

matplotlib.use("Agg", force=False)

import matplotlib.pyplot as plt  # noqa: E402 - after choosing the back-end
from matplotlib.ticker import FixedLocator, NullFormatter  # noqa: E402

from simtest.harness.claims import BEST_LEVEL, MIN_N_INTERVAL, _unique, best_marks  # noqa: E402
from simtest.harness.report.numbers import fmt  # noqa: E402

__all__ = ["make_figures", "figure_png", "style", "trend_figure", "takeaways", "x_scale", "MIN_N_INTERVAL"]

_STYLE = {"paper_oracle": ("#1f77b4", "o"), "paper_selected": ("#9467bd", "s"),
          "cone_axis": ("#d62728", "^"), "joint_cone_axis": ("#ff7f0e", "v"),
          "bp_ray": ("#555555", "D")}
_EXTRA_COLOURS = ("#2ca02c", "#17becf", "#8c564b", "#e377c2", "#bcbd22", "#7f7f7f")
_EXTRA_MARKERS = ("P", "X", "h", "*", "<", ">")

#: Errors below this (degrees) are drawn at it on log axes.
FLOOR_DEG = 1e-4

_FAMILY_MARKERS = ("o", "s", "^", "v", "D", "P", "X", "h", "*", "<", ">")


def style(estimator: str, order: list[str] | None = None) -> tuple[str, str]:
    """Colour and marker of an estimator (fixed for the known ones, cycled for new ones).

    Parameters
    ----------
    estimator : str
        Estimator name.
    order : list of str, optional
        The suite's estimators, to give new names a stable place in the cycle.

    Returns
    -------
    (str, str)
        Matplotlib colour and marker.
    """
    if estimator in _STYLE:
        return _STYLE[estimator]
    extra = [e for e in (order or [estimator]) if e not in _STYLE]
    i = extra.index(estimator) if estimator in extra else 0
    return _EXTRA_COLOURS[i % len(_EXTRA_COLOURS)], _EXTRA_MARKERS[i % len(_EXTRA_MARKERS)]


def figure_png(fig) -> bytes:
    """PNG bytes of a figure as laid out (no tight-bbox cropping: what is checked is saved); the
    figure is closed (pyplot keeps every open figure).

    Parameters
    ----------
    fig : matplotlib.figure.Figure

    Returns
    -------
    bytes
    """
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=100)
    plt.close(fig)
    return buf.getvalue()


def _val(m: dict, k: str) -> float:
    v = m.get(k) if m else None
    return np.nan if v is None else float(v)


def _n_text(ns) -> str:
    """``"n 20"`` or ``"n 5 to 15"`` from the n of the points drawn (``"n 0"`` for none)."""
    ns = [int(v) for v in ns if v is not None]
    if not ns:
        return "n 0"
    lo, hi = min(ns), max(ns)
    return f"n {lo}" if lo == hi else f"n {lo} to {hi}"


def x_scale(xs) -> tuple[str, float | None]:
    """The scale of a numeric sweep axis: linear, or logarithmic where its settings are geometric.

    Parameters
    ----------
    xs : array_like
        The settings in display units.

    Returns
    -------
    (str, float or None)
        ``("log", None)`` for three or more positive settings spanning a factor of 8 or more
        whose gaps are more even in log than in linear; ``("symlog", t)`` for such settings
        spanning a factor of 20 or more, plus 0 (linear within ``t``, the smallest positive
        setting: a narrower span reads better on a linear axis than with a linear stretch
        around 0); ``("linear", None)`` otherwise.
    """
    x = np.unique(np.asarray(xs, dtype=np.float64))
    x = x[np.isfinite(x)]
    pos = x[x > 0]
    zero = pos.size < x.size
    if (x < 0).any() or pos.size < 3 or pos.max() / pos.min() < (20 if zero else 8):
        return "linear", None

    def unevenness(v):
        g = np.diff(v)
        return float(g.std() / g.mean())

    if unevenness(np.log(pos)) >= unevenness(x):
        return "linear", None
    return ("symlog", float(pos.min())) if zero else ("log", None)


def _set_x_scale(ax, xs) -> None:
    """Scale of a sweep axis (:func:`x_scale`), before anything is drawn (margins follow it)."""
    kind, t = x_scale(xs)
    if kind == "log":
        ax.set_xscale("log")
    elif kind == "symlog":
        ax.set_xscale("symlog", linthresh=t, linscale=0.5)
        hi = float(np.nanmax(xs))
        decades = 10.0 ** np.arange(np.ceil(np.log10(t)), np.floor(np.log10(hi)) + 1)
        ax.xaxis.set_major_locator(FixedLocator([0.0, *decades]))
    if kind != "linear":
        ax.xaxis.set_minor_formatter(NullFormatter())
    ax.grid(True, which="major", alpha=0.3)
    # 5 % of the axis beyond the extreme settings, in the scale's own units
    v = np.asarray(xs, dtype=np.float64)
    v = v[np.isfinite(v)]
    if v.size:
        tr = ax.xaxis.get_transform()
        lo, hi = tr.transform(np.array([[v.min()], [v.max()]]))[:, 0]
        pad = 0.05 * (hi - lo) if hi > lo else 0.5
        ax.set_xlim(*tr.inverted().transform(np.array([[lo - pad], [hi + pad]]))[:, 0])


def _log_y(ax) -> None:
    ax.set_yscale("log")
    ax.yaxis.set_minor_formatter(NullFormatter())
    ax.grid(True, which="major", alpha=0.3)


def _sweep_x(sw: dict, sc: list[dict]) -> np.ndarray:
    return np.array([float(c["x"]) * float(sw["display_scale"]) for c in sc])


def _curves(sw: dict, sc: list[dict], ests: list[str]):
    """Median error against the setting, every point at its true x (a numeric axis)."""
    x = _sweep_x(sw, sc)
    order = np.argsort(x, kind="stable")
    x = x[order]
    sc = [sc[i] for i in order]
    fails = {e: np.array([_val(c["metrics"]["estimators"].get(e, {}), "failure_rate") for c in sc]) for e in ests}
    any_fail = any(np.nansum(f) > 0 for f in fails.values())
    if any_fail:
        fig, (ax, axf) = plt.subplots(2, 1, figsize=(7.0, 5.6), layout="constrained", height_ratios=(3, 1), sharex=True)
    else:
        fig, ax = plt.subplots(figsize=(7.0, 4.4), layout="constrained")
        axf = None
    _set_x_scale(ax, x)
    for k, e in enumerate(ests):
        col, mk = style(e, ests)
        # size 9 down to 4 points, fill alternating
        size, mfc = 9.0 - 5.0 * k / max(len(ests) - 1, 1), col if k % 2 == 0 else "white"
        ms = [c["metrics"]["estimators"].get(e, {}) for c in sc]
        med, lo, hi = (np.array([_val(m, k) for m in ms]) for k in ("median", "p5", "p95"))
        n_ok = np.array([int(m.get("n_ok", 0) or 0) if m else 0 for m in ms])
        med_f, lo_f, hi_f = (np.maximum(v, FLOOR_DEG) for v in (med, lo, hi))
        ok = np.isfinite(med)
        (line,) = ax.plot(x[ok], med_f[ok], mk + "-", color=col, ms=size, lw=1, mfc=mfc,
                          alpha=0.85, label=f"{e} ({_n_text(n_ok[ok])})", zorder=3 + k)
        line.set_gid(f"series:{e}")
        bar = ok & (n_ok >= MIN_N_INTERVAL)
        if bar.any():
            ax.errorbar(x[bar], med_f[bar], yerr=[np.clip(med_f[bar] - lo_f[bar], 0, None),
                                                  np.clip(hi_f[bar] - med_f[bar], 0, None)],
                        fmt="none", ecolor=col, elinewidth=1, capsize=2, alpha=0.5, zorder=2 + k)
        if axf is not None:
            n_all = np.array([int(m.get("n", 0) or 0) if m else 0 for m in ms])
            has = n_all > 0
            (fl,) = axf.plot(x[has], 100 * fails[e][has], mk, color=col, ms=size * 0.7,
                             mfc=mfc, alpha=0.85, ls="none", zorder=3 + k)
            fl.set_gid(f"failures:{e}")
    _log_y(ax)
    ax.set_ylabel(f"normal error (deg)\nmedian, bar p5 to p95\n(bar where n >= {MIN_N_INTERVAL})")
    ax.set_title(f"{sw['name']} ({sw['protocol']} protocol); errors below {FLOOR_DEG:g} deg drawn at it", fontsize=9)
    bottom = axf if axf is not None else ax
    if axf is not None:
        n_all = [int(c["metrics"]["estimators"].get(e, {}).get("n", 0) or 0) for c in sc for e in ests]
        axf.set_ylabel(f"failures\n(% of {_n_text(n_all)})")
        axf.set_ylim(-5, 105)
        ax.tick_params(axis="x", labelbottom=False)
    bottom.set_xlabel(sw["label"])
    longest = max((len(t) for t in ax.get_legend_handles_labels()[1]), default=0)
    fig.legend(loc="outside lower center", ncols=min(len(ests), 3 if longest <= 34 else 2), fontsize=8,
               title="estimator (n successes per point); each point at its true setting", title_fontsize=8)
    return fig


def _bars(sw: dict, sc: list[dict], ests: list[str]):
    """The paper's figure-3 style: mean bars, black std, cyan [min, max], one panel per estimator."""
    scale = sw["display_scale"]
    labels = [f"{c['x'] * scale:g}" for c in sc]
    ncol = min(len(ests), 3)
    nrow = int(np.ceil(len(ests) / ncol))
    fig, axes = plt.subplots(nrow, ncol, figsize=(3.4 * ncol, 2.9 * nrow + 0.6), layout="constrained", squeeze=False)
    pos = np.arange(len(sc), dtype=float)
    rotate = len(labels) > 6 or max((len(t) for t in labels), default=0) > 4
    for ax, e in itertools.zip_longest(axes.ravel(), ests):
        if e is None:
            ax.set_visible(False)
            continue
        ms = [c["metrics"]["estimators"].get(e, {}) for c in sc]
        mean, std, mn, mx = (np.array([_val(m, k) for m in ms]) for k in ("mean", "std", "min", "max"))
        n_ok = np.array([int(m.get("n_ok", 0) or 0) if m else 0 for m in ms])
        ok = np.isfinite(mean)
        bar = ok & (n_ok >= MIN_N_INTERVAL)
        col, _ = style(e, ests)
        ax.bar(pos[ok], mean[ok], width=0.6, color=col, alpha=0.8, gid=f"bars:{e}")
        if bar.any():
            ax.errorbar(pos[bar], mean[bar], yerr=np.clip([mean[bar] - mn[bar], mx[bar] - mean[bar]], 0, None),
                        fmt="none", ecolor="c", elinewidth=4, alpha=0.6)
            ax.errorbar(pos[bar], mean[bar], yerr=std[bar], fmt="none", ecolor="k", elinewidth=1.2, capsize=3)
        ax.set_title(f"{e} ({_n_text(n_ok[ok])} per bar)", fontsize=9)
        ax.set_ylabel("normal error (deg)", fontsize=8)
        ax.tick_params(labelsize=7)
        ax.xaxis.set_major_locator(FixedLocator(pos))
        ax.set_xticks(pos, labels)
        ax.set_xlim(-0.6, len(sc) - 0.4)
        if rotate:
            ax.tick_params(axis="x", labelrotation=90)
        ax.set_xlabel(sw["label"], fontsize=8)
    sep = "; " if ncol > 1 else "\n"
    fig.suptitle(f"{sw['name']}: mean (bars), std (black), [min, max] (cyan){sep}intervals "
                 f"where n >= {MIN_N_INTERVAL}", fontsize=9)
    return fig


def _rho_cases(results: dict) -> list[dict]:
    """The curved rendered cases with a predicted gap, one per setting; empty if none has a measurement."""
    cs = [c for c in results["cases"] if c["protocol"] == "rendered"
          and c["metrics"]["diagnostics"].get("predicted_gap") is not None
          and not c.get("family", "").startswith("plane")]
    cases = _unique(cs)
    measured = any(np.isfinite(_val(c["metrics"]["diagnostics"], "eigenvalue_gap"))
                   or any(np.isfinite(_val(c["metrics"]["estimators"].get(e, {}), "mean"))
                          for e in RHO_ESTIMATOR_MARKERS) for c in cases)
    return cases if measured else []


#: How the right panel of curvature_rho tells the two circle-pose estimators apart.
RHO_ESTIMATOR_MARKERS = {"paper_oracle": {"marker": "o", "ms": 10, "fillstyle": "none", "mew": 1.5},
                         "paper_selected": {"marker": "+", "ms": 7, "fillstyle": "full", "mew": 1.5}}


def _rho_figure(results: dict):
    """Predicted against measured eigenvalue gap and circle-pose error, every curved case."""
    cases = _rho_cases(results)
    if not cases:
        return None
    fams = sorted({c.get("family", "?") for c in cases})
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(10.5, 5.0), layout="constrained")
    ests = [e for e in RHO_ESTIMATOR_MARKERS if e in results["suite"]["estimators"]]
    for i, fam in enumerate(fams):
        mk = _FAMILY_MARKERS[i % len(_FAMILY_MARKERS)]
        fc = [c for c in cases if c.get("family") == fam]
        d = [c["metrics"]["diagnostics"] for c in fc]
        k1, k2, pg, mg, pp = (np.array([_val(x, k) for x in d]) for k in
                              ("k1_per_mm", "k2_per_mm", "predicted_gap", "eigenvalue_gap", "predicted_pose_deg"))
        kind = np.where(k2 >= 0, "convex", np.where(k1 > 0, "saddle", "concave"))
        samples = [int(c.get("samples") or c.get("realisations") or 0) for c in fc]
        for shape, fill, size in (("convex", "full", 7), ("saddle", "left", 8), ("concave", "none", 9)):
            sel = kind == shape
            if not sel.any():
                continue
            (ln,) = a1.plot(pg[sel], mg[sel], mk, ms=size, color=f"C{i}", fillstyle=fill,
                            mew=1.2, alpha=0.85, ls="none",
                            label=f"{fam} ({shape}): {int(sel.sum())} cases, "
                                  f"{_n_text(np.asarray(samples)[sel])} highlights each")
            ln.set_gid(f"gap:{fam}:{shape}")
        for e in ests:
            me = np.array([_val(c["metrics"]["estimators"].get(e, {}), "mean") for c in fc])
            (ln,) = a2.plot(pp, me, ls="none", color=f"C{i}", alpha=0.9, **RHO_ESTIMATOR_MARKERS[e])
            ln.set_gid(f"pose:{fam}:{e}")
    a1.plot([0, 1], [0, 1], "k--", lw=1, label="measured = predicted")
    a2.plot([0, 90], [0, 90], "k--", lw=1)
    for ax, lim, xlabel, ylabel, title in (
            (a1, (-0.03, 1.03), "predicted eigenvalue gap 1 - rho^2 (dimensionless)",
             "measured eigenvalue gap of C' (dimensionless)", "eigenvalue gap, case means"),
            (a2, (-3, 93), "predicted circle-pose error asin(sqrt(1 - rho^2)) (deg)", "measured mean error (deg)",
             "circle pose, case means (colour: family)")):
        ax.set(xlim=lim, ylim=lim, xlabel=xlabel, ylabel=ylabel)
        ax.set_title(title, fontsize=9)
        ax.grid(True, alpha=0.3)
    if ests:
        # n of the drawn points only (a case whose estimator never succeeded has no mean)
        n_ok = {e: [int(m.get("n_ok", 0) or 0) for c in cases for m in [c["metrics"]["estimators"].get(e, {})]
                    if np.isfinite(_val(m, "mean"))] for e in ests}
        handles = [plt.Line2D([], [], ls="none", color="k", **RHO_ESTIMATOR_MARKERS[e]) for e in ests]
        # upper left: above the diagonal, where a mean error would exceed its prediction
        a2.legend(handles, [f"{e} ({_n_text(n_ok[e])} per case)" for e in ests],
                  loc="upper left", fontsize=8, title="estimator", title_fontsize=8)
    fig.legend(*a1.get_legend_handles_labels(), loc="outside lower center", ncols=2 if len(fams) > 1 else 1, fontsize=8,
               title="rho = |1 + k2 d| / |1 + k1 d| (case means of k1 >= k2 at the BP): filled "
                     "convex (k2 >= 0), half saddle (k1 > 0 > k2), hollow concave (k1 <= 0)", title_fontsize=8)
    return fig


def trend_figure(history: list[dict]):
    """Headline metrics over nightly runs (family medians per estimator, log scale).

    Parameters
    ----------
    history : list of dict
        Lines of the nightly history (:func:`simtest.harness.nightly.history_line`), oldest first.

    Returns
    -------
    matplotlib.figure.Figure or None
        None for an empty history.
    """
    if not history:
        return None
    fams = sorted({f for h in history for f in h.get("families", {})})
    ests = sorted({e for h in history for f in h.get("families", {}).values() for e in f})
    ncol = min(len(fams), 3) or 1
    nrow = int(np.ceil(len(fams) / ncol)) or 1
    fig, axes = plt.subplots(nrow, ncol, figsize=(3.8 * ncol, 2.9 * nrow + 1.0), layout="constrained", squeeze=False)
    runs = np.arange(len(history))
    labels = [h.get("created_utc", "")[:10] for h in history]
    for ax, fam in itertools.zip_longest(axes.ravel(), fams):
        if fam is None:
            ax.set_visible(False)
            continue
        for e in ests:
            col, mk = style(e, ests)
            y = np.array([np.nan if (h.get("families", {}).get(fam, {}).get(e)) is None
                          else max(h["families"][fam][e], FLOOR_DEG) for h in history])
            if np.isfinite(y).any():
                ax.plot(runs, y, mk + "-", color=col, ms=4, lw=1, label=e)
        _log_y(ax)
        ns = [v for h in history for v in (h.get("n", {}).get(fam) or {}).values()]
        ax.set_title(f"{fam} ({_n_text(ns) + ' per median' if ns else 'n not in the history'})", fontsize=9)
        ax.set_ylabel("median error (deg)", fontsize=8)
        step = max(1, int(np.ceil(len(runs) / 4)))
        ax.set_xticks(runs[::step], labels[::step])
        ax.tick_params(labelsize=7, axis="x", labelrotation=30)
        ax.set_xlabel("nightly run (UTC date)", fontsize=8)
    first = {}  # each label once, with its first handle
    for ax in axes.ravel():
        for h, lab in zip(*ax.get_legend_handles_labels()):
            first.setdefault(lab, h)
    fig.legend(list(first.values()), list(first), loc="outside lower center", ncols=min(len(first), 5) or 1, fontsize=8)
    fig.suptitle("Nightly trend: median error per scene family", fontsize=10)
    return fig


def make_figures(results: dict, history: list[dict] | None = None) -> dict:
    """Every figure of a report -> ``{file name: Figure}`` (caller closes them).

    Parameters
    ----------
    results : dict
        A ``results.json`` document.
    history : list of dict, optional
        Nightly history lines; adds ``nightly_trend.png``.

    Returns
    -------
    dict of str to matplotlib.figure.Figure
        ``<sweep>_curves.png`` for every sweep, ``<sweep>_bars.png`` for sweeps that check a
        paper claim (the paper's figure-3 style), ``curvature_rho.png`` when the suite has
        curved rendered cases, ``nightly_trend.png`` with a history.
    """
    return {name: draw(*args) for name, draw, _, args in _figure_plan(results, history)}


def _figure_plan(results: dict, history: list[dict] | None) -> list[tuple]:
    """``(file name, draw, takeaway, arguments)`` per figure of a report."""
    cases = {c["id"]: c for c in results["cases"]}
    ests = list(results["suite"]["estimators"])
    plan = []
    for sw in results["sweeps"]:
        sc = [cases[k] for k in sw["cases"]]
        if not sc:
            continue
        plan.append((f"{sw['name']}_curves.png", _curves, _curves_takeaway, (sw, sc, ests)))
        if sw.get("paper") and (sw["paper"].get("source", "paper") == "paper"):
            plan.append((f"{sw['name']}_bars.png", _bars, _bars_takeaway, (sw, sc, ests)))
    if _rho_cases(results):
        plan.append(("curvature_rho.png", _rho_figure, _rho_takeaway, (results,)))
    if history:
        plan.append(("nightly_trend.png", trend_figure, _trend_takeaway, (history,)))
    return plan


def _curves_takeaway(sw: dict, sc: list[dict], ests: list[str]) -> str:
    x = _sweep_x(sw, sc)
    order = np.argsort(x, kind="stable")
    x, sc = x[order], [sc[i] for i in order]
    # settings at which each estimator is the lowest beyond the interval
    clear = Counter(e for c in sc for e, m in best_marks({e: c["metrics"]["estimators"].get(e) for e in ests}).items()
                    if m == "best")
    meds = {e: np.array([_val(c["metrics"]["estimators"].get(e, {}), "median") for c in sc]) for e in ests}
    drawn = {e: v for e, v in meds.items() if np.isfinite(v).any()}
    span = (f"Across the {len(sc)} settings ({sw['label']}: {x[0]:g} to {x[-1]:g})"
            if x.size > 1 else f"At the one setting ({sw['label']}: {x[0]:g})")
    if not drawn:
        return f"{span}, no estimator succeeded."
    low = min(drawn, key=lambda e: np.nanmedian(drawn[e]))
    high = max(drawn, key=lambda e: np.nanmax(drawn[e]))
    i_hi = int(np.nanargmax(drawn[high]))
    text = (f"{span}, {low} has the lowest median errors (middle value "
            f"{fmt(np.nanmedian(drawn[low]))} deg, {fmt(np.nanmin(drawn[low]))} to "
            f"{fmt(np.nanmax(drawn[low]))} deg) and {high} the highest ({fmt(drawn[high][i_hi])} deg at {x[i_hi]:g})")
    if clear:
        top = max(clear, key=clear.get)
        text += (f"; {top} is lowest beyond the {100 * BEST_LEVEL:g} % interval at {clear[top]} of {len(sc)} settings")
    else:
        text += (f"; no estimator is lowest beyond the {100 * BEST_LEVEL:g} % interval at any "
                 f"setting (n below {MIN_N_INTERVAL} or differences within the noise)")
    fr = {e: np.array([_val(c["metrics"]["estimators"].get(e, {}), "failure_rate") for c in sc]) for e in ests}
    worst = max(ests, key=lambda e: np.nan_to_num(fr[e], nan=-1).max())
    if np.nanmax(np.nan_to_num(fr[worst], nan=0)) > 0:
        j = int(np.nanargmax(fr[worst]))
        text += f"; failures reach {100 * fr[worst][j]:.3g} % ({worst} at {x[j]:g})"
    return text + "."


def _bars_takeaway(sw: dict, sc: list[dict], ests: list[str]) -> str:
    x = _sweep_x(sw, sc)
    parts = []
    for e in ests:
        mean = np.array([_val(c["metrics"]["estimators"].get(e, {}), "mean") for c in sc])
        ok = np.flatnonzero(np.isfinite(mean))
        if ok.size:
            parts.append(f"{e} {fmt(mean[ok[0]])} to {fmt(mean[ok[-1]])} deg")
    if not parts:
        return f"No estimator succeeded at any of the {len(sc)} settings."
    text = (f"Mean error from the first to the last setting ({sw['label']}: {x[0]:g} to "
            f"{x[-1]:g}): " + ", ".join(parts))
    comp = [c for c in sw.get("comparison") or [] if c.get("holds") is not None]
    if comp:
        verdict = "holds" if all(c["holds"] for c in comp) else "does not hold"
        text += (f"; the paper's claim ({sw['paper'].get('claim', '')}) {verdict}: "
                 + "; ".join(f"{c['estimator']}: {c['ours']}" for c in comp))
    return text + "."


def _rho_takeaway(results: dict) -> str:
    cases = _rho_cases(results)
    d = [c["metrics"]["diagnostics"] for c in cases]
    gap = np.array([_val(x, "eigenvalue_gap") - _val(x, "predicted_gap") for x in d])
    gap = np.abs(gap[np.isfinite(gap)])
    text = f"Over {len(cases)} curved cases"
    if gap.size:
        text += (f", the measured eigenvalue gap differs from 1 - rho^2 by {fmt(np.median(gap))}"
                 f" in the median (at most {fmt(gap.max())}, {gap.size} cases)")
    else:
        text += ", none has a measured eigenvalue gap"
    for e in RHO_ESTIMATOR_MARKERS:
        if e not in results["suite"]["estimators"]:
            continue
        dev = np.array([_val(c["metrics"]["estimators"].get(e, {}), "mean")
                        - _val(c["metrics"]["diagnostics"], "predicted_pose_deg") for c in cases])
        dev = np.abs(dev[np.isfinite(dev)])
        if dev.size:
            text += (f"; {e}'s mean error differs from the predicted circle-pose error by "
                     f"{fmt(np.median(dev))} deg in the median (at most {fmt(dev.max())} deg, {dev.size} cases)")
    return text + "."


def _trend_takeaway(history: list[dict]) -> str:
    first, last = history[0], history[-1]
    best = None
    for fam, f in last.get("families", {}).items():
        for e, v in f.items():
            v0 = first.get("families", {}).get(fam, {}).get(e)
            if v is None or v0 is None:
                continue
            r = np.log(max(v, FLOOR_DEG) / max(v0, FLOOR_DEG))
            if best is None or abs(r) > abs(best[0]):
                best = (r, fam, e, v0, v)
    span = (f"Over {len(history)} nightly runs ({first.get('created_utc', '')[:10]} to "
            f"{last.get('created_utc', '')[:10]})")
    if best is None:
        return span + ", no family median is in both the first and the last run."
    r, fam, e, v0, v = best
    return (f"{span}, the largest change of a family median from the first run to the last is "
            f"{e} on {fam}: {fmt(v0)} to {fmt(v)} deg (x {fmt(float(np.exp(r)))}).")


def takeaways(results: dict, history: list[dict] | None = None) -> dict[str, str]:
    """One sentence per figure of :func:`make_figures`, every number read from the results.

    Parameters
    ----------
    results : dict
        A ``results.json`` document.
    history : list of dict, optional
        Nightly history lines (the ``nightly_trend.png`` sentence).

    Returns
    -------
    dict of str to str
        ``{figure file name: sentence}`` for the same names :func:`make_figures` draws.
    """
    return {name: say(*args) for name, _, say, args in _figure_plan(results, history)}
