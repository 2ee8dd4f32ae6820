"""The bisector: the BP ray corrected by the rig for a given depth (closed form), each light's
bisector at a point (:func:`light_bisectors`), and how far a plane's normal is from them
(:func:`reflection_offset_deg`)."""

from __future__ import annotations

import numpy as np

from simtest.geometry.angles import angle_between_deg, unit
from simtest.geometry.lights import LightRig
from simtest.reconstruct._pixels import uv_to_rc
from simtest.reconstruct.lightaware.estimate import LightAwareEstimate, OK
from simtest.reconstruct.lightaware.model import _mean_light, _rays
from simtest.reconstruct.lightaware.solve import _bisector_plane


def bisector(bp_uv, camera, rig: LightRig, depth_mm) -> LightAwareEstimate:
    """The BP ray corrected by the rig for a given depth: the normal that makes the BP specular.

    At depth s along the BP's ray ``X = s d`` and ``N = unit(unit(-X) + unit(L - X))``, L the rig's
    intensity-weighted mean light. Exact for a plane at the BP's true depth.

    Parameters
    ----------
    bp_uv : array_like of shape (2,)
        Brightest point (u, v), undistorted px.
    camera : array_like of shape (3, 3) or CameraModel
        Intrinsics K, or a camera model with ``pixel_to_ray``.
    rig : LightRig
        The lights, camera frame, mm.
    depth_mm : float or ndarray of shape (H, W)
        Distance from the camera centre to the BP along its ray, mm; or a depth map, sampled at the
        nearest pixel of the BP.

    Returns
    -------
    LightAwareEstimate
        ``normal`` (unit, facing the camera), ``depth_mm`` as given, ``normal_sigma_deg`` None.

    Raises
    ------
    ValueError
        A non-finite BP, a depth that is not > 0, or a BP outside the depth map.
    """
    bp = np.asarray(bp_uv, dtype=np.float64).reshape(-1)
    if bp.shape != (2,) or not np.isfinite(bp).all():
        raise ValueError(f"bp_uv: need 2 finite numbers (u, v), got {bp_uv!r}")
    dm = np.asarray(depth_mm, dtype=np.float64)
    if dm.ndim == 2:
        r, c = (int(v) for v in np.rint(uv_to_rc(bp)))
        if not (0 <= r < dm.shape[0] and 0 <= c < dm.shape[1]):
            raise ValueError(f"bp_uv {bp.tolist()} lies outside the depth map of shape {dm.shape}")
        s = float(dm[r, c])
    elif dm.ndim == 0:
        s = float(dm)
    else:
        raise ValueError(f"depth_mm: a number or an (H, W) map, got shape {dm.shape}")
    if not (np.isfinite(s) and s > 0):
        raise ValueError(f"depth_mm: must be finite and > 0 at the BP, got {s}")
    n = _bisector_plane(_rays(camera, bp[None])[0], _mean_light(rig), s)[0]
    return LightAwareEstimate("bisector", OK, "", n, s)


def reflection_offset_deg(bp_uv, camera, rig: LightRig, normal, distance_mm: float) -> float:
    """How far a plane's normal is from obeying the law of reflection at the BP: the least angle,
    degrees, between ``normal`` and the bisector of the directions to the camera and to one light of
    the rig, at the point where the plane meets the BP's ray.

    At a highlight's specular point the surface normal bisects the directions to the camera and to
    the light that made it (:func:`light_bisectors`), on any surface. A plane fit whose specular point
    lies at the BP gives 0 (on a plane the lobe's peak sits a little off it: the falloff and the diffuse
    term shift it); on a curved patch a plane's normal can miss the law by degrees.

    Parameters
    ----------
    bp_uv, camera, rig
        As in :func:`bisector`.
    normal : array_like of shape (3,)
        Unit plane normal facing the camera (``n . X = -h`` on the plane), camera frame.
    distance_mm : float
        The plane's distance ``h`` from the camera centre, mm (> 0).

    Returns
    -------
    float
        Degrees in [0, 180]; NaN where the BP's ray does not meet the plane in front of the camera.
    """
    n = np.asarray(normal, dtype=np.float64)
    ray = _rays(camera, np.asarray(bp_uv, dtype=np.float64).reshape(1, 2))[0]
    facing = -float(n @ ray)
    if not (facing > 0 and distance_mm > 0):
        return float("nan")
    return float(np.min(angle_between_deg(light_bisectors((float(distance_mm) / facing) * ray, rig), n)))


def light_bisectors(point_mm, rig: LightRig) -> np.ndarray:
    """Each light's bisector at ``point_mm`` (3,), camera frame, mm: ``unit(unit(-X) + unit(L_j - X))``, the
    normal that makes X light j's specular point (the law of reflection), as an (n_lights, 3) array facing
    the camera; a NaN row for a light at X."""
    X = np.asarray(point_mm, dtype=np.float64)
    return unit(unit(-X) + unit(rig.positions - X, axis=-1), axis=-1)
