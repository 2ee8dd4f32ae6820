"""Scene spec -> Mitsuba scene dict: a pure function, testable without rendering.

The scene is built in the OpenCV camera frame (x right, y down, z forward, mm), so Mitsuba's world frame,
its AOVs and the ground truth are camera-frame; world-frame geometry is moved with ``inv(cam_to_world)``.
The dict holds only plain values: (4, 4) numpy arrays under ``to_world`` and ``simtest_arrays`` mesh
placeholders, which :func:`simtest.render.scene_load.materialize` turns into Mitsuba objects.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from simtest.scene.spec import CameraSpec, LightSpec, MeshGeometry, SceneSpec

__all__ = ["LIGHT_SEED_KEY", "intrinsics_matrix", "cam_to_world_matrix", "light_position_cam", "mesh_to_world_matrix",
           "mitsuba_scene_dict"]

#: Stable key of the light-offset draw in ``SeedSequence([seed, LIGHT_SEED_KEY])``.
LIGHT_SEED_KEY = 0x11647

#: Mitsuba sensor transform of the camera-frame camera: look_at((0,0,0), (0,0,1), up=(0,-1,0)).
#: Mitsuba's camera-local x points left, so the columns are (left, up, forward, origin).
_SENSOR_TO_WORLD = np.diag([-1.0, -1.0, 1.0, 1.0])


def intrinsics_matrix(camera: CameraSpec) -> np.ndarray:
    """Intrinsics K (3, 3), pixel centres at integers: ``[[f, 0, W/2 - 0.5 + ox], [0, f, H/2 - 0.5 + oy], [0, 0, 1]]``.

    ``f`` is ``camera.focal``, ``(ox, oy)`` ``camera.principal_offset_px`` (Mitsuba puts pixel centres at i + 0.5).
    """
    f = camera.focal
    ox, oy = camera.principal_offset_px
    return np.array([[f, 0.0, camera.width_px / 2.0 - 0.5 + ox], [0.0, f, camera.height_px / 2.0 - 0.5 + oy],
                     [0.0, 0.0, 1.0]], dtype=np.float64)


def cam_to_world_matrix(camera: CameraSpec) -> np.ndarray:
    """The (4, 4) pose of the OpenCV camera in the scene's world frame (columns x, y, z axes and the centre)."""
    c = np.asarray(camera.position_mm, dtype=np.float64)
    z = np.asarray(camera.look_at_mm, dtype=np.float64) - c
    z /= np.linalg.norm(z)
    up = np.asarray(camera.up, dtype=np.float64)
    y = -(up - np.dot(up, z) * z)
    y /= np.linalg.norm(y)
    x = np.cross(y, z)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = x, y, z, c
    return m


def light_position_cam(light: LightSpec, seed: int) -> np.ndarray:
    """Point-light position (3,) in the camera frame, mm: ``epsilon (cos a, sin a, b)``.

    ``a`` (uniform in [0, 2 pi)) and ``b`` (uniform in [-0.5, 0.5]) are drawn from
    ``SeedSequence([seed, LIGHT_SEED_KEY])`` when the spec leaves them None (paper, section 4).
    """
    if light.epsilon_mm == 0.0:
        return np.zeros(3)
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), LIGHT_SEED_KEY]))
    a_draw, b_draw = rng.uniform(0.0, 2.0 * math.pi), rng.uniform(-0.5, 0.5)
    a = math.radians(light.alpha_deg) if light.alpha_deg is not None else a_draw
    b = light.b if light.b is not None else b_draw
    return light.epsilon_mm * np.array([math.cos(a), math.sin(a), b])


def mesh_to_world_matrix(geometry: MeshGeometry) -> np.ndarray:
    """(4, 4) mesh-to-world transform ``x -> Rz Ry Rx (scale x) + t`` of a mesh spec."""
    rx, ry, rz = (math.radians(v) for v in (geometry.rotate_deg or (0.0, 0.0, 0.0)))
    cx, sx, cy, sy, cz, sz = math.cos(rx), math.sin(rx), math.cos(ry), math.sin(ry), math.cos(rz), math.sin(rz)
    Rx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    Ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    Rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    m = np.eye(4)
    m[:3, :3] = Rz @ Ry @ Rx * (geometry.scale if geometry.scale is not None else 1.0)
    m[:3, 3] = geometry.translate_mm or (0.0, 0.0, 0.0)
    return m


