"""One dataset sample: a pure function of (root seed, index).

Sample ``i`` draws its parameters from ``default_rng(SeedSequence([config.seed, i]))``, builds a
scene spec (:func:`build_scene`), renders it and collects arrays and highlight records
(:func:`render_sample`); nothing depends on the worker or the other samples.

Redraw rule: an analytic pose whose brightest point is undefined for some light (a camera inside a
cylinder, :func:`truth_problem`) keeps its family and redraws every other parameter, in the same
order, from child ``k`` of the sample's SeedSequence (``spawn_key=(k - 1,)``), k = 1, 2, ... up to
:data:`MAX_REDRAWS`; the parameters record ``redraw = k``. A defined truth without a highlight keeps
the sample with an empty ``highlights`` list.

Isophote labels (tangent-plane model): for each highlight and isovalue ``t`` the record holds the
image conic of the circle of radius ``r_-`` (paper Prop. 2, :func:`simtest.specular.isophote_radius`,
``c = 1``) in the tangent plane at the BP, centred on the foot ``F = (N . X_bp) N`` of the
perpendicular from the camera centre, at distance ``V_Z = -N . X_bp``
(:func:`simtest.geometry.conics.project_circle`). Exact for a plane with a co-located light and the
falloff cancelled; the first-order model the method assumes on curved surfaces.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import io
import math
import os
import threading
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from PIL import Image

from simtest._io import jsonable
from simtest._lazy import require
from simtest._llvm import configure_llvm_env
from simtest.constants import LUMINANCE_BT709, MAX_SEED
from simtest.dataset.config import PARAMS, DatasetConfig
from simtest.geometry.angles import unit
from simtest.geometry.conics import conic_kind, conic_to_ellipse, project_circle
from simtest.render import render_scene
from simtest.render.endoscope import light_rig
from simtest.render.sensor import apply_sensor, video_frame
from simtest.scene import bundled_mesh_path
from simtest.scene.poses import colon_pose, liver_surface_pose
from simtest.scene.spec import scene_from_dict, scene_to_dict
from simtest.simulate.truth import HighlightTruthError, cylinder_highlight, sphere_highlight
from simtest.specular import isophote_radius

__all__ = ["CHANNELS", "Sample", "build_scene", "draw_parameters", "MAX_REDRAWS", "isophote_record",
           "render_sample", "sample_rng", "truth_problem"]

#: Most redraws of one sample (the module's redraw rule); more is an error naming the family.
MAX_REDRAWS = 100

_RADIANCE_UNIT = "linear radiance (light_intensity x BRDF, / d^2 in mm when the falloff is kept)"

#: Arrays stored per sample: name -> (dtype, shape as text, unit, description).
CHANNELS: dict[str, dict[str, str]] = {
    "sensor_png": {"dtype": "uint8", "shape": "(nbytes,)", "unit": "PNG file bytes",
                   "description": "the sensor image as an endoscope outputs it (8-bit PNG; "
                                  "auto-exposure (record `exposure_applied`), clipping, noise and "
                                  "quantisation applied): gray (H, W) for appearance \"phong\", an sRGB "
                                  "video frame (H, W, 3) for appearance \"tissue\" (record `color`); "
                                  "decode with PIL.Image.open(io.BytesIO(a.tobytes()))"},
    "linear": {"dtype": "float32", "shape": "(H, W)", "unit": _RADIANCE_UNIT,
               "description": "linear image before the sensor model (specular + diffuse; for appearance "
                              "\"tissue\" the BT.601 luma of the linear RGB render)"},
    "specular": {"dtype": "float32", "shape": "(H, W)", "unit": _RADIANCE_UNIT,
                 "description": "specular-only linear image"},
    "normals": {"dtype": "float32", "shape": "(H, W, 3)", "unit": "unit vector",
                "description": "ground-truth surface normal, OpenCV camera frame (x right, y down, z "
                               "forward), facing the camera; 0 outside `mask`"},
    "depth": {"dtype": "float32", "shape": "(H, W)", "unit": "mm",
              "description": "z-depth along the optical axis (camera frame); 0 outside `mask`"},
    "mask": {"dtype": "bool", "shape": "(H, W)", "unit": "-",
             "description": "pixel covered by the surface (silhouette pixels excluded)"},
    "highlight_mask": {"dtype": "bool", "shape": "(H, W)", "unit": "-",
                       "description": "specular-only radiance >= min(isovalues) x the image's maximum "
                                      "specular radiance (the region inside the outermost labelled "
                                      "isophote)"},
}


@dataclass(frozen=True)
class Sample:
    """One rendered sample.

    Attributes
    ----------
    index : int
        Sample index in the dataset.
    arrays : dict of str to ndarray
        The arrays of :data:`CHANNELS`, in that order.
    record : dict
        JSON-ready labels and provenance: ``index``, ``family``, ``params`` (every drawn value),
        ``K`` (3, 3), ``cam_to_world`` (4, 4), ``highlights`` (dicts with ``bp_px``, ``bp_mm``,
        ``normal``, ``k1``, ``k2``, ``in_frame``, ``isophotes``), ``camera`` (:func:`camera_file`),
        ``scene``, ``variant``, ``render_seed``, ``exposure_applied``, ``color`` ("grey" or "rgb").
    """

    index: int
    arrays: dict
    record: dict


def sample_rng(seed: int, index: int) -> np.random.Generator:
    """A fresh ``default_rng(SeedSequence([seed, index]))`` for sample ``index`` of root ``seed`` (0 is
    valid): the same ``(seed, index)`` gives the same stream in any process."""
    return np.random.default_rng(np.random.SeedSequence([int(seed), int(index)]))


def draw_parameters(config: DatasetConfig, index: int) -> dict[str, Any]:
    """Draw the parameters of sample ``index`` (pure function of ``(config, index)``).

    The draw order is fixed: the family (weighted), then each parameter the family uses in the
    order of :data:`simtest.dataset.config.PARAMS`, then the render seed. A pose without a
    defined brightest point is redrawn from a child of the sample's SeedSequence (module notes,
    "the redraw rule"; :func:`truth_problem`).

    Parameters
    ----------
    config : DatasetConfig
        The validated config.
    index : int
        Sample index, 0 <= index < config.count.

    Returns
    -------
    dict
        ``{"family": str, <param>: value, ..., "render_seed": int}``, JSON-ready; units as in
        the parameter names (``_mm``, ``_deg``, ``_px``); plus ``"redraw": k`` (k >= 1) when
        the pose was redrawn k times.

    Raises
    ------
    IndexError
        If ``index`` is outside ``0 .. config.count - 1``.
    ValueError
        If :data:`MAX_REDRAWS` redraws in a row have no defined truth (the config's family
        almost never gives one).
    """
    if not 0 <= index < max(config.count, 1):
        raise IndexError(f"sample index {index} is outside 0..{config.count - 1}")
    rng = sample_rng(config.seed, index)
    names = [f for f, _ in config.families]
    w = np.array([w for _, w in config.families], dtype=np.float64)
    family = names[int(rng.choice(len(names), p=w / w.sum()))]
    out = _draw_family(config, family, rng)
    why = truth_problem(config, out)
    k = 0
    while why is not None:
        k += 1
        if k > MAX_REDRAWS:
            raise ValueError(f"sample {index}: {MAX_REDRAWS} draws in a row of family {family!r} have no defined "
                             f"brightest point (last: {why}); narrow params.{family} (e.g. view_angle_deg, radius_mm) "
                             "so that the camera stays outside the surface")
        child = np.random.SeedSequence([int(config.seed), int(index)], spawn_key=(k - 1,))
        out = _draw_family(config, family, np.random.default_rng(child))
        out["redraw"] = k
        why = truth_problem(config, out)
    return out


def _draw_family(config: DatasetConfig, family: str, rng: np.random.Generator) -> dict[str, Any]:
    """The family's parameters in the order of :data:`PARAMS`, then the render seed, from ``rng``."""
    out: dict[str, Any] = {"family": family}
    dists = config.params[family]
    for p in PARAMS:
        if p.name in dists:
            out[p.name] = dists[p.name].draw(rng, integer=p.integer)
    out["render_seed"] = int(rng.integers(0, MAX_SEED))
    return out


