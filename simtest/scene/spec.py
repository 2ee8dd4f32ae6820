"""Scene specifications: TOML files loaded into validated, frozen dataclasses.

A scene file has the sections ``[camera]``, ``[light]``, ``[material]``, ``[geometry]``,
``[sensor]``, ``[render]`` and the top-level keys ``name`` and ``description``. Every key has a
default except the geometry's shape parameters; unknown keys, wrong types and out-of-range values
raise :class:`SceneError` with the message ``"<file>: <section.key>: <reason>"``.

Lengths in mm, angles in degrees (suffixes ``_mm``, ``_deg``, ``_px``). Spheres, cylinders and
meshes are given in the world frame, planes and saddles relative to the camera; the camera pose
places an OpenCV camera (x right, y down, z forward). With the default pose the world frame is
the camera frame.

Examples
--------
>>> spec = scene_from_dict({"geometry": {"type": "sphere", "center_mm": [0, 0, 100],
...                                      "radius_mm": 20}})
>>> spec.camera.width_px, spec.material.model
(406, 'phong')
>>> with_overrides(spec, {"material.n": 80}).material.n
80.0

References
----------
.. [1] K. Makki, A. Bartoli, "Normal Reconstruction from Specularity in the Endoscopic Setting",
       eq. 1 (the Phong lobe) and section 3.1 (the light offset ``L = V + epsilon (cos a, sin a, b)``).
.. [2] B. T. Phong, "Illumination for computer generated pictures", CACM 18(6), 1975.
       https://doi.org/10.1145/360825.360839
.. [3] B. Walter, S. R. Marschner, H. Li, K. E. Torrance, "Microfacet models for refraction
       through rough surfaces", EGSR 2007. https://doi.org/10.2312/EGWR/EGSR07/195-206
"""

from __future__ import annotations

import dataclasses
import functools
import math
import os
from dataclasses import field
from pathlib import Path
from typing import Annotated, Any, Literal, Mapping, get_args

import tomli_w
from pydantic import Field

from simtest._checks import keyed_error
from simtest._config import Floats, Int, Num, Str, Vec2, Vec3, parse_toml, validated
from simtest.constants import MAX_SEED
from simtest.scene.kinds import (GEOMETRY_KEY_ORDER, GEOMETRY_KEYS, GEOMETRY_TYPES, CylinderGeometry, GeometrySpec,
                                 MeshGeometry, PlaneGeometry, SaddleGeometry, SphereGeometry, _frozen)
from simtest.resources import bundled_scene_path, data_root

__all__ = ["SceneError", "CameraSpec", "LightSpec", "MaterialSpec", "GeometrySpec", "PlaneGeometry",
           "SphereGeometry", "CylinderGeometry", "SaddleGeometry", "MeshGeometry", "GEOMETRY_TYPES",
           "SensorSpec", "RenderSpec", "SceneSpec", "load_scene", "scene_from_dict", "scene_to_dict",
           "scene_to_toml", "with_overrides", "GEOMETRY_KEYS", "RENDER_VARIANTS"]


class SceneError(ValueError):
    """A scene file or dict is invalid. The message reads ``"<file>: <key>: <reason>"``."""


#: Mitsuba variants the renderer accepts ("auto": cuda_ad_rgb when a GPU is usable, else llvm_ad_rgb);
#: RGB only: the colour channels separate the specular-only image from the full image in one render.
Variant = Literal["auto", "llvm_ad_rgb", "cuda_ad_rgb"]
RENDER_VARIANTS: tuple[str, ...] = get_args(Variant)

_Channel = Annotated[Num, Field(gt=0.0, le=1.0)]  # a linear-RGB albedo: no black, no gain
_Positive = Annotated[Num, Field(gt=0.0)]  # a length (mm), or a white-balance gain: a channel never vanishes
#: The tissues of simtest.render.tissue.TISSUE_ALBEDO.
_Tissue = Literal["mucosa", "liver", "peritoneum", "gallbladder"]


