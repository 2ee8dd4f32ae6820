"""Endoscope renders: light rigs, wide-angle camera models and exact per-pixel ground truth.

A scene with a light rig, a camera model other than the distortion-free pinhole, or tissue is drawn here
instead of through Mitsuba's ``perspective`` sensor. Each sample's ray comes from the camera model
(:mod:`simtest.geometry.cameras`), so every ground-truth map is exact per pixel, taken from the ray
through the pixel centre. The lights of a rig are summed in closed form at every sample (radiant
intensity ``I_i max(0, w_z)^m_i``, ``1 / s^2`` for inverse-square falloff, times the BSDF): no
light-selection noise. A light guide with a diameter is a disc in the lens plane, sampled by a Vogel
spiral over a pixel's ``spp`` samples; its ground truth stays that of the disc's centre.
"""

from __future__ import annotations

import math

import numpy as np

from simtest._lazy import require
from simtest.geometry.camera_file import load_camera
from simtest.geometry.cameras import CameraModel, FisheyeCamera, OmnidirectionalCamera, PinholeCamera, c3vd_camera
from simtest.geometry.lights import Light, LightRig
from simtest.render.mitsuba_dict import intrinsics_matrix, light_position_cam
from simtest.render.wavefront import dr_input
from simtest.scene.spec import SceneSpec

__all__ = ["COLONOSCOPE_GUIDE_OFFSET_MM", "LAPAROSCOPE_RING_RADIUS_MM", "GUIDE_PROFILE_EXPONENT", "RAY_SEED_KEY",
           "camera_model", "colonoscope_rig", "cf_h190_rig", "guide_radius_mm", "CF_H190_GUIDE_OFFSET_MM",
           "CF_H190_GUIDE_DIAMETER_MM", "light_rig", "uses_endoscope", "laparoscope_rig",
           "scaled_omnidirectional", "sample_positions"]

#: Distance from the lens centre to each of the colonoscope's two light guides, mm. An assumption: a tip
#: 13 mm across (Olympus CF-HQ190L, C3VD's scope) puts the guides' centres 3 to 5 mm from the lens's.
COLONOSCOPE_GUIDE_OFFSET_MM = 4.0
#: Radius of the laparoscope's ring of fibre bundles, mm. An assumption: a 10 mm laparoscope's fibres lie
#: between the rod lens (about 6 mm across) and the sheath.
LAPAROSCOPE_RING_RADIUS_MM = 4.0
#: Exponent m of the cos^m emission profile of one light guide: Lambertian, an assumption.
GUIDE_PROFILE_EXPONENT = 1.0

#: Olympus CF-H190 (EndoMapper's scope): distance of each light guide from the lens centre, mm, from
#: EndoMapper's photometric calibration (Azagra et al., Scientific Data 10, 671, 2023,
#: https://doi.org/10.1038/s41597-023-02564-7). The guides' layout along the image's x axis is assumed.
CF_H190_GUIDE_OFFSET_MM = 3.3
#: Diameter of each CF-H190 light guide's output face, mm: an assumption, not part of the calibration.
CF_H190_GUIDE_DIAMETER_MM = 1.0

#: Stable key of the sub-pixel sample stream in ``SeedSequence([seed, RAY_SEED_KEY])``.
RAY_SEED_KEY = 0xE4D05


def colonoscope_rig(offset_mm: float = COLONOSCOPE_GUIDE_OFFSET_MM, profile_exponent: float = GUIDE_PROFILE_EXPONENT,
                    intensity: float = 1.0) -> LightRig:
    """Two light guides on opposite sides of the lens, at ``(-offset, 0, 0)`` and ``(+offset, 0, 0)``.

    Parameters
    ----------
    offset_mm : float
        Distance of each guide from the lens centre along the image's x axis, mm (> 0).
    profile_exponent : float
        m of each guide's cos^m profile about the scope axis (>= 0).
    intensity : float
        Relative power of each guide (> 0).

    Returns
    -------
    LightRig
        Two inverse-square lights, camera frame, in the lens plane (z = 0).

    Examples
    --------
    >>> colonoscope_rig().positions.tolist()
    [[-4.0, 0.0, 0.0], [4.0, 0.0, 0.0]]
    """
    return LightRig(tuple(Light((s * float(offset_mm), 0.0, 0.0), intensity, "inverse_square",
                                profile_exponent) for s in (-1.0, 1.0)))


def cf_h190_rig(profile_exponent: float = GUIDE_PROFILE_EXPONENT, intensity: float = 1.0) -> LightRig:
    """An Olympus CF-H190's guides: :func:`colonoscope_rig` at :data:`CF_H190_GUIDE_OFFSET_MM`.

    Examples
    --------
    >>> cf_h190_rig().positions.tolist()
    [[-3.3, 0.0, 0.0], [3.3, 0.0, 0.0]]
    """
    return colonoscope_rig(CF_H190_GUIDE_OFFSET_MM, profile_exponent, intensity)