def truth_problem(config: DatasetConfig, params: dict) -> str | None:
    """Why a drawn pose has no defined brightest point, or None when it has one (no rendering).

    Runs the analytic truth (:func:`simtest.simulate.truth.sphere_highlight`,
    :func:`~simtest.simulate.truth.cylinder_highlight`) of the sample's scene for every light of
    its rig, as the renderer will; mesh families and planes always have a defined truth (a plane's
    BP is closed form; a mesh's BPs are searched in the render).

    Parameters
    ----------
    config : DatasetConfig
        The validated config.
    params : dict
        Drawn parameters (:func:`draw_parameters`).

    Returns
    -------
    str or None
        The :class:`~simtest.simulate.truth.HighlightTruthError` message (e.g. the camera inside a
        cylinder), or None.
    """
    if params["family"] not in ("spheres", "cylinders"):
        return None
    spec = build_scene(config, params)
    geo = spec.geometry
    # Camera frame (no pose); the intrinsics only place the BP's pixel.
    K, size = np.eye(3), (1, 1)
    c = np.asarray(geo.center_mm, dtype=np.float64)
    try:
        for light in light_rig(spec, params["render_seed"]).lights:
            pos = np.asarray(light.position_mm, dtype=np.float64)
            if geo.type == "sphere":
                sphere_highlight(c, geo.radius_mm, pos, K, size)
            else:
                axis = np.asarray(geo.axis if geo.axis is not None else (1.0, 0.0, 0.0), np.float64)
                length = geo.length_mm if geo.length_mm is not None else 20.0 * geo.radius_mm
                cylinder_highlight(c, axis, geo.radius_mm, length, pos, K, size)
    except HighlightTruthError as exc:
        return str(exc)
    return None


