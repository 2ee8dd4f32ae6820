"""End-to-end records: what ``simtest render`` then ``simtest reconstruct`` give a user.

A rendered realisation's frame (``frame.png``'s array) and camera file (``camera.json``: the camera
model, the light rig and the sensor's response, written and read back as the command line does)
go through :func:`simtest.reconstruct.cli.reconstruct_single`, the call behind ``simtest
reconstruct IMAGE`` with its defaults. Each in-frame ground-truth highlight gets a record: matched
to the nearest detection (any status) within :data:`MATCH_PX`, that detection's status, what its
recommended normal came from (``normal_from``: the fit, or ``bp_ray`` where it fell back), the
recommended normal's error (deg) and depth error (%). A frame also counts its false "ok": ok
detections farther than :data:`MATCH_PX` from every true highlight (macro and micro-relief).
"""

from __future__ import annotations

import math
import tempfile
from collections import Counter
from pathlib import Path

import numpy as np

from simtest.geometry.camera_file import load_camera, save_camera

__all__ = ["MATCH_PX", "user_camera_file", "frame_records", "summarise_records"]

#: How far a detection's BP may lie from a true highlight's BP to be that highlight's, px: the
#: harness's default ``match_px`` (:mod:`simtest.harness.cases`), so both sections match the same
#: highlights; a clipped plateau's brightest pixel lies within it of the specular point on the
#: suites' frames, and the two guides' highlights of the endoscope plane lie farther apart.
MATCH_PX = 15.0

#: Errors (deg) that count as a usable normal (issue 63's headline shares).
WITHIN_DEG = (1.0, 5.0)


def user_camera_file(result):
    """The camera file ``simtest render`` writes for ``result``, read back as ``simtest reconstruct``
    reads it (:func:`~simtest.geometry.camera_file.save_camera`, then ``load_camera``)."""
    from simtest.render.render import video_response  # the renderer's, not needed to summarise
    response = video_response(result.spec.sensor) if result.video is not None else None
    with tempfile.TemporaryDirectory() as d:
        path = save_camera(Path(d) / "camera.json", result.camera_model, result.light_rig, response)
        return load_camera(path)


def frame_records(result, depth_errors) -> list[dict]:
    """The end-to-end records of a render (``RenderResult``), one per in-frame highlight: ``detected``,
    ``distance_px``, ``status`` (``not_detected`` where none matched), ``normal_from``,
    ``error_deg``, ``depth_err_pct`` (``depth_errors(estimate, highlight, rig)``'s
    ``recommended_depth_err_pct``; NaN where none); the first holds the frame's ``frame_false_ok``.
    A frame without an in-frame highlight gives one record, ``truth`` False, with that count.
    """
    from simtest.harness.estimators import score
    from simtest.reconstruct.cli import reconstruct_single  # the command's call (numba: imported late)

    cam = user_camera_file(result)
    ests, _ = reconstruct_single(np.asarray(result.frame), cam)
    found = [(e, np.asarray(e.bp_px, float)) for e in ests if getattr(e, "bp_px", None) is not None]
    truths = [np.asarray(h.bp_px, float) for h in (*result.highlights, *result.relief_highlights)]
    false_ok = sum(1 for e, bp in found if e.status == "ok"
                   and all(float(np.linalg.norm(bp - t)) > MATCH_PX for t in truths))
    out = []
    for h in (h for h in result.highlights if getattr(h, "in_frame", True)):
        dist, best = min(((float(np.linalg.norm(bp - np.asarray(h.bp_px, float))), i)
                          for i, (_, bp) in enumerate(found)), default=(math.inf, None))
        e = found[best][0] if best is not None and dist <= MATCH_PX else None
        err = score(e, h.normal, ("recommended",), light=int(getattr(h, "light", 0)))["recommended"][0]
        rec = getattr(e, "recommended", None)
        out.append({"truth": True, "detected": e is not None, "distance_px": dist,
                    "status": "not_detected" if e is None else str(e.status),
                    "normal_from": None if rec is None else str(rec.normal_from), "error_deg": err,
                    "depth_err_pct": depth_errors(e, h, cam.lights)["recommended_depth_err_pct"]})
    out = out or [{"truth": False}]
    out[0]["frame_false_ok"] = float(false_ok)
    return out


def summarise_records(records) -> dict | None:
    """The end-to-end figures of a case or a family (None without a record).

    Returns
    -------
    dict or None
        ``n`` (true highlights), ``detected`` and ``ok`` (shares), ``within_1deg`` and
        ``within_5deg`` (shares of the true highlights whose recommended normal errs at most that
        much, whatever its status: what a user gets), ``n_ok`` and ``median_ok_deg`` (over those
        with status ok), ``median_ok_depth_err_pct``, ``false_ok_per_frame``, ``statuses`` and
        ``normal_from`` (counts), ``match_px``.
    """
    records = list(records)
    if not records:
        return None
    t = [r for r in records if r.get("truth")]
    err = np.array([r["error_deg"] for r in t], dtype=np.float64)
    ok = np.array([r["status"] == "ok" for r in t], dtype=bool)
    fo = np.array([r["frame_false_ok"] for r in records if "frame_false_ok" in r], dtype=np.float64)
    dep = np.array([r["depth_err_pct"] for r in t], dtype=np.float64)[ok] if t else np.zeros(0)
    dep = dep[np.isfinite(dep)]
    okerr = err[ok & np.isfinite(err)] if t else err
    n = len(t)
    share = (lambda m: float(np.mean(m)) if n else None)  # noqa: E731
    return {"n": n, "detected": share([r["detected"] for r in t]), "ok": share(ok),
            **{f"within_{d:g}deg": share(np.nan_to_num(err, nan=np.inf) <= d) for d in WITHIN_DEG},
            "n_ok": int(okerr.size), "median_ok_deg": float(np.median(okerr)) if okerr.size else None,
            "median_ok_depth_err_pct": float(np.median(dep)) if dep.size else None,
            "false_ok_per_frame": float(np.mean(fo)) if fo.size else None,
            "statuses": dict(sorted(Counter(r["status"] for r in t).items())),
            "normal_from": dict(sorted(Counter(r["normal_from"] or "none" for r in t).items())),
            "match_px": MATCH_PX}
