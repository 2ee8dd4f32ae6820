"""The estimates (:class:`IsophoteEstimate`, :class:`SpecularityEstimate`) and their assembly from a
frame's drafts (:func:`_complete`): the cone fits and estimators of every isophote in one batch each,
the joint cone axes and the ``merged`` test."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from simtest.reconstruct._pixels import Roi
from simtest.reconstruct.cone_fit import FitFrame, fit_cones, to_camera, to_fit_frame
from simtest.reconstruct.estimators import estimate_from_conics, joint_cone_axes
from simtest.reconstruct.failures import OK, Failure
from simtest.reconstruct.recommend import recommend


@dataclass(frozen=True)
class IsophoteEstimate:
    """The result at one isovalue.

    Attributes
    ----------
    isovalue : float
        t in (0, 1), relative to the normalisation (the BP intensity by default).
    status : str
        ``"ok"`` or a reason from :data:`~simtest.reconstruct.failures.REASONS`.
    detail : str
        Numbers behind a failure.
    points_uv : ndarray of shape (N, 2) or None
        Contour points as found in the image (distorted pixel coordinates), px.
    closed : bool
        False if the contour is cut (then fitted only with ``allow_open=True``).
    conic : ndarray of shape (3, 3) or None
        Fitted point conic in undistorted pixels (unit Frobenius norm) for a pinhole camera; None
        for other models (the fit is ``normalised_conic``).
    ellipse : simtest.geometry.conics.Ellipse or None
        Its centre (u, v) px, semi-axes (a >= b) px and angle (rad); None as ``conic``.
    fit_residual_px : float or None
        RMS Sampson distance of the points to the conic on the fit plane, px.
    normals_paper : ndarray of shape (2, 3) or None
        N+ and N-.
    paper_selected : ndarray of shape (3,) or None
        The non-oracle choice among N+ and N- (closer to the BP ray).
    paper_selected_index : int or None
        0 if that is N+, 1 if N-.
    cone_axis : ndarray of shape (3,) or None
        Cone-axis normal.
    eigenvalue_gap : float or None
        0 for a right circular cone.
    normalised_conic : ndarray of shape (3, 3) or None
        The isophote cone C' in the camera frame (K^T C K for a pinhole), unit Frobenius norm.
    """

    isovalue: float
    status: str
    detail: str = ""
    points_uv: np.ndarray | None = None
    closed: bool = False
    conic: np.ndarray | None = None
    ellipse: object | None = None
    fit_residual_px: float | None = None
    normals_paper: np.ndarray | None = None
    paper_selected: np.ndarray | None = None
    paper_selected_index: int | None = None
    cone_axis: np.ndarray | None = None
    eigenvalue_gap: float | None = None
    normalised_conic: np.ndarray | None = None

    @property
    def ok(self) -> bool:
        """True if the status is ``"ok"``."""
        return self.status == OK


def _of_primary(name: str, doc: str) -> property:
    """A property of :class:`SpecularityEstimate`: its primary isophote's ``name`` (None without one)."""
    def get(self):
        p = self.primary
        return None if p is None else getattr(p, name)
    return property(get, doc=doc)


