"""The Mitsuba side of a render: the variant (:func:`choose_variant`), the scene description built
(:func:`materialize`, meshes, texture) and kept between renders (:func:`_mitsuba_scene`), a ray caster."""

from __future__ import annotations

import dataclasses
import os
import threading
from typing import Any

import numpy as np

from simtest import _llvm
from simtest._lazy import require
from simtest.geometry.camera import pixel_to_ray
from simtest.render.mitsuba_dict import _SENSOR_TO_WORLD, cam_to_world_matrix, mesh_to_world_matrix, mitsuba_scene_dict
from simtest.render.tissue import in_camera, tissue_params, with_neighbours
from simtest.render.wavefront import dr_columns, dr_input
from simtest.scene.meshes import MeshError, load_mesh
from simtest.scene.spec import SceneSpec
from simtest.simulate.truth import saddle_mesh


class RendererUnavailable(RuntimeError):
    """Mitsuba cannot run the requested variant here (no LLVM / no GPU); the message names a fix."""


class RenderInputError(ValueError):
    """A scene cannot be rendered as given (a bad mesh file, a film too large); the message names the key and value."""


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
        "auto"/None: ``cuda_ad_rgb`` when a CUDA device is usable, else ``llvm_ad_rgb``; else as given.

    Raises
    ------
    RendererUnavailable
        If the variant cannot run here: no usable LLVM (the message names :data:`simtest._llvm.LLVM_FIX`)
        or no CUDA device.
    """
    libllvm = _llvm.configure_llvm_env()
    if libllvm:
        major = _llvm._major(libllvm)
        if major is not None and major < _llvm.MIN_LLVM_MAJOR and (requested or "auto") != "cuda_ad_rgb":
            raise RendererUnavailable(
                f"Dr.Jit is pointed at LLVM {major} ({libllvm}), too old for the llvm variants "
                f"(LLVM {_llvm.MIN_LLVM_MAJOR}+ needed): {_llvm.LLVM_FIX}")
    dr, mi = require("drjit"), require("mitsuba")
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
        # Dr.Jit may load an older system libLLVM, which aborts the process at the first kernel
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
    """Turn the plain dict of :func:`mitsuba_scene_dict` into what ``mi.load_dict`` takes (needs a variant)."""
    mi = require("mitsuba")
    if isinstance(d, dict):
        if d.get("type") == "simtest_arrays":
            return _make_mesh(d["vertices"], d["faces"], d["normals"], materialize(d["bsdf"]))
        return {k: mi.ScalarTransform4f(v.tolist()) if k == "to_world" and isinstance(v, np.ndarray)
                else materialize(v) for k, v in d.items()}
    return d


def _make_mesh(vertices, faces, normals, bsdf_dict):
    mi = require("mitsuba")
    props = mi.Properties()
    props["bsdf"] = mi.load_dict(bsdf_dict)
    mesh = mi.Mesh("surface", len(vertices), len(faces), props=props, has_vertex_normals=True)
    params = mi.traverse(mesh)
    params["vertex_positions"] = mi.Float(dr_input(np.ravel(vertices)))
    params["faces"] = mi.UInt32(dr_input(np.ravel(faces), np.uint32))
    params["vertex_normals"] = mi.Float(dr_input(np.ravel(normals)))
    params.update()
    return mesh


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
    """(4, 4) camera-to-scene-frame pose of a mesh (its world frame) or saddle (identity) scene."""
    if spec.geometry.frame == "camera":
        return np.eye(4)
    return cam_to_world_matrix(spec.camera)


def cam_to_texture_matrix(spec: SceneSpec) -> np.ndarray:
    """(4, 4) rigid map from the camera frame to the tissue texture's frame.

    Meshes: the mesh file's axes moved by the mesh's rotation and translation (without its scale); spheres
    and cylinders: the world frame; planes and saddles: the camera frame (identity).
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
    """The tissue texture of ``spec`` as a function of camera-frame points."""
    mat = spec.material
    t = tissue_params(mat.tissue, mat.texture_seed, mat.relief_mm, mat.relief_scale_mm, relief_min_mm=mat.relief_min_mm,
                      relief_hurst=mat.relief_hurst, base=mat.albedo, film_variation=mat.film_variation,
                      film_scale_mm=mat.film_scale_mm, subsurface_mm=mat.subsurface_mm or 0.0,
                      film_thickness_mm=mat.film_thickness_mm, film_thickness_spread=mat.film_thickness_spread)
    t = with_neighbours(t, (mat.wall_tissue, mat.wall_centre_mm, mat.wall_radius_mm),
                        (mat.organ_tissue, mat.organ_centre_mm, mat.organ_axes_mm))
    axes = spec.geometry.texture_axes()
    if axes is not None:  # the vessels in the surface's own axes (a plane's, in the camera frame)
        t = dataclasses.replace(t, uv_axes=axes)
    return in_camera(t, cam_to_texture_matrix(spec))


