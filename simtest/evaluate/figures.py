"""The figures of ``simtest evaluate detection``'s report: the confidence's reliability diagram and the
frames with their hits, false positives and misses (the precision-recall curve: :mod:`.operating`)."""

from __future__ import annotations

import math

import matplotlib.pyplot as plt
import numpy as np

from simtest.evaluate.detection import SPECULAR_KIND, LabelledFrame

__all__ = ["FIGURE_FRAMES_MAX", "detection_figure", "reliability_figure"]


def reliability_figure(results: dict):
    """The reliability diagram of the confidence: fraction of targets against mean confidence per bin,
    for every candidate and for the ``ok`` ones, with each bin's count.
    """
    fig, ax = plt.subplots(figsize=(5.2, 4.4), layout="constrained")
    ax.plot([0, 1], [0, 1], color="0.6", lw=1, ls="--", label="perfect calibration")
    for key, marker, colour in (("candidates", "o", "#1f77b4"), ("ok", "s", "#d62728")):
        rows = [r for r in results["reliability"][key] if r["n"]]
        x = [r["mean_confidence"] for r in rows]
        y = [r["fraction_true"] for r in rows]
        ax.plot(x, y, marker=marker, color=colour, label=f"{key} (n = {sum(r['n'] for r in rows)})")
        for r, xi, yi in zip(rows, x, y):
            ax.annotate(f"n={r['n']}", (xi, yi), textcoords="offset points", xytext=(4, -10), fontsize=7, color=colour)
    ax.set(xlim=(0, 1), ylim=(0, 1), xlabel="mean confidence in the bin",
           ylabel="fraction that are labelled targets", title="Reliability of the confidence")
    ax.legend(fontsize=8, loc="upper left")
    return fig


#: Most frames :func:`detection_figure` draws.
FIGURE_FRAMES_MAX = 24


def detection_figure(frames: list[LabelledFrame], results: dict, *, columns: int = 6):
    """The frames with what detection got right and wrong, as a matplotlib figure.

    ``ok`` estimates on targets: green circles; on a render's other specular structures (``specular``):
    orange pluses; on anything else: red crosses; targets no ``ok`` estimate found: yellow squares. Of
    more than :data:`FIGURE_FRAMES_MAX` frames only those with an error are drawn.
    """
    pairs = list(zip(frames, results["frames"]))
    left_out = 0
    if len(pairs) > FIGURE_FRAMES_MAX:
        wrong = [(fr, res) for fr, res in pairs if res["ok"] > res["ok_tp"] or res["missed_targets_ok"]]
        left_out = len(pairs) - min(len(wrong), FIGURE_FRAMES_MAX)
        pairs = wrong[:FIGURE_FRAMES_MAX] or pairs[:1]
    frames = [fr for fr, _ in pairs]
    n = len(frames)
    cols = min(columns, n)
    rows_n = math.ceil(n / cols)
    fig, axes = plt.subplots(rows_n, cols, figsize=(max(2.6 * cols, 8.0), 2.9 * rows_n + 0.8),
                             squeeze=False, layout="constrained")
    for ax in axes.ravel():
        ax.set_axis_off()
    for ax, (fr, res) in zip(axes.ravel(), pairs):
        ax.imshow(fr.image, cmap="gray" if fr.image.ndim == 2 else None)
        tp = np.array([r["bp_px"] for r in res["candidates_detail"] if r["tp_ok"]]).reshape(-1, 2)
        wrong = [r for r in res["candidates_detail"] if r["status"] == "ok" and not r["tp_ok"]]
        glint = np.array([r["bp_px"] for r in wrong if r["on"] == SPECULAR_KIND]).reshape(-1, 2)
        fp = np.array([r["bp_px"] for r in wrong if r["on"] != SPECULAR_KIND]).reshape(-1, 2)
        miss = np.array(res["missed_targets_ok"]).reshape(-1, 2)
        ax.scatter(tp[:, 0], tp[:, 1], s=40, facecolors="none", edgecolors="#2ca02c", lw=1.2)
        ax.scatter(glint[:, 0], glint[:, 1], s=34, marker="+", c="#ff7f0e", lw=1.2)
        ax.scatter(fp[:, 0], fp[:, 1], s=30, marker="x", c="#d62728", lw=1.2)
        ax.scatter(miss[:, 0], miss[:, 1], s=40, marker="s", facecolors="none", edgecolors="#ffcc00", lw=1.2)
        on_glints = "" if fr.specular_px is None else f"{len(glint)} on other glints, "
        ax.set_title(f"{fr.name}: {res['ok_tp']} hit, {on_glints}{len(fp)} false, "
                     f"{len(miss)} missed (of {res['targets']})", fontsize=7)
    p, pct = results["pooled"], lambda v: "n/a" if v is None else f"{v:.2f}"
    fig.suptitle(f"ok estimates against labelled isolated highlights: precision {pct(p['precision_ok'])}, "
                 f"recall {pct(p['recall_ok'])} over {p['targets']} targets\n(green circle: hit, "
                 + ("orange plus: on a glint that is no isolated highlight,\n"
                    if any(fr.specular_px is not None for fr in frames) else "")
                 + "red cross: false positive, yellow square: missed)"
                 + (f"; {left_out} frames without an error not drawn" if left_out else ""), fontsize=9)
    return fig