def build_scene(config: DatasetConfig, params: dict):
    """The scene spec of a sample from its drawn parameters (pure; no rendering).

    Analytic families are written in the camera frame (camera at the origin looking along +z):

    - planes: ``tilt_deg = view_angle_deg``, ``azimuth_deg``, ``distance_mm``.
    - spheres: centre at ``(distance_mm + radius_mm)`` along the direction ``view_angle_deg`` off
      the optical axis, at ``azimuth_deg`` about it.
    - cylinders: axis through ``(0, 0, distance_mm + radius_mm)``, tilted ``view_angle_deg`` out
      of the image plane, at ``azimuth_deg`` in it.
    - colon: the bundled ``meshes/<colon_mesh>.ply``; camera on its centre line at fraction ``station`` of
      the arc length, moved ``radial_offset`` x radius off it, looking ``view_angle_deg`` off the
      tangent toward ``azimuth_deg`` (and moved to the opposite side), image rolled by ``roll_deg``.
    - liver: the bundled ``meshes/liver.ply``; camera ``distance_mm`` from the surface point in the
      direction (``azimuth_deg``, ``elevation_deg``) from its centre, looking at it along a line
      ``view_angle_deg`` off its normal (tilted toward ``roll_deg``).

    Parameters
    ----------
    config : DatasetConfig
        The validated config (its ``variant`` and ``source`` are used).
    params : dict
        Output of :func:`draw_parameters`.

    Returns
    -------
    simtest.scene.SceneSpec
        Lengths in mm, angles in degrees; the camera has an M x M film with
        ``K = [[f, 0, M/2 - 0.5], [0, f, M/2 - 0.5], [0, 0, 1]]``.

    Raises
    ------
    FileNotFoundError
        If the bundled colon or liver mesh is missing (build it with ``simtest meshes build``).
    ValueError
        If the colon mesh carries no centre line in its metadata.
    simtest.scene.SceneError
        If the drawn values make an invalid scene spec.
    """
    fam = params["family"]
    m = params["resolution_px"]
    camera: dict[str, Any] = {"width_px": m, "height_px": m, "fov_deg": params["fov_deg"]}
    rig = params.get("light_rig", "point")
    if rig == "point":
        light = {"epsilon_mm": params["light_offset_mm"], "alpha_deg": params["light_offset_a_deg"],
                 "b": params["light_offset_b"], "falloff": params["light_falloff"],
                 "intensity": params["light_intensity"]}
    else:
        light = {"rig": rig, "falloff": "keep", "intensity": params["light_intensity"]}
    sensor = {"exposure": params["exposure"], "saturation": params["saturation"],
              "gaussian_sigma": params["noise_sigma"], "full_well_e": params["full_well_e"],
              "gamma": params["gamma"], "bit_depth": 8}
    if params.get("appearance", "phong") == "tissue":
        material = {"model": "tissue", "tissue": "liver" if fam == "liver" else "mucosa",
                    "distribution": params["tissue_lobe"], "c": params["phong_c"],
                    "n": params["phong_n"], "relief_mm": params["relief_mm"],
                    "texture_seed": params["render_seed"]}
        # sample_from_render makes the video frame from the RGB render (auto-exposure).
        sensor.update(output="video", tone="srgb")
    else:
        material = {"model": "phong", "c": params["phong_c"], "n": params["phong_n"],
                    "diffuse_albedo": params["diffuse_albedo"]}
    render = {"spp": params["spp"], "seed": params["render_seed"], "variant": config.variant, "sampler": "multijitter"}
    view = math.radians(params.get("view_angle_deg", 0.0))
    az = math.radians(params.get("azimuth_deg", 0.0))
    if fam == "planes":
        geometry = {"type": "plane", "tilt_deg": params["view_angle_deg"],
                    "azimuth_deg": params["azimuth_deg"], "distance_mm": params["distance_mm"]}
    elif fam == "spheres":
        r = params["radius_mm"]
        d = params["distance_mm"] + r
        centre = [d * math.sin(view) * math.cos(az), d * math.sin(view) * math.sin(az), d * math.cos(view)]
        geometry = {"type": "sphere", "center_mm": centre, "radius_mm": r}
    elif fam == "cylinders":
        r = params["radius_mm"]
        axis = [math.cos(view) * math.cos(az), math.cos(view) * math.sin(az), math.sin(view)]
        geometry = {"type": "cylinder", "center_mm": [0.0, 0.0, params["distance_mm"] + r],
                    "radius_mm": r, "axis": axis}
    elif fam in ("colon", "liver"):
        if fam == "colon":
            pose = colon_pose(params["station"], params["view_angle_deg"],
                              azimuth_deg=params["azimuth_deg"], radial_offset=params["radial_offset"],
                              roll_deg=params["roll_deg"], mesh=params.get("colon_mesh", "colon"))
        else:
            pose = liver_surface_pose(params["azimuth_deg"], params["elevation_deg"],
                                      params["distance_mm"], params["view_angle_deg"], params["roll_deg"])
        geometry = {"type": "mesh", "path": pose.path}
        camera.update(pose.camera_keys())
    else:  # pragma: no cover - the config refuses unknown families
        raise ValueError(f"unknown family {fam!r}")
    d = {"name": f"dataset-{fam}", "camera": camera, "light": light, "material": material,
         "geometry": geometry, "sensor": sensor, "render": render}
    return scene_from_dict(d, source=f"{config.source}: sample")


