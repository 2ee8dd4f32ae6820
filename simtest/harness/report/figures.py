"""Report figures (matplotlib, Agg): per-sweep error curves, figure-3 bars, rho, nightly trend.

Every figure uses constrained layout, labels each axis with its unit, draws each estimator with
its own colour and marker, side by side (dodged) where values coincide, and keeps its legend
outside the axes. :func:`layout_problems` checks a drawn figure: no two text boxes overlap and
none leaves the figure (the report tests run it on every figure).
"""

from __future__ import annotations

import io
import itertools

import matplotlib
import numpy as np

matplotlib.use("Agg", force=False)

import matplotlib.pyplot as plt  # noqa: E402 - after choosing the back-end
from matplotlib.text import Text  # noqa: E402
from matplotlib.ticker import FixedLocator, NullFormatter  # noqa: E402

__all__ = ["make_figures", "figure_png", "layout_problems", "style", "trend_figure"]

_STYLE = {"paper_oracle": ("#1f77b4", "o"), "paper_selected": ("#9467bd", "s"),
          "cone_axis": ("#d62728", "^"), "joint_cone_axis": ("#ff7f0e", "v"),
          "bp_ray": ("#555555", "D")}
_EXTRA_COLOURS = ("#2ca02c", "#17becf", "#8c564b", "#e377c2", "#bcbd22", "#7f7f7f")
_EXTRA_MARKERS = ("P", "X", "h", "*", "<", ">")

#: Errors below this (degrees) are drawn at it on log axes (the BP ray of the paper protocol at
#: theta = 0 is exactly 0).
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
    """PNG bytes of a figure as laid out (no tight-bbox cropping: what is checked is saved).

    Parameters
    ----------
    fig : matplotlib.figure.Figure

    Returns
    -------
    bytes
    """
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=100)
    return buf.getvalue()


def _val(m: dict, k: str) -> float:
    v = m.get(k) if m else None
    return np.nan if v is None else float(v)


def _xticks(ax, labels: list[str], label: str) -> None:
    ax.xaxis.set_major_locator(FixedLocator(range(len(labels))))
    ax.set_xticks(range(len(labels)), labels)
    ax.set_xlabel(label)
    if len(labels) > 6 or max((len(s) for s in labels), default=0) > 5:
        # vertical: the boxes of slanted labels overlap their neighbours' long before the text
        ax.tick_params(axis="x", labelrotation=90)


def _log_y(ax) -> None:
    ax.set_yscale("log")
    ax.yaxis.set_minor_formatter(NullFormatter())
    ax.grid(True, which="major", alpha=0.3)


