"""Wavefront ray casting and light-rig shading on a loaded Mitsuba scene (camera-frame rays from the origin).

:func:`cast` gives hit points, camera-facing shading normals and triangle indices; :func:`shade` and
:func:`shade_tissue` evaluate every light of a rig in closed form (:mod:`simtest.render.endoscope`). Call
them after :func:`simtest.render.scene_load.choose_variant`.
"""

from __future__ import annotations

import numpy as np

from simtest.geometry.cameras import OmnidirectionalCamera, PinholeCamera
from simtest.geometry.lights import LightRig
from simtest._lazy import require
from simtest.render import tissue

__all__ = ["DR_ALIGN_BYTES", "Pending", "albedo_map", "cast", "coverage", "dr_columns", "dr_input", "model_rays",
           "relief_normals", "shade", "shade_tissue"]

#: Dr.Jit's LLVM backend reads a NumPy array in place and compiles each kernel for whether its inputs start on a
#: 64-byte boundary (``align 64`` or ``align 1`` in the kernel): an array from the heap lands on either at random,
#: so without this every render could compile (and cache) another variant of its kernels. Bytes.
DR_ALIGN_BYTES = 64


def dr_input(a, dtype=np.float32) -> np.ndarray:
    """``a`` as a C-contiguous ``dtype`` array whose data start on a :data:`DR_ALIGN_BYTES` boundary (itself where
    it is one already), to hand to Dr.Jit: the same compiled kernels whatever the allocator gave.

    Parameters
    ----------
    a : array_like
        Any shape.
    dtype : numpy dtype
        The Dr.Jit array's element type (float32 for ``Float``, uint32 for ``UInt32``).

    Returns
    -------
    ndarray
        Equal to ``a`` cast to ``dtype``, same shape (an empty one wherever it starts: no byte is read).
    """
    a, dtype = np.asarray(a), np.dtype(dtype)
    if a.dtype == dtype and a.flags.c_contiguous and (a.size == 0 or a.ctypes.data % DR_ALIGN_BYTES == 0):
        return a  # (empty: nothing read)
    buf = np.empty(a.size + DR_ALIGN_BYTES // dtype.itemsize, dtype)  # (its start: a multiple of the item size)
    start = (-buf.ctypes.data % DR_ALIGN_BYTES) // dtype.itemsize
    out = buf[start:start + a.size].reshape(a.shape)
    out[...] = a  # cast, made contiguous and aligned in one copy
    return out


def dr_columns(a: np.ndarray) -> list:
    """The columns of an (N, k) array as aligned float32 arrays (:func:`dr_input`), for ``mi.Vector3f(*...)``."""
    return [dr_input(a[:, i]) for i in range(a.shape[1])]


def _intersect(scene, ray):
    """``scene.ray_intersect`` of camera rays, traced as coherent rays (same hits, faster)."""
    mi = require("mitsuba")
    return scene.ray_intersect(ray, mi.RayFlags.All, True)


def _occluded(scene, ray, active):
    """``scene.ray_test`` of shadow rays toward one light (coherent: they converge on it)."""
    return scene.ray_test(ray, True, active)


def _rays(d):
    """Rays (``mitsuba.Ray3f``) from the origin along ``d``, an (N, 3) numpy array or a Dr.Jit ``Vector3f``."""
    mi = require("mitsuba")
    if isinstance(d, np.ndarray):
        d = mi.Vector3f(*dr_columns(d))
    return mi.Ray3f(mi.Point3f(0.0), d)


def model_rays(model, uv):
    """Unit rays (``mi.Vector3f``, float32) of pixel positions through ``model``.

    The distortion-free pinhole and the omnidirectional model are evaluated in closed form in Dr.Jit; other
    models go through ``model.pixel_to_ray`` in numpy.

    Parameters
    ----------
    model : CameraModel
    uv : ndarray of shape (N, 2) or tuple of Dr.Jit Float
        Pixel positions (u, v).
    """
    dr, mi = require("drjit"), require("mitsuba")
    if isinstance(uv, tuple):  # (u, v) Dr.Jit arrays (simtest.render.endoscope.sample_positions)
        u, v = uv
    else:
        u, v = (mi.Float(c) for c in dr_columns(np.asarray(uv)))
    if isinstance(model, OmnidirectionalCamera):
        A = np.asarray(model._Ainv, dtype=np.float64)
        du, dv = u - float(model.cx), v - float(model.cy)
        x = float(A[0, 0]) * du + float(A[0, 1]) * dv
        y = float(A[1, 0]) * du + float(A[1, 1]) * dv
        r = dr.sqrt(x * x + y * y)
        a = [float(c) for c in model.a]
        z = a[0] + r * (a[1] + r * (a[2] + r * (a[3] + r * a[4])))
        return dr.normalize(mi.Vector3f(x, y, z))
    if isinstance(model, PinholeCamera) and model.dist_coeffs is None:
        K = np.asarray(model.K, dtype=np.float64)
        x = (u - float(K[0, 2])) / float(K[0, 0])
        y = (v - float(K[1, 2])) / float(K[1, 1])
        return dr.normalize(mi.Vector3f(x, y, 1.0))
    uv = np.stack([np.array(u, dtype=np.float64), np.array(v, dtype=np.float64)], axis=-1)
    return mi.Vector3f(*dr_columns(model.pixel_to_ray(uv)))


def cast(scene, d: np.ndarray, *, later: bool = False):
    """Intersect rays from the camera centre.

    Parameters
    ----------
    scene : mitsuba.Scene
        Built in the camera frame (OpenCV axes, mm).
    d : ndarray of shape (N, 3)
        Unit ray directions, camera frame (float64; cast as float32).
    later : bool
        Read the hits now but return a function that makes the dict, to call while queued kernels run.

    Returns
    -------
    dict
        ``hit`` (N,) bool; ``t`` (N,) float64 distance, mm; ``p = t d`` (N, 3) float64; ``n`` (N, 3) unit
        shading normal facing the camera; ``prim`` (N,) int64 triangle index. Misses carry NaN.
    """
    dr = require("drjit")
    d = np.asarray(d, dtype=np.float64)
    si = _intersect(scene, _rays(d))
    valid, t_j, n_j, prim_j = si.is_valid(), si.t, si.sh_frame.n, si.prim_index
    dr.eval(valid, t_j, n_j, prim_j)
    hit, t32, n32, prim = (np.array(valid, dtype=bool), np.array(t_j), np.array(n_j), np.array(prim_j, dtype=np.int64))

    def finish() -> dict[str, np.ndarray]:
        t = np.where(hit, t32.astype(np.float64), np.nan)
        # per coordinate: the bits of np.linalg.norm over the last axis, without strided passes
        nx, ny, nz = n32.astype(np.float64)
        scale = np.maximum(np.sqrt(nx * nx + ny * ny + nz * nz), 1e-30)
        nx, ny, nz = nx / scale, ny / scale, nz / scale
        flip = (nx * d[:, 0] + ny * d[:, 1] + nz * d[:, 2]) > 0
        n = np.stack([nx, ny, nz], axis=1)
        n[flip] *= -1.0
        n[~hit] = np.nan
        p = t[:, None] * d
        return {"hit": hit & np.isfinite(t), "t": t, "p": p, "n": n, "prim": prim}

    return finish if later else finish()


def shade(scene, d: np.ndarray, rig: LightRig, *, shadows: bool, spp: int = 1,
          defer: bool = False, guide_radius_mm: float = 0.0) -> tuple[np.ndarray, np.ndarray] | Pending:
    """Radiance along rays from the camera centre, lit by every light of ``rig``.

    Parameters
    ----------
    scene : mitsuba.Scene
        Built in the camera frame, one BSDF per shape (no emitters needed).
    d : ndarray of shape (N, 3) or mitsuba.Vector3f
        Unit ray directions, camera frame (:func:`model_rays`).
    rig : LightRig
        Lights in the camera frame.
    shadows : bool
        Trace a shadow ray to each light.
    spp : int
        Consecutive rays per pixel: the results are their means (``N / spp`` pixels).
    defer : bool
        Queue the kernels and return a :class:`Pending`.
    guide_radius_mm : float
        Each light a disc of this radius in the lens plane (:func:`disc_offsets`); 0: points.

    Returns
    -------
    value : ndarray of shape (N / spp, 3), float32
        ``sum_i f(wi, wo_i) I_i max(0, w_z)^m_i / s_i^2`` (``1 / s^2`` only for inverse-square lights), ``f``
        the BSDF, ``wo_i`` the unit direction to light i, ``w = -wo_i`` and ``s_i`` the light distance.
    coverage : ndarray of shape (N / spp,), float32
        Fraction of the rays that hit the surface.
    """
    dr, mi = require("drjit"), require("mitsuba")
    ray = _rays(d)
    si = _intersect(scene, ray)
    valid = si.is_valid()
    bsdf = si.bsdf(ray)
    ctx = mi.BSDFContext()
    total = mi.Color3f(0.0)
    n_rays = dr.width(ray.d)
    for i, light in enumerate(rig.lights):
        off = disc_offsets(n_rays, spp, guide_radius_mm, i) if guide_radius_mm > 0 else None
        lp, wo, weight = _light_at(light, si.p, off)
        lit = valid
        if shadows:
            lit = lit & ~_occluded(scene, si.spawn_ray_to(lp), valid)
        value = bsdf.eval(ctx, si, si.to_local(wo), lit)
        total += dr.select(lit, value * weight, mi.Color3f(0.0))
    out = Pending(_per_pixel(spp, total.x, total.y, total.z, dr.select(valid, 1.0, 0.0)),
                  lambda r, g, b, cov: (np.stack([r, g, b], axis=-1), cov))
    return out if defer else out.fetch()


def coverage(scene, d, *, spp: int = 1, defer: bool = False) -> np.ndarray | Pending:
    """Fraction of each pixel's rays that hit the surface (no shading).

    Parameters
    ----------
    scene, d, spp, defer
        As :func:`shade`.

    Returns
    -------
    ndarray of shape (N / spp,), float32
        The ``coverage`` that :func:`shade` and :func:`shade_tissue` return for the same rays.
    """
    dr = require("drjit")
    valid = scene.ray_intersect_preliminary(_rays(d), True).is_valid()
    out = Pending(_per_pixel(spp, dr.select(valid, 1.0, 0.0)), lambda cov: cov)
    return out if defer else out.fetch()


class Pending:
    """Per-pixel results whose Dr.Jit kernels are queued but not yet read; :meth:`fetch` waits and returns them."""

    def __init__(self, values: tuple, finish):
        self._values = values
        self._finish = finish

    def fetch(self):
        """Wait for the kernels; return what the shading function returns without ``defer``."""
        out = tuple(np.array(x, dtype=np.float32) for x in self._values)
        self._values = ()
        return self._finish(*out)


def _per_pixel(spp: int, *values):
    """Means over each run of ``spp`` consecutive samples, as queued Dr.Jit arrays (thread-count independent)."""
    dr = require("drjit")
    dr.eval(*values)  # one kernel for every per-sample value (a reduction evaluates its input alone)
    if spp > 1:
        values = tuple(dr.block_sum(x, spp) / spp for x in values)
        dr.eval(*values)
    return values


#: Golden angle, rad: the step of the Vogel spiral of the disc guides' sample points.
GOLDEN_ANGLE = float(np.pi * (3.0 - np.sqrt(5.0)))


def disc_offsets(n_rays: int, spp: int, radius_mm: float, light_index: int):
    """Offsets (x, y), mm, in the lens plane of each ray's point on a disc guide (Dr.Jit Floats).

    Sample ``k`` of a pixel takes point ``k`` of a Vogel spiral: radius ``R sqrt((k + 1/2) / spp)``, angle
    ``k g + i pi / 2`` (``g`` the golden angle, ``i`` the light's index).
    """
    dr, mi = require("drjit"), require("mitsuba")
    k = mi.Float(dr.arange(mi.UInt32, n_rays) % spp)
    r = float(radius_mm) * dr.sqrt((k + 0.5) / float(spp))
    a = k * GOLDEN_ANGLE + 0.5 * np.pi * light_index
    return r * dr.cos(a), r * dr.sin(a)


def _light_at(light, p, offset=None):
    """A rig light seen from points ``p``: its position, the unit direction ``wo`` to it and its weight.

    The weight is ``I max(0, w_z)^m / s^2`` (``1 / s^2`` only for an inverse-square light); ``offset``: the
    (x, y) disc-guide offsets, or None for the point.
    """
    dr, mi = require("drjit"), require("mitsuba")
    lp = mi.Point3f(*(float(x) for x in light.position_mm))
    if offset is not None:
        lp = mi.Point3f(lp.x + offset[0], lp.y + offset[1], lp.z)
    to_light = lp - p
    s2 = dr.squared_norm(to_light)
    wo = to_light * dr.rsqrt(s2)
    weight = mi.Float(float(light.intensity))
    if light.profile_exponent > 0:
        weight = weight * dr.power(dr.maximum(-wo.z, 0.0), float(light.profile_exponent))
    if light.falloff == "inverse_square":
        weight = weight / s2
    return lp, wo, weight


#: Dr.Jit textures of the tissue's arrays, keyed by the array's id and the Mitsuba variant
_TEXTURES: dict[tuple[int, str], tuple[np.ndarray, object]] = {}


def _texture(tex: np.ndarray):
    """``mi.Texture2f`` of ``tex`` (linear filter, mirrored repeat), cached for the last few arrays."""
    dr, mi = require("drjit"), require("mitsuba")
    key = (id(tex), mi.variant())
    hit = _TEXTURES.get(key)
    if hit is not None and hit[0] is tex:
        return hit[1]
    t = mi.Texture2f(mi.TensorXf(dr_input(tex)), filter_mode=dr.FilterMode.Linear,
                     wrap_mode=dr.WrapMode.Mirror)
    if len(_TEXTURES) >= 4:
        _TEXTURES.pop(next(iter(_TEXTURES)))
    _TEXTURES[key] = (tex, t)
    return t


def _dr_xp():
    """The numpy names :mod:`simtest.render.tissue` uses, on Dr.Jit arrays (a namespace)."""
    dr, mi = require("drjit"), require("mitsuba")

    class _DrXp:
        sin, cos, exp, sqrt = staticmethod(dr.sin), staticmethod(dr.cos), staticmethod(dr.exp), staticmethod(dr.sqrt)
        maximum, minimum, power = staticmethod(dr.maximum), staticmethod(dr.minimum), staticmethod(dr.power)
        where = staticmethod(dr.select)

        @staticmethod
        def texture(tex: np.ndarray, s, r):
            """Bilinear, mirrored lookup of an (H, W, C) array at texture coordinates (s, r) in [0, 1]."""
            return _texture(tex).eval(mi.Point2f(s, r))

        @staticmethod
        def const(x: float):
            """A value the kernel reads at launch, so one compiled kernel serves every pose."""
            return dr.opaque(mi.Float, x)

    return _DrXp


def relief_normals(p: np.ndarray, n: np.ndarray, texture, *, defer: bool = False) -> np.ndarray | Pending:
    """Shading normals with the tissue's micro-relief (:func:`simtest.render.tissue.relief_normal`), in Dr.Jit.

    Parameters
    ----------
    p, n : ndarray of shape (..., 3)
        Surface points (mm) and unit macro normals, camera frame.
    texture : simtest.render.tissue.TissueParams
    defer : bool
        Return a :class:`Pending`.

    Returns
    -------
    ndarray of shape (..., 3), float32
        Unit shading normals, on the side of ``n``; NaN where ``p`` or ``n`` is.
    """
    return _per_point(tissue.relief_normal(_dr_xp(), _dr_rows(p), _dr_rows(n), texture), p.shape, defer)


def albedo_map(p: np.ndarray, texture, n: np.ndarray | None = None, *, defer: bool = False) -> np.ndarray | Pending:
    """Diffuse albedo of the tissue (:func:`simtest.render.tissue.albedo`) at surface points, in Dr.Jit.

    Parameters
    ----------
    p : ndarray of shape (..., 3)
        Surface points, camera frame, mm (``texture`` in the camera frame).
    texture : simtest.render.tissue.TissueParams
    n : ndarray of shape (..., 3), optional
        Surface normals at ``p`` (the vessels' triplanar mapping weighs them).
    defer : bool
        Return a :class:`Pending`.

    Returns
    -------
    ndarray of shape (..., 3), float32
        Linear RGB albedo in [0, 1]; NaN where ``p`` is.
    """
    return _per_point(tissue.albedo(_dr_xp(), _dr_rows(p), texture, None if n is None else _dr_rows(n)), p.shape, defer)


def _dr_rows(a: np.ndarray) -> list:
    """The three coordinates of a (..., 3) array as flat float32 Dr.Jit arrays."""
    mi = require("mitsuba")
    return [mi.Float(c) for c in dr_columns(np.reshape(a, (-1, 3)))]


def _per_point(values, shape: tuple, defer: bool):
    """Three queued Dr.Jit arrays as a (..., 3) float32 array of ``shape``, or its :class:`Pending`."""
    out = tuple(values)
    require("drjit").eval(*out)
    pending = Pending(out, lambda x, y, z: np.stack([x, y, z], axis=-1).reshape(shape))
    return pending if defer else pending.fetch()


def shade_tissue(scene, d: np.ndarray, rig: LightRig, texture, material, *, shadows: bool, spp: int = 1,
                 defer: bool = False, guide_radius_mm: float = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray] | Pending:
    """Radiance of procedural tissue (:mod:`simtest.render.tissue`) along rays from the camera centre.

    Parameters
    ----------
    scene, d, rig, shadows, spp, defer, guide_radius_mm
        As :func:`shade` (the scene's BSDF is not used).
    texture : simtest.render.tissue.TissueParams
    material : simtest.scene.spec.MaterialSpec
        ``distribution`` (lobe), ``microfacet_alpha``, ``n``, ``film_ior``, ``c``.

    Returns
    -------
    rgb : ndarray of shape (N / spp, 3), float32
        ``sum_i (albedo / pi cos_d + f_s cos_o) I_i max(0, w_z)^m_i / s_i^2``, ``cos_o`` of the shading normal,
        ``cos_d`` of the diffuse one.
    specular : ndarray of shape (N / spp,), float32
        The specular part alone.
    coverage : ndarray of shape (N / spp,), float32
    """
    dr, mi = require("drjit"), require("mitsuba")
    xp = _dr_xp()
    ray = _rays(d)
    si = _intersect(scene, ray)
    valid = si.is_valid()
    n = si.sh_frame.n
    n = dr.select(dr.dot(n, ray.d) > 0, -n, n)  # facing the camera
    p = (si.p.x, si.p.y, si.p.z)
    ns, nd = tissue.relief_normal(xp, p, (n.x, n.y, n.z), texture, diffuse=True)
    alb = [dr.select(valid, a, 0.0) for a in tissue.albedo(xp, p, texture, (n.x, n.y, n.z))]  # misses: 0, not NaN
    wi = -ray.d
    wi = (wi.x, wi.y, wi.z)
    rgb = [mi.Float(0.0), mi.Float(0.0), mi.Float(0.0)]
    spec = mi.Float(0.0)
    # opaque: a new roughness reuses the kernel; varying over the film where it varies
    alpha = tissue.film_alpha(xp, p, texture, tissue._const(xp, material.microfacet_alpha))
    n_rays = dr.width(ray.d)
    for i, light in enumerate(rig.lights):
        off = disc_offsets(n_rays, spp, guide_radius_mm, i) if guide_radius_mm > 0 else None
        lp, wo, weight = _light_at(light, si.p, off)
        lit = valid & (dr.dot(wo, n) > 0)
        if shadows:
            lit = lit & ~_occluded(scene, si.spawn_ray_to(lp), valid)
        w3 = (wo.x, wo.y, wo.z)
        cos_o = dr.maximum(ns[0] * wo.x + ns[1] * wo.y + ns[2] * wo.z, 0.0)
        fs = tissue.specular_lobe(xp, ns, wi, w3, material.distribution, alpha,
                                  material.n, material.film_ior, material.c)
        e = dr.select(lit, cos_o * weight, 0.0)
        ed = e if nd is ns else dr.select(lit, dr.maximum(dr.dot(mi.Vector3f(*nd), wo), 0.0) * weight, 0.0)
        spec += fs * e
        for c in range(3):
            rgb[c] += alb[c] / dr.pi * ed + fs * e
    out = Pending(_per_pixel(spp, *rgb, spec, dr.select(valid, 1.0, 0.0)),
                  lambda r, g, b, sp, cov: (np.stack([r, g, b], axis=-1), sp, cov))
    return out if defer else out.fetch()