def isophote_record(bp_mm, normal, K, isovalues, phong_n: float) -> list[dict]:
    """Tangent-plane isophote conics at a BP (see the module notes).

    Parameters
    ----------
    bp_mm : array_like of shape (3,)
        Brightest point, camera frame, mm.
    normal : array_like of shape (3,)
        Unit normal at the BP, camera frame, facing the camera.
    K : ndarray of shape (3, 3)
        Intrinsics, pixels (integer pixel centres).
    isovalues : sequence of float
        Levels t in (0, 1) relative to the Phong peak.
    phong_n : float
        Phong exponent n.

    Returns
    -------
    list of dict
        Per isovalue: ``t``, ``radius_mm``, ``centre_mm``, ``conic`` (3 x 3 point conic, unit
        Frobenius norm, pixels), ``kind`` and ``ellipse`` (None unless a real ellipse).
    """
    X = np.asarray(bp_mm, dtype=np.float64)
    N = unit(normal)
    d = float(N @ X)  # < 0 when the normal faces the camera
    foot = d * N
    v_z = abs(d)
    out = []
    for t in isovalues:
        r = float(isophote_radius(float(t), float(phong_n), v_z, 1.0))
        rec: dict[str, Any] = {"t": float(t), "radius_mm": r, "centre_mm": foot.tolist(),
                               "conic": None, "kind": "degenerate", "ellipse": None}
        if r > 0 and np.isfinite(r) and v_z > 0:
            try:
                C = project_circle(foot, N, r, K)
            except ValueError:
                pass
            else:
                rec["conic"] = C.tolist()
                rec["kind"] = conic_kind(C)
                e = conic_to_ellipse(C)
                rec["ellipse"] = e.as_dict() if e is not None else None
        out.append(rec)
    return out