def _curves(sw: dict, sc: list[dict], ests: list[str]):
    scale = sw["display_scale"]
    labels = [f"{c['x'] * scale:g}" for c in sc]
    pos = np.arange(len(sc), dtype=float)
    fails = {e: np.array([_val(c["metrics"]["estimators"].get(e, {}), "failure_rate")
                          for c in sc]) for e in ests}
    any_fail = any(np.nansum(f) > 0 for f in fails.values())
    if any_fail:
        fig, (ax, axf) = plt.subplots(2, 1, figsize=(7.0, 5.6), layout="constrained",
                                      height_ratios=(3, 1), sharex=True)
    else:
        fig, ax = plt.subplots(figsize=(7.0, 4.4), layout="constrained")
        axf = None
    width = 0.6 / max(len(ests), 1)
    for k, e in enumerate(ests):
        col, mk = style(e, ests)
        ms = [c["metrics"]["estimators"].get(e, {}) for c in sc]
        med = np.array([_val(m, "median") for m in ms])
        lo = np.array([_val(m, "p5") for m in ms])
        hi = np.array([_val(m, "p95") for m in ms])
        x = pos + (k - (len(ests) - 1) / 2) * width
        med_f, lo_f, hi_f = (np.maximum(v, FLOOR_DEG) for v in (med, lo, hi))
        ok = np.isfinite(med)
        ax.errorbar(x[ok], med_f[ok], yerr=[np.clip(med_f[ok] - lo_f[ok], 0, None),
                                             np.clip(hi_f[ok] - med_f[ok], 0, None)],
                    fmt=mk + "-", color=col, ms=5, lw=1, elinewidth=1, capsize=2, label=e,
                    mfc=col if k % 2 == 0 else "white")
        if axf is not None:
            axf.plot(x, 100 * fails[e], mk, color=col, ms=5, mfc=col if k % 2 == 0 else "white")
    _log_y(ax)
    ax.set_ylabel("normal error (deg)\nmedian, bar p5 to p95")
    ax.set_title(f"{sw['name']} ({sw['protocol']} protocol); errors below {FLOOR_DEG:g} deg drawn "
                 "at it", fontsize=9)
    if axf is not None:
        axf.set_ylabel("failures (%)")
        axf.set_ylim(-5, 105)
        axf.grid(True, alpha=0.3)
        _xticks(axf, labels, sw["label"])
        ax.tick_params(axis="x", labelbottom=False)
    else:
        _xticks(ax, labels, sw["label"])
    fig.legend(loc="outside lower center", ncols=min(len(ests), 3), fontsize=8,
               title="estimator (side by side at each setting)", title_fontsize=8)
    return fig


def _bars(sw: dict, sc: list[dict], ests: list[str]):
    """The paper's figure-3 style: mean bars, black std, cyan [min, max], one panel per estimator."""
    scale = sw["display_scale"]
    labels = [f"{c['x'] * scale:g}" for c in sc]
    ncol = min(len(ests), 3)
    nrow = int(np.ceil(len(ests) / ncol))
    fig, axes = plt.subplots(nrow, ncol, figsize=(3.4 * ncol, 2.9 * nrow + 0.6),
                             layout="constrained", squeeze=False)
    pos = np.arange(len(sc))
    for ax, e in itertools.zip_longest(axes.ravel(), ests):
        if e is None:
            ax.set_visible(False)
            continue
        ms = [c["metrics"]["estimators"].get(e, {}) for c in sc]
        mean, std, mn, mx = (np.array([_val(m, k) for m in ms]) for k in ("mean", "std", "min",
                                                                           "max"))
        ok = np.isfinite(mean)
        col, _ = style(e, ests)
        ax.bar(pos[ok], mean[ok], width=0.6, color=col, alpha=0.8)
        ax.errorbar(pos[ok], mean[ok], yerr=np.clip([mean[ok] - mn[ok], mx[ok] - mean[ok]], 0,
                                                    None),
                    fmt="none", ecolor="c", elinewidth=4, alpha=0.6)
        ax.errorbar(pos[ok], mean[ok], yerr=std[ok], fmt="none", ecolor="k", elinewidth=1.2,
                    capsize=3)
        ax.set_title(e, fontsize=9)
        ax.set_ylabel("normal error (deg)", fontsize=8)
        ax.tick_params(labelsize=7)
        step = max(1, int(np.ceil(len(labels) / 6)))
        ax.set_xticks(pos[::step], labels[::step])
        ax.set_xlabel(sw["label"], fontsize=8)
    fig.suptitle(f"{sw['name']}: mean (bars), std (black), [min, max] (cyan)", fontsize=9)
    return fig


