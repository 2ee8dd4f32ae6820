"""Render a scene spec with Mitsuba 3: image, sensor image, per-pixel and per-highlight truth.

One render gives everything: the ``simtest_gt`` integrator (:mod:`simtest.render.integrator`)
traces each camera ray once, lights it from the point light and adds shading normals and
positions; the colour channels carry the full image (R), the specular-only image (G) and the
diffuse-only image (B) (see :mod:`simtest.render.phong`); alpha is the pixel coverage. All outputs
are camera-frame: analytic shapes and saddles are built in the OpenCV camera frame; mesh files are
built once in their world frame and a render moves the sensor to the camera pose (the integrator
writes its AOVs in the camera frame), so that a new view reuses the loaded scene and its
acceleration structure (:func:`_mitsuba_scene`).

This is the only module of simtest that imports Mitsuba, and it does so when a render is asked for,
through :func:`simtest._lazy.require`; the Mitsuba plugins (:mod:`simtest.render.phong`,
:mod:`simtest.render.integrator`, which subclass Mitsuba's classes when imported) are imported by
:func:`choose_variant` once a variant is set.
"""

from __future__ import annotations

import dataclasses
import json
import os
import resource
import threading
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from PIL import Image

from simtest import _llvm
from simtest._io import OutputFolderError, atomic_write, atomic_write_text, replace_output_folder
from simtest._io import check_output_folder as _check_output_folder
from simtest._lazy import require
from simtest.constants import MAX_SEED
from simtest.geometry.camera import pixel_to_ray
from simtest.geometry.camera_file import save_camera, save_intrinsics
from simtest.geometry.cameras import CameraModel, PinholeCamera
from simtest.geometry.lights import Light, LightRig
from simtest.geometry.response import video_response
from simtest.render.mitsuba_dict import (
    _SENSOR_TO_WORLD,
    cam_to_world_matrix,
    intrinsics_matrix,
    light_position_cam,
    mesh_to_world_matrix,
    mitsuba_scene_dict,
    plane_normal_cam,
    rotation_from_z,
)
from simtest.render import wavefront
from simtest.render.endoscope import camera_model, guide_radius_mm, light_rig, sample_positions, uses_endoscope
from simtest.render.sensor import LUMA_WEIGHTS, apply_sensor, field_stop_mask, frame_luma, video_frame
from simtest.render.tissue import in_camera, relief_normal, tissue_params, with_neighbours
from simtest.render.truth import ReliefHighlight, mesh_highlight_candidates, mesh_highlights, relief_highlights
from simtest.scene.meshes import MeshError, load_mesh
from simtest.scene.spec import SceneSpec, scene_to_dict
from simtest.simulate.truth import (
    HighlightTruth,
    cylinder_highlight,
    plane_highlight,
    saddle_mesh,
    sphere_highlight,
)

__all__ = [
    "MAX_SEED",
    "RenderResult",
    "RendererUnavailable",
    "RenderInputError",
    "check_film_fits",
    "visible_highlights",
    "choose_variant",
    "render_scene",
    "write_render",
    "RENDER_FILES",
    "OutputFolderError",
]




class RendererUnavailable(RuntimeError):
    """Mitsuba cannot run the requested variant here (no LLVM / no GPU); the message names a fix."""


class RenderInputError(ValueError):
    """A scene cannot be rendered as given: a bad mesh file or a film too large for memory.

    The message names the file or key and the value, for a one-line error.
    """


#: Bytes of memory one film pixel needs during a render, whatever the spp: Mitsuba's LLVM
#: variant renders the samples of a pixel in a loop, so its peak grows with the film only
#: (measured on a plane: 818 MB at 2048^2 against 312 MB at 1024^2, about 160 B/px, at 4 and 16
#: spp alike), plus the float32 images and ground-truth maps the renderer keeps (about 90 B/px)
#: and the compressed copy written to disk; 400 B/px leaves a margin for other shapes.
BYTES_PER_PIXEL = 400
#: Memory a render needs besides its film (the Mitsuba/LLVM runtime, measured ~300 MB).
BASE_BYTES = 512 * 2**20


def available_memory_bytes() -> int | None:
    """Memory a new allocation can get: MemAvailable, capped by RLIMIT_AS / RLIMIT_DATA.

    Returns None when neither is known (not Linux and no limit).
    """
    avail: int | None = None
    try:
        with open("/proc/meminfo", encoding="ascii") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    avail = int(line.split()[1]) * 1024
                    break
    except OSError:
        avail = None
    for lim in (resource.RLIMIT_AS, resource.RLIMIT_DATA):
        soft, _ = resource.getrlimit(lim)
        if soft != resource.RLIM_INFINITY:
            used = 0
            if lim == resource.RLIMIT_AS:
                try:
                    with open("/proc/self/statm", encoding="ascii") as fh:
                        used = int(fh.read().split()[0]) * os.sysconf("SC_PAGE_SIZE")
                except OSError:
                    used = 0
            room = max(int(soft) - used, 0)
            avail = room if avail is None else min(avail, room)
    return avail


def check_film_fits(spec: SceneSpec) -> None:
    """Raise :class:`RenderInputError` if the film of ``spec`` would not fit in memory.

    The need is estimated as ``BASE_BYTES + BYTES_PER_PIXEL * W * H`` (see
    :data:`BYTES_PER_PIXEL`), so that a render too large is refused with a message instead of
    being killed or crashing inside Mitsuba.
    """
    W, H = spec.camera.width_px, spec.camera.height_px
    need = BASE_BYTES + BYTES_PER_PIXEL * W * H
    avail = available_memory_bytes()
    if avail is not None and need > avail:
        raise RenderInputError(
            f"{spec.source}: camera.width_px x camera.height_px: a {W} x {H} render needs about "
            f"{need / 2**30:.1f} GiB of memory, more than the {avail / 2**30:.1f} GiB available")