def guide_radius_mm(spec: SceneSpec) -> float:
    """Radius of each light guide's disc, mm: ``light.guide_diameter_mm / 2``, else the "cf_h190" rig's, else 0."""
    lt = spec.light
    if lt.guide_diameter_mm is not None:
        return 0.5 * float(lt.guide_diameter_mm)
    return 0.5 * CF_H190_GUIDE_DIAMETER_MM if lt.rig == "cf_h190" else 0.0


def laparoscope_rig(radius_mm: float = LAPAROSCOPE_RING_RADIUS_MM, count: int = 8,
                    profile_exponent: float = GUIDE_PROFILE_EXPONENT, intensity: float = 1.0) -> LightRig:
    """A ring of ``count`` equal lights around the lens, at ``radius_mm`` in the lens plane.

    Parameters
    ----------
    radius_mm : float
        Ring radius, mm (> 0).
    count : int
        Number of lights, 6 to 8.
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
    angles = [2.0 * math.pi * k / count for k in range(count)]
    return LightRig(tuple(Light((float(radius_mm) * math.cos(a), float(radius_mm) * math.sin(a), 0.0), intensity,
                                "inverse_square", profile_exponent) for a in angles))


def scaled_omnidirectional(model: OmnidirectionalCamera, width_px: int) -> OmnidirectionalCamera:
    """The same lens on a film scaled to ``width_px``: ``a_k' = a_k s^(1 - k)``, ``s = width_px / W``."""
    W, H = model.image_size
    s = width_px / W
    a = [model.a[k] * s ** (1 - k) for k in range(5)]
    return OmnidirectionalCamera(cx=s * (model.cx + 0.5) - 0.5, cy=s * (model.cy + 0.5) - 0.5, a=a, c=model.c,
                                 d=model.d, e=model.e, image_size=(int(width_px), int(round(H * s))))


def sample_positions(spp: int, width: int, first_pixel: int, n_pixels: int, seed: int, *,
                     pixels: np.ndarray | None = None):
    """Sub-pixel sample positions of a run of pixels, drawn in Dr.Jit (float32), seeded.

    Pixel ``q`` (row-major) gets ``spp`` samples in [-0.5, 0.5)^2 about its centre: a jittered grid when
    ``spp`` is a square, else a Latin hypercube. Sample ``j`` of pixel ``q`` draws from PCG32 stream
    ``q spp + j`` of ``SeedSequence([seed, RAY_SEED_KEY])``, independent of how the frame is cut into runs.

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
        The run as row-major pixel indices instead (each gets the samples of a contiguous run).

    Returns
    -------
    (mitsuba.Float, mitsuba.Float)
        ``u`` and ``v`` of the samples, the ``spp`` samples of a pixel consecutive.
    """
    dr, mi = require("drjit"), require("mitsuba")
    state = int(np.random.SeedSequence([int(seed), RAY_SEED_KEY]).generate_state(1, np.uint64)[0])
    n = int(n_pixels) * int(spp)
    off = int(first_pixel) * int(spp)
    # sample g of the frame draws from (state + g, g); opaque: kernel inputs, not compiled constants
    if pixels is None:
        rng = mi.PCG32(n, dr.opaque(mi.UInt64, (state + off) % 2**64), dr.opaque(mi.UInt64, off))
        j = dr.arange(mi.UInt32, n)
        s = j % spp
        q = j // spp + dr.opaque(mi.UInt32, int(first_pixel))
    else:
        n = len(pixels) * int(spp)
        j = dr.arange(mi.UInt32, n)
        s = j % spp
        q = dr.gather(mi.UInt32, mi.UInt32(dr_input(pixels, np.uint32)), j // spp)
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
    """Whether ``spec`` needs the endoscope renderer (a light rig, a camera model or tissue)."""
    cam = spec.camera
    return (cam.model != "pinhole" or cam.dist_coeffs is not None or spec.light.rig != "single"
            or spec.material.model == "tissue")


def camera_model(spec: SceneSpec) -> CameraModel:
    """The camera model of ``spec``'s film (:class:`simtest.scene.spec.CameraSpec`).

    ``"pinhole"`` and ``"fisheye"`` take K from :func:`simtest.render.mitsuba_dict.intrinsics_matrix`;
    ``"c3vd"`` is C3VD's calibration scaled to ``width_px``; ``"file"`` the camera file's model.

    Raises
    ------
    ValueError
        If the film size does not match the model's (``"c3vd"``, ``"file"``).
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
    """The lights of ``spec`` in the camera frame (:class:`simtest.scene.spec.LightSpec`), scaled by its intensity.

    ``"single"``: one isotropic light at :func:`simtest.render.mitsuba_dict.light_position_cam` (falloff "none"
    when the scene cancels it); the presets; ``"file"``: the camera file's lights.
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