@_frozen
class CameraSpec:
    """Pinhole camera.

    Attributes
    ----------
    width_px, height_px : int
        Film size in pixels.
    fov_deg : float or None
        Horizontal field of view (full angle across the film width), degrees in (0, 180).
    focal_px : float or None
        Focal length in pixels. At most one of ``fov_deg`` and ``focal_px``; with neither,
        ``focal_px = width_px`` (the paper's f = M).
    principal_offset_px : (2,) float
        Principal point minus the film centre ``(W/2 - 0.5, H/2 - 0.5)``, pixels.
    position_mm, look_at_mm, up : (3,) float
        Camera pose in the world frame; ``up`` is shown at the top of the image (default (0, -1, 0)).
    model : {"pinhole", "fisheye", "c3vd", "file"}
        "pinhole" without ``dist_coeffs`` is Mitsuba's perspective sensor; the others trace each
        pixel's rays from the camera model (:mod:`simtest.render.endoscope`): "pinhole" with
        ``dist_coeffs`` (OpenCV radial-tangential), "fisheye" (OpenCV Kannala-Brandt, ``fisheye_d``),
        "c3vd" (C3VD's Olympus colonoscope calibration, 1350 x 1080, scaled to ``width_px``), "file"
        (the model of ``file``; the film size must match).
    dist_coeffs : list of float or None
        OpenCV distortion coefficients (k1, k2, p1, p2[, k3[, k4, k5, k6]]) of "pinhole".
    fisheye_d : (4,) float or None
        Kannala-Brandt coefficients (k1, k2, k3, k4) of "fisheye".
    file : str or None
        Camera file (JSON) for ``model = "file"`` or ``light.rig = "file"``; relative paths as for
        ``geometry.path``.
    """

    width_px: Int = Field(406, ge=1, le=16384)
    height_px: Int = Field(406, ge=1, le=16384)
    fov_deg: Num | None = Field(None, gt=0.0, lt=180.0)
    focal_px: Num | None = Field(None, gt=0.0)
    principal_offset_px: Vec2 = (0.0, 0.0)
    position_mm: Vec3 = (0.0, 0.0, 0.0)
    look_at_mm: Vec3 = (0.0, 0.0, 1.0)
    up: Vec3 = (0.0, -1.0, 0.0)
    model: Literal["pinhole", "fisheye", "c3vd", "file"] = "pinhole"
    dist_coeffs: Floats | None = None
    fisheye_d: Floats | None = None
    file: Str | None = None

    @property
    def focal(self) -> float:
        """Focal length f in pixels: ``focal_px``, else ``(W / 2) / tan(fov / 2)``, else ``width_px``.

        The intrinsics are ``K = [[f, 0, W/2 - 0.5 + ox], [0, f, H/2 - 0.5 + oy], [0, 0, 1]]``,
        ``(ox, oy) = principal_offset_px``.
        """
        if self.focal_px is not None:
            return float(self.focal_px)
        if self.fov_deg is not None:
            return 0.5 * self.width_px / math.tan(math.radians(self.fov_deg) / 2.0)
        return float(self.width_px)

    @property
    def fov_x_deg(self) -> float:
        """Horizontal field of view, degrees: ``2 atan((W / 2) / f)``."""
        return math.degrees(2.0 * math.atan(0.5 * self.width_px / self.focal))


@_frozen
class LightSpec:
    """Point light carried by the camera, or a light rig.

    The light sits at ``L = V + epsilon (cos a, sin a, b)`` in the camera frame (paper section 3.1);
    ``a`` (uniform in [0, 360) deg) and ``b`` (uniform in [-0.5, 0.5]) are drawn from the render seed
    unless given.

    Attributes
    ----------
    epsilon_mm : float
        Offset scale, >= 0 (0: co-located).
    alpha_deg, b : float or None
        Offset direction parameters; None draws them from the seed.
    intensity : float
        Radiant intensity (arbitrary units), > 0; scales each light of a rig.
    falloff : {"cancel", "keep"}
        "keep": radiance falls as 1/d^2 (a real endoscope). "cancel": undone, so that an exact-Phong
        surface shows ``intensity * c cos(beta)^n`` (paper eq. 1).
    rig : {"single", "colonoscope", "laparoscope", "file", "cf_h190"}
        "single": the one light above. Rigs (:mod:`simtest.render.endoscope`): "colonoscope" (two
        guides ``guide_offset_mm`` either side of the lens along x), "laparoscope" (a ring of
        ``guide_count`` lights of radius ``guide_offset_mm``), "file" (the lights of ``camera.file``),
        "cf_h190" (Olympus CF-H190, :func:`simtest.render.endoscope.cf_h190_rig`). A rig needs
        ``epsilon_mm = 0`` and ``falloff = "keep"``.
    guide_offset_mm : float or None
        Colonoscope: guide distance from the lens centre; laparoscope: ring radius (default: the preset's).
    guide_count : int or None
        Laparoscope: lights in the ring, 6 to 8 (default 8).
    guide_diameter_mm : float or None
        Diameter of each guide's emitting disc, mm (0 to 10; 0: point lights). Default 0, the
        preset's for "cf_h190".
    profile_exponent : float or None
        m of each light's cos^m emission profile (default: 0 for "single", the presets' 1 for a rig).
    """

    epsilon_mm: Num = Field(0.0, ge=0.0)
    alpha_deg: Num | None = None
    b: Num | None = None
    intensity: Num = Field(1.0, gt=0.0)
    falloff: Literal["cancel", "keep"] = "cancel"
    rig: Literal["single", "colonoscope", "laparoscope", "file", "cf_h190"] = "single"
    guide_offset_mm: Num | None = Field(None, gt=0.0)
    guide_diameter_mm: Num | None = Field(None, ge=0.0, le=10.0)
    guide_count: Int | None = Field(None, ge=6, le=8)
    profile_exponent: Num | None = Field(None, ge=0.0)


