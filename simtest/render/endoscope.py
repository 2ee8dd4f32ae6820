"""Endoscope renders: light rigs, wide-angle camera models and exact per-pixel ground truth.

The default renderer (:func:`simtest.render.render.render_scene` on a plain scene) draws a pinhole
camera with one point light through Mitsuba's ``perspective`` sensor. A scene that asks for an
endoscope (a light rig, a camera model other than the distortion-free pinhole) is drawn here
instead:

- **Rays from the camera model.** Every sample's ray is ``model.pixel_to_ray(uv)`` of the camera
  model (:mod:`simtest.geometry.cameras`: pinhole with distortion, fisheye, omnidirectional),
  computed in float64 and handed to Mitsuba's ``ray_intersect`` as a wavefront: no warped pinhole
  render, so every ground-truth map is exact per pixel.
- **Ground truth from the pixel centre.** Position, normal and depth of each pixel come from the ray
  through its centre (not from an average over the pixel's samples), so that projecting a pixel's
  ground-truth position with the camera model lands on that pixel (to float32 round-off of the
  intersection, measured below 1e-3 px) and its normal is the surface normal there.
- **Light rigs.** The lights of a :class:`simtest.geometry.lights.LightRig` (1 to 8 points in the
  camera frame, moving with the camera) are summed in closed form for each sample: radiant
  intensity ``I_i max(0, w_z)^m_i`` toward the unit direction ``w`` from light i to the surface
  point (a cos^m profile about the scope axis +z), times ``1 / s^2`` for the inverse-square falloff
  (s the light distance), times the BSDF. This is Mitsuba's point emitter with a profile, evaluated
  for every light at every sample instead of sampling one light per sample: the image carries no
  light-selection noise. Shadow rays are traced on meshes.
- **Light guides as discs.** With a guide diameter (``light.guide_diameter_mm``, the "cf_h190"
  preset's by default) each light is a disc in the lens plane centred on its position: the
  ``spp`` samples of a pixel take their light points on a Vogel (golden-angle) spiral over the
  disc, one per sample, each emitting the light's intensity with the same cos^m profile, so a
  pixel's mean is the disc's radiance (the area emitter's integral by stratified quadrature) with
  no added noise. The ground truth stays that of the disc's centre (its position).
- **Presets.** :func:`colonoscope_rig`, :func:`cf_h190_rig` and :func:`laparoscope_rig` (geometry
  and sources in their docstrings).

Importing this module is cheap; Mitsuba loads when a render runs.
"""

from __future__ import annotations

import math

import numpy as np

from simtest._lazy import require
from simtest.geometry.camera_file import load_camera
from simtest.geometry.cameras import (
    CameraModel,
    FisheyeCamera,
    OmnidirectionalCamera,
    PinholeCamera,
    c3vd_camera,
)
from simtest.geometry.lights import Light, LightRig
from simtest.render.mitsuba_dict import intrinsics_matrix, light_position_cam
from simtest.scene.spec import SceneSpec

__all__ = ["COLONOSCOPE_GUIDE_OFFSET_MM", "LAPAROSCOPE_RING_RADIUS_MM", "GUIDE_PROFILE_EXPONENT", "RAY_SEED_KEY",
           "camera_model", "colonoscope_rig", "cf_h190_rig", "guide_radius_mm", "CF_H190_GUIDE_OFFSET_MM",
           "CF_H190_GUIDE_DIAMETER_MM", "CF_H190_GAMMA", "light_rig", "uses_endoscope", "laparoscope_rig",
           "scaled_omnidirectional", "sample_positions"]

#: Distance from the lens centre to each of the colonoscope's two light guides, mm. An assumption:
#: a colonoscope tip 13 mm across (Olympus CF-HQ190L: 13.2 mm distal end, the scope of C3VD) carries
#: the objective lens and two light guides side by side; the guides' centres sit 3 to 5 mm from
#: the lens's. 4 mm gives the offset/working-distance ratio epsilon/d of 0.08 to 0.8 over 5 to
#: 50 mm of tissue distance.
COLONOSCOPE_GUIDE_OFFSET_MM = 4.0
#: Radius of the laparoscope's ring of fibre bundles around its rod lens, mm. An assumption: a
#: 10 mm laparoscope has its illumination fibres in an annulus between the rod lens (about 6 mm
#: across) and the sheath, centred near r = 4 mm.
LAPAROSCOPE_RING_RADIUS_MM = 4.0
#: Exponent m of the cos^m emission profile of one light-guide output. A fibre bundle behind a
#: diffusing lens spreads its light over the scope's 140 to 170 deg field; m = 1 (Lambertian) is an
#: assumption, not a measurement.
GUIDE_PROFILE_EXPONENT = 1.0

