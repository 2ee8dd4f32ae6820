"""End-to-end records: what ``simtest render`` then ``simtest reconstruct`` give a user.

A rendered realisation's frame (``frame.png``'s array) and camera file (``camera.json``: the camera
model, the light rig and the sensor's response, written and read back as the command line does)
go through :func:`simtest.reconstruct.cli.reconstruct_single`, the call behind ``simtest
reconstruct IMAGE`` with its defaults. Each in-frame ground-truth highlight gets a record: matched
to the nearest detection (any status) within :data:`~simtest.harness.metrics.MATCH_PX`, that
detection's status, what its recommended normal came from (``normal_from``: the fit, or
``bp_ray`` where it fell back), the recommended normal's error (deg) and depth error (%). A frame
also counts its false "ok": ok detections farther than ``MATCH_PX`` from every true highlight
(macro and micro-relief). :func:`simtest.harness.metrics.summarise_records` makes the figures.
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

__all__ = ["user_camera_file", "frame_records"]

def user_camera_file(result):
    """The camera file ``simtest render`` writes for ``result``, read back as ``simtest reconstruct``
    reads it (:func:`~simtest.geometry.camera_file.save_camera`, then ``load_camera``)."""
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