@_frozen
class MaterialSpec:
    """Surface reflectance: a specular lobe plus an optional Lambertian part.

    Attributes
    ----------
    model : {"phong", "microfacet", "tissue"}
        "phong": exact paper eq. 1, ``c max(0, cos beta)^n``. "microfacet": Mitsuba's
        ``roughconductor`` or ``roughplastic`` (``base``). "tissue": procedural RGB tissue
        (:mod:`simtest.render.tissue`) with a wet dielectric film whose lobe is ``distribution``, with
        Fresnel's reflectance at ``film_ior``, scaled by ``c``.
    c : float
        Specular scale (Phong c; microfacet specular reflectance), >= 0.
    n : float
        Phong exponent, > 0; also sets the default microfacet alpha (:attr:`microfacet_alpha`).
    distribution : {"beckmann", "ggx", "phong"}
        Microfacet normal distribution [3]; "phong" (eq. 1) only for "tissue".
    alpha : float or None
        Microfacet roughness in (0, 1]; None derives it from ``n``.
    base : {"conductor", "plastic"}
        Mitsuba base BSDF of the microfacet model.
    ior : float
        Interior index of refraction of the plastic base, > 1.
    diffuse_albedo : float
        Lambertian albedo in [0, 1], added to the specular lobe; not with the conductor base nor
        "tissue".
    tissue : {"mucosa", "liver", "peritoneum", "gallbladder"}
        The tissue of ``model = "tissue"``.
    film_ior : float
        Index of refraction of the wet film, 1.3 to 1.5.
    relief_mm, relief_scale_mm, relief_min_mm, relief_hurst : float
        RMS height (mm, 0: smooth), longest and shortest wavelength (mm; None: 0.05 or
        ``relief_scale_mm``) and Hurst exponent (0 to 1) of the tissue's self-affine micro-relief.
    subsurface_mm : float or None
        Diffusion length of the diffuse light, mm: shorter relief waves shade the film only
        (:func:`simtest.render.tissue.tissue_params`); None or 0: both.
    texture_seed : int
        Seed of the tissue texture, independent of the render seed.
    albedo : (float, float, float) or None
        Linear-RGB base albedo, each in (0, 1]; None: the tissue's default. ``simtest simreal --fit``
        sets it.
    film_variation, film_scale_mm : float
        Log standard deviation (0 to 3) and typical wavelength (mm) of the film's roughness variation
        (:func:`simtest.render.tissue.film_alpha`).
    film_thickness_mm, film_thickness_spread : float
        Median thickness (mm, 0 to 1; 0: none) and log standard deviation (0 to 1.5) of the wet film
        that levels the micro-relief.
    wall_tissue, wall_centre_mm, wall_radius_mm
        A second tissue at the surface points at least ``wall_radius_mm`` from ``wall_centre_mm`` (the
        texture frame), e.g. the wall around :func:`simtest.scene.meshes.abdomen.build_liver_in_abdomen`.
        The three keys go together.
    organ_tissue, organ_centre_mm, organ_axes_mm
        A third tissue inside the ellipsoid of that centre and semi-axes (texture frame), e.g. the
        gallbladder. The three keys go together.
    """

    model: Literal["phong", "microfacet", "tissue"] = "phong"
    c: Num = Field(1.0, ge=0.0)
    n: Num = Field(50.0, gt=0.0)
    distribution: Literal["beckmann", "ggx", "phong"] = "beckmann"
    alpha: Num | None = Field(None, gt=0.0, le=1.0)
    base: Literal["conductor", "plastic"] = "conductor"
    ior: Num = Field(1.5, gt=1.0)
    diffuse_albedo: Num = Field(0.0, ge=0.0, le=1.0)
    tissue: _Tissue = "mucosa"
    film_ior: Num = Field(1.38, ge=1.3, le=1.5)
    relief_mm: Num = Field(0.0, ge=0.0, le=1.0)
    relief_scale_mm: Num = Field(0.3, ge=0.05, le=5.0)
    relief_min_mm: Num | None = Field(None, ge=0.005, le=1.0)
    relief_hurst: Num = Field(0.8, ge=0.0, le=1.0)
    subsurface_mm: Num | None = Field(None, ge=0.0, le=10.0)
    texture_seed: Int = Field(0, ge=0, le=MAX_SEED)
    albedo: tuple[_Channel, _Channel, _Channel] | None = None
    film_variation: Num = Field(0.0, ge=0.0, le=3.0)
    film_scale_mm: Num = Field(2.0, ge=0.05, le=50.0)
    film_thickness_mm: Num = Field(0.0, ge=0.0, le=1.0)
    film_thickness_spread: Num = Field(0.0, ge=0.0, le=1.5)
    wall_tissue: _Tissue | None = None
    wall_centre_mm: Vec3 | None = None
    wall_radius_mm: Num | None = Field(None, gt=0.0)
    organ_tissue: _Tissue | None = None
    organ_centre_mm: Vec3 | None = None
    organ_axes_mm: tuple[_Positive, _Positive, _Positive] | None = None

    @property
    def microfacet_alpha(self) -> float:
        """``alpha`` or, if None, the Beckmann alpha matching Phong ``n``: sqrt(2 / (4 n + 2)).

        With a co-located light the mirror angle is ``beta = 2 theta_h``, so a Blinn exponent ``4 n``
        matches the paper's lobe near the peak; Walter et al.'s [3] Blinn-to-Beckmann conversion
        ``sqrt(2 / (m + 2))`` then gives this alpha (it matches ``n - 0.75`` to leading order once the
        BSDF's ``1 / cos^5 theta_h`` is included).
        """
        return float(self.alpha) if self.alpha is not None else math.sqrt(2.0 / (4.0 * self.n + 2.0))


