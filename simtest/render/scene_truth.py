"""A render's highlights (:func:`_highlights`, :func:`visible_highlights`) and sensor image
(:func:`_sensor_image`), shared by the pinhole and the endoscope renders."""

from __future__ import annotations

import numpy as np

from simtest.render.mitsuba_dict import cam_to_world_matrix
from simtest.render.sensor import apply_sensor, frame_luma, video_frame
from simtest.render.truth import mesh_highlights
from simtest.scene.spec import SceneSpec
from simtest.simulate.truth import HighlightTruth
from simtest.render.scene_load import _make_caster, _mesh_in_camera


def _highlights(spec: SceneSpec, res: dict, light_pos, K, scene, pose, *, cast=None,
                candidates=None) -> list[HighlightTruth]:
    """Highlights of one light: closed forms for analytic shapes, a search on meshes.

    ``cast`` (:data:`simtest.render.truth.Caster`) replaces the pinhole caster of ``scene``/``pose``;
    ``candidates`` are the mesh search's start pixels when already found.
    """
    geo = spec.geometry
    size = (spec.camera.width_px, spec.camera.height_px)
    w2c = np.linalg.inv(cam_to_world_matrix(spec.camera))
    if not geo.triangulated:  # plane, sphere, cylinder: closed forms (simtest.scene.kinds)
        hl = geo.highlight(w2c, light_pos, K, size)
        return [hl] if hl is not None else []
    # mesh, saddle: the search
    mesh = _mesh_in_camera(spec)
    if cast is None:
        cast = _make_caster(scene, K, pose)
    return mesh_highlights(cast, res["normals_raw"], res["position_raw"], res["mask"], light_pos, K,
                           mesh["vertices"], mesh["faces"], mesh["k1"], mesh["k2"], candidates=candidates)


def _sensor_image(linear: np.ndarray, rgb: np.ndarray | None, spec: SceneSpec,
                  seed: int, tissue: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray | None]:
    """The sensor image (:func:`apply_sensor`, or the video frame's luma) and the video frame (or None)."""
    if spec.sensor.output == "video":
        frame = video_frame(rgb if rgb is not None else linear, spec.sensor, seed, tissue=tissue)
        return frame_luma(frame), frame
    return apply_sensor(linear, spec.sensor, seed), None


def visible_highlights(highlights: list[HighlightTruth], specular: np.ndarray) -> list[HighlightTruth]:
    """The highlights a camera can see: finite, in front of the camera, lit where in frame.

    A brightest point found on the analytic surface or the mesh is dropped when its position or
    normal is not finite, when it lies behind the camera (``z <= 0``: e.g. the nearest point of a
    sphere the camera looks away from), or when it is in frame but its pixel carries no specular
    light (a shadowed BP, or a light the visible side does not face).

    Parameters
    ----------
    highlights : list of HighlightTruth
    specular : ndarray of shape (H, W)
        The render's specular-only linear image.

    Returns
    -------
    list of HighlightTruth
        The kept highlights, in their order.
    """
    H, W = specular.shape[:2]
    out = []
    for h in highlights:
        if not (np.all(np.isfinite(h.bp_mm)) and np.all(np.isfinite(h.normal)) and np.all(np.isfinite(h.bp_px))):
            continue
        if h.bp_mm[2] <= 0.0:
            continue
        if h.in_frame:
            u, v = int(round(h.bp_px[0])), int(round(h.bp_px[1]))
            if 0 <= u < W and 0 <= v < H and not specular[v, u] > 0.0:
                continue
        out.append(h)
    return out
