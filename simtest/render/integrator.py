"""One-trace direct-lighting integrator with ground-truth AOVs, ``simtest_gt`` (Mitsuba 3 plugin).

Mitsuba's ``aov`` integrator traces each camera ray once for its AOVs and once more inside the
nested ``direct`` integrator, which then traces a shadow ray. For scenes lit by one point light this
integrator traces the camera ray once, evaluates the BSDF for the light, and writes the shading
normal and the position (world frame = the camera frame here) as AOVs, in that order after RGBA:
``nn.X nn.Y nn.Z pp.X pp.Y pp.Z``.

A scene may also be built in another frame than the camera's (meshes: their world frame, so that
a new camera pose only moves the sensor instead of rebuilding the acceleration structure); then
:meth:`set_camera_pose` gives the camera pose and the AOVs are written in the camera frame all the
same (``n_cam = R^T n``, ``p_cam = R^T (p - c)`` per sample, before the pixel average).

The shadow ray is optional (property ``shadows``): with a co-located light every point the camera
sees is lit, and a single plane, sphere or cylinder seen from outside cannot shadow itself (points
facing away from the light get zero from the BSDF), so the renderer asks for shadows only for
meshes lit from an offset light.

Importing this module imports Mitsuba; call :func:`register` after ``mi.set_variant``.
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
            """Write AOVs in the camera frame of the pose ``cam_to_scene`` ((4, 4), columns: the
            camera's x, y, z axes and its centre in the scene frame); None: the scene frame is the
            camera frame. The values are opaque: a new pose reuses the compiled kernel."""
            if cam_to_scene is None:
                self.pose = None
                return
            self.pose = tuple(
                mi.Vector3f(*(dr.opaque(mi.Float, float(cam_to_scene[i][j])) for i in range(3)))
                for j in range(4))

        def aov_names(self):
            return AOV_NAMES

        def sample(self, scene, sampler, ray, medium=None, active=True):
            si = scene.ray_intersect(ray, active)
            valid = active & si.is_valid()
            ds, em_weight = scene.sample_emitter_direction(
                si, sampler.next_2d(valid), self.shadows, valid)
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
            aovs = [dr.select(valid, n.x, zero), dr.select(valid, n.y, zero),
                    dr.select(valid, n.z, zero), dr.select(valid, p.x, zero),
                    dr.select(valid, p.y, zero), dr.select(valid, p.z, zero)]
            return L, valid, aovs

        def to_string(self):
            return f"GroundTruthIntegrator[shadows={self.shadows}]"

    return GroundTruthIntegrator


def register() -> None:
    """Register ``simtest_gt`` for the current Mitsuba variant (once per variant)."""
    variant = mi.variant()
    if variant in _registered:
        return
    cls = _make_class()
    mi.register_integrator(PLUGIN_NAME, lambda props: cls(props))
    _registered.add(variant)
