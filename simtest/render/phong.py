"""The exact Phong BSDF of the paper (eq. 1) as a Mitsuba 3 Python plugin, ``simtest_phong``.

For the direction to the camera ``wi`` and to the light ``wo`` (local shading frame)::

    f = c * max(0, dot(reflect(wi), wo))^n  [* |p - L|^2 if the light falloff is cancelled]
        + albedo / pi * cos(theta_o)

so a point light of intensity I gives ``I c cos(beta)^n / d^2`` (no foreshortening on the specular part,
as in the paper). Colour channels: R = specular + diffuse, G = specular only, B = diffuse only.
Importing this module imports Mitsuba; call :func:`register` after ``mi.set_variant``.
"""

from __future__ import annotations

import drjit as dr
import mitsuba as mi

__all__ = ["register", "PLUGIN_NAME"]

PLUGIN_NAME = "simtest_phong"

#: log2 of the smallest Phong lobe ``cos(beta)^n`` kept; smaller lobes are exactly 0. Far below any sensor,
#: and every kept lobe a normal float32, so the image does not depend on whether the kernel's thread
#: flushes denormals (Dr.Jit's pool threads do, the calling thread does not).
LOBE_LOG2_MIN = -100.0

#: float32's smallest normal number: a ``cos(beta)`` below it counts as 0 on every thread
FLT_MIN = 1.1754943508222875e-38

_registered: set[str] = set()


def _make_class():
    class PhongBSDF(mi.BSDF):
        """Exact Phong lobe plus an optional Lambertian part.

        Properties ``c``, ``n``, ``albedo``, ``cancel_falloff`` and ``light_pos`` (world frame, mm).
        """

        def __init__(self, props):
            mi.BSDF.__init__(self, props)
            c = float(props.get("c", 1.0))
            n = float(props.get("n", 50.0))
            albedo = float(props.get("albedo", 0.0))
            self.cancel_falloff = bool(props.get("cancel_falloff", False))
            lp = props.get("light_pos", mi.ScalarPoint3f(0.0, 0.0, 0.0))
            self.set_params(c, n, albedo, [float(lp[i]) for i in range(3)])
            flags = mi.BSDFFlags.GlossyReflection | mi.BSDFFlags.FrontSide
            if albedo > 0.0:
                flags = flags | mi.BSDFFlags.DiffuseReflection
            self.m_flags = flags
            self.m_components = [flags]

        def set_params(self, c, n, albedo, light_pos):
            """Set c, n, the albedo and the light position (world frame, mm) of a loaded BSDF, as opaque JIT values.

            Whether ``albedo > 0`` and ``cancel_falloff`` are fixed at construction.
            """
            c, n, albedo = float(c), float(n), float(albedo)
            self._repr = f"PhongBSDF[c={c}, n={n}, albedo={albedo}]"
            # opaque: a sweep over n, c, albedo or the light reuses one compiled kernel
            self.c = dr.opaque(mi.Float, c)
            self.n = dr.opaque(mi.Float, n)
            self.albedo_over_pi = dr.opaque(mi.Float, albedo / dr.pi)
            self.light_pos = mi.Point3f(*(dr.opaque(mi.Float, float(light_pos[i])) for i in range(3)))

        def sample(self, ctx, si, sample1, sample2, active=True):
            # only direct lighting from a point light: BSDF sampling never reaches it
            return dr.zeros(mi.BSDFSample3f), mi.Color3f(0.0)

        def eval(self, ctx, si, wo, active=True):
            wi = si.wi
            cos_i = mi.Frame3f.cos_theta(wi)
            cos_o = mi.Frame3f.cos_theta(wo)
            r = mi.Vector3f(-wi.x, -wi.y, wi.z)  # mirror of wi about the shading normal
            cos_beta = dr.maximum(dr.dot(r, wo), 0.0)
            # lobes below 2^LOBE_LOG2_MIN are 0, decided from n log2(cos beta) (never a denormal)
            seen = (cos_beta >= FLT_MIN) & (self.n * dr.log2(dr.maximum(cos_beta, FLT_MIN)) > LOBE_LOG2_MIN)
            spec = dr.select(seen, self.c * dr.power(cos_beta, self.n), 0.0)
            if self.cancel_falloff:
                spec = spec * dr.squared_norm(si.p - self.light_pos)
            diff = self.albedo_over_pi * dr.maximum(cos_o, 0.0)
            ok = active & (cos_i > 0.0) & (cos_o > 0.0)
            value = mi.Color3f(spec + diff, spec, diff)
            return dr.select(ok, value, mi.Color3f(0.0))

        def pdf(self, ctx, si, wo, active=True):
            return mi.Float(0.0)

        def eval_pdf(self, ctx, si, wo, active=True):
            return self.eval(ctx, si, wo, active), mi.Float(0.0)

        def to_string(self):
            return self._repr

    return PhongBSDF


def register() -> None:
    """Register ``simtest_phong`` for the current Mitsuba variant (once per variant)."""
    variant = mi.variant()
    if variant not in _registered:
        cls = _make_class()  # bound to the current variant's mi.BSDF
        mi.register_bsdf(PLUGIN_NAME, lambda props: cls(props))
        _registered.add(variant)