@dataclass(frozen=True)
class RenderResult:
    """Everything one render produces. Images are (H, W[, 3]) arrays, camera frame, mm.

    Attributes
    ----------
    linear : ndarray of shape (H, W), float32
        Linear radiance (specular + diffuse). An endoscope render with a video sensor's field stop
        is 0 outside the stop (so are ``rgb`` and ``specular``): no light reaches there.
    sensor : ndarray of shape (H, W), uint8 or uint16
        After exposure, noise, clipping, gamma and quantisation (:func:`apply_sensor`).
    specular : ndarray of shape (H, W), float32
        Specular-only linear radiance.
    normals : ndarray of shape (H, W, 3), float32
        Unit shading normals facing the camera; NaN outside ``mask``.
    depth : ndarray of shape (H, W), float32
        z-depth, mm; NaN outside ``mask``.
    distance : ndarray of shape (H, W), float32
        Distance from the camera centre to the pixel's mean surface point, mm; NaN outside
        ``mask``.
    position : ndarray of shape (H, W, 3), float32
        Surface point, camera frame, mm; NaN outside ``mask``.
    mask : ndarray of shape (H, W), bool
        Pixels entirely covered by the surface (every sample hit it).
    coverage : ndarray of shape (H, W), float32
        Fraction of each pixel covered by the surface.
    K : ndarray of shape (3, 3)
        Intrinsics, pixel centres at integer coordinates.
    cam_to_world : ndarray of shape (4, 4)
        Camera pose in the scene's world frame.
    light_pos : ndarray of shape (3,)
        Point-light position, camera frame, mm.
    highlights : list of HighlightTruth
    variant : str
        Mitsuba variant used.
    seed : int
    spec : SceneSpec
    camera : CameraModel or None
        The camera model of an endoscope render (rays traced from it); None for Mitsuba's
        perspective sensor, whose model is the pinhole ``K``.
    lights : LightRig or None
        The light rig of an endoscope render; None for the one light at ``light_pos``.
    rgb : ndarray of shape (H, W, 3), float32, or None
        Linear RGB radiance of a tissue render (``material.model = "tissue"``); None when the
        image is grey (``linear``).
    shading_normals : ndarray of shape (H, W, 3), float32, or None
        Unit shading normals with the tissue's micro-relief, facing the camera, NaN outside
        ``mask`` (``normals`` is the macro normal of the surface); None without micro-relief.
    video : ndarray of shape (H, W, 3), uint8, or None
        The video frame when the sensor made one (``sensor.output = "video"``: ``sensor`` is its
        luma); :attr:`frame` gives it, or develops it from the linear image otherwise.
    field_stop : ndarray of shape (H, W), bool, or None
        Pixels inside the scope's field stop (``sensor.field_stop`` with a video sensor); None when
        the whole film sees the scene. Outside it there is no light and no truth: ``mask`` is
        False and the per-pixel truth NaN there.
    albedo : ndarray of shape (H, W, 3), float32, or None
        Linear RGB diffuse albedo of the tissue at each pixel centre's surface point (the function
        the renderer shades with), NaN outside ``mask``; None without tissue.
    relief_highlights : list of ReliefHighlight
        Specular points of the tissue's micro-relief (glints: the shading normal bisects camera
        and light), in frame, lit and unoccluded, each with its light
        (:func:`simtest.render.truth.relief_highlights`); ``highlights`` holds the macro surface's.
    """

    linear: np.ndarray
    sensor: np.ndarray
    specular: np.ndarray
    normals: np.ndarray
    depth: np.ndarray
    distance: np.ndarray
    position: np.ndarray
    mask: np.ndarray
    coverage: np.ndarray
    K: np.ndarray
    cam_to_world: np.ndarray
    light_pos: np.ndarray
    highlights: list[HighlightTruth]
    variant: str
    seed: int
    spec: SceneSpec = field(repr=False)
    camera: CameraModel | None = None
    lights: LightRig | None = None
    rgb: np.ndarray | None = None
    shading_normals: np.ndarray | None = None
    video: np.ndarray | None = field(default=None, repr=False)
    field_stop: np.ndarray | None = field(default=None, repr=False)
    albedo: np.ndarray | None = field(default=None, repr=False)
    relief_highlights: list = field(default_factory=list)

    @property
    def frame(self) -> np.ndarray:
        """The 8-bit RGB video frame (H, W, 3) of the scene's sensor (:func:`video_frame`)."""
        if self.video is not None:
            return self.video
        return video_frame(self.rgb if self.rgb is not None else self.linear, self.spec.sensor, self.seed,
                           tissue=self.coverage >= TISSUE_COVERAGE)

    @property
    def camera_model(self) -> CameraModel:
        """The camera model of the film (a pinhole with ``K`` for a perspective render)."""
        if self.camera is not None:
            return self.camera
        H, W = self.linear.shape[:2]
        return PinholeCamera(self.K, image_size=(W, H))

    @property
    def light_rig(self) -> LightRig:
        """The lights of the render, camera frame (one light at ``light_pos`` unless a rig)."""
        if self.lights is not None:
            return self.lights
        falloff = "none" if self.spec.light.falloff == "cancel" else "inverse_square"
        return LightRig((Light(tuple(float(x) for x in self.light_pos), self.spec.light.intensity,
                               falloff),))

    @property
    def gray(self) -> np.ndarray:
        """The linear image (already single-channel)."""
        return self.linear


# ------------------------------------------------------------------------------------------------
# Mitsuba set-up


def _loaded_llvm_major(dr) -> int | None:
    """Major version of the LLVM library Dr.Jit has loaded, or None where Dr.Jit does not say."""
    try:
        return int(dr.detail.llvm_version()[0])
    except Exception:  # noqa: BLE001 - an older or newer Dr.Jit without this call: not checked
        return None