@_frozen
class SensorSpec:
    """Sensor model applied to the linear image (:func:`simtest.render.sensor.apply_sensor`).

    ``s = exposure * L``; Poisson noise with ``full_well_e`` electrons at full scale (0: none);
    Gaussian read noise ``gaussian_sigma`` (fraction of full scale); clip to [0, saturation];
    ``y = s^(1 / gamma)``; quantise to ``2^bit_depth - 1`` levels.

    Attributes
    ----------
    exposure : float
        Multiplier of the linear image, > 0.
    saturation : float
        Clip level, fraction of full scale, in (0, 1].
    gamma : float
        Output gamma, > 0 (1: linear).
    bit_depth : int
        Bits per pixel, 1 to 16.
    gaussian_sigma : float
        Read-noise standard deviation, fraction of full scale, >= 0.
    full_well_e : float
        Electrons at full scale for Poisson shot noise, >= 0 (0: none).
    output : {"grey", "video"}
        "grey": the steps above; "video": the BT.601 luma of the 8-bit RGB video frame made by the
        keys below (:func:`simtest.render.sensor.video_frame`).
    exposure_mode : {"fixed", "auto"}
        Video: "fixed" multiplies by ``exposure``; "auto" brings the mean luma in the field stop to
        ``auto_mean`` of full scale.
    auto_mean : float
        Target mean of the "auto" exposure, (0, 1].
    metering : {"field", "tissue"}
        Pixels "auto" averages: the whole field stop, or only those on tissue.
    auto_clip_percent : float
        Peak-protecting "auto" exposure, [0, 100]: at most the exposure at which this percentage of
        the metered pixels clips in its brightest white-balanced channel. 100: the mean alone.
    white_balance : (3,) float
        Video: gains of R, G, B, > 0.
    tone : {"gamma", "srgb"}
        Video tone curve: ``s^(1 / gamma)`` or sRGB (IEC 61966-2-1).
    color_saturation : float
        Video: colour saturation about the luma (1: unchanged, 0: grey), >= 0.
    vignetting : float
        Video: relative illumination ``1 - v (r / r_max)^2``, r_max the half diagonal, v in [0, 1).
    jpeg_quality : int
        Video: JPEG quality 1 to 100, 0: no compression.
    field_stop : {"none", "circle", "octagon"}
        Video: the scope's field stop; pixels outside are black.
    field_stop_radius : float
        Field-stop radius, fraction of half the image width (octagon: its inscribed circle).
    """

    exposure: Num = Field(1.0, gt=0.0)
    saturation: Num = Field(1.0, gt=0.0, le=1.0)
    gamma: Num = Field(1.0, gt=0.0)
    bit_depth: Int = Field(8, ge=1, le=16)
    gaussian_sigma: Num = Field(0.0, ge=0.0)
    full_well_e: Num = Field(0.0, ge=0.0)
    output: Literal["grey", "video"] = "grey"
    exposure_mode: Literal["fixed", "auto"] = "fixed"
    auto_mean: Num = Field(0.25, gt=0.0, le=1.0)
    metering: Literal["field", "tissue"] = "field"
    auto_clip_percent: Num = Field(100.0, ge=0.0, le=100.0)
    white_balance: tuple[_Positive, _Positive, _Positive] = (1.0, 1.0, 1.0)
    tone: Literal["gamma", "srgb"] = "gamma"
    color_saturation: Num = Field(1.0, ge=0.0)
    vignetting: Num = Field(0.0, ge=0.0, lt=1.0)
    jpeg_quality: Int = Field(0, ge=0, le=100)
    field_stop: Literal["none", "circle", "octagon"] = "none"
    field_stop_radius: Num = Field(1.0, gt=0.0)


