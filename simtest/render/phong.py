"""The exact Phong BSDF of the paper (eq. 1) as a Mitsuba 3 Python plugin, ``simtest_phong``.

Mitsuba 3 has no Phong BSDF. This one returns, for the direction to the camera ``wi`` and the
direction to the light ``wo`` (both in the local shading frame, Mitsuba's convention)::

    f = c * max(0, dot(reflect(wi), wo))^n  [* |p - L|^2 if the light falloff is cancelled]
        + albedo / pi * cos(theta_o)

so that with a point light of intensity I the radiance is ``I c cos(beta)^n / d^2`` (or
``I c cos(beta)^n`` with the falloff cancelled): paper eq. 1 with no cosine foreshortening on the
specular part, as the paper's model has none.

Colour channels carry separate images in one render (the renderer uses RGB variants for this):
R = specular + diffuse (the image), G = specular only, B = diffuse only.

Importing this module imports Mitsuba; call :func:`register` after ``mi.set_variant``.
"""

from __future__ import annotations

import drjit as dr
import mitsuba as mi

__all__ = ["register", "PLUGIN_NAME"]

PLUGIN_NAME = "simtest_phong"

#: log2 of the smallest Phong lobe ``cos(beta)^n`` kept; smaller lobes are set to exactly 0.
#: 2^-100 (~7.9e-31) is far below anything an 8-bit (or 16-bit) sensor can see, and keeping every
#: kept lobe a normal float32 (>= 2^-126) makes the image independent of the floating-point mode
#: of the thread that runs the kernel: Dr.Jit's pool threads flush denormals to zero and the
#: calling thread (thread count 0 or 1) does not, which changed pixels near 1e-30 with the thread
#: count (a colon sample of ``scenes/datasets/example.toml``: 1.4848451e-30 vs 1.484845e-30).
LOBE_LOG2_MIN = -100.0

#: float32's smallest normal number: a ``cos(beta)`` below it is a denormal (read as 0 by a
#: thread that treats denormals as zero), so it counts as 0 on every thread.
FLT_MIN = 1.1754943508222875e-38

_registered: set[str] = set()


def _make_class():
    class PhongBSDF(mi.BSDF):
        """Exact Phong lobe plus an optional Lambertian part (see the module docstring).

        Properties
        ----------
        c : float
            Specular scale (paper's c).
        n : float
            Phong exponent (paper's n).
        albedo : float
            Lambertian albedo.
        cancel_falloff : bool
            Multiply by the squared distance from the shading point to ``light_pos`` (world frame).
        light_pos : (3,) float
            The point light position, world frame (mm).
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
            """Set c, n, the albedo and the light position (world frame, mm) of a loaded BSDF.

            The renderer reuses a loaded scene for new parameter values this way. Whether
            ``albedo > 0`` (the diffuse flag) and ``cancel_falloff`` are fixed at construction.
            """
            c, n, albedo = float(c), float(n), float(albedo)
            self._repr = f"PhongBSDF[c={c}, n={n}, albedo={albedo}]"
            # Opaque JIT values, not Python floats: the compiled kernel then does not depend on
            # the parameter values, so a sweep over n, c, albedo or the light reuses one kernel
            # from the cache instead of compiling one per value.
            self.c = dr.opaque(mi.Float, c)
            self.n = dr.opaque(mi.Float, n)
            self.albedo_over_pi = dr.opaque(mi.Float, albedo / dr.pi)
            self.light_pos = mi.Point3f(*(dr.opaque(mi.Float, float(light_pos[i]))
                                          for i in range(3)))

        def sample(self, ctx, si, sample1, sample2, active=True):
            # Only direct lighting from a point light is rendered: BSDF sampling never reaches it.
            # A zero sample keeps integrators that ask for one (e.g. `path`) consistent.
            return dr.zeros(mi.BSDFSample3f), mi.Color3f(0.0)

        def eval(self, ctx, si, wo, active=True):
            wi = si.wi
            cos_i = mi.Frame3f.cos_theta(wi)
            cos_o = mi.Frame3f.cos_theta(wo)
            r = mi.Vector3f(-wi.x, -wi.y, wi.z)  # mirror of wi about the shading normal
            cos_beta = dr.maximum(dr.dot(r, wo), 0.0)
            # Lobes below 2^LOBE_LOG2_MIN are 0, decided from n log2(cos beta) (never a denormal):
            # the same image whatever thread runs the kernel (see LOBE_LOG2_MIN).
            seen = (cos_beta >= FLT_MIN) & (self.n * dr.log2(dr.maximum(cos_beta, FLT_MIN))
                                            > LOBE_LOG2_MIN)
            spec = dr.select(seen, self.c * dr.power(cos_beta, self.n), 0.0)
            if self.cancel_falloff:
                d = si.p - self.light_pos
                spec = spec * dr.squared_norm(d)
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
    if variant in _registered:
        return
    cls = _make_class()  # bound to the current variant's mi.BSDF
    mi.register_bsdf(PLUGIN_NAME, lambda props: cls(props))
    _registered.add(variant)