@dataclass(frozen=True)
class SpecularityEstimate:
    """Everything estimated for one highlight.

    Attributes
    ----------
    bp_px : ndarray of shape (2,)
        Brightest point (u, v) as detected in the image, px.
    bp_intensity : float
        Intensity used for normalisation (image units).
    saturated : bool
        True if the BP is the centroid of a clipped plateau.
    roi : Roi
        Final region of interest (array indices, half-open).
    status : str
        ``"ok"`` or a reason: a detection rejection, the primary isophote's failure, or ``merged``
        (the primary isophote encloses another highlight's BP).
    detail : str
        Numbers behind the status.
    bp_ray : ndarray of shape (3,) or None
        BP-ray normal (minus the unit viewing ray of the BP); None when the BP has no ray.
    isophotes : tuple of IsophoteEstimate
        One per isovalue, in the order given.
    joint_cone_axis : ndarray of shape (3,) or None
        Common axis of the nested isophotes, when at least two succeeded.
    light_aware : dict or None
        The light-aware estimates by name, when a light rig off the camera centre is known (empty
        where no fit ran); None: no such rig.
    confidence : float or None
        In [0, 1] (:func:`simtest.reconstruct.verify.confidence`); None where not verified.
    """

    bp_px: np.ndarray
    bp_intensity: float
    saturated: bool
    roi: Roi
    status: str
    detail: str
    bp_ray: np.ndarray
    isophotes: tuple[IsophoteEstimate, ...]
    joint_cone_axis: np.ndarray | None = None
    light_aware: dict | None = None
    confidence: float | None = None

    @property
    def ok(self) -> bool:
        """True if the status is ``"ok"``."""
        return self.status == OK

    @property
    def recommended(self):
        """The recommended normal (:func:`simtest.reconstruct.recommend.recommend`)."""
        return recommend(self)

    @property
    def primary(self) -> IsophoteEstimate | None:
        """The isophote at the first isovalue (None for a rejected detection)."""
        return self.isophotes[0] if self.isophotes else None

    points_uv = _of_primary("points_uv", "Primary isophote points (N, 2) px, or None.")
    conic = _of_primary("conic", "Primary fitted conic (3, 3), or None.")
    ellipse = _of_primary("ellipse", "Primary ellipse parameters, or None.")
    normals_paper = _of_primary("normals_paper", "Primary N+ and N- (2, 3), or None.")
    paper_selected = _of_primary("paper_selected", "Primary non-oracle paper normal (3,), or None.")
    cone_axis = _of_primary("cone_axis", "Primary cone-axis normal (3,), or None.")
    eigenvalue_gap = _of_primary("eigenvalue_gap", "Primary eigenvalue gap, or None.")
    fit_residual_px = _of_primary("fit_residual_px", "Primary RMS Sampson residual, px, or None.")

@dataclass(frozen=True)
class _Pending:
    """An isophote extracted and waiting for its cone fit (done for a whole frame at once)."""

    isovalue: float
    iso: object  # simtest.reconstruct.isophote.Isophote

@dataclass
class _Draft:
    """One highlight after its isophotes were extracted, before the frame's batched fits."""

    bp_uv: np.ndarray
    i_bp: float
    saturated: bool
    roi: Roi
    bp_ray: np.ndarray
    fitf: FitFrame
    results: list
    other_bps: object = ()
    own_bp: int = -1  # this highlight's own row in other_bps (skipped), -1 if not there
