"""``results.json`` and ``report.html`` of ``simtest evaluate c3vd``.

``results.json``::

    {"schema": "simtest.evaluate.c3vd", "schema_version": 1, "simtest_version": ...,
     "sequence": "path", "camera": {camera file object}, "settings": {isovalues, normalise, ...},
     "n_frames": int, "n_highlights": int, "n_ok": int, "n_scored": int,
     "estimators": {name: {"n", "median_deg", "mean_deg", "p95_deg"}},       # vs GT at the BP
     "estimators_footprint": {name: {...}},                               # vs footprint mean
     "depth": {name: {"n", "median_abs", "median", "p95_abs"}},           # relative depth error
     "highlights": [rows of simtest.evaluate.score.score_highlights]}

``report.html`` is self-contained (figures inlined as PNG): the tables above, the error
distributions per estimator with ``bp_ray`` beside, and the error against the distance from the
principal point, the highlight size and the ground-truth curvature. Angles in degrees.
"""

from __future__ import annotations

import base64
import html
import io

import numpy as np
from matplotlib.figure import Figure
from matplotlib.ticker import FixedLocator, FuncFormatter

from simtest.reconstruct.overlay import estimator_colour

__all__ = ["SCHEMA", "SCHEMA_VERSION", "render_html", "figures"]

SCHEMA = "simtest.evaluate.c3vd"
SCHEMA_VERSION = 1


def _png(fig) -> bytes:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110, bbox_inches="tight")  # Agg canvas: no display needed
    return buf.getvalue()


_TICKS = [0, 0.01, 0.1, 1, 10, 100]


def _deg_axis(axis) -> None:
    """A symmetric-log angle axis in degrees (0 allowed) with plain tick labels."""
    axis.set_major_locator(FixedLocator(_TICKS))
    axis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))


def _errors(rows, key, name):
    return np.array([r[key][name] for r in rows if r["scored"] and r[key].get(name) is not None], dtype=np.float64)


def _style(name):
    return dict(color=estimator_colour(name), ls="--" if name == "bp_ray" else "-", lw=1.8 if name == "bp_ray" else 1.4)


def figures(results: dict) -> dict[str, bytes]:
    """The report's figures as PNG bytes, by title.

    Parameters
    ----------
    results : dict
        The ``results.json`` document.

    Returns
    -------
    dict of str to bytes
    """
    rows = results["highlights"]
    names = list(results["estimators"])
    figs: dict[str, bytes] = {}

    fig = Figure(figsize=(11, 4.2))
    axes = fig.subplots(1, 2, sharey=True)
    for ax, key, title in ((axes[0], "errors_bp_deg", "ground truth at the BP"),
                           (axes[1], "errors_footprint_deg", "ground truth averaged over the isophote")):
        for name in names:
            e = np.sort(_errors(rows, key, name))
            if len(e):
                ax.step(e, np.arange(1, len(e) + 1) / len(e), where="post", label=f"{name} (n={len(e)})", **_style(name))
        ax.set_xscale("symlog", linthresh=0.01, linscale=0.3)
        _deg_axis(ax.xaxis)
        ax.set_xlim(0, 180)
        ax.set_xlabel("angular error (deg)")
        ax.set_title(title)
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("fraction of highlights with error <= x")
    axes[0].set_ylim(0, 1.02)
    axes[0].legend(fontsize=8, loc="lower right")
    figs["Error distribution per estimator (bp_ray dashed: the baseline)"] = _png(fig)

    for field, label, title in (
        ("dist_pp_px", "distance of the BP from the principal point (px)", "Error against distance from the principal point"),
        ("size_px", "highlight size: diameter of the isophote's footprint (px)", "Error against highlight size"),
        ("gt_curvature_per_mm", "ground-truth curvature max(|k1|, |k2|) from depth (1/mm)", "Error against ground-truth curvature"),
    ):
        xs_all = [r[field] for r in rows if r["scored"] and r[field] is not None]
        fig = Figure(figsize=(11, 4.2))
        ax = fig.subplots()
        if not xs_all:
            ax.text(0.5, 0.5, f"no {field} in these results" + (" (no depth files)" if "curv" in field else ""),
                    ha="center", va="center", transform=ax.transAxes)
            ax.set_axis_off()
        else:
            for name in names:
                pairs = np.array([(r[field], r["errors_bp_deg"][name]) for r in rows
                                  if r["scored"] and r[field] is not None and r["errors_bp_deg"].get(name) is not None])
                if not len(pairs):
                    continue
                ax.scatter(pairs[:, 0], pairs[:, 1], s=8, alpha=0.35, color=estimator_colour(name))
                # binned medians, 8 quantile bins
                edges = np.unique(np.quantile(pairs[:, 0], np.linspace(0, 1, 9)))
                if len(edges) > 2:
                    idx = np.clip(np.searchsorted(edges, pairs[:, 0], side="right") - 1, 0, len(edges) - 2)
                    xm = [pairs[idx == b, 0].mean() for b in range(len(edges) - 1) if np.any(idx == b)]
                    ym = [np.median(pairs[idx == b, 1]) for b in range(len(edges) - 1) if np.any(idx == b)]
                    ax.plot(xm, ym, marker="o", ms=3, label=f"{name} (median per bin)", **_style(name))
            ax.set_yscale("symlog", linthresh=0.01, linscale=0.3)
            _deg_axis(ax.yaxis)
            ax.set_xlabel(label)
            ax.set_ylabel("angular error vs GT at the BP (deg)")
            ax.grid(alpha=0.3)
            if ax.get_legend_handles_labels()[0]:  # too few points for a binned median: no legend
                ax.legend(fontsize=8)
        ax.set_title(title)
        figs[title] = _png(fig)
    return figs