def _rho_figure(results: dict):
    """Predicted against measured eigenvalue gap and circle-pose error, every curved case."""
    cs = [c for c in results["cases"] if c["protocol"] == "rendered"
          and c["metrics"]["diagnostics"].get("predicted_gap") is not None
          and not c.get("family", "").startswith("plane")]
    seen, cases = set(), []
    for c in cs:
        if c["key"] not in seen:
            seen.add(c["key"])
            cases.append(c)
    if not cases:
        return None
    fams = sorted({c.get("family", "?") for c in cases})
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(10.5, 4.6), layout="constrained")
    ests = [e for e in ("paper_oracle", "paper_selected") if e in results["suite"]["estimators"]]
    for i, fam in enumerate(fams):
        mk = _FAMILY_MARKERS[i % len(_FAMILY_MARKERS)]
        fc = [c for c in cases if c.get("family") == fam]
        d = [c["metrics"]["diagnostics"] for c in fc]
        k1 = np.array([_val(x, "k1_per_mm") for x in d])
        k2 = np.array([_val(x, "k2_per_mm") for x in d])
        kind = np.where(k2 >= 0, "convex", np.where(k1 > 0, "saddle", "concave"))
        pg = np.array([_val(x, "predicted_gap") for x in d])
        mg = np.array([_val(x, "eigenvalue_gap") for x in d])
        pp = np.array([_val(x, "predicted_pose_deg") for x in d])
        for shape, fill in (("convex", "full"), ("saddle", "left"), ("concave", "none")):
            sel = kind == shape
            if not sel.any():
                continue
            a1.plot(pg[sel], mg[sel], mk, ms=7, color=f"C{i}", fillstyle=fill,
                    label=f"{fam} ({shape})", ls="none")
            for j, e in enumerate(ests):
                me = np.array([_val(c["metrics"]["estimators"].get(e, {}), "mean") for c in fc])
                a2.plot(pp[sel], me[sel], mk, ms=7 if j == 0 else 4, color=f"C{i}",
                        fillstyle=fill if j == 0 else "none", ls="none",
                        alpha=1.0 if j == 0 else 0.6)
    a1.plot([0, 1], [0, 1], "k--", lw=1, label="measured = predicted")
    a1.set_xlim(-0.03, 1.03)
    a1.set_ylim(-0.03, 1.03)
    a1.set_xlabel("predicted eigenvalue gap 1 - rho^2 (dimensionless)")
    a1.set_ylabel("measured eigenvalue gap of C' (dimensionless)")
    a1.set_title("eigenvalue gap, case means", fontsize=9)
    a1.grid(True, alpha=0.3)
    a2.plot([0, 90], [0, 90], "k--", lw=1)
    a2.set_xlim(-3, 93)
    a2.set_ylim(-3, 93)
    a2.set_xlabel("predicted circle-pose error asin(sqrt(1 - rho^2)) (deg)")
    a2.set_ylabel("measured mean error (deg)")
    a2.set_title("circle pose: paper_oracle (large), paper_selected (small)", fontsize=9)
    a2.grid(True, alpha=0.3)
    fig.legend(*a1.get_legend_handles_labels(), loc="outside lower center",
               ncols=min(3, len(fams) * 2 + 1), fontsize=8,
               title="rho = |1 + k2 d| / |1 + k1 d| (case means of k1 >= k2 at the BP): filled "
                     "convex (k2 >= 0), half saddle (k1 > 0 > k2), hollow concave (k1 <= 0)",
               title_fontsize=8)
    return fig