def _complete(drafts: list) -> list[SpecularityEstimate]:
    """Fit the cones and run the estimators of every pending isophote of ``drafts``, one batch each,
    and finish each highlight (``merged`` test, joint cone axis).
    """
    # the drafts among the estimates (a real frame's thousands of rejections are finished already)
    dr = [d for d in drafts if type(d) is _Draft]
    pend = [(d, i) for d in dr for i, r in enumerate(d.results) if type(r) is _Pending]
    fits = fit_cones([d.results[i].iso.points_uv for d, i in pend], [d.fitf for d, _ in pend])
    fitted = [k for k, f in enumerate(fits) if f]
    ests = [] if not fitted else estimate_from_conics(
        np.array([fits[k].cone_fit_frame for k in fitted]).reshape(-1, 3, 3),
        np.array([to_fit_frame(pend[k][0].fitf, pend[k][0].bp_ray) for k in fitted]).reshape(-1, 3))
    est_of = dict(zip(fitted, ests))
    for k, ((d, i), fit) in enumerate(zip(pend, fits)):
        p = d.results[i]
        t, iso = p.isovalue, p.iso
        if not fit:
            d.results[i] = IsophoteEstimate(t, fit.reason, fit.detail, iso.points_uv, iso.closed)
            continue
        est = est_of[k]
        # (IsophoteEstimate's fields given in order)
        if not est:
            d.results[i] = IsophoteEstimate(t, est.reason, est.detail, iso.points_uv, iso.closed, fit.conic,
                                            fit.ellipse, fit.residual_px, None, None, None, None, None, fit.cone)
            continue
        f = d.fitf  # the estimators ran in the fit frame (identity for a pinhole): rotate back
        if f.on_image_plane:
            paper, selected, axis = est.paper, est.paper_selected, est.cone_axis
        else:
            paper, selected, axis = to_camera(f, est.paper), to_camera(f, est.paper_selected), to_camera(f, est.cone_axis)
        d.results[i] = IsophoteEstimate(t, OK, "" if iso.closed else "open contour fitted (allow_open=True)",
                                        iso.points_uv, iso.closed, fit.conic, fit.ellipse, fit.residual_px, paper,
                                        selected, est.paper_selected_index, axis, est.eigenvalue_gap, fit.cone)
    # joint cone axes of the highlights with two or more good isophotes, in one batch
    multi = [d for d in dr if sum(r.status == OK for r in d.results) >= 2]
    cones, group = [], []
    for g, d in enumerate(multi):
        for r in d.results:
            if r.ok:
                c = r.normalised_conic
                cones.append(c if d.fitf.on_image_plane else d.fitf.R @ c @ d.fitf.R.T)
                group.append(g)
    axes = joint_cone_axes(np.array(cones).reshape(-1, 3, 3), np.array(group, dtype=int),
                           np.array([to_fit_frame(d.fitf, d.bp_ray) for d in multi]).reshape(-1, 3)) if multi else ()
    joint_of = {id(d): (to_camera(d.fitf, j) if not isinstance(j, Failure) else None) for d, j in zip(multi, axes)}
    enclosed = _enclosed_counts(dr)
    return [_finish(d, joint_of.get(id(d)), enclosed.get(id(d))) if type(d) is _Draft else d for d in drafts]
def _enclosed_counts(drafts: list) -> dict:
    """``id(draft) -> n``: how many other BPs each draft's closed ok primary isophote encloses, one batch
    per frame's BPs (``other_bps``: a frame's :class:`_SortedBps`, or () for none).
    """
    todo = [d for d in drafts if isinstance(d.other_bps, _SortedBps) and d.results[0].status == OK
            and d.results[0].closed and len(d.other_bps) > (d.own_bp >= 0)]
    out = {}
    for others in {id(d.other_bps): d.other_bps for d in todo}.values():
        group = [d for d in todo if d.other_bps is others]
        n_in = count_enclosed([d.results[0].points_uv for d in group], others.uv, [d.own_bp for d in group], others.u)
        out.update(zip(map(id, group), n_in.tolist()))
    return out


