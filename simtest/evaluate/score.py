"""Scoring reconstructed highlights against per-pixel ground-truth normals (and depth).

Per ``ok`` estimate with valid ground truth at its BP: ``errors_bp_deg`` (angle to the true
normal at the BP pixel), ``errors_footprint_deg`` (to the renormalised mean normal inside the
primary isophote), ``dist_pp_px`` (BP to principal point), ``size_px`` (diameter of a disc of the
footprint's area) and, with depth, ``gt_curvature_per_mm`` (largest absolute principal curvature
of a quadric height field fitted in the BP's tangent frame), ``depth_gt_mm`` (distance along the
BP's ray) and ``depth_rel_error`` (``(estimate - truth) / truth`` per estimator with a depth).
Estimators are every normal the estimate has, and the recommended ``normal``.
"""

from __future__ import annotations

import cv2
import numpy as np

from simtest.geometry.angles import angle_between_deg
from simtest.geometry.cameras import CameraModel
from simtest.reconstruct.io import estimate_to_dict

__all__ = ["estimator_normals", "estimator_depths", "score_highlights", "summarise", "summarise_depth"]

#: Entries of an estimate's ``normals`` that are not one normal per highlight.
_NOT_ESTIMATORS = {"paper", "paper_selected_index"}


def estimator_normals(spec: dict) -> dict[str, np.ndarray | None]:
    """Every estimator's normal of one specularity dict (``estimates.json`` form).

    Parameters
    ----------
    spec : dict
        One entry of ``specularities``.

    Returns
    -------
    dict of str to ndarray of shape (3,) or None
        Estimator name -> normal (camera frame), None where that estimator gave none.
    """
    out: dict[str, np.ndarray | None] = {}
    for name, v in spec.get("normals", {}).items():
        if name in _NOT_ESTIMATORS:
            continue
        a = None if v is None else np.asarray(v, dtype=np.float64)
        if a is None or a.shape == (3,):
            out[name] = a
    if "normal" in spec:  # the recommended normal (estimates schema 2)
        out["normal"] = None if spec["normal"] is None else np.asarray(spec["normal"], dtype=np.float64)
    return out


def estimator_depths(spec: dict) -> dict[str, float]:
    """Every depth of one specularity dict, as :func:`estimator_normals` reads it: estimator name ->
    distance from the camera centre to the specular point along its ray, mm (the recommended
    ``depth_mm`` as ``normal``, then each light-aware estimator's; those without one left out)."""
    out: dict[str, float] = {}
    if spec.get("depth_mm") is not None:
        out["normal"] = float(spec["depth_mm"])
    for name, r in (spec.get("light_aware") or {}).items():
        if r.get("depth_mm") is not None:
            out[name] = float(r["depth_mm"])
    return out


def _ray_distance(depth_mm, camera: CameraModel, bp_uv) -> float | None:
    """The distance along the BP's ray to the surface, mm, from the z-depth at the sub-pixel BP
    (bilinear where the four neighbours are valid, else the nearest pixel's).
    """
    H, W = depth_mm.shape
    u, v = float(bp_uv[0]), float(bp_uv[1])
    ui, vi = int(round(u)), int(round(v))
    if not (0 <= ui < W and 0 <= vi < H) or not np.isfinite(depth_mm[vi, ui]):
        return None
    z = float(depth_mm[vi, ui])
    u0, v0 = int(np.floor(u)), int(np.floor(v))
    if 0 <= u0 < W - 1 and 0 <= v0 < H - 1:
        q = depth_mm[v0:v0 + 2, u0:u0 + 2]
        if np.isfinite(q).all():
            a, b = u - u0, v - v0
            z = float((1 - b) * ((1 - a) * q[0, 0] + a * q[0, 1]) + b * ((1 - a) * q[1, 0] + a * q[1, 1]))
    ray = camera.pixel_to_ray(np.array([[u, v]], dtype=np.float64))[0]
    if not (np.isfinite(ray).all() and ray[2] > 0):
        return None
    return z / float(ray[2] / np.linalg.norm(ray))