@_frozen
class RenderSpec:
    """Rendering settings. ``seed`` drives the sampler, the sensor noise and the light draw.

    Attributes
    ----------
    spp : int
        Samples per pixel, 1 to 2^20.
    sampler : {"multijitter", "independent", "stratified"}
        Mitsuba sampler plugin.
    seed : int
        Render seed in [0, 2^31 - 1].
    variant : str
        One of :data:`RENDER_VARIANTS`.
    """

    spp: Int = Field(16, ge=1, le=1 << 20)
    sampler: Literal["multijitter", "independent", "stratified"] = "multijitter"
    seed: Int = Field(0, ge=0, le=MAX_SEED)
    variant: Variant = "auto"


_SECTIONS: dict[str, type] = {"camera": CameraSpec, "light": LightSpec, "material": MaterialSpec,
                              "geometry": GeometrySpec, "sensor": SensorSpec, "render": RenderSpec}


@_frozen
class SceneSpec:
    """A whole scene: one camera with its light, one surface, a sensor and render settings.

    Attributes
    ----------
    name, description : str
        Free text (``name`` defaults to the file stem when loaded from a file).
    camera : CameraSpec
    light : LightSpec
    material : MaterialSpec
    geometry : GeometrySpec
    sensor : SensorSpec
    render : RenderSpec
    source : str
        File path or ``"<dict>"``, for messages; not serialised and not compared.
    """

    name: Str = "scene"
    description: Str = ""
    camera: CameraSpec = field(default_factory=CameraSpec)
    light: LightSpec = field(default_factory=LightSpec)
    material: MaterialSpec = field(default_factory=MaterialSpec)
    geometry: GeometrySpec = field(default_factory=PlaneGeometry)
    sensor: SensorSpec = field(default_factory=SensorSpec)
    render: RenderSpec = field(default_factory=RenderSpec)
    source: str = field(default="<dict>", compare=False)


#: ``_err(source, key, reason)``: the one-line error of a bad key (:func:`simtest._checks.keyed_error`).
_err = functools.partial(keyed_error, SceneError)