def _encode_png(img: np.ndarray) -> np.ndarray:
    buf = io.BytesIO()
    Image.fromarray(img).save(buf, format="PNG", optimize=False, compress_level=6)
    return np.frombuffer(buf.getvalue(), dtype=np.uint8).copy()


def _gray(a: np.ndarray) -> np.ndarray:
    a = np.asarray(a)
    if a.ndim == 3:
        # Rec. 709 luminance (simtest.constants says why not Rec. 601)
        if a.dtype == np.uint8:
            return np.round(a[..., :3].astype(np.float64) @ LUMINANCE_BT709).astype(np.uint8)
        return (a[..., :3].astype(np.float64) @ LUMINANCE_BT709).astype(np.float32)
    return a


def _auto_exposure(linear: np.ndarray, mask: np.ndarray, config: DatasetConfig) -> float:
    """``level / q``, ``q`` the ``config.auto_exposure`` percentile of grey ``linear`` in ``mask``.

    1 when auto-exposure is off or ``q`` is not positive.
    """
    if config.auto_exposure is None or not mask.any():
        return 1.0
    pct, level = config.auto_exposure
    q = float(np.percentile(_gray(linear)[mask], pct))
    return level / q if q > 0 and math.isfinite(q) else 1.0


def _portable_scene(spec) -> dict:
    """The scene spec as a dict, a bundled mesh path written as ``meshes/<name>.ply`` (same on any machine)."""
    d = jsonable(scene_to_dict(spec))
    geo = d.get("geometry", {})
    if geo.get("type") == "mesh" and geo.get("path"):
        path = Path(geo["path"])
        if path.parent == bundled_mesh_path("colon").parent:
            geo["path"] = f"meshes/{path.name}"
    return d


def mesh_sha256(family: str) -> str | None:
    """64 hex digits of the sha256 of ``meshes/<family>.ply`` (``"colon"``, ``"colon_haustral"`` or
    ``"liver"``); None for analytic families or a missing file."""
    if family not in ("colon", "colon_haustral", "liver"):
        return None
    path = bundled_mesh_path(family)
    return hashlib.sha256(path.read_bytes()).hexdigest() if path.is_file() else None


def camera_file(result) -> dict:
    """The camera file of a :class:`simtest.render.RenderResult` as a JSON object.

    ``{"model": "pinhole", "K", "dist_coeffs": None, "image_size": [W, H], "lights": [...]}`` in the
    format of :func:`simtest.geometry.camera_file.save_camera`: the render's pinhole K (pixels,
    integer pixel centres) and its light rig (camera frame, mm); falloff ``"none"`` when the dataset
    cancels the 1/d^2 falloff of the specular image, else ``"inverse_square"``.
    """
    d = result.camera_model.to_json_dict()
    d["lights"] = result.light_rig.to_json_list()
    return jsonable(d)