def choose_variant(requested: str | None = None) -> str:
    """Select and activate a Mitsuba variant; return its name.

    Parameters
    ----------
    requested : str, optional
        "auto"/None: ``cuda_ad_rgb`` when a CUDA device is usable, else ``llvm_ad_rgb``. Any other
        value is used as given.

    Raises
    ------
    RendererUnavailable
        If the variant cannot run here: no usable LLVM (the message names
        :data:`simtest._llvm.LLVM_FIX`) or no CUDA device.
    """

    libllvm = _llvm.configure_llvm_env()
    if libllvm:
        major = _llvm._major(libllvm)
        if major is not None and major < _llvm.MIN_LLVM_MAJOR and (requested or "auto") != "cuda_ad_rgb":
            raise RendererUnavailable(
                f"Dr.Jit is pointed at LLVM {major} ({libllvm}), too old for the llvm variants "
                f"(LLVM {_llvm.MIN_LLVM_MAJOR}+ needed): {_llvm.LLVM_FIX}")
    dr = require("drjit")
    mi = require("mitsuba")

    variant = requested or "auto"
    if variant == "auto":
        has_cuda = False
        if "cuda_ad_rgb" in mi.variants():
            try:
                has_cuda = bool(dr.has_backend(dr.JitBackend.CUDA))
            except Exception:  # noqa: BLE001 - any failure means: no usable GPU
                has_cuda = False
        variant = "cuda_ad_rgb" if has_cuda else "llvm_ad_rgb"
    if variant not in mi.variants():
        raise RendererUnavailable(f"Mitsuba variant {variant!r} is not in this build "
                                  f"(available: {', '.join(mi.variants())})")
    if variant.startswith("llvm") and not dr.has_backend(dr.JitBackend.LLVM):
        raise RendererUnavailable(
            f"Mitsuba variant {variant!r} needs an LLVM shared library that Dr.Jit can load "
            f"(DRJIT_LIBLLVM_PATH={os.environ.get('DRJIT_LIBLLVM_PATH')!r}): {_llvm.LLVM_FIX}")
    if variant.startswith("llvm"):
        # With no LLVM 16+ found, Dr.Jit loads whatever libLLVM the system offers; Debian 12's
        # LLVM 15 aborts the process at the first kernel, so its version is checked here.
        loaded = _loaded_llvm_major(dr)
        if loaded is not None and loaded < _llvm.MIN_LLVM_MAJOR:
            raise RendererUnavailable(
                f"Dr.Jit loaded LLVM {loaded}, too old for the llvm variants "
                f"(LLVM {_llvm.MIN_LLVM_MAJOR}+ needed): {_llvm.LLVM_FIX}")
    if variant.startswith("cuda") and not dr.has_backend(dr.JitBackend.CUDA):
        raise RendererUnavailable(f"Mitsuba variant {variant!r} needs a CUDA GPU; none is usable. "
                                  "Use variant 'auto' or 'llvm_ad_rgb'.")
    if mi.variant() != variant:
        mi.set_variant(variant)
    from simtest.render import integrator, phong

    phong.register()
    integrator.register()
    return variant


def materialize(d: Any) -> Any:
    """Turn the plain dict of :func:`mitsuba_scene_dict` into what ``mi.load_dict`` takes.

    (4, 4) numpy arrays under ``to_world`` become ``mi.ScalarTransform4f``; ``simtest_arrays``
    placeholders become ``mi.Mesh`` objects with vertex normals. Needs an active variant.
    """
    mi = require("mitsuba")

    if isinstance(d, dict):
        if d.get("type") == "simtest_arrays":
            return _make_mesh(d["vertices"], d["faces"], d["normals"], materialize(d["bsdf"]))
        out = {}
        for k, v in d.items():
            if k == "to_world" and isinstance(v, np.ndarray):
                out[k] = mi.ScalarTransform4f(v.tolist())
            else:
                out[k] = materialize(v)
        return out
    return d


def _make_mesh(vertices, faces, normals, bsdf_dict):
    mi = require("mitsuba")

    props = mi.Properties()
    props["bsdf"] = mi.load_dict(bsdf_dict)
    mesh = mi.Mesh("surface", len(vertices), len(faces), props=props, has_vertex_normals=True)
    params = mi.traverse(mesh)
    params["vertex_positions"] = mi.Float(np.ravel(np.asarray(vertices, dtype=np.float32)))
    params["faces"] = mi.UInt32(np.ravel(np.asarray(faces, dtype=np.uint32)))
    params["vertex_normals"] = mi.Float(np.ravel(np.asarray(normals, dtype=np.float32)))
    params.update()
    return mesh


# ------------------------------------------------------------------------------------------------
# Meshes


_MESH_CACHE: dict[tuple, Any] = {}
_MESH_DATA_CACHE: dict[tuple, dict[str, np.ndarray]] = {}
_MESH_DATA_CACHE_SIZE = 4


def _load_mesh_file(path: str):
    key = (path, os.path.getmtime(path))
    if key not in _MESH_CACHE:
        _MESH_CACHE.clear()
        _MESH_CACHE[key] = load_mesh(path)
    return _MESH_CACHE[key]


def _scene_pose(spec: SceneSpec) -> np.ndarray:
    """(4, 4) camera-to-scene-frame pose of a mesh or saddle scene.

    Meshes are rendered in their world frame (a new camera pose then moves only the sensor);
    a saddle is defined in the camera frame (identity).
    """
    if spec.geometry.frame == "camera":
        return np.eye(4)
    return cam_to_world_matrix(spec.camera)


def cam_to_texture_matrix(spec: SceneSpec) -> np.ndarray:
    """(4, 4) rigid map from the camera frame to the frame the tissue texture is attached to.

    Meshes: the mesh file's own axes moved by the mesh's rotation and translation (mm, without its
    ``scale``: the texture keeps its wavelengths in mm), so that the tissue stays on the mesh
    whatever the camera pose or the mesh placement; spheres and cylinders: the world frame (their
    centres and axes are given in it); planes and saddles are defined in the camera frame, which
    is then their texture frame (identity).
    """
    geo = spec.geometry
    if geo.frame == "camera":
        return np.eye(4)
    c2w = cam_to_world_matrix(spec.camera)
    if geo.type != "mesh":
        return c2w
    m = mesh_to_world_matrix(geo)
    R = m[:3, :3] / (geo.scale if geo.scale is not None else 1.0)
    w2t = np.eye(4)
    w2t[:3, :3], w2t[:3, 3] = R.T, -R.T @ m[:3, 3]
    return w2t @ c2w


def tissue_texture(spec: SceneSpec):
    """The tissue texture of ``spec`` (``material.model = "tissue"``) as a function of camera-frame
    points (:func:`simtest.render.tissue.in_camera` of :func:`cam_to_texture_matrix`)."""
    mat = spec.material
    t = tissue_params(mat.tissue, mat.texture_seed, mat.relief_mm, mat.relief_scale_mm,
                      relief_min_mm=mat.relief_min_mm, relief_hurst=mat.relief_hurst, base=mat.albedo,
                      film_variation=mat.film_variation, film_scale_mm=mat.film_scale_mm)
    t = with_neighbours(t, (mat.wall_tissue, mat.wall_centre_mm, mat.wall_radius_mm),
                        (mat.organ_tissue, mat.organ_centre_mm, mat.organ_axes_mm))
    if spec.geometry.type == "plane":  # the vessels in the plane's own axes (its texture frame: the camera's)
        t = dataclasses.replace(t, uv_axes=rotation_from_z(plane_normal_cam(spec.geometry))[:, :2].T.copy())
    return in_camera(t, cam_to_texture_matrix(spec))


