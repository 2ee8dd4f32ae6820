"""A render's highlights (:func:`_highlights`, :func:`visible_highlights`) and sensor image
(:func:`_sensor_image`), shared by the pinhole and the endoscope renders."""

from __future__ import annotations

import numpy as np

from simtest.render.mitsuba_dict import cam_to_world_matrix, plane_normal_cam
from simtest.render.sensor import apply_sensor, frame_luma, video_frame
from simtest.render.truth import mesh_highlights
from simtest.scene.spec import SceneSpec
from simtest.simulate.truth import HighlightTruth, cylinder_highlight, plane_highlight, sphere_highlight
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
    hl: HighlightTruth | None
    if geo.type == "plane":
        hl = plane_highlight(plane_normal_cam(geo), geo.distance_mm, light_pos, K, size)
        half = geo.extent_mm if geo.extent_mm is not None else 100.0 * geo.distance_mm
        foot = -geo.distance_mm * plane_normal_cam(geo)
        if hl is not None and np.max(np.abs(hl.bp_mm - foot)) > half:
            hl = None
    elif geo.type == "sphere":
        hl = sphere_highlight((w2c @ np.append(geo.center_mm, 1.0))[:3], geo.radius_mm, light_pos, K, size)
    elif geo.type == "cylinder":
        c = (w2c @ np.append(geo.center_mm, 1.0))[:3]
        axis = np.asarray(geo.axis if geo.axis is not None else (1.0, 0.0, 0.0), dtype=np.float64)
        length = geo.length_mm if geo.length_mm is not None else 20.0 * geo.radius_mm
        hl = cylinder_highlight(c, w2c[:3, :3] @ axis, geo.radius_mm, length, light_pos, K, size)
    else:
        mesh = _mesh_in_camera(spec)
        if cast is None:
            cast = _make_caster(scene, K, pose)
        return mesh_highlights(cast, res["normals_raw"], res["position_raw"], res["mask"], light_pos, K,
                               mesh["vertices"], mesh["faces"], mesh["k1"], mesh["k2"], candidates=candidates)
    return [hl] if hl is not None else []


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