def sample_from_render(config: DatasetConfig, index: int, params: dict, result) -> Sample:
    """The :class:`Sample` (arrays of :data:`CHANNELS`, zero outside the mask, and the JSON-ready
    record) of ``result``, the render of :func:`build_scene` ``(config, params)``; the config's
    isovalues set the highlight mask and the isophote labels. ValueError if the sensor image is not
    8-bit."""
    mask = np.asarray(result.mask, dtype=bool)
    normals = np.where(mask[..., None], np.nan_to_num(np.asarray(result.normals, np.float32)), 0.0)
    depth = np.where(mask, np.nan_to_num(np.asarray(result.depth, np.float32)), 0.0)
    linear = np.asarray(_gray(result.gray if hasattr(result, "gray") else result.linear), np.float32)
    specular = np.asarray(_gray(result.specular), np.float32)
    exposure = _auto_exposure(linear, mask, config) * float(result.spec.sensor.exposure)
    if result.rgb is not None:  # tissue: the sRGB video frame of the RGB render
        sensor_spec = dataclasses.replace(result.spec.sensor, exposure_mode="fixed", exposure=exposure)
        sensor = video_frame(result.rgb, sensor_spec, result.seed)
    elif exposure != result.spec.sensor.exposure:  # the sensor model again, with the auto exposure
        sensor_spec = dataclasses.replace(result.spec.sensor, exposure=exposure)
        sensor = _gray(apply_sensor(result.linear, sensor_spec, result.seed))
    else:
        sensor = _gray(result.sensor)
    if sensor.dtype != np.uint8:
        raise ValueError(f"sample {index}: sensor image is {sensor.dtype}, expected uint8 (bit_depth 8)")
    peak = float(np.max(specular)) if specular.size else 0.0
    t_min = min(config.isovalues)
    hmask = (specular >= t_min * peak) if peak > 0 else np.zeros_like(mask)
    f32 = functools.partial(np.ascontiguousarray, dtype=np.float32)
    arrays = {"sensor_png": _encode_png(np.ascontiguousarray(sensor)), "linear": f32(linear), "specular": f32(specular),
              "normals": f32(normals), "depth": f32(depth), "mask": np.ascontiguousarray(mask),
              "highlight_mask": np.ascontiguousarray(hmask, dtype=bool)}
    K = np.asarray(result.K, dtype=np.float64)
    f64 = lambda a: jsonable(np.asarray(a, np.float64))  # noqa: E731
    highlights = [{"bp_px": f64(h.bp_px), "bp_mm": f64(h.bp_mm), "normal": f64(h.normal), "k1": float(h.k1),
                   "k2": float(h.k2), "in_frame": bool(h.in_frame),
                   "isophotes": isophote_record(h.bp_mm, h.normal, K, config.isovalues, params["phong_n"])}
                  for h in result.highlights]
    record = {"index": int(index), "family": params["family"], "params": jsonable(params),
              "render_seed": int(params["render_seed"]), "K": K.tolist(),
              "cam_to_world": np.asarray(result.cam_to_world, np.float64).tolist(),
              "image_size": [int(mask.shape[1]), int(mask.shape[0])], "variant": str(result.variant),
              "exposure_applied": exposure, "color": "rgb" if sensor.ndim == 3 else "grey",
              "highlights": highlights, "camera": camera_file(result), "scene": _portable_scene(result.spec)}
    return Sample(index=int(index), arrays=arrays, record=record)


_THREADS_SET = False
_RENDER_LOCK = threading.Lock()


def _configure_threads() -> None:
    """Apply the Dr.Jit thread count a local worker pool asked for (once per process)."""
    global _THREADS_SET
    if _THREADS_SET:
        return
    _THREADS_SET = True
    n = os.environ.get("SIMTEST_DATASET_THREADS")
    if not n:
        return
    configure_llvm_env()
    require("drjit", purpose="rendering a dataset sample").set_thread_count(int(n))


def render_sample(config: DatasetConfig, index: int) -> Sample:
    """Draw, build, render and label sample ``index`` of ``config`` (parameters as
    :func:`draw_parameters`).

    Returns
    -------
    Sample
        Identical (bit for bit) whenever called with the same config, index and Mitsuba variant,
        in any process.

    Raises
    ------
    IndexError
        If ``index`` is out of range.
    FileNotFoundError
        If a bundled mesh the family needs is missing.
    """
    params = draw_parameters(config, index)
    spec = build_scene(config, params)
    # One render at a time per process: Mitsuba's variant set-up is not safe to race across threads.
    with _RENDER_LOCK:
        _configure_threads()
        result = render_scene(spec, seed=params["render_seed"])
    return sample_from_render(config, index, params, result)