def _build_geometry(data: Any, source: str) -> GeometrySpec:
    """The geometry class of ``data["type"]`` (default "plane") built from the other keys (None: unset)."""
    if not isinstance(data, Mapping):
        raise _err(source, "geometry", f"expected a table, got {type(data).__name__} {data!r}")
    kind = validated(Str, data.get("type", "plane"), SceneError, source, "geometry.type")
    if kind not in GEOMETRY_TYPES:
        opts = ", ".join(repr(c) for c in GEOMETRY_TYPES)
        raise _err(source, "geometry.type", f"must be one of {opts}", kind)
    cls = GEOMETRY_TYPES[kind]
    for key in data:
        if key not in GEOMETRY_KEY_ORDER:
            raise _err(source, f"geometry.{key}",
                       f"unknown key (known keys: {', '.join(GEOMETRY_KEY_ORDER)})", data[key])
        if key != "type" and data[key] is not None and key not in cls.__pydantic_fields__:
            required, optional = GEOMETRY_KEYS[kind]
            raise _err(source, f"geometry.{key}",
                       f"not a key of geometry type {kind!r} (keys: {', '.join(required + optional)})")
    own = {k: v for k, v in data.items() if k != "type" and v is not None}
    return validated(cls, own, SceneError, source, "geometry")


def _validate(spec: SceneSpec, source: str, base_dirs: tuple[Path, ...]) -> SceneSpec:
    cam, geo, mat = spec.camera, spec.geometry, spec.material
    if cam.fov_deg is not None and cam.focal_px is not None:
        raise _err(source, "camera.focal_px", "give either camera.fov_deg or camera.focal_px, not both")
    fwd = tuple(b - a for a, b in zip(cam.position_mm, cam.look_at_mm))
    if math.hypot(*fwd) == 0.0:
        raise _err(source, "camera.look_at_mm", "equals camera.position_mm")
    if math.hypot(*cam.up) == 0.0:
        raise _err(source, "camera.up", "is the zero vector")
    cross = (fwd[1] * cam.up[2] - fwd[2] * cam.up[1], fwd[2] * cam.up[0] - fwd[0] * cam.up[2],
             fwd[0] * cam.up[1] - fwd[1] * cam.up[0])
    if math.hypot(*cross) <= 1e-9 * math.hypot(*fwd) * math.hypot(*cam.up):
        raise _err(source, "camera.up", "is parallel to the viewing direction")
    lt = spec.light
    if cam.model == "fisheye" and (cam.fisheye_d is None or len(cam.fisheye_d) != 4):
        raise _err(source, "camera.fisheye_d", "the fisheye model needs 4 coefficients [k1, k2, k3, k4]")
    if cam.fisheye_d is not None and cam.model != "fisheye":
        raise _err(source, "camera.fisheye_d", f"only for camera.model = \"fisheye\" (not {cam.model!r})")
    if cam.dist_coeffs is not None:
        if cam.model != "pinhole":
            raise _err(source, "camera.dist_coeffs", f"only for camera.model = \"pinhole\" (not {cam.model!r})")
        if len(cam.dist_coeffs) not in (4, 5, 8):
            raise _err(source, "camera.dist_coeffs",
                       f"expected 4, 5 or 8 OpenCV coefficients, got {len(cam.dist_coeffs)}")
    needs_file = cam.model == "file" or lt.rig == "file"
    if needs_file and cam.file is None:
        raise _err(source, "camera.file", "missing (camera.model or light.rig is \"file\")")
    if cam.file is not None and not needs_file:
        raise _err(source, "camera.file", "only with camera.model = \"file\" or light.rig = \"file\"")
    if lt.rig != "single":
        if lt.epsilon_mm != 0.0:
            raise _err(source, "light.epsilon_mm", f"must be 0 with light.rig = {lt.rig!r} (the rig places the lights)")
        if lt.falloff != "keep":
            raise _err(source, "light.falloff", f"a light rig falls off as 1/d^2: set light.falloff = \"keep\" "
                                                f"(light.rig = {lt.rig!r})")
    if lt.guide_count is not None and lt.rig != "laparoscope":
        raise _err(source, "light.guide_count", "only for light.rig = \"laparoscope\"")
    if lt.guide_diameter_mm is not None and lt.rig not in ("colonoscope", "laparoscope", "cf_h190"):
        raise _err(source, "light.guide_diameter_mm", "only for light.rig = \"colonoscope\", \"laparoscope\" or "
                   "\"cf_h190\"")
    if lt.guide_offset_mm is not None and lt.rig not in ("colonoscope", "laparoscope"):
        raise _err(source, "light.guide_offset_mm", "only for light.rig = \"colonoscope\" or \"laparoscope\"")
    if cam.file is not None:
        spec = dataclasses.replace(spec, camera=dataclasses.replace(
            cam, file=str(_resolve_file(cam.file, base_dirs, source, "camera.file", "camera file"))))
    if mat.distribution == "phong" and mat.model != "tissue":
        raise _err(source, "material.distribution", "\"phong\" is a lobe of model \"tissue\" "
                   "(model \"phong\" is the paper's exact lobe)")
    if mat.relief_min_mm is not None and mat.relief_min_mm > mat.relief_scale_mm:
        raise _err(source, "material.relief_min_mm", f"the shortest wavelength {mat.relief_min_mm} mm exceeds "
                   f"the longest, material.relief_scale_mm = {mat.relief_scale_mm} mm")
    for keys in (("wall_tissue", "wall_centre_mm", "wall_radius_mm"), ("organ_tissue", "organ_centre_mm", "organ_axes_mm")):
        given = [getattr(mat, k) is not None for k in keys]
        if any(given) and not all(given):
            raise _err(source, f"material.{keys[0]}", f"material.{keys[0]}, {keys[1]} and {keys[2]} go together "
                       "(give all three or none)")
    if spec.sensor.output == "video" and spec.sensor.bit_depth != 8:
        raise _err(source, "sensor.bit_depth", "a video frame is 8-bit: set sensor.bit_depth = 8 with output = \"video\"")
    if mat.model == "microfacet" and mat.base == "conductor" and mat.diffuse_albedo > 0:
        raise _err(source, "material.diffuse_albedo",
                   "a conductor has no diffuse part; use material.base = \"plastic\" for tissue")

    for key in GEOMETRY_KEYS[geo.type][0]:  # the required keys, in field order
        if getattr(geo, key) is None:
            raise _err(source, f"geometry.{key}", f"missing (required for type {geo.type!r})")
    if geo.type == "cylinder" and geo.axis is not None and math.hypot(*geo.axis) == 0.0:
        raise _err(source, "geometry.axis", "is the zero vector")
    if geo.type == "mesh":  # geo.path is set: a required key, checked above
        path = _resolve_file(geo.path, base_dirs, source, "geometry.path", "mesh file")
        spec = dataclasses.replace(spec, geometry=dataclasses.replace(geo, path=str(path)))
    return spec