def _mesh_in_scene(spec: SceneSpec) -> dict[str, np.ndarray]:
    """Mesh arrays in the scene frame of :func:`_scene_pose` (cached per geometry and file).

    Returns ``vertices`` (V, 3), ``faces`` (F, 3), ``normals`` (V, 3) unit, ``k1``, ``k2`` (V,)
    (1/mm, sign convention of :mod:`simtest.scene.meshes`, flipped with the normals). Treat the
    arrays as read-only: they are shared between renders.
    """
    geo = spec.geometry
    key: tuple = (geo, os.path.getmtime(geo.path) if geo.type == "mesh" else None)
    hit = _MESH_DATA_CACHE.get(key)
    if hit is not None:
        return hit
    if geo.type == "saddle":
        data = saddle_mesh(geo.distance_mm, geo.radius1_mm, geo.radius2_mm,
                           geo.extent_mm if geo.extent_mm is not None else geo.distance_mm,
                           geo.resolution if geo.resolution is not None else 129)
    else:
        try:
            mesh = _load_mesh_file(geo.path)
        except MeshError as exc:
            raise RenderInputError(f"{spec.source}: geometry.path: {exc}") from None
        except Exception as exc:  # noqa: BLE001 - trimesh's PLY reader raises assorted types
            raise RenderInputError(f"{spec.source}: geometry.path: {geo.path}: not a mesh simtest "
                                   f"can read ({type(exc).__name__}: {exc})") from None
        attrs = mesh.vertex_attributes
        faces = np.asarray(mesh.faces)
        nv = len(mesh.vertices)
        if faces.size and (faces.min() < 0 or faces.max() >= nv):
            bad = int(np.argmax(np.any((faces < 0) | (faces >= nv), axis=1)))
            raise RenderInputError(
                f"{spec.source}: geometry.path: mesh {geo.path}: face {bad} indexes vertex "
                f"{faces[bad].tolist()} out of range (the mesh has {nv} vertices)")
        for name in ("k1", "k2"):
            if name not in attrs:
                raise RenderInputError(f"{spec.source}: geometry.path: mesh {geo.path} has no vertex "
                                 f"attribute {name!r} (build it with `simtest meshes build`)")
        m = mesh_to_world_matrix(geo)
        v = np.asarray(mesh.vertices, dtype=np.float64) @ m[:3, :3].T + m[:3, 3]
        n = np.asarray(mesh.vertex_normals, dtype=np.float64) @ m[:3, :3].T
        n /= np.linalg.norm(n, axis=1, keepdims=True)
        k1 = np.asarray(attrs["k1"], dtype=np.float64)
        k2 = np.asarray(attrs["k2"], dtype=np.float64)
        s = geo.scale if geo.scale is not None else 1.0
        k1, k2 = k1 / s, k2 / s
        if geo.flip_normals:
            n, k1, k2 = -n, -k2, -k1
        data = {"vertices": v, "faces": np.asarray(mesh.faces, dtype=np.int64), "normals": n,
                "k1": k1, "k2": k2}
    for a in data.values():
        a.flags.writeable = False
    _cache_put(_MESH_DATA_CACHE, _MESH_DATA_CACHE_SIZE, key, data)
    return data


def _mesh_in_camera(spec: SceneSpec) -> dict[str, np.ndarray]:
    """Mesh arrays (as :func:`_mesh_in_scene`) moved into the camera frame."""
    data = _mesh_in_scene(spec)
    pose = _scene_pose(spec)
    if np.array_equal(pose, np.eye(4)):
        return data
    R, c = pose[:3, :3], pose[:3, 3]
    return {**data, "vertices": (data["vertices"] - c) @ R, "normals": data["normals"] @ R}


# ------------------------------------------------------------------------------------------------
# Rendering

_SCENE_CACHE: dict[tuple, Any] = {}
_SCENE_CACHE_SIZE = 4
#: Pixel-centre ray tables of the endoscope renderer (:func:`_pixel_rays`), by camera model.
_PIXEL_RAYS: dict[tuple, np.ndarray] = {}
_RENDER_LOCK = threading.RLock()


def clear_caches() -> None:
    """Forget every loaded Mitsuba scene and mesh (the next render rebuilds them)."""
    with _RENDER_LOCK:
        _SCENE_CACHE.clear()
        _MESH_CACHE.clear()
        _MESH_DATA_CACHE.clear()
        _PIXEL_RAYS.clear()


def _load_dict(spec: SceneSpec, d: dict):
    mi = require("mitsuba")

    if spec.geometry.type == "cylinder":
        # Mitsuba flags float32 round-off in R diag(r, r, length) as "shearing": silence that.
        level = mi.logger().log_level()
        mi.set_log_level(mi.LogLevel.Error)
        try:
            return mi.load_dict(materialize(d))
        finally:
            mi.set_log_level(level)
    return mi.load_dict(materialize(d))


def _cache_put(cache: dict, size: int, key: tuple, value) -> None:
    """Keep ``value`` under ``key`` in ``cache``, dropping the oldest entry beyond ``size``."""
    if len(cache) >= size:
        cache.pop(next(iter(cache)))
    cache[key] = value