def _mesh_in_scene(spec: SceneSpec) -> dict[str, np.ndarray]:
    """Mesh arrays in the scene frame, cached, read-only: ``vertices``, ``faces``, ``normals``, ``k1``, ``k2``."""
    geo = spec.geometry
    key: tuple = (geo, geo.stamp())
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
        s = geo.scale if geo.scale is not None else 1.0
        k1, k2 = (np.asarray(attrs[name], dtype=np.float64) / s for name in ("k1", "k2"))
        if geo.flip_normals:
            n, k1, k2 = -n, -k2, -k1
        data = {"vertices": v, "faces": np.asarray(mesh.faces, dtype=np.int64), "normals": n, "k1": k1, "k2": k2}
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
    level = mi.logger().log_level()
    if spec.geometry.quiet_load:  # a false warning on its transform
        mi.set_log_level(mi.LogLevel.Error)
    try:
        return mi.load_dict(materialize(d))
    finally:
        mi.set_log_level(level)


def _cache_put(cache: dict, size: int, key: tuple, value) -> None:
    """Keep ``value`` under ``key`` in ``cache``, dropping the oldest entry beyond ``size``."""
    if len(cache) >= size:
        cache.pop(next(iter(cache)))
    cache[key] = value


def _mitsuba_scene(spec: SceneSpec, light_pos: np.ndarray, variant: str):
    """Load (or reuse) the Mitsuba scene: ``(scene, pose)``, pose None for analytic shapes (camera frame).

    Mesh and saddle scenes are cached by their structure, and every render sets all the values that may
    differ between specs sharing it (pose, light, Phong c, n, albedo): a render never depends on the last.
    """
    geo = spec.geometry
    if not geo.triangulated:
        key = (variant, spec.camera, spec.material, geo, spec.light.intensity, spec.light.falloff,
               tuple(np.round(light_pos, 12)), spec.render.spp, spec.render.sampler)
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
    key = (variant, "mesh", geo, geo.stamp(),
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
    """Ray caster through pixels (:data:`simtest.render.truth.Caster`) with camera-frame results.

    ``pose`` is the camera-to-scene-frame pose of a scene not built in the camera frame.
    """
    dr, mi = require("drjit"), require("mitsuba")
    identity = pose is None or np.array_equal(pose, np.eye(4))

    def cast(uv: np.ndarray) -> dict:
        d = pixel_to_ray(uv, K)
        if not identity:
            d = d @ pose[:3, :3].T
        d = d.astype(np.float32)
        n_rays = len(d)
        c = np.zeros(3, np.float32) if identity else pose[:3, 3].astype(np.float32)
        o = mi.Point3f(*(dr_input(np.full(n_rays, x, np.float32)) for x in c))
        ray = mi.Ray3f(o, mi.Vector3f(*dr_columns(d)))
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