#: Olympus CF-H190 colonoscope (the scope of the EndoMapper dataset): distance of each of its two
#: light guides from the lens centre, mm. From EndoMapper's photometric calibration of this scope
#: (Azagra et al., "EndoMapper dataset of complete calibrated endoscopy procedures", Scientific
#: Data 10, 671, 2023, https://doi.org/10.1038/s41597-023-02564-7: lights about 3.3 mm from the
#: lens, camera response gamma 2.2). The guides' layout along the image's x axis is assumed.
CF_H190_GUIDE_OFFSET_MM = 3.3
#: Diameter of each CF-H190 light guide's output face, mm: an assumption (fibre-bundle guides of
#: colonoscopes are about 1 mm across), not part of the calibration.
CF_H190_GUIDE_DIAMETER_MM = 1.0
#: The camera response of the CF-H190 in the same calibration (a display gamma): a scene of this
#: scope sets ``sensor.tone = "gamma"`` and ``sensor.gamma`` to it.
CF_H190_GAMMA = 2.2

#: Stable key of the sub-pixel sample stream in ``SeedSequence([seed, RAY_SEED_KEY])``.
RAY_SEED_KEY = 0xE4D05


def colonoscope_rig(offset_mm: float = COLONOSCOPE_GUIDE_OFFSET_MM,
                    profile_exponent: float = GUIDE_PROFILE_EXPONENT,
                    intensity: float = 1.0) -> LightRig:
    """Two light guides on opposite sides of the lens, at ``(-offset, 0, 0)`` and ``(+offset, 0, 0)``.

    Parameters
    ----------
    offset_mm : float
        Distance of each guide from the lens centre along the image's x axis, mm (> 0).
    profile_exponent : float
        m of each guide's cos^m profile about the scope axis (>= 0).
    intensity : float
        Relative power of each guide (> 0); the rig's total is twice this.

    Returns
    -------
    LightRig
        Two inverse-square lights, camera frame (OpenCV axes), in the plane of the lens (z = 0).

    Notes
    -----
    The default offset is :data:`COLONOSCOPE_GUIDE_OFFSET_MM` (an assumption stated there).

    Examples
    --------
    >>> colonoscope_rig().positions.tolist()
    [[-4.0, 0.0, 0.0], [4.0, 0.0, 0.0]]
    """
    return LightRig(tuple(Light((s * float(offset_mm), 0.0, 0.0), intensity, "inverse_square",
                                profile_exponent) for s in (-1.0, 1.0)))


def cf_h190_rig(profile_exponent: float = GUIDE_PROFILE_EXPONENT, intensity: float = 1.0) -> LightRig:
    """The light guides of an Olympus CF-H190 colonoscope: :func:`colonoscope_rig` at
    :data:`CF_H190_GUIDE_OFFSET_MM` (EndoMapper's calibration; source there). Each guide is a disc
    of :data:`CF_H190_GUIDE_DIAMETER_MM` (:func:`guide_radius_mm`).

    Examples
    --------
    >>> cf_h190_rig().positions.tolist()
    [[-3.3, 0.0, 0.0], [3.3, 0.0, 0.0]]
    """
    return colonoscope_rig(CF_H190_GUIDE_OFFSET_MM, profile_exponent, intensity)


def guide_radius_mm(spec: SceneSpec) -> float:
    """Radius of each light guide's disc, mm (0: point lights): ``light.guide_diameter_mm / 2``,
    by default 0, or :data:`CF_H190_GUIDE_DIAMETER_MM` / 2 for the "cf_h190" rig."""
    lt = spec.light
    if lt.guide_diameter_mm is not None:
        return 0.5 * float(lt.guide_diameter_mm)
    return 0.5 * CF_H190_GUIDE_DIAMETER_MM if lt.rig == "cf_h190" else 0.0


def laparoscope_rig(radius_mm: float = LAPAROSCOPE_RING_RADIUS_MM, count: int = 8,
                    profile_exponent: float = GUIDE_PROFILE_EXPONENT,
                    intensity: float = 1.0) -> LightRig:
    """A ring of ``count`` equal lights around the lens, at ``radius_mm`` in the lens plane.

    Parameters
    ----------
    radius_mm : float
        Ring radius, mm (> 0).
    count : int
        Number of lights, 6 to 8 (a ring of fibre bundles sampled at that many points).
    profile_exponent : float
        m of each light's cos^m profile about the scope axis.
    intensity : float
        Relative power of each light.

    Returns
    -------
    LightRig
        Light k at ``radius (cos(2 pi k / count), sin(2 pi k / count), 0)``, camera frame.

    Raises
    ------
    ValueError
        If ``count`` is not in 6 to 8.
    """
    count = int(count)
    if not 6 <= count <= 8:
        raise ValueError(f"laparoscope_rig: count must be 6 to 8, got {count}")
    lights = []
    for k in range(count):
        a = 2.0 * math.pi * k / count
        lights.append(Light((float(radius_mm) * math.cos(a), float(radius_mm) * math.sin(a), 0.0),
                            intensity, "inverse_square", profile_exponent))
    return LightRig(tuple(lights))


