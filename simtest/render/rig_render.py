"""Endoscope renders (:func:`_render_endoscope`): light rigs and camera models
(:mod:`simtest.render.endoscope`), shaded in wavefronts (:mod:`simtest.render.wavefront`); and a render's
highlights (:func:`_highlights`, :func:`visible_highlights`) and sensor image (:func:`_sensor_image`),
shared with the pinhole renders of :mod:`simtest.render.render`."""

from __future__ import annotations

import dataclasses
import json

import numpy as np

from simtest.render.mitsuba_dict import cam_to_world_matrix, mitsuba_scene_dict
from simtest.render import wavefront
from simtest.render.endoscope import camera_model, guide_radius_mm, light_rig, sample_positions
from simtest.render.sensor import LUMA_WEIGHTS, apply_sensor, field_stop_mask, frame_luma, video_frame
from simtest.render.tissue import relief_normal
from simtest.render.truth import ReliefHighlight, mesh_highlight_candidates, mesh_highlights, relief_highlights
from simtest.scene.spec import SceneSpec
from simtest.simulate.truth import HighlightTruth, pixel_in_frame
from simtest.render.outputs import TISSUE_COVERAGE, RenderResult
from simtest.render.scene_load import (_PIXEL_RAYS, _SCENE_CACHE, _SCENE_CACHE_SIZE, _cache_put, _load_dict,
                                       _make_caster, _mesh_in_camera, tissue_texture)

#: Pixels per wavefront of the endoscope renderer (times spp rays); the image does not depend on it
BLOCK_PIXELS = 1 << 16


