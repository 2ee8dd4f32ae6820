"""Precision against recall over the confidence: where a user sets ``--min-confidence``.

Each minimum confidence c gives, on a labelled set, a precision (share of kept ``ok`` estimates
on a labelled isolated highlight) and a recall (share of those highlights with a kept ``ok``
estimate), read off the default run's matches (:func:`simtest.evaluate.detection.score_frame`).
"""

from __future__ import annotations

import matplotlib.pyplot as plt
import numpy as np

from simtest.decisions import DEFAULT_MIN_CONFIDENCE

__all__ = ["THRESHOLDS", "precision_recall", "precision_recall_figure"]

#: The confidences at which the curve is read.
THRESHOLDS = tuple(np.round(np.arange(0.0, 1.0001, 0.05), 2))


def precision_recall(confidence, tp_ok, targets: int, thresholds=THRESHOLDS, target_ids=None) -> list[dict]:
    """Precision and recall of the fits that pass the checks kept at each minimum confidence.

    Parameters
    ----------
    confidence : array_like of shape (N,)
        The confidence of each fit that passes the checks.
    tp_ok : array_like of bool, shape (N,)
        Whether it is a target's first such match.
    targets : int
        Labelled targets in the frames.
    thresholds : sequence of float
        The minimum confidences.
    target_ids : sequence, optional
        The target each estimate is a true positive on: recall counts distinct targets; default one
        target an estimate.

    Returns
    -------
    list of dict
        Per threshold ``{"min_confidence", "kept", "precision", "recall"}`` (precision None where
        nothing is kept, recall None without targets).

    Raises
    ------
    ValueError
        For arrays of different lengths.
    """
    conf = np.asarray(confidence, dtype=np.float64).reshape(-1)
    tp = np.asarray(tp_ok, dtype=bool).reshape(-1)
    if conf.shape != tp.shape:
        raise ValueError(f"precision_recall: {conf.size} confidences but {tp.size} labels")
    ids = list(range(conf.size)) if target_ids is None else list(target_ids)
    rows = []
    for c in thresholds:
        keep = conf >= c
        kept, hits, found = int(keep.sum()), int(tp[keep].sum()), len({ids[i] for i in np.flatnonzero(keep & tp)})
        rows.append({"min_confidence": float(c), "kept": kept, "precision": hits / kept if kept else None,
                     "recall": found / targets if targets else None})
    return rows


def precision_recall_figure(rows: list[dict], default: float | None = DEFAULT_MIN_CONFIDENCE):
    """Precision against recall, one point per minimum confidence, the default marked.

    Parameters
    ----------
    rows : list of dict
        :func:`precision_recall`'s rows.
    default : float or None
        The run's default minimum confidence, marked (None: not marked, frames of both kinds).

    Returns
    -------
    matplotlib.figure.Figure
    """
    fig, ax = plt.subplots(figsize=(5.2, 4.4), layout="constrained")
    pts = [r for r in rows if r["precision"] is not None and r["recall"] is not None]
    ax.plot([r["recall"] for r in pts], [r["precision"] for r in pts], "o-", color="#1f77b4", ms=3,
            label="min confidence 0 to 1 (step 0.05)")
    for r in pts[::4]:
        ax.annotate(f"{r['min_confidence']:.2f}", (r["recall"], r["precision"]),
                    textcoords="offset points", xytext=(4, 4), fontsize=7)
    marked = [r for r in pts if default is not None and abs(r["min_confidence"] - default) < 1e-9]
    if marked:
        d = marked[0]
        ax.plot([d["recall"]], [d["precision"]], "*", color="#d62728", ms=14,
                label=f"default (--min-confidence {default:g}): P {d['precision']:.2f}, R {d['recall']:.2f}")
    ax.set(xlim=(0, 1), ylim=(0, 1.02), xlabel="recall (labelled isolated highlights found ok)",
           ylabel="precision (ok estimates on one)", title="fits that pass the checks over --min-confidence")
    ax.legend(fontsize=8, loc="lower left")
    return fig