def _mitsuba_scene(spec: SceneSpec, light_pos: np.ndarray, variant: str):
    """Load (or reuse) the Mitsuba scene; the seed and sensor do not change it.

    Returns ``(scene, pose)``: ``pose`` (4, 4) is the camera-to-scene-frame pose for mesh and
    saddle scenes, None for analytic shapes (built in the camera frame).

    Mesh and saddle scenes are cached by what their structure depends on (the geometry, the film,
    the sampler, the material model and flags, whether shadows are traced) and every render sets
    all the values that may change between specs sharing that structure (camera pose, light
    position and intensity, Phong c, n, albedo) before rendering, on a fresh scene as on a reused
    one: a render never depends on what the process rendered before.
    """
    geo = spec.geometry
    if not geo.triangulated:
        key = (variant, spec.camera, spec.material, geo, spec.light.intensity,
               spec.light.falloff, tuple(np.round(light_pos, 12)), spec.render.spp,
               spec.render.sampler)
        hit = _SCENE_CACHE.get(key)
        if hit is None:
            hit = (_load_dict(spec, mitsuba_scene_dict(spec, light_pos_cam=light_pos)), None)
            _cache_put(_SCENE_CACHE, _SCENE_CACHE_SIZE, key, hit)
        return hit

    mi = require("mitsuba")

    mat = spec.material
    shadows = bool(spec.light.epsilon_mm > 0)
    cam = spec.camera
    film = (cam.width_px, cam.height_px, cam.focal, tuple(cam.principal_offset_px))
    if mat.model == "phong":
        mat_key: tuple = ("phong", mat.diffuse_albedo > 0.0, spec.light.falloff == "cancel")
    else:
        mat_key = (mat, spec.light.falloff)
    key = (variant, "mesh", geo, os.path.getmtime(geo.path) if geo.type == "mesh" else None,
           film, mat_key, shadows, spec.render.spp, spec.render.sampler)
    entry = _SCENE_CACHE.get(key)
    if entry is None:
        d = mitsuba_scene_dict(spec, light_pos_cam=np.zeros(3), mesh_cam=_mesh_in_scene(spec))
        scene = _load_dict(spec, d)
        entry = (scene, mi.traverse(scene))
        _cache_put(_SCENE_CACHE, _SCENE_CACHE_SIZE, key, entry)
    scene, params = entry
    pose = _scene_pose(spec)
    light_scene = pose[:3, :3] @ np.asarray(light_pos, dtype=np.float64) + pose[:3, 3]
    params["sensor.to_world"] = mi.ScalarTransform4f((pose @ _SENSOR_TO_WORLD).tolist())
    params["light.position"] = mi.Point3f(*(float(x) for x in light_scene))
    params["light.intensity.value"] = mi.Color3f(float(spec.light.intensity))
    params.update()
    if mat.model == "phong":
        bsdf = scene.shapes()[0].bsdf()
        bsdf.set_params(mat.c, mat.n, mat.diffuse_albedo, light_scene)
    integ = scene.integrator()
    integ.set_camera_pose(None if geo.frame == "camera" else pose)
    return scene, pose


def _make_caster(scene, K: np.ndarray, pose: np.ndarray | None = None):
    """Ray caster through pixels (see :data:`simtest.render.truth.Caster`), camera-frame results.

    ``pose`` is the camera-to-scene-frame pose of a scene not built in the camera frame.
    """
    dr = require("drjit")
    mi = require("mitsuba")

    identity = pose is None or np.array_equal(pose, np.eye(4))

    def cast(uv: np.ndarray) -> dict:
        d = pixel_to_ray(uv, K)
        if not identity:
            d = d @ pose[:3, :3].T
        d = d.astype(np.float32)
        n_rays = len(d)
        if identity:
            o = mi.Point3f(np.zeros(n_rays, np.float32), np.zeros(n_rays, np.float32),
                           np.zeros(n_rays, np.float32))
        else:
            c = pose[:3, 3].astype(np.float32)
            o = mi.Point3f(np.full(n_rays, c[0]), np.full(n_rays, c[1]), np.full(n_rays, c[2]))
        ray = mi.Ray3f(o, mi.Vector3f(d[:, 0], d[:, 1], d[:, 2]))
        si = scene.ray_intersect(ray)
        valid, p_j, n_j, prim_j = si.is_valid(), si.p, si.sh_frame.n, si.prim_index
        dr.eval(valid, p_j, n_j, prim_j)  # one kernel for all four outputs
        hit = np.array(valid, dtype=bool)
        p = np.array(p_j, dtype=np.float64).T
        n = np.array(n_j, dtype=np.float64).T
        if not identity:
            p = (p - pose[:3, 3]) @ pose[:3, :3]
            n = n @ pose[:3, :3]
        n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-30)
        n = np.where(np.sum(n * p, axis=1, keepdims=True) > 0, -n, n)
        prim = np.array(prim_j, dtype=np.int64)
        return {"hit": hit & np.all(np.isfinite(p), axis=1), "p": p, "n": n, "prim": prim}

    return cast


def _highlights(spec: SceneSpec, res: dict, light_pos, K, scene, pose, *, cast=None,
                candidates=None) -> list[HighlightTruth]:
    """Highlights of one light: closed forms for analytic shapes, a search on meshes.

    ``cast`` (uv -> hits, see :data:`simtest.render.truth.Caster`) replaces the pinhole caster of
    ``scene``/``pose`` (the endoscope renderer passes one that traces its camera model's rays);
    ``candidates`` are the mesh search's start pixels when already found
    (:func:`simtest.render.truth.mesh_highlight_candidates`).
    """
    geo = spec.geometry
    size = (spec.camera.width_px, spec.camera.height_px)
    w2c = np.linalg.inv(cam_to_world_matrix(spec.camera))
    hl: HighlightTruth | None
    if geo.type == "plane":
        hl = plane_highlight(plane_normal_cam(geo), geo.distance_mm, light_pos, K, size)
        if hl is not None:
            half = geo.extent_mm if geo.extent_mm is not None else 100.0 * geo.distance_mm
            foot = -geo.distance_mm * plane_normal_cam(geo)
            if np.max(np.abs(hl.bp_mm - foot)) > half:
                hl = None
        return [hl] if hl is not None else []
    if geo.type == "sphere":
        c = (w2c @ np.append(geo.center_mm, 1.0))[:3]
        hl = sphere_highlight(c, geo.radius_mm, light_pos, K, size)
        return [hl] if hl is not None else []
    if geo.type == "cylinder":
        c = (w2c @ np.append(geo.center_mm, 1.0))[:3]
        axis = np.asarray(geo.axis if geo.axis is not None else (1.0, 0.0, 0.0), dtype=np.float64)
        length = geo.length_mm if geo.length_mm is not None else 20.0 * geo.radius_mm
        hl = cylinder_highlight(c, w2c[:3, :3] @ axis, geo.radius_mm, length, light_pos, K, size)
        return [hl] if hl is not None else []
    mesh = _mesh_in_camera(spec)
    if cast is None:
        cast = _make_caster(scene, K, pose)
    return mesh_highlights(cast, res["normals_raw"], res["position_raw"],
                           res["mask"], light_pos, K, mesh["vertices"], mesh["faces"],
                           mesh["k1"], mesh["k2"], candidates=candidates)