def scaled_omnidirectional(model: OmnidirectionalCamera, width_px: int) -> OmnidirectionalCamera:
    """The same lens on a film scaled to ``width_px`` (for small test renders of C3VD's camera).

    Notes
    -----
    Scaling pixel coordinates by ``s = width_px / W`` (centres at integers: ``u' + 0.5 = s (u +
    0.5)``) maps the ray ``(x, y, a0 + a2 r^2 + a3 r^3 + a4 r^4)`` of a pixel to a parallel ray
    ``(s x, s y, s (a0 + ...))``, so ``a_k' = a_k s^(1 - k)`` and the affine part is unchanged.
    """
    W, H = model.image_size
    s = width_px / W
    a = [model.a[k] * s ** (1 - k) for k in range(5)]
    return OmnidirectionalCamera(cx=s * (model.cx + 0.5) - 0.5, cy=s * (model.cy + 0.5) - 0.5, a=a,
                                 c=model.c, d=model.d, e=model.e,
                                 image_size=(int(width_px), int(round(H * s))))


def sample_positions(spp: int, width: int, first_pixel: int, n_pixels: int, seed: int, *,
                     pixels: np.ndarray | None = None):
    """Sub-pixel sample positions of a run of pixels, drawn in Dr.Jit (float32), seeded.

    Pixel ``q`` (row-major, ``u = q mod width``, ``v = q div width``) gets ``spp`` samples at
    ``(u + du, v + dv)`` with ``(du, dv)`` in [-0.5, 0.5)^2: a jittered ``sqrt(spp)``-sided grid when
    ``spp`` is a square, else ``spp`` strata in ``du`` paired with a per-pixel cyclic shift of the
    strata in ``dv`` (a Latin hypercube). The jitter of sample ``j`` of pixel ``q`` is the PCG32
    stream ``q spp + j`` of the state drawn from ``SeedSequence([seed, RAY_SEED_KEY])``, so a
    pixel's samples do not depend on how the frame is cut into runs, nor on Dr.Jit's thread count.

    Parameters
    ----------
    spp : int
        Samples per pixel (>= 1).
    width : int
        Image width, px.
    first_pixel, n_pixels : int
        The run: pixels ``first_pixel .. first_pixel + n_pixels - 1`` in row-major order.
    seed : int
        Root seed.
    pixels : ndarray of shape (M,), int, optional
        The run as a list of row-major pixel indices instead (``first_pixel`` and ``n_pixels``
        are then not used): each pixel gets the very samples it gets in a contiguous run.

    Returns
    -------
    (mitsuba.Float, mitsuba.Float)
        ``u`` and ``v`` of the ``n_pixels * spp`` samples, pixel-major (the ``spp`` samples of a
        pixel are consecutive), pixel centres at integers.
    """
    dr, mi = require("drjit"), require("mitsuba")
    state = int(np.random.SeedSequence([int(seed), RAY_SEED_KEY]).generate_state(1, np.uint64)[0])
    n = int(n_pixels) * int(spp)
    off = int(first_pixel) * int(spp)
    # PCG32 of size n gives element i the state initstate + i and the stream initseq + i: with
    # both offset by the run's first sample, sample g of the frame draws from (state + g, g).
    # (opaque: the seed and the run's start are kernel inputs, not constants compiled into it)
    if pixels is None:
        rng = mi.PCG32(n, dr.opaque(mi.UInt64, (state + off) % 2**64), dr.opaque(mi.UInt64, off))
        j = dr.arange(mi.UInt32, n)
        s = j % spp
        q = j // spp + dr.opaque(mi.UInt32, int(first_pixel))
    else:
        n = len(pixels) * int(spp)
        j = dr.arange(mi.UInt32, n)
        s = j % spp
        q = dr.gather(mi.UInt32, mi.UInt32(np.ascontiguousarray(pixels, dtype=np.uint32)), j // spp)
        g = mi.UInt64(q) * int(spp) + mi.UInt64(s)  # the sample's index in the frame
        rng = mi.PCG32(n)
        rng.seed(dr.opaque(mi.UInt64, state) + g, g)
    r1, r2 = rng.next_float32(), rng.next_float32()
    k = int(round(math.sqrt(spp)))
    if k * k == spp:
        du = (mi.Float(s % k) + r1) / k - 0.5
        dv = (mi.Float(s // k) + r2) / k - 0.5
    else:  # the pixel's cyclic shift: the third draw of its first sample
        r3 = rng.next_float32()
        shift = mi.UInt32(dr.gather(mi.Float, r3, j - s) * spp) % spp
        du = (mi.Float(s) + r1) / spp - 0.5
        dv = (mi.Float((s + shift) % spp) + r2) / spp - 0.5
    return mi.Float(q % width) + du, mi.Float(q // width) + dv


def uses_endoscope(spec: SceneSpec) -> bool:
    """Whether ``spec`` needs the endoscope renderer (a light rig, a camera model or tissue).

    Scenes with the default keys (``camera.model = "pinhole"`` without distortion, ``light.rig =
    "single"``) keep Mitsuba's perspective sensor and the one-light integrator, bit for bit.
    """
    cam = spec.camera
    return (cam.model != "pinhole" or cam.dist_coeffs is not None or spec.light.rig != "single"
            or spec.material.model == "tissue")


def camera_model(spec: SceneSpec) -> CameraModel:
    """The camera model of ``spec``'s film (see :class:`simtest.scene.spec.CameraSpec`).

    ``"pinhole"`` and ``"fisheye"`` take K from the film size, focal length and principal offset
    (:func:`simtest.render.mitsuba_dict.intrinsics_matrix`) with ``dist_coeffs`` / ``fisheye_d``;
    ``"c3vd"`` is C3VD's published calibration scaled to ``width_px``
    (:func:`scaled_omnidirectional`); ``"file"`` is the camera file's model.

    Raises
    ------
    ValueError
        If the film size does not match the model's (``"c3vd"``, ``"file"``); the message names
        the key and the size expected.
    """
    cam = spec.camera
    size = (cam.width_px, cam.height_px)
    if cam.model in ("pinhole", "fisheye"):
        K = intrinsics_matrix(cam)
        if cam.model == "fisheye":
            return FisheyeCamera(K, cam.fisheye_d, image_size=size)
        return PinholeCamera(K, dist_coeffs=cam.dist_coeffs, image_size=size)
    if cam.model == "c3vd":
        model = c3vd_camera()
        if cam.width_px != model.image_size[0]:
            model = scaled_omnidirectional(model, cam.width_px)
    else:
        model = load_camera(cam.file).model
    if tuple(model.image_size) != size:
        raise ValueError(f"{spec.source}: camera.height_px: the {cam.model} camera's film is "
                         f"{model.image_size[0]} x {model.image_size[1]} px at width {cam.width_px}; "
                         f"the scene gives {size[0]} x {size[1]}")
    return model


def light_rig(spec: SceneSpec, seed: int) -> LightRig:
    """The lights of ``spec`` in the camera frame (see :class:`simtest.scene.spec.LightSpec`).

    ``"single"``: one isotropic light at :func:`simtest.render.mitsuba_dict.light_position_cam`
    (falloff "none" when the scene cancels it, so that the image shows ``I c cos(beta)^n``);
    ``"colonoscope"`` / ``"laparoscope"``: the presets with ``guide_offset_mm``, ``guide_count``
    and ``profile_exponent``; ``"file"``: the camera file's lights. ``light.intensity`` scales
    every light.
    """
    lt = spec.light
    m = GUIDE_PROFILE_EXPONENT if lt.profile_exponent is None else lt.profile_exponent
    if lt.rig == "single":
        falloff = "none" if lt.falloff == "cancel" else "inverse_square"
        return LightRig((Light(tuple(light_position_cam(lt, seed)), lt.intensity, falloff,
                               lt.profile_exponent or 0.0),))
    if lt.rig == "colonoscope":
        off = COLONOSCOPE_GUIDE_OFFSET_MM if lt.guide_offset_mm is None else lt.guide_offset_mm
        return colonoscope_rig(off, m, lt.intensity)
    if lt.rig == "cf_h190":
        return cf_h190_rig(m, lt.intensity)
    if lt.rig == "laparoscope":
        r = LAPAROSCOPE_RING_RADIUS_MM if lt.guide_offset_mm is None else lt.guide_offset_mm
        return laparoscope_rig(r, lt.guide_count or 8, m, lt.intensity)
    rig = load_camera(spec.camera.file).lights
    return LightRig(tuple(Light(x.position_mm, x.intensity * lt.intensity, x.falloff,
                                x.profile_exponent) for x in rig.lights))
