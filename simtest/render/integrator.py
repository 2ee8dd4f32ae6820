"""One-trace direct-lighting integrator with ground-truth AOVs, ``simtest_gt`` (Mitsuba 3 plugin).

Traces each camera ray once (Mitsuba's ``aov`` + ``direct`` trace it twice), evaluates the BSDF for the
point light and writes the shading normal and position as AOVs after RGBA: ``nn.X nn.Y nn.Z pp.X pp.Y
pp.Z``, in the camera frame (:meth:`set_camera_pose` for a scene built in another frame). The shadow ray
is optional (``shadows``): the renderer asks for it only on meshes lit from an offset light. Importing
this module imports Mitsuba; call :func:`register` after ``mi.set_variant``.
"""

from __future__ import annotations

import drjit as dr
import mitsuba as mi

__all__ = ["register", "PLUGIN_NAME", "AOV_NAMES"]

PLUGIN_NAME = "simtest_gt"
AOV_NAMES = ["nn.X", "nn.Y", "nn.Z", "pp.X", "pp.Y", "pp.Z"]

_registered: set[str] = set()


def _make_class():
    class GroundTruthIntegrator(mi.SamplingIntegrator):
        """Direct lighting from the scene's emitters (one sample) plus normal and position AOVs."""

        def __init__(self, props):
            mi.SamplingIntegrator.__init__(self, props)
            self.shadows = bool(props.get("shadows", True))
            self.pose = None  # (x, y, z axes, centre) of the camera in the scene frame

        def set_camera_pose(self, cam_to_scene):
            """Write AOVs in the camera frame of ``cam_to_scene`` (4, 4) (None: the scene frame), as opaque values."""
            self.pose = None if cam_to_scene is None else tuple(
                mi.Vector3f(*(dr.opaque(mi.Float, float(cam_to_scene[i][j])) for i in range(3))) for j in range(4))

        def aov_names(self):
            return AOV_NAMES

        def sample(self, scene, sampler, ray, medium=None, active=True):
            si = scene.ray_intersect(ray, active)
            valid = active & si.is_valid()
            ds, em_weight = scene.sample_emitter_direction(si, sampler.next_2d(valid), self.shadows, valid)
            bsdf = si.bsdf(ray)
            ctx = mi.BSDFContext()
            lit = valid & (ds.pdf != 0.0)
            value = bsdf.eval(ctx, si, si.to_local(ds.d), lit)
            L = dr.select(lit, value * em_weight, mi.Spectrum(0.0))
            n, p = si.sh_frame.n, si.p
            if self.pose is not None:
                ex, ey, ez, centre = self.pose
                d = p - centre
                n = mi.Vector3f(dr.dot(n, ex), dr.dot(n, ey), dr.dot(n, ez))
                p = mi.Point3f(dr.dot(d, ex), dr.dot(d, ey), dr.dot(d, ez))
            zero = mi.Float(0.0)
            aovs = [dr.select(valid, n.x, zero), dr.select(valid, n.y, zero), dr.select(valid, n.z, zero),
                    dr.select(valid, p.x, zero), dr.select(valid, p.y, zero), dr.select(valid, p.z, zero)]
            return L, valid, aovs

        def to_string(self):
            return f"GroundTruthIntegrator[shadows={self.shadows}]"

    return GroundTruthIntegrator


def register() -> None:
    """Register ``simtest_gt`` for the current Mitsuba variant (once per variant)."""
    variant = mi.variant()
    if variant not in _registered:
        cls = _make_class()
        mi.register_integrator(PLUGIN_NAME, lambda props: cls(props))
        _registered.add(variant)
