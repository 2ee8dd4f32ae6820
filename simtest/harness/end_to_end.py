"""End-to-end records: what ``simtest render`` then ``simtest reconstruct`` give a user.

A rendered frame and its camera file, written and read back as the command line does, go through
:func:`simtest.reconstruct.cli.reconstruct_single` with its defaults; each in-frame true highlight
is matched to the nearest detection (any status) within :data:`~simtest.harness.metrics.MATCH_PX`.
:func:`simtest.harness.metrics.summarise_records` makes the figures.
"""

from __future__ import annotations

import math
import tempfile
from pathlib import Path

import numpy as np

from simtest.geometry.camera_file import load_camera, save_camera
from simtest.geometry.response import video_response
from simtest.harness.estimators import score
from simtest.harness.metrics import MATCH_PX
from simtest.reconstruct.cli import reconstruct_single
from simtest.render.truth import lobe_peak, smoothed_specular
from simtest.simulate.truth import bisector

__all__ = ["user_camera_file", "frame_records"]


def user_camera_file(result):
    """The camera file ``simtest render`` writes for ``result``, read back as ``simtest reconstruct`` does."""
    response = video_response(result.spec.sensor) if result.video is not None else None
    with tempfile.TemporaryDirectory() as d:
        path = save_camera(Path(d) / "camera.json", result.camera_model, result.light_rig, response)
        return load_camera(path)


def frame_records(result, depth_errors) -> list[dict]:
    """The end-to-end records of a render, one per in-frame highlight.

    Each holds ``truth``, ``detected``, ``distance_px``, ``status`` (``not_detected`` where none
    matched), ``normal_from``, ``error_deg``, ``bp_ray_error_deg`` (the same detection's BP ray:
    the baseline on the same highlights), ``sigma_deg`` (the recommended normal's stated 1-sigma,
    deg; None where it states none), ``depth_err_pct`` and ``depth_within_2sigma``
    (``depth_errors(estimate, highlight, rig)``'s ``recommended_depth_err_pct`` and
    ``recommended_depth_within_2sigma``: 1 or 0 where the recommended depth states a sigma, else
    NaN); the first also ``frame_false_ok``, the ok
    detections farther than ``MATCH_PX`` from every true highlight and on no specular lobe, and
    ``frame_lobe_ok_deg``, the errors of those on a lobe with no exact BP (:func:`_lobe_errors`). A
    frame without an in-frame highlight gives one record with ``truth`` False.
    """
    cam = user_camera_file(result)
    ests, _ = reconstruct_single(np.asarray(result.frame), cam)
    found = [(e, np.asarray(e.bp_px, float)) for e in ests if getattr(e, "bp_px", None) is not None]
    truths = [np.asarray(h.bp_px, float) for h in (*result.highlights, *result.relief_highlights)]
    far = [(e, bp) for e, bp in found if e.status == "ok"
           and all(float(np.linalg.norm(bp - t)) > MATCH_PX for t in truths)]
    lobes = _lobe_errors(result, far)
    out = []
    for h in (h for h in result.highlights if getattr(h, "in_frame", True)):
        dist, best = min(((float(np.linalg.norm(bp - np.asarray(h.bp_px, float))), i)
                          for i, (_, bp) in enumerate(found)), default=(math.inf, None))
        e = found[best][0] if best is not None and dist <= MATCH_PX else None
        got = score(e, h.normal, ("recommended", "bp_ray"), light=int(getattr(h, "light", 0)))
        err = got["recommended"][0]
        rec = getattr(e, "recommended", None)
        depth = depth_errors(e, h, cam.lights)
        out.append({"truth": True, "detected": e is not None, "distance_px": dist,
                    "status": "not_detected" if e is None else str(e.status),
                    "normal_from": None if rec is None else str(rec.normal_from), "error_deg": err,
                    "bp_ray_error_deg": got["bp_ray"][0],
                    "sigma_deg": None if getattr(rec, "normal_sigma_deg", None) is None
                    else float(rec.normal_sigma_deg),
                    "depth_err_pct": depth["recommended_depth_err_pct"],
                    "depth_within_2sigma": depth.get("recommended_depth_within_2sigma", math.nan)})
    out = out or [{"truth": False}]
    out[0]["frame_false_ok"] = float(len(far) - len(lobes))
    out[0]["frame_lobe_ok_deg"] = lobes
    return out


def _lobe_errors(result, far) -> list[float]:
    """The recommended normal's error, deg, of each ok detection ``far`` from every listed highlight that sits
    on a specular lobe's peak (:func:`simtest.render.truth.lobe_peak`), against the surface normal there with
    the light whose bisector lies nearest it."""
    if not far:
        return []
    sm = smoothed_specular(result.specular)
    valid = np.asarray(result.mask, bool) & (True if result.field_stop is None else np.asarray(result.field_stop))
    lights = np.asarray(result.light_rig.positions, float)
    out = []
    for e, bp in far:
        if (peak := lobe_peak(sm, valid, bp)) is None:
            continue
        v, u = int(peak[1]), int(peak[0])
        n, p = np.asarray(result.normals[v, u], float), np.asarray(result.position[v, u], float)
        light = int(np.argmax(bisector(p[None], lights) @ n))
        out.append(float(score(e, n, ("recommended",), light=light)["recommended"][0]))
    return out