def _bsdf_dict(spec: SceneSpec, light_pos: np.ndarray) -> dict[str, Any]:
    mat = spec.material
    if mat.model == "phong":
        return {"type": "simtest_phong", "c": float(mat.c), "n": float(mat.n), "albedo": float(mat.diffuse_albedo),
                "cancel_falloff": spec.light.falloff == "cancel", "light_pos": [float(x) for x in light_pos]}
    # Channels: R = image, G = specular only, B = diffuse only (see simtest.render.phong).
    spec_rgb = {"type": "rgb", "value": [mat.c, mat.c, 0.0]}
    common = {"distribution": mat.distribution, "alpha": mat.microfacet_alpha}
    if mat.base == "conductor":
        return {"type": "roughconductor", "material": "none", "specular_reflectance": spec_rgb, **common}
    a = mat.diffuse_albedo
    return {"type": "roughplastic", "int_ior": mat.ior, "ext_ior": 1.0,
            "specular_reflectance": spec_rgb,
            "diffuse_reflectance": {"type": "rgb", "value": [a, 0.0, a]},
            "nonlinear": False, **common}


def mitsuba_scene_dict(spec: SceneSpec, *, light_pos_cam: np.ndarray | None = None,
                       mesh_cam: dict[str, np.ndarray] | None = None) -> dict[str, Any]:
    """Translate a scene spec into a Mitsuba scene dict in the camera frame (pure function).

    Parameters
    ----------
    spec : SceneSpec
    light_pos_cam : ndarray of shape (3,), optional
        Light position in the camera frame, mm; default :func:`light_position_cam` with ``spec.render.seed``.
    mesh_cam : dict, optional
        For mesh and saddle geometry (required there): ``vertices`` (V, 3), ``normals`` (V, 3), ``faces`` (F, 3).

    Returns
    -------
    dict
        Keys ``type``, ``integrator``, ``sensor``, ``light``, ``surface``.

    Raises
    ------
    ValueError
        If a mesh geometry comes without ``mesh_cam``.
    """
    cam, geo = spec.camera, spec.geometry
    if light_pos_cam is None:
        light_pos_cam = light_position_cam(spec.light, spec.render.seed)
    light_pos_cam = np.asarray(light_pos_cam, dtype=np.float64)
    w2c = np.linalg.inv(cam_to_world_matrix(cam))

    sensor = {"type": "perspective", "fov": cam.fov_x_deg, "fov_axis": "x",
              # Mitsuba's offsets are fractions of the film size and move the principal point the other way
              "principal_point_offset_x": -cam.principal_offset_px[0] / cam.width_px,
              "principal_point_offset_y": -cam.principal_offset_px[1] / cam.height_px,
              "near_clip": 1e-2, "far_clip": 1e8, "to_world": _SENSOR_TO_WORLD.copy(),
              "film": {"type": "hdrfilm", "width": cam.width_px, "height": cam.height_px, "pixel_format": "rgba",
                       "rfilter": {"type": "box"}, "sample_border": False},
              "sampler": {"type": spec.render.sampler, "sample_count": spec.render.spp}}
    # offset lights can cast shadows only on meshes (simtest.render.integrator)
    integrator = {"type": "simtest_gt", "shadows": bool(spec.light.epsilon_mm > 0 and geo.triangulated)}
    light = {"type": "point", "position": [float(x) for x in light_pos_cam],
             "intensity": {"type": "rgb", "value": [spec.light.intensity] * 3}}
    bsdf = _bsdf_dict(spec, light_pos_cam)

    if not geo.triangulated:  # plane, sphere, cylinder (simtest.scene.kinds)
        surface = geo.surface(w2c, bsdf)
    else:  # mesh, saddle
        if mesh_cam is None:
            raise ValueError(f"{spec.source}: geometry.type {geo.type!r} needs mesh_cam arrays")
        surface = {"type": "simtest_arrays", "vertices": mesh_cam["vertices"],
                   "faces": mesh_cam["faces"], "normals": mesh_cam["normals"], "bsdf": bsdf}

    return {"type": "scene", "integrator": integrator, "sensor": sensor, "light": light, "surface": surface}