def _resolve_file(name: str, base_dirs: tuple[Path, ...], source: str, key: str, what: str) -> Path:
    """An existing file named in a scene: absolute, or relative to the first of ``base_dirs`` holding it."""
    path = Path(name).expanduser()
    if not path.is_absolute():
        candidates = [d / path for d in base_dirs]
        found = next((p for p in candidates if p.is_file()), None)
        if found is None:
            tried = ", ".join(str(p) for p in candidates) or str(path)
            raise _err(source, key, f"{what} not found: {name!r} (tried {tried})")
        path = found
    elif not path.is_file():
        raise _err(source, key, f"{what} not found: {str(path)!r}")
    return path.resolve()


def scene_from_dict(d: Mapping[str, Any], source: str = "<dict>", base_dir: str | Path | None = None) -> SceneSpec:
    """Build and validate a :class:`SceneSpec` from a nested dict (the TOML layout).

    Parameters
    ----------
    d : mapping
        Top-level keys ``name``, ``description`` and the six sections.
    source : str
        Shown at the start of every error message (the file name).
    base_dir : path, optional
        Folder relative file paths are resolved from (before the bundled data root).

    Returns
    -------
    SceneSpec
        Validated and frozen; file paths made absolute.

    Raises
    ------
    SceneError
        On an unknown key, a wrong type, an out-of-range value, a missing required geometry key or a
        missing file.
    """
    if not isinstance(d, Mapping):
        raise _err(source, "<root>", f"expected a table, got {type(d).__name__}")
    known = ("name", "description", *_SECTIONS)
    for key in d:
        if key not in known:
            raise _err(source, key, f"unknown key (known keys: {', '.join(known)})", d[key])
    if "geometry" not in d:
        raise _err(source, "geometry", "missing section [geometry] (it needs at least `type`)")
    data = {**d, "geometry": _build_geometry(d["geometry"], source), "source": source}
    spec = validated(SceneSpec, data, SceneError, source)
    dirs = [Path(base_dir)] if base_dir is not None else []
    dirs.append(data_root())
    return _validate(spec, source, tuple(dirs))


