"""The accuracy tolerance: how far a change of the reconstruction may move its results.

Within :data:`ACCURACY`, "ok" statuses change on at most 1 % of the candidates (appearing,
disappearing, or turning ok/rejected; not between two rejection reasons), and the normals of the
highlights ok before and after move by a median of at most 0.01 deg and a 95th percentile of at
most 0.05 deg, for every estimator both give (0.01 deg is a tenth of the smallest error the
committed reports resolve). Candidates are paired by their BPs (nearest within ``match_px``).

``tests/golden.py --snapshot DIR`` / ``--compare DIR`` and ``tests/test_golden.py`` hold the
golden set to this tolerance.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from simtest.geometry.angles import angle_between_deg

__all__ = ["ACCURACY", "AccuracyTolerance", "Comparison", "compare_estimates", "pooled_comparison"]


@dataclass(frozen=True)
class AccuracyTolerance:
    """Bounds on how far a change may move the reconstruction's results (module docstring).

    Attributes
    ----------
    status_change_frac : float
        Largest fraction of candidates whose ok status may change.
    median_move_deg, p95_move_deg : float
        Largest median and 95th percentile of the angle between an estimator's normals before
        and after, over the highlights ok in both, deg.
    match_px : float
        Two candidates are the same when their BPs are this close, px.
    """

    status_change_frac: float = 0.01
    median_move_deg: float = 0.01
    p95_move_deg: float = 0.05
    match_px: float = 1.0


#: The project's accuracy tolerance (issue "Real-time reconstruction within a stated accuracy").
ACCURACY = AccuracyTolerance()


@dataclass
class Comparison:
    """What a change did to one or more frames' results.

    Attributes
    ----------
    candidates : int
        Candidates before or after (the larger count of each frame, summed).
    status_changes : list of str
        One line per candidate whose ok status changed (or that appeared or disappeared).
    moves_deg : dict of str to list of float
        Per estimator, the angle its normal moved on each highlight ok before and after, deg.
    """

    candidates: int = 0
    status_changes: list[str] = field(default_factory=list)
    moves_deg: dict[str, list[float]] = field(default_factory=dict)

    def stats(self) -> dict[str, dict[str, float]]:
        """Per estimator: ``{"n", "median", "p95", "max"}`` of its movements, deg."""
        out = {}
        for k, v in sorted(self.moves_deg.items()):
            a = np.asarray(v, dtype=np.float64)
            if a.size:
                out[k] = {"n": int(a.size), "median": float(np.median(a)),
                          "p95": float(np.percentile(a, 95)), "max": float(a.max())}
        return out

    def problems(self, tol: AccuracyTolerance = ACCURACY) -> list[str]:
        """Every bound of ``tol`` this comparison breaks, one line each (empty: within it)."""
        out = []
        frac = len(self.status_changes) / self.candidates if self.candidates else 0.0
        if frac > tol.status_change_frac:
            out.append(f"ok status changed on {len(self.status_changes)} of {self.candidates} candidates "
                       f"({frac:.2%} > {tol.status_change_frac:.0%}): " + "; ".join(self.status_changes[:5]))
        for k, s in self.stats().items():
            if s["median"] > tol.median_move_deg or s["p95"] > tol.p95_move_deg:
                out.append(f"{k}: normals moved by a median of {s['median']:.3g} deg and a 95th "
                           f"percentile of {s['p95']:.3g} deg over {s['n']} highlights (bounds "
                           f"{tol.median_move_deg:g} and {tol.p95_move_deg:g} deg)")
        return out

    def within(self, tol: AccuracyTolerance = ACCURACY) -> bool:
        """True when no bound of ``tol`` is broken."""
        return not self.problems(tol)


def _pairs(before: list[dict], after: list[dict], match_px: float):
    """One-to-one pairs of candidates by BP distance (greedy, nearest first)."""
    if not before or not after:
        return [], set(range(len(before))), set(range(len(after)))
    a = np.array([r["bp_px"] for r in before], float)
    b = np.array([r["bp_px"] for r in after], float)
    d = np.linalg.norm(a[:, None, :] - b[None, :, :], axis=2)
    order = np.argsort(d, axis=None, kind="stable")
    used_a, used_b, pairs = set(), set(), []
    for flat in order:
        i, j = divmod(int(flat), len(after))
        if d[i, j] > match_px:
            break
        if i in used_a or j in used_b:
            continue
        used_a.add(i)
        used_b.add(j)
        pairs.append((i, j))
    return pairs, set(range(len(before))) - used_a, set(range(len(after))) - used_b


def compare_estimates(before: list[dict], after: list[dict], *, name: str = "",
                      tol: AccuracyTolerance = ACCURACY) -> Comparison:
    """Compare one frame's estimates before and after a change.

    Parameters
    ----------
    before, after : list of dict
        Rows with ``"bp_px"`` ([u, v] px), ``"status"`` and ``"normals"`` ({estimator: [x, y, z]
        or None}, unit vectors in the camera frame), as ``estimates.json``'s specularities.
    name : str
        The frame, for the lines of :attr:`Comparison.status_changes`.
    tol : AccuracyTolerance
        Its ``match_px`` pairs the candidates.

    Returns
    -------
    Comparison
    """
    pairs, gone, new = _pairs(before, after, tol.match_px)
    cmp = Comparison(candidates=max(len(before), len(after)))
    where = f"{name}: " if name else ""
    for i in sorted(gone):
        if before[i]["status"] == "ok":
            cmp.status_changes.append(f"{where}ok candidate at {before[i]['bp_px']} disappeared")
    for j in sorted(new):
        if after[j]["status"] == "ok":
            cmp.status_changes.append(f"{where}ok candidate at {after[j]['bp_px']} appeared")
    for i, j in pairs:
        b, a = before[i], after[j]
        if (b["status"] == "ok") != (a["status"] == "ok"):
            cmp.status_changes.append(f"{where}candidate at {b['bp_px']}: {b['status']} -> {a['status']}")
            continue
        if b["status"] != "ok":
            continue
        for k, nb in (b.get("normals") or {}).items():
            na = (a.get("normals") or {}).get(k)
            if nb is None or na is None or np.asarray(nb, float).shape != (3,) or np.asarray(na, float).shape != (3,):
                continue
            cmp.moves_deg.setdefault(k, []).append(angle_between_deg(nb, na))
    return cmp


def pooled_comparison(comparisons: list[Comparison]) -> Comparison:
    """Several frames' comparisons as one (counts and movements pooled)."""
    out = Comparison()
    for c in comparisons:
        out.candidates += c.candidates
        out.status_changes += c.status_changes
        for k, v in c.moves_deg.items():
            out.moves_deg.setdefault(k, []).extend(v)
    return out