def trend_figure(history: list[dict]):
    """Headline metrics over nightly runs (family medians per estimator, log scale).

    Parameters
    ----------
    history : list of dict
        Lines of the nightly history file (:func:`simtest.harness.nightly.history_line`), oldest
        first; each has ``run_id``, ``created_utc`` and ``families``: {family: {estimator:
        median}}.

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
    fig, axes = plt.subplots(nrow, ncol, figsize=(3.8 * ncol, 2.9 * nrow + 1.0),
                             layout="constrained", squeeze=False)
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
        ax.set_title(fam, fontsize=9)
        ax.set_ylabel("median error (deg)", fontsize=8)
        step = max(1, int(np.ceil(len(runs) / 4)))
        ax.set_xticks(runs[::step], labels[::step])
        ax.tick_params(labelsize=7, axis="x", labelrotation=30)
        ax.set_xlabel("nightly run (UTC date)", fontsize=8)
    handles, labs = [], []
    for ax in axes.ravel():
        for h, lab in zip(*ax.get_legend_handles_labels()):
            if lab not in labs:
                handles.append(h)
                labs.append(lab)
    fig.legend(handles, labs, loc="outside lower center", ncols=min(len(labs), 5) or 1,
               fontsize=8)
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
    cases = {c["id"]: c for c in results["cases"]}
    ests = list(results["suite"]["estimators"])
    out = {}
    for sw in results["sweeps"]:
        sc = [cases[k] for k in sw["cases"]]
        if not sc:
            continue
        out[f"{sw['name']}_curves.png"] = _curves(sw, sc, ests)
        if sw.get("paper") and (sw["paper"].get("source", "paper") == "paper"):
            out[f"{sw['name']}_bars.png"] = _bars(sw, sc, ests)
    rho = _rho_figure(results)
    if rho is not None:
        out["curvature_rho.png"] = rho
    if history:
        out["nightly_trend.png"] = trend_figure(history)
    return out


def _drawn_texts(fig) -> list:
    """Text artists that are drawn: visible, non-empty, tick labels inside the view limits."""
    out = []
    skip = set()
    for ax in fig.axes:
        leg = ax.get_legend()
        if leg is not None:
            skip.update(id(t) for t in leg.findobj(Text))
        for axis, lim in ((ax.xaxis, ax.get_xlim()), (ax.yaxis, ax.get_ylim())):
            lo, hi = min(lim), max(lim)
            for tick in axis.get_major_ticks() + axis.get_minor_ticks():
                for lab in (tick.label1, tick.label2):
                    if not (lo - 1e-9 * abs(hi - lo) <= tick.get_loc() <= hi + 1e-9 * abs(hi - lo)):
                        skip.add(id(lab))
    for leg in fig.legends:
        skip.update(id(t) for t in leg.findobj(Text))
    for t in fig.findobj(Text):
        if id(t) in skip or not t.get_visible() or not t.get_text().strip():
            continue
        if t.axes is not None and not t.axes.get_visible():
            continue
        out.append(t)
    return out


def layout_problems(fig, tol_px: float = 0.5) -> list[str]:
    """Overlapping or clipped text in a figure (after drawing it).

    Parameters
    ----------
    fig : matplotlib.figure.Figure
        The figure, as it will be saved (its size and dpi).
    tol_px : float
        Overlap or overhang allowed, pixels (half a pixel: anti-aliasing, not a collision).

    Returns
    -------
    list of str
        One line per problem: ``"'A' overlaps 'B'"`` or ``"'A' leaves the figure"``; legends
        count as one box each. Empty when the layout is clean.
    """
    fig.canvas.draw()
    r = fig.canvas.get_renderer()
    W, H = fig.bbox.width, fig.bbox.height
    boxes = [(repr(t.get_text()), t.get_window_extent(r)) for t in _drawn_texts(fig)]
    legends = list(fig.legends) + [ax.get_legend() for ax in fig.axes
                                   if ax.get_legend() is not None and ax.get_visible()]
    boxes += [(f"legend {i}", leg.get_window_extent(r)) for i, leg in enumerate(legends)]
    out = []
    for name, b in boxes:
        if b.x0 < -tol_px or b.y0 < -tol_px or b.x1 > W + tol_px or b.y1 > H + tol_px:
            out.append(f"{name} leaves the figure ({b.x0:.0f}, {b.y0:.0f}, {b.x1:.0f}, "
                       f"{b.y1:.0f} in {W:.0f} x {H:.0f} px)")
    for (na, a), (nb, b) in itertools.combinations(boxes, 2):
        w = min(a.x1, b.x1) - max(a.x0, b.x0)
        h = min(a.y1, b.y1) - max(a.y0, b.y0)
        if w > tol_px and h > tol_px:
            out.append(f"{na} overlaps {nb}")
    return out