def load_scene(path: str | Path) -> SceneSpec:
    """Load and validate a TOML scene file.

    Parameters
    ----------
    path : str or Path
        A ``.toml`` file, or the name of a bundled scene (e.g. ``"plane_58deg"``).

    Returns
    -------
    SceneSpec
        Validated; ``name`` defaults to the file stem and ``source`` is the file path.

    Raises
    ------
    SceneError
        If the file is missing, is not valid TOML, or fails validation (see
        :func:`scene_from_dict`).
    """
    p = Path(path)
    if not p.is_file() and p.suffix != ".toml" and "/" not in str(path):
        try:
            p = bundled_scene_path(str(path))
        except KeyError as exc:
            raise SceneError(f"{path}: no such file and no bundled scene of that name "
                             f"({exc.args[0]})") from None
    if not p.is_file():
        raise SceneError(f"{p}: no such file")
    data = parse_toml(p.read_bytes(), p, SceneError)
    spec = scene_from_dict(data, source=str(p), base_dir=p.resolve().parent)
    if "name" not in data:
        spec = dataclasses.replace(spec, name=p.stem)
    return spec


def scene_to_dict(spec: SceneSpec) -> dict[str, Any]:
    """Return the nested dict (TOML layout) of ``spec``; None values are left out.

    ``scene_from_dict(scene_to_dict(s)) == s`` for a valid spec ``s``.

    Parameters
    ----------
    spec : SceneSpec
        A validated spec.

    Returns
    -------
    dict
        ``{"name", "description", "camera": {...}, ..., "render": {...}}`` with tuples as lists
        (lengths in mm, angles in degrees, as in the file); ``source`` is not included.
    """
    out: dict[str, Any] = {"name": spec.name, "description": spec.description}
    for section in _SECTIONS:
        sub = getattr(spec, section)
        d = {"type": sub.type} if section == "geometry" else {}
        for f in dataclasses.fields(sub):
            v = getattr(sub, f.name)
            if v is not None:
                d[f.name] = list(v) if isinstance(v, tuple) else v
        out[section] = d
    return out


def with_overrides(spec: SceneSpec, overrides: Mapping[str, Any]) -> SceneSpec:
    """Return a copy of ``spec`` with dotted keys replaced, validated again.

    Parameters
    ----------
    spec : SceneSpec
        The base spec.
    overrides : mapping
        e.g. ``{"material.n": 80, "geometry.tilt_deg": 30, "render.seed": 3}``; ``name`` and
        ``description`` may be given bare. None unsets an optional key. Overrides apply in order;
        ``geometry.type`` set to another type starts the geometry afresh (the old type's keys are
        dropped), so the keys of the new type follow it.

    Returns
    -------
    SceneSpec
        A new validated spec (relative mesh paths resolved from the base spec's folder).

    Raises
    ------
    SceneError
        If a key is unknown or a value invalid (the message names the key).
    """
    d = scene_to_dict(spec)
    for dotted, value in overrides.items():
        parts = dotted.split(".")
        if len(parts) == 1 and parts[0] in ("name", "description"):
            d[parts[0]] = value
            continue
        if len(parts) != 2 or parts[0] not in _SECTIONS:
            raise _err(spec.source, dotted, "unknown key (expected <section>.<key>, sections: "
                       f"{', '.join(_SECTIONS)})")
        if dotted == "geometry.type" and value != d["geometry"].get("type"):
            d["geometry"] = {}  # another kind of surface: the old one's keys do not apply
        d[parts[0]][parts[1]] = list(value) if isinstance(value, tuple) else value
    base = Path(spec.source).resolve().parent if spec.source not in ("<dict>", "") else None
    return scene_from_dict(d, source=spec.source, base_dir=base)


def scene_to_toml(spec: SceneSpec, folder: str | Path | None = None, header: str = "") -> str:
    """The scene file (TOML text) of ``spec``: ``load_scene`` of it gives ``spec`` back.

    Parameters
    ----------
    spec : SceneSpec
    folder : str or Path, optional
        The folder the file will be written to: file paths of the scene (``geometry.path``,
        ``camera.file``) are written relative to it (absolute without).
    header : str
        Comment lines put first (each prefixed with ``# ``).
    """
    d = scene_to_dict(spec)
    if folder is not None:
        for section, key in (("geometry", "path"), ("camera", "file")):
            if key in d.get(section, {}):
                d[section][key] = os.path.relpath(d[section][key], Path(folder).resolve())
    comments = "".join(f"# {x}\n" if x else "#\n" for x in header.splitlines())
    return comments + tomli_w.dumps(d)