def _sensor_image(linear: np.ndarray, rgb: np.ndarray | None, spec: SceneSpec,
                  seed: int, tissue: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray | None]:
    """The sensor image: :func:`apply_sensor` ("grey") or the video frame's luma ("video"), and the
    video frame when one was made (else None). ``tissue``: the pixels the surface covers (the
    "tissue" metering's)."""
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
        if not (np.all(np.isfinite(h.bp_mm)) and np.all(np.isfinite(h.normal))
                and np.all(np.isfinite(h.bp_px))):
            continue
        if h.bp_mm[2] <= 0.0:
            continue
        if h.in_frame:
            u, v = int(round(h.bp_px[0])), int(round(h.bp_px[1]))
            if 0 <= u < W and 0 <= v < H and not specular[v, u] > 0.0:
                continue
        out.append(h)
    return out


def render_scene(spec: SceneSpec, *, seed: int | None = None,
                 variant: str | None = None) -> RenderResult:
    """Render ``spec`` and return the images with their ground truth.

    Parameters
    ----------
    spec : SceneSpec
    seed : int, optional
        Root seed of the sampler, the sensor noise and the light draw; None uses
        ``spec.render.seed``. The same seed gives bit-identical outputs.
    variant : str, optional
        Mitsuba variant; None uses ``spec.render.variant`` ("auto": CUDA if usable, else LLVM).

    Returns
    -------
    RenderResult

    Raises
    ------
    ValueError
        If ``seed`` is outside [0, 2^31 - 1] (:data:`MAX_SEED`).
    RendererUnavailable
        If Mitsuba cannot run the variant here.
    RenderInputError
        If the mesh file is not a readable PLY with k1/k2, a face indexes a missing vertex, or the
        film would not fit in memory (:func:`check_film_fits`).
    simtest.simulate.truth.HighlightTruthError
        If the brightest point of an analytic sphere or cylinder cannot be solved for (camera or
        light inside the surface).

    Notes
    -----
    With ``light.falloff = "cancel"`` the Phong BSDF multiplies by the squared light distance per
    sample (exact); the microfacet BSDFs are Mitsuba's own, so the image is multiplied per pixel by
    the squared light distance of the pixel's mean surface point (exact on fully covered pixels of a
    plane to second order in the pixel footprint).
    """
    mi = require("mitsuba")

    seed = spec.render.seed if seed is None else int(seed)
    if not 0 <= seed <= MAX_SEED:
        raise ValueError(f"render seed {seed} is out of range: must be in [0, 2^31 - 1 = {MAX_SEED}] "
                         "(Mitsuba's samplers take 32-bit seeds; the range of render.seed in scene files)")
    check_film_fits(spec)
    variant = choose_variant(variant or spec.render.variant)
    if uses_endoscope(spec):
        with _RENDER_LOCK:
            return _render_endoscope(spec, seed, variant)
    light_pos = light_position_cam(spec.light, seed)
    # Cached Mitsuba scenes are updated in place for each render (see _mitsuba_scene): one
    # render at a time per process, from the update to the last highlight ray cast.
    with _RENDER_LOCK:
        scene, pose = _mitsuba_scene(spec, light_pos, variant)

        image = mi.render(scene, spp=spec.render.spp, seed=seed)
        # A view of Dr.Jit's (host) memory, no copy; the view keeps ``image`` alive. Only new arrays
        # derived from it are returned.
        out = np.asarray(image)
        if out.dtype != np.float32:
            out = out.astype(np.float32)
        alpha = out[..., 3]
        nn, pp = out[..., 4:7], out[..., 7:10]
        nlen = np.sqrt(np.einsum("ijk,ijk->ij", nn, nn))
        mask = (alpha >= 1.0) & (nlen > 0)
        linear, specular = out[..., 0].copy(), out[..., 1].copy()
        if spec.light.falloff == "cancel" and spec.material.model != "phong":
            cov = np.where(alpha > 0, alpha, 1.0)[..., None]
            pos_mean = pp / cov  # partially covered pixels: mean over the samples that hit
            d2 = np.sum((pos_mean - light_pos.astype(np.float32)) ** 2, axis=-1)
            d2 = np.where(alpha > 0, d2, 0.0).astype(np.float32)
            linear *= d2
            specular *= d2

        # Unit normals facing the camera (n . ray < 0; the position lies along the ray from the
        # origin); NaN outside the mask.
        sign = np.where(np.einsum("ijk,ijk->ij", nn, pp) > 0, -1.0, 1.0).astype(np.float32)
        scale = np.where(mask, sign / np.where(mask, nlen, 1.0), np.float32(np.nan))
        normals = nn * scale[..., None]
        position = np.where(mask[..., None], pp, np.float32(np.nan))
        depth = position[..., 2].copy()
        distance = np.sqrt(np.einsum("ijk,ijk->ij", position, position))  # |mean position|

        K = intrinsics_matrix(spec.camera)
        if spec.geometry.triangulated:
            res = {"normals_raw": np.where(mask[..., None], normals, 0.0),
                   "position_raw": np.where(mask[..., None], position, 0.0), "mask": mask}
        else:
            res = {}
        highlights = visible_highlights(_highlights(spec, res, light_pos, K, scene, pose), specular)
    sensor, video = _sensor_image(linear, None, spec, seed, tissue=alpha >= TISSUE_COVERAGE)
    return RenderResult(
        linear=linear, sensor=sensor, specular=specular, normals=normals, depth=depth,
        distance=distance, position=position, mask=mask, coverage=alpha.astype(np.float32),
        K=K, cam_to_world=cam_to_world_matrix(spec.camera), light_pos=light_pos,
        highlights=highlights, variant=variant, seed=seed, spec=spec, video=video,
    )


# ------------------------------------------------------------------------------------------------
# Endoscope renders: light rigs and camera models (see simtest.render.endoscope)

#: Coverage from which a pixel counts as tissue for the "tissue" metering of the auto-exposure
#: (``sensor.metering``): half the pixel or more on the surface.
TISSUE_COVERAGE = 0.5

#: Pixels per wavefront of the endoscope renderer (times spp rays). The image does not depend on it:
#: each sample draws its sub-pixel position from its own stream
#: (:func:`simtest.render.endoscope.sample_positions`) and each pixel's samples are summed in order.
BLOCK_PIXELS = 1 << 16