def _render_endoscope(spec: SceneSpec, seed: int, variant: str) -> RenderResult:
    """Render a scene with a light rig or a camera model (see :mod:`simtest.render.endoscope`)."""
    model = camera_model(spec)
    rig = light_rig(spec, seed)
    W, H = model.image_size
    geo = spec.geometry
    mesh = _mesh_in_camera(spec) if geo.triangulated else None
    key = (variant, "endoscope", spec.camera, spec.material, geo, geo.stamp())
    scene = _SCENE_CACHE.get(key)
    if scene is None:
        d = mitsuba_scene_dict(spec, light_pos_cam=np.zeros(3), mesh_cam=mesh)
        surface = d["surface"]
        if spec.material.model == "tissue":
            surface["bsdf"] = {"type": "diffuse"}  # not used: the tissue is shaded in wavefront
        elif surface["bsdf"]["type"] == "simtest_phong":
            surface["bsdf"]["cancel_falloff"] = False  # the rig's lights carry the falloff
        scene = _load_dict(spec, {"type": "scene", "surface": surface})
        _cache_put(_SCENE_CACHE, _SCENE_CACHE_SIZE, key, scene)
    shadows = bool(geo.triangulated and not rig.is_colocated)
    guide_r = guide_radius_mm(spec)
    mat = spec.material
    texture = tissue_texture(spec) if mat.model == "tissue" else None

    n_pix = W * H
    # the pixel centres' truth first; then every block's kernels are queued (Dr.Jit runs them
    # asynchronously) while this thread computes the truth maps and the highlight search's starts
    centre = wavefront.cast(scene, _pixel_rays(model), later=True)
    spp = spec.render.spp
    stop = _field_stop(spec, W, H)
    shaded, dark = _shaded_pixels(stop, W * H)
    pending, covered = [], []
    for b0 in range(0, len(shaded), BLOCK_PIXELS):
        run = shaded[b0:b0 + BLOCK_PIXELS]
        rays = wavefront.model_rays(model, sample_positions(spp, W, 0, 0, seed, pixels=run))
        if texture is None:
            pending.append(wavefront.shade(scene, rays, rig, shadows=shadows, spp=spp, defer=True,
                                           guide_radius_mm=guide_r))
        else:
            pending.append(wavefront.shade_tissue(scene, rays, rig, texture, mat, shadows=shadows, spp=spp,
                                                  guide_radius_mm=guide_r, defer=True))
    for b0 in range(0, len(dark), BLOCK_PIXELS):
        rays = wavefront.model_rays(model, sample_positions(spp, W, 0, 0, seed, pixels=dark[b0:b0 + BLOCK_PIXELS]))
        covered.append(wavefront.coverage(scene, rays, spp=spp, defer=True))
    c = centre()
    mask, p, n = c["hit"].reshape(H, W), c["p"].reshape(H, W, 3), c["n"].reshape(H, W, 3)
    if stop is not None:  # no truth where the scope shows nothing
        mask = mask & stop
    del c, centre
    nan = np.float32(np.nan)
    position = np.where(mask[..., None], p, nan).astype(np.float32)
    normals = np.where(mask[..., None], n, nan).astype(np.float32)
    depth = position[..., 2].copy()
    distance = np.where(mask, np.linalg.norm(p, axis=-1), nan).astype(np.float32)
    res = {"normals_raw": np.where(mask[..., None], n, 0.0), "position_raw": np.where(mask[..., None], p, 0.0),
           "mask": mask}
    relief = wavefront.relief_normals(p, n, texture, defer=True) if texture is not None else None
    alb = wavefront.albedo_map(p, texture, n, defer=True) if texture is not None else None
    starts = [mesh_highlight_candidates(res["normals_raw"], res["position_raw"], mask, light.position)
              if mesh is not None else None for light in rig.lights]
    spec_img = np.zeros(n_pix, np.float32)
    value = np.zeros((n_pix, 3), np.float32)
    coverage = np.empty(n_pix, np.float32)
    for b0, job in zip(range(0, len(shaded), BLOCK_PIXELS), pending):
        out = job.fetch()
        if texture is None:
            val, cov = out
            sp = val[:, 1]
        else:
            val, sp, cov = out
        run = shaded[b0:b0 + BLOCK_PIXELS]
        value[run] = val
        spec_img[run] = sp
        coverage[run] = cov
    for b0, job in zip(range(0, len(dark), BLOCK_PIXELS), covered):
        coverage[dark[b0:b0 + BLOCK_PIXELS]] = job.fetch()
    del pending, covered
    value = value.reshape(H, W, 3)
    rgb = shading = albedo = None
    if texture is None:
        linear = value[..., 0].copy()
    else:
        rgb = value
        linear = (value @ np.asarray(LUMA_WEIGHTS, dtype=np.float32)).astype(np.float32)
        shading = np.where(mask[..., None], relief.fetch(), nan).astype(np.float32)
        albedo = np.where(mask[..., None], alb.fetch(), nan).astype(np.float32)
    specular = spec_img.reshape(H, W)

    def cast_uv(q: np.ndarray) -> dict:
        return wavefront.cast(scene, model.pixel_to_ray(q))

    def cast_relief(q: np.ndarray) -> dict:
        """``cast_uv`` with the relief's shading normal (float64, the renderer's function) as ``n``."""
        hit = cast_uv(q)
        pq, nq = hit["p"].T, hit["n"].T
        hit["n_macro"] = hit["n"]
        hit["n"] = np.stack(relief_normal(np, tuple(pq), tuple(nq), texture), axis=-1)
        return hit

    # K of a pinhole or fisheye model; the pinhole stand-in's K (f = a0) of an omnidirectional
    K = np.asarray(model.K if hasattr(model, "K") else model.pinhole_stand_in().K, dtype=np.float64)
    highlights: list[HighlightTruth] = []
    for i, light in enumerate(rig.lights):
        found = _highlights(spec, res, light.position, K, None, None, cast=cast_uv, candidates=starts[i])
        for h in found:
            uvh = model.ray_to_pixel(h.bp_mm[None])[0] if h.bp_mm[2] > 0 else np.full(2, np.nan)
            highlights.append(dataclasses.replace(h, bp_px=uvh, light=i, in_frame=pixel_in_frame(uvh, (W, H))))
    highlights = [h for h in visible_highlights(highlights, specular) if _unoccluded(h, cast_uv)]
    glints: list[ReliefHighlight] = []
    if texture is not None and np.any(texture.relief_amp):
        for i, light in enumerate(rig.lights):
            for h in relief_highlights(cast_relief, shading, position, mask, light.position, specular=specular):
                if h.in_frame and h.bp_mm[2] > 0:
                    glints.append(dataclasses.replace(h, light=i))
        glints = visible_highlights(glints, specular)
        if glints:  # unoccluded, as _unoccluded, in one cast
            c = cast_uv(np.array([h.bp_px for h in glints], dtype=np.float64))
            dist = np.linalg.norm(np.array([h.bp_mm for h in glints]), axis=1)
            seen = c["hit"] & (np.abs(c["t"] - dist) <= OCCLUSION_REL * dist)
            glints = [h for h, s_ in zip(glints, seen) if s_]
    coverage = coverage.reshape(H, W)
    sensor, video = _sensor_image(linear, rgb, spec, seed, tissue=coverage >= TISSUE_COVERAGE)
    return RenderResult(linear=linear, sensor=sensor, specular=specular, normals=normals, depth=depth,
                        distance=distance, position=position, mask=mask, coverage=coverage, K=K,
                        cam_to_world=cam_to_world_matrix(spec.camera), light_pos=rig.lights[0].position,
                        highlights=highlights, variant=variant, seed=seed, spec=spec, camera=model, lights=rig, rgb=rgb,
                        shading_normals=shading, video=video, field_stop=stop, albedo=albedo, relief_highlights=glints)