def _footprint(points_uv: np.ndarray, shape) -> tuple[np.ndarray, np.ndarray]:
    """Row and column indices of the pixels inside a closed contour."""
    pts = np.asarray(points_uv, dtype=np.float64)
    lo = np.maximum(np.floor(pts.min(axis=0)).astype(int), 0)
    hi = np.minimum(np.ceil(pts.max(axis=0)).astype(int), [shape[1] - 1, shape[0] - 1])
    if np.any(hi < lo):
        return np.zeros(0, int), np.zeros(0, int)
    mask = np.zeros((hi[1] - lo[1] + 1, hi[0] - lo[0] + 1), np.uint8)
    shift = 4  # sub-pixel polygon vertices (1/16 px)
    poly = np.round((pts - lo) * (1 << shift)).astype(np.int32)
    cv2.fillPoly(mask, [poly], 1, lineType=cv2.LINE_8, shift=shift)
    rr, cc = np.nonzero(mask)
    return rr + lo[1], cc + lo[0]


def _curvature(depth_mm, camera: CameraModel, bp_uv, normal, half_px: float) -> float | None:
    H, W = depth_mm.shape
    u0, v0 = int(round(bp_uv[0])), int(round(bp_uv[1]))
    h = int(max(3, np.ceil(half_px)))
    r0, r1, c0, c1 = max(0, v0 - h), min(H, v0 + h + 1), max(0, u0 - h), min(W, u0 + h + 1)
    d = depth_mm[r0:r1, c0:c1]
    vv, uu = np.mgrid[r0:r1, c0:c1]
    ok = np.isfinite(d)
    if ok.sum() < 12 or not np.isfinite(depth_mm[v0, u0]):
        return None
    rays = camera.pixel_to_ray(np.stack([uu[ok], vv[ok]], axis=1).astype(np.float64))
    with np.errstate(divide="ignore", invalid="ignore"):
        X = rays * (d[ok] / rays[:, 2])[:, None]  # z-depth along each ray
    X = X[np.isfinite(X).all(axis=1) & (rays[:, 2] > 0)]
    if len(X) < 12:
        return None
    ray0 = camera.pixel_to_ray(np.array([[u0, v0]], dtype=np.float64))[0]
    P0 = ray0 * depth_mm[v0, u0] / ray0[2]
    n = np.asarray(normal, dtype=np.float64)
    e1 = np.cross(n, [1.0, 0, 0] if abs(n[0]) < 0.9 else [0, 1.0, 0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(n, e1)
    Y = X - P0
    x, y, z = Y @ e1, Y @ e2, Y @ n
    A = np.column_stack([0.5 * x * x, x * y, 0.5 * y * y, x, y, np.ones_like(x)])
    coef, *_ = np.linalg.lstsq(A, z, rcond=None)
    k = np.linalg.eigvalsh(np.array([[coef[0], coef[1]], [coef[1], coef[2]]]))
    return float(np.abs(k).max())


def score_highlights(frame_id: str, estimates, truth, camera: CameraModel) -> list[dict]:
    """One row per highlight of a frame (module docstring).

    Parameters
    ----------
    frame_id : str
        The frame's number.
    estimates : list of SpecularityEstimate
    truth : simtest.evaluate.c3vd.GroundTruth
    camera : CameraModel

    Returns
    -------
    list of dict
        ``frame``, ``bp_px``, ``status``, ``scored``, ``dist_pp_px``, ``size_px``,
        ``gt_curvature_per_mm``, ``errors_bp_deg`` and ``errors_footprint_deg`` ({estimator:
        degrees or None}), and with depth ``depth_gt_mm`` and ``depth_rel_error``.
    """
    gt = truth.normals
    H, W = gt.shape[:2]
    pp = camera.principal_point
    rows = []
    for est in estimates:
        spec = estimate_to_dict(est)
        bp = np.asarray(est.bp_px, dtype=np.float64)
        row = {"frame": frame_id, "bp_px": [float(bp[0]), float(bp[1])], "status": est.status,
               "dist_pp_px": float(np.hypot(*(bp - pp))), "size_px": None, "gt_curvature_per_mm": None,
               "scored": False, "errors_bp_deg": {}, "errors_footprint_deg": {}}
        rows.append(row)
        if not est.ok:
            continue
        u, v = int(round(bp[0])), int(round(bp[1]))
        if not (0 <= u < W and 0 <= v < H) or not np.isfinite(gt[v, u]).all():
            row["status_gt"] = "no ground truth at the BP"
            continue
        n_bp = gt[v, u]
        rr, cc = _footprint(est.points_uv, gt.shape)
        n_fp = None
        if len(rr):
            row["size_px"] = float(2.0 * np.sqrt(len(rr) / np.pi))
            g = gt[rr, cc]
            g = g[np.isfinite(g).all(axis=1)]
            if len(g):
                m = g.mean(axis=0)
                n_fp = m / np.linalg.norm(m) if np.linalg.norm(m) > 0 else None
        if truth.depth_mm is not None:
            half = 0.5 * (row["size_px"] or 6.0)
            row["gt_curvature_per_mm"] = _curvature(truth.depth_mm, camera, bp, n_bp, half)
            gt_d = _ray_distance(truth.depth_mm, camera, bp)
            if gt_d is not None:
                row["depth_gt_mm"] = gt_d
                row["depth_rel_error"] = {name: (d - gt_d) / gt_d for name, d in estimator_depths(spec).items()}
        row["scored"] = True
        for name, n in estimator_normals(spec).items():
            row["errors_bp_deg"][name] = None if n is None else float(angle_between_deg(n, n_bp))
            row["errors_footprint_deg"][name] = (None if n is None or n_fp is None
                                                 else float(angle_between_deg(n, n_fp)))
    return rows


def summarise(rows: list[dict], key: str = "errors_bp_deg") -> dict[str, dict]:
    """Per-estimator statistics over the scored rows.

    Parameters
    ----------
    rows : list of dict
        From :func:`score_highlights`.
    key : {"errors_bp_deg", "errors_footprint_deg"}
        Which ground truth.

    Returns
    -------
    dict
        ``{name: {"n", "median_deg", "mean_deg", "p95_deg"}}`` (None statistics when n = 0),
        estimators in a fixed order (``normal`` first when present, ``bp_ray`` last).
    """
    names = sorted({name for r in rows for name in r[key]}, key=lambda s: (s != "normal", s == "bp_ray", s))
    out = {}
    for name in names:
        vals = np.array([r[key][name] for r in rows if r["scored"] and r[key].get(name) is not None], dtype=np.float64)
        if len(vals):
            out[name] = {"n": int(len(vals)), "median_deg": float(np.median(vals)),
                         "mean_deg": float(vals.mean()), "p95_deg": float(np.percentile(vals, 95))}
        else:
            out[name] = {"n": 0, "median_deg": None, "mean_deg": None, "p95_deg": None}
    return out


def summarise_depth(rows: list[dict]) -> dict[str, dict]:
    """Per-estimator statistics of the depth's relative error over the scored rows.

    Parameters
    ----------
    rows : list of dict
        From :func:`score_highlights`.

    Returns
    -------
    dict
        ``{name: {"n", "median_abs", "median", "p95_abs"}}``: the median absolute relative error,
        the median signed one (the bias) and the 95th percentile of the absolute one (fractions,
        not percent); ``normal`` (the recommended depth) first.
    """
    names = sorted({name for r in rows for name in r.get("depth_rel_error", {})}, key=lambda s: (s != "normal", s))
    out = {}
    for name in names:
        e = np.array([r["depth_rel_error"][name] for r in rows
                      if r["scored"] and name in r.get("depth_rel_error", {})], dtype=np.float64)
        out[name] = {"n": int(len(e)), "median_abs": float(np.median(np.abs(e))), "median": float(np.median(e)),
                     "p95_abs": float(np.percentile(np.abs(e), 95))}
    return out