def _render_endoscope(spec: SceneSpec, seed: int, variant: str) -> RenderResult:
    """Render a scene with a light rig or a camera model (see :mod:`simtest.render.endoscope`)."""
    model = camera_model(spec)
    rig = light_rig(spec, seed)
    W, H = model.image_size
    geo = spec.geometry
    mesh = _mesh_in_camera(spec) if geo.triangulated else None
    key = (variant, "endoscope", spec.camera, spec.material, geo,
           os.path.getmtime(geo.path) if geo.type == "mesh" else None)
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
    # The pixel centres' ground truth first (its casts wait for every kernel queued before them).
    centre = wavefront.cast(scene, _pixel_rays(model), later=True)
    # Then the image: every block's kernels are queued (Dr.Jit's LLVM back-end runs them
    # asynchronously on its thread pool) while this thread computes the ground-truth maps and the
    # highlight search's start pixels in numpy; the results are read after that.
    spp = spec.render.spp
    shaded, dark = _shaded_pixels(spec, W, H)
    pending, covered = [], []
    for b0 in range(0, len(shaded), BLOCK_PIXELS):
        run = shaded[b0:b0 + BLOCK_PIXELS]
        rays = wavefront.model_rays(model, sample_positions(spp, W, 0, 0, seed, pixels=run))
        if texture is None:
            pending.append(wavefront.shade(scene, rays, rig, shadows=shadows, spp=spp, defer=True,
                                           guide_radius_mm=guide_r))
        else:
            pending.append(wavefront.shade_tissue(scene, rays, rig, texture, mat, shadows=shadows, spp=spp,
                                                  guide_radius_mm=guide_r,
                                                  defer=True))
    for b0 in range(0, len(dark), BLOCK_PIXELS):
        rays = wavefront.model_rays(model, sample_positions(spp, W, 0, 0, seed, pixels=dark[b0:b0 + BLOCK_PIXELS]))
        covered.append(wavefront.coverage(scene, rays, spp=spp, defer=True))
    c = centre()
    stop = _field_stop(spec, W, H)
    mask, p, n = c["hit"].reshape(H, W), c["p"].reshape(H, W, 3), c["n"].reshape(H, W, 3)
    if stop is not None:  # no truth where the scope shows nothing
        mask = mask & stop
        p = np.where(mask[..., None], p, np.nan)
        n = np.where(mask[..., None], n, np.nan)
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

    K = _stand_in_K(model)
    highlights: list[HighlightTruth] = []
    for i, light in enumerate(rig.lights):
        found = _highlights(spec, res, light.position, K, None, None, cast=cast_uv, candidates=starts[i])
        for h in found:
            uvh = model.ray_to_pixel(h.bp_mm[None])[0] if h.bp_mm[2] > 0 else np.full(2, np.nan)
            highlights.append(dataclasses.replace(
                h, bp_px=uvh, light=i,
                in_frame=bool(np.all(np.isfinite(uvh)) and -0.5 <= uvh[0] < W - 0.5
                              and -0.5 <= uvh[1] < H - 0.5)))
    highlights = [h for h in visible_highlights(highlights, specular) if _unoccluded(h, cast_uv)]
    glints: list[ReliefHighlight] = []
    if texture is not None and np.any(texture.relief_amp):
        for i, light in enumerate(rig.lights):
            for h in relief_highlights(cast_relief, shading, position, mask, light.position,
                                       specular=specular):
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
    return RenderResult(
        linear=linear, sensor=sensor, specular=specular, normals=normals, depth=depth,
        distance=distance, position=position, mask=mask, coverage=coverage,
        K=K, cam_to_world=cam_to_world_matrix(spec.camera), light_pos=rig.lights[0].position,
        highlights=highlights, variant=variant, seed=seed, spec=spec, camera=model, lights=rig,
        rgb=rgb, shading_normals=shading, video=video, field_stop=stop, albedo=albedo,
        relief_highlights=glints)


def _field_stop(spec: SceneSpec, W: int, H: int) -> np.ndarray | None:
    """(H, W) bool: the pixels inside the scope's field stop (``sensor.field_stop`` with a video
    sensor), or None when the whole film sees the scene."""
    sensor = spec.sensor
    if sensor.output != "video" or sensor.field_stop == "none":
        return None
    return field_stop_mask((H, W), sensor.field_stop, sensor.field_stop_radius)


def _shaded_pixels(spec: SceneSpec, W: int, H: int) -> tuple[np.ndarray, np.ndarray]:
    """Row-major indices of the pixels the endoscope renderer shades, and of the others.

    A scope's field stop (``sensor.field_stop``, with a video sensor) lets no light onto the
    pixels outside it: the renderer traces no shading rays there, and their radiance (``linear``,
    ``rgb``, ``specular``) is 0; their coverage is computed as everywhere, their ground truth is
    NaN (``mask`` False).
    Every shaded pixel gets the samples it gets in a full-frame render, so its value does not
    depend on the field stop.
    """
    stop = _field_stop(spec, W, H)
    if stop is None:
        return np.arange(W * H, dtype=np.int64), np.zeros(0, dtype=np.int64)
    inside = stop.ravel()
    return np.flatnonzero(inside), np.flatnonzero(~inside)


def _pixel_rays(model) -> np.ndarray:
    """Unit rays (W H, 3) of every pixel centre through ``model``, row-major, float64 (read-only).

    The table is kept for the last two camera models (a sweep or a dataset renders one camera
    model at many poses and seeds).
    """
    W, H = model.image_size
    key = (type(model).__name__, json.dumps(model.params(), sort_keys=True, default=repr), W, H)
    rays = _PIXEL_RAYS.get(key)
    if rays is None:
        v, u = np.mgrid[0:H, 0:W]
        rays = model.pixel_to_ray(np.stack([u.ravel(), v.ravel()], axis=-1).astype(np.float64))
        rays.flags.writeable = False
        _cache_put(_PIXEL_RAYS, 2, key, rays)
    return rays


def _stand_in_K(model) -> np.ndarray:
    """K of a pinhole or fisheye model; the pinhole stand-in's K (f = a0) of an omnidirectional."""
    if hasattr(model, "K"):
        return np.asarray(model.K, dtype=np.float64)
    return np.asarray(model.pinhole_stand_in().K, dtype=np.float64)


#: Relative depth difference above which a highlight's point counts as hidden behind another surface.
OCCLUSION_REL = 1e-4


def _unoccluded(h: HighlightTruth, cast_uv) -> bool:
    """Whether the ray through the highlight's pixel first meets the surface at its point."""
    if not h.in_frame:
        return True  # out of frame: listed for completeness, not checked against the image
    c = cast_uv(np.asarray(h.bp_px, dtype=np.float64)[None])
    dist = float(np.linalg.norm(h.bp_mm))
    return bool(c["hit"][0]) and abs(float(c["t"][0]) - dist) <= OCCLUSION_REL * dist


