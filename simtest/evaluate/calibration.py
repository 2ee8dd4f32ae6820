"""The confidence's calibration: an L2-penalised logistic fit of labelled features, its
leave-one-frame-out confidences, their reliability per bin, ranking AUC, and the penalty chosen
by cross-validation.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import minimize
from scipy.special import expit
from scipy.stats import mannwhitneyu

__all__ = ["CONFIDENCE_BINS", "L2_PENALTY", "PENALTY_GRID", "fit_logistic", "reliability",
           "cross_validated_confidence", "ranking_auc", "select_penalty"]

#: Confidence bins of the reliability diagram (the issue's: [0.5, 0.7), [0.7, 0.9), [0.9, 1]).
CONFIDENCE_BINS = (0.0, 0.3, 0.5, 0.7, 0.9, 1.0)
#: L2 penalty of the logistic fit on its weights: the value of :data:`PENALTY_GRID` with the smallest
#: leave-one-frame-out log-loss on the labelled frames (:func:`select_penalty`; ``tests/test_verify.py``).
L2_PENALTY = 1.0
#: Penalties :func:`select_penalty` tries.
PENALTY_GRID = (0.01, 0.1, 1.0, 10.0, 100.0, 1000.0)


def fit_logistic(X: np.ndarray, y: np.ndarray, penalty: float = L2_PENALTY) -> np.ndarray:
    """L2-penalised logistic regression by ``scipy.optimize.minimize`` (BFGS).

    Returns
    -------
    ndarray of shape (1 + X.shape[1],)
        Intercept, then weights.
    """
    A = np.c_[np.ones(len(X)), X]
    t = y.astype(np.float64)

    def loss(c):
        z = A @ c
        nll = np.sum(np.logaddexp(0.0, z) - t * z)
        return nll + 0.5 * penalty * np.sum(c[1:] ** 2), A.T @ (expit(z) - t) + penalty * np.r_[0.0, c[1:]]

    return minimize(loss, np.zeros(A.shape[1]), jac=True, method="BFGS").x


def reliability(conf: np.ndarray, y: np.ndarray, bins=CONFIDENCE_BINS) -> list[dict]:
    """Per confidence bin: count, mean confidence and the fraction of true highlights."""
    out = []
    for lo, hi in zip(bins[:-1], bins[1:]):
        m = (conf >= lo) & ((conf < hi) if hi < 1.0 else (conf <= hi))
        out.append({"bin": [lo, hi], "n": int(m.sum()), "mean_confidence": float(conf[m].mean()) if m.any() else None,
                    "fraction_true": float(y[m].mean()) if m.any() else None})
    return out


def cross_validated_confidence(X: np.ndarray, y: np.ndarray, group: np.ndarray,
                               penalty: float = L2_PENALTY) -> np.ndarray:
    """Each candidate's confidence from the logistic fitted on the other frames (leave one frame out).

    Parameters
    ----------
    X : ndarray of shape (N, F)
        Features (:func:`~simtest.evaluate.detection.confidence_rows`).
    y : ndarray of bool, shape (N,)
        Labels.
    group : ndarray of int, shape (N,)
        Frame of each row.
    penalty : float
        L2 penalty of :func:`fit_logistic`.

    Returns
    -------
    ndarray of shape (N,)
    """
    out = np.empty(len(y))
    for g in np.unique(group):
        m = group == g
        c = fit_logistic(X[~m], y[~m], penalty)
        out[m] = 1.0 / (1.0 + np.exp(-(c[0] + X[m] @ c[1:])))
    return out


def ranking_auc(conf: np.ndarray, y: np.ndarray) -> float | None:
    """The area under the ROC curve by the Mann-Whitney U statistic (ties count a half); None without
    both classes.
    """
    y = np.asarray(y, bool)
    if y.all() or not y.any():
        return None
    return float(mannwhitneyu(conf[y], conf[~y]).statistic / (y.sum() * (~y).sum()))


def select_penalty(X: np.ndarray, y: np.ndarray, group: np.ndarray, grid=PENALTY_GRID) -> float:
    """The L2 penalty of ``grid`` whose leave-one-frame-out confidences
    (:func:`cross_validated_confidence`) have the smallest mean log-loss (ties: the larger
    penalty).

    Returns
    -------
    float
    """
    best, best_loss = None, np.inf
    for pen in sorted(grid, reverse=True):
        p = np.clip(cross_validated_confidence(X, y, group, pen), 1e-12, 1 - 1e-12)
        loss = -float(np.mean(np.where(y, np.log(p), np.log1p(-p))))
        if loss < best_loss - 1e-12:
            best, best_loss = float(pen), loss
    return best