def _table(stats: dict, columns: dict, cell) -> str:
    """One row per estimator: its name, ``n``, then ``cell(value)`` of each ``columns`` key."""
    head = "".join(f"<th>{h}</th>" for h in ("estimator", "n", *columns.values()))
    body = []
    for name, s in stats.items():
        cells = [html.escape(name), str(s["n"])] + [cell(s[k]) for k in columns]
        body.append("<tr>" + "".join(f"<td>{c}</td>" for c in cells) + "</tr>")
    return f"<table><tr>{head}</tr>{''.join(body)}</table>"


#: The columns (statistic -> header) and cell format of the normals' tables and of the depth's.
_DEG = ({"median_deg": "median (deg)", "mean_deg": "mean (deg)", "p95_deg": "p95 (deg)"},
        lambda v: "-" if v is None else f"{v:.2f}")
_DEPTH = ({"median_abs": "median |error| (%)", "median": "median error (%)", "p95_abs": "p95 |error| (%)"},
          lambda v: f"{100 * v:.1f}")


def render_html(results: dict) -> str:
    """The self-contained HTML report page of a ``results.json`` document."""
    figs = figures(results)
    s = results
    parts = [
        "<!doctype html><html><head><meta charset='utf-8'><title>simtest evaluate c3vd</title>",
        "<style>body{font-family:sans-serif;max-width:1150px;margin:auto}table{border-collapse:collapse}"
        "td,th{border:1px solid #ccc;padding:3px 8px;text-align:right}img{max-width:100%}</style></head><body>",
        f"<h1>Normals against C3VD-format ground truth: {html.escape(str(s['sequence']))}</h1>",
        f"<p>{s['n_frames']} frame(s), {s['n_highlights']} highlight candidate(s), {s['n_ok']} reconstructed, "
        f"{s['n_scored']} scored (ground truth valid at the BP). Camera model: "
        f"{html.escape(s['camera']['model'])}. Settings: {html.escape(str(s['settings']))}.</p>",
        "<h2>Against the ground-truth normal at the BP</h2>", _table(s["estimators"], *_DEG),
        "<h2>Against the ground-truth normal averaged over the isophote's footprint</h2>",
        _table(s["estimators_footprint"], *_DEG),
    ]
    if s.get("depth") is not None:
        parts += ["<h2>Depth of the specular point along its ray, relative to the ground truth</h2>",
                  _table(s["depth"], *_DEPTH) if s["depth"] else
                  "<p>No estimator gave a depth (a camera file without a light rig of offset lights, or "
                  "no depth observable).</p>"]
    for title, png in figs.items():
        b64 = base64.b64encode(png).decode("ascii")
        parts.append(f"<h2>{html.escape(title)}</h2><p><img alt='{html.escape(title)}' src='data:image/png;base64,{b64}'></p>")
    parts.append("</body></html>")
    return "\n".join(parts)