# ------------------------------------------------------------------------------------------------
# Output files


#: File names of one render's output set (``write_render``); a folder holding anything else is not
#: replaced.
RENDER_FILES = ("image.png", "intrinsics.json", "ground_truth.npz", "highlights.json", "camera.json",
                "frame.png")


def check_output_folder(out: str | Path, option: str = "--out") -> None:
    """Raise :class:`~simtest._io.OutputFolderError` unless ``out`` is new, empty, or a folder
    holding only a render's files (:data:`RENDER_FILES`): ``simtest render`` replaces its output
    folder as a whole, so anything else there would be lost.
    """
    _check_output_folder(out, RENDER_FILES, option)


def _light_dict(light: Light) -> dict:
    """JSON-ready form of one light of a rig (every field of :class:`Light`; tuples as lists)."""
    out = {}
    for f in dataclasses.fields(light):
        v = getattr(light, f.name)
        out[f.name] = [float(x) for x in v] if isinstance(v, (tuple, list, np.ndarray)) else v
    return out


def write_render(result: RenderResult, out_dir: str | Path) -> dict[str, Path]:
    """Write a render to ``out_dir`` as one set: a failed write leaves the previous set or none.

    Files: ``image.png`` (the sensor image, 8 or 16 bit grey), ``intrinsics.json``
    (:func:`simtest.geometry.camera.save_intrinsics`), ``ground_truth.npz`` (``normals`` (H, W, 3),
    ``depth``, ``distance`` (H, W) mm, ``position`` (H, W, 3), ``mask``, ``linear``, ``specular``,
    ``coverage``, ``K``, ``cam_to_world``, ``light_pos`` (the first light, camera frame, mm),
    ``light_positions`` (L, 3) (every light of the rig), ``field_stop`` (H, W) bool (the pixels
    inside the scope's field stop; all True without one; outside it ``mask`` is False and the
    truth NaN)), ``highlights.json`` (``highlights``: list of :meth:`HighlightTruth.to_dict` with
    ``kind`` "macro"; ``relief_highlights``: the micro-relief's glints,
    :meth:`simtest.render.truth.ReliefHighlight.to_dict`, ``kind`` "micro_relief"; ``lights``:
    every light of the rig (``position_mm``, ``intensity``, ``falloff``, ``profile_exponent``,
    camera frame); with the scene, seed and variant), ``camera.json`` (the camera model and its
    light rig, :func:`simtest.geometry.camera_file.save_camera`; with a video sensor, its
    ``"response"``, :func:`simtest.geometry.response.video_response`), ``frame.png`` (the 8-bit RGB
    video frame, :attr:`RenderResult.frame`); tissue renders add ``rgb`` (H, W, 3),
    ``shading_normals`` (H, W, 3) and ``albedo`` (H, W, 3) to ``ground_truth.npz``.

    The files are written into a temporary sibling folder that then replaces ``out_dir`` by
    renames (:func:`simtest._io.replace_output_folder`, which first clears what a killed write
    left beside it); ``out_dir`` may be new, empty or a previous render's folder
    (:data:`RENDER_FILES`).

    Returns
    -------
    dict
        File role -> path.

    Raises
    ------
    OutputFolderError
        If ``out_dir`` is a file or holds other files than a render's.
    OSError
        If writing fails (``out_dir`` then keeps its previous content, or does not exist).
    """

    out = Path(out_dir).absolute()
    check_output_folder(out)
    names = dict(zip(("image", "intrinsics", "ground_truth", "highlights", "camera", "frame"), RENDER_FILES))
    img = result.sensor
    if img.dtype == np.uint8:
        pil = Image.fromarray(img, mode="L")
    else:
        pil = Image.fromarray(img.astype(np.uint16))
    H, W = result.linear.shape[:2]
    rig = result.light_rig
    meta = {
        "scene": result.spec.name,
        "seed": result.seed,
        "variant": result.variant,
        "light_pos_mm": [float(x) for x in result.light_pos],
        "lights": [{**_light_dict(light), "diameter_mm": 2.0 * guide_radius_mm(result.spec)}
                   for light in rig.lights],
        "image_size": [W, H],
        "highlights": [{**h.to_dict(), "kind": "macro"} for h in result.highlights],
        "relief_highlights": [h.to_dict() for h in result.relief_highlights],
        "spec": scene_to_dict(result.spec),
    }
    stop = result.field_stop if result.field_stop is not None else np.ones((H, W), dtype=bool)
    light_positions = np.array([light.position_mm for light in rig.lights], dtype=np.float64).reshape(-1, 3)

    def fill(tmp: Path) -> None:
        paths = {k: tmp / v for k, v in names.items()}
        atomic_write(paths["image"], lambda t: pil.save(t, format="PNG"))
        save_intrinsics(paths["intrinsics"], result.K, dist_coeffs=None, image_size=(W, H))

        def write_npz(t):
            with open(t, "wb") as fh:
                np.savez_compressed(
                    fh, normals=result.normals, depth=result.depth, distance=result.distance,
                    position=result.position, mask=result.mask, linear=result.linear,
                    specular=result.specular, coverage=result.coverage, K=result.K,
                    cam_to_world=result.cam_to_world, light_pos=result.light_pos,
                    light_positions=light_positions, field_stop=stop,
                    **({"rgb": result.rgb} if result.rgb is not None else {}),
                    **({"albedo": result.albedo} if result.albedo is not None else {}),
                    **({"shading_normals": result.shading_normals}
                       if result.shading_normals is not None else {}))

        atomic_write(paths["ground_truth"], write_npz)
        atomic_write_text(paths["highlights"], json.dumps(meta, indent=2))
        # a video frame's camera file carries its sensor's response, so that the light-aware fits
        # of `simtest reconstruct` run on the frame's linear intensities
        save_camera(paths["camera"], result.camera_model, result.light_rig,
                    video_response(result.spec.sensor) if result.video is not None else None)
        frame = Image.fromarray(result.frame, mode="RGB")
        atomic_write(paths["frame"], lambda t: frame.save(t, format="PNG"))

    replace_output_folder(out, fill, owned=RENDER_FILES)
    return {k: out / v for k, v in names.items()}