def count_enclosed(polys: list, points, skips, us: np.ndarray | None = None) -> np.ndarray:
    """How many points each closed polygon encloses (the ``merged`` test).

    Parameters
    ----------
    polys : list of ndarray of shape (N_j, 2)
        Closed polygons (u, v), N_j >= 1, without a repeated end point.
    points : array_like of shape (k, 2)
        The points (u, v): sorted by u where ``us`` is given.
    skips : sequence of int
        Per polygon, the row of ``points`` not counted (its own BP); -1 for none.
    us : ndarray of shape (k,), optional
        The points' u, where the caller sorted them by it.

    Returns
    -------
    ndarray of int64, shape (len(polys),)
        Per polygon, the points but its skipped one inside by the even-odd rule, with the answers of
        :func:`~simtest.reconstruct.isophote.polygon_contains` (on edges and vertices too).
    """
    uv = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    skip = np.asarray(skips, dtype=np.int64).reshape(-1)
    if us is None:
        order = np.argsort(uv[:, 0], kind="stable")
        rank = np.empty_like(order)
        rank[order] = np.arange(len(order))
        uv = uv[order]
        skip = np.where(skip >= 0, rank[np.maximum(skip, 0)] if len(rank) else -1, -1)
        us = uv[:, 0]
    n_poly = len(polys)
    if n_poly == 0 or len(uv) == 0:
        return np.zeros(n_poly, np.int64)
    n_vert = np.array([len(p) for p in polys], dtype=np.int64)
    start = np.cumsum(n_vert) - n_vert
    verts = np.concatenate(polys, axis=0, dtype=np.float64)
    lo, hi = np.minimum.reduceat(verts, start, axis=0), np.maximum.reduceat(verts, start, axis=0)
    # (polygon, point) pairs of the points whose u lies in the polygon's u range, then v's
    first = np.searchsorted(us, lo[:, 0], "left")
    n_near = np.searchsorted(us, hi[:, 0], "right") - first
    pj = np.repeat(np.arange(n_poly), n_near)
    pk = np.arange(len(pj)) - np.repeat(np.cumsum(n_near) - n_near - first, n_near)
    pv = uv[pk, 1]
    keep = (pk != skip[pj]) & (pv >= lo[pj, 1]) & (pv <= hi[pj, 1])
    pj, pk = pj[keep], pk[keep]
    if len(pj) == 0:
        return np.zeros(n_poly, np.int64)
    # each pair against each edge of its polygon, from vertex e to the next (cyclic); the crossing's
    # u computed only where the edge straddles the point's v
    nxt = np.arange(1, len(verts) + 1)
    nxt[start + n_vert - 1] = start
    y, y2 = verts[:, 1], verts[nxt, 1]
    n_edge = n_vert[pj]
    ends = np.cumsum(n_edge)
    e = np.arange(ends[-1]) + np.repeat(start[pj] - (ends - n_edge), n_edge)
    py = np.repeat(uv[pk, 1], n_edge)
    s = np.flatnonzero((y[e] > py) != (y2[e] > py))
    e, py, pair = e[s], py[s], np.searchsorted(ends, s, "right")
    x, ye, x2, ye2 = verts[e, 0], y[e], verts[nxt[e], 0], y2[e]
    crosses = uv[pk[pair], 0] < x + (py - ye) * (x2 - x) / (ye2 - ye)
    inside = np.bincount(pair[crosses], minlength=len(pj)) % 2 == 1
    return np.bincount(pj[inside], minlength=n_poly).astype(np.int64)


class _SortedBps:
    """A frame's BPs (k, 2) sorted by u, and their u (k,) contiguous, for the ``merged`` test."""

    __slots__ = ("uv", "u")

    def __init__(self, uv: np.ndarray):
        self.uv = uv
        self.u = np.ascontiguousarray(uv[:, 0])

    def __len__(self) -> int:
        return len(self.uv)


def _merge_guard(det, bps_arr: np.ndarray) -> tuple[_SortedBps, np.ndarray, np.ndarray]:
    """``(others, keep, row_in_others)``: the BPs an isophote must not enclose sorted by u, which
    candidates are among them, and each one's row there (-1 if not there).
    """
    keep = np.array([c.status != "too_small" for c in det.candidates], dtype=bool)
    kept = np.flatnonzero(keep)
    order = np.argsort(bps_arr[kept, 0], kind="stable")
    others = _SortedBps(np.ascontiguousarray(bps_arr[kept][order]))
    row_in_others = np.full(len(keep), -1, dtype=np.int64)
    row_in_others[kept[order]] = np.arange(len(kept))
    return others, keep, row_in_others


def _finish(d: _Draft, joint, enclosed: int | None) -> SpecularityEstimate:
    """The estimate of a completed draft: the primary isophote's status, ``merged`` when it encloses
    another candidate's BP (``enclosed``: the count of :func:`_enclosed_counts`, None where not counted).
    """
    primary = d.results[0]
    status, detail = primary.status, primary.detail
    if enclosed:
        status, detail = "merged", f"the isophote at t = {primary.isovalue} encloses {enclosed} other BP(s)"
    return SpecularityEstimate(d.bp_uv, d.i_bp, d.saturated, d.roi, status, detail, d.bp_ray, tuple(d.results), joint)

def _replaced(est: SpecularityEstimate, **changes) -> SpecularityEstimate:
    """``dataclasses.replace(est, **changes)`` for a :class:`SpecularityEstimate`, by copying its ``__dict__``."""
    new = object.__new__(SpecularityEstimate)
    new.__dict__.update(est.__dict__)
    new.__dict__.update(changes)
    return new