def _field_stop(spec: SceneSpec, W: int, H: int) -> np.ndarray | None:
    """(H, W) bool: the pixels inside the scope's field stop (``sensor.field_stop`` with a video
    sensor), or None when the whole film sees the scene."""
    sensor = spec.sensor
    if sensor.output != "video" or sensor.field_stop == "none":
        return None
    return field_stop_mask((H, W), sensor.field_stop, sensor.field_stop_radius)


def _shaded_pixels(stop: np.ndarray | None, n_pix: int) -> tuple[np.ndarray, np.ndarray]:
    """Row-major indices of the pixels the endoscope renderer shades (inside the field ``stop``), and of the others.

    Outside the stop no shading rays are traced (radiance 0, truth NaN, coverage computed as everywhere);
    a shaded pixel gets the samples of a full-frame render.
    """
    if stop is None:
        return np.arange(n_pix, dtype=np.int64), np.zeros(0, dtype=np.int64)
    inside = stop.ravel()
    return np.flatnonzero(inside), np.flatnonzero(~inside)


def _pixel_rays(model) -> np.ndarray:
    """Unit rays (W H, 3) of every pixel centre through ``model``, row-major, float64, read-only (cached)."""
    W, H = model.image_size
    key = (type(model).__name__, json.dumps(model.params(), sort_keys=True, default=repr), W, H)
    rays = _PIXEL_RAYS.get(key)
    if rays is None:
        v, u = np.mgrid[0:H, 0:W]
        rays = model.pixel_to_ray(np.stack([u.ravel(), v.ravel()], axis=-1).astype(np.float64))
        rays.flags.writeable = False
        _cache_put(_PIXEL_RAYS, 2, key, rays)
    return rays


#: Relative depth difference above which a highlight's point counts as hidden behind another surface.
OCCLUSION_REL = 1e-4


def _unoccluded(h: HighlightTruth, cast_uv) -> bool:
    """Whether the ray through the highlight's pixel first meets the surface at its point."""
    if not h.in_frame:
        return True  # out of frame: listed for completeness, not checked against the image
    c = cast_uv(np.asarray(h.bp_px, dtype=np.float64)[None])
    dist = float(np.linalg.norm(h.bp_mm))
    return bool(c["hit"][0]) and abs(float(c["t"][0]) - dist) <= OCCLUSION_REL * dist


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
