"""The kinds of surface a scene holds: one frozen pydantic class per ``geometry.type`` (its own keys only).

Class attributes tell the renderer how to treat a kind: ``type`` (its name in the scene file),
``frame`` (``"world"``, or ``"camera"`` when placed relative to the camera) and ``triangulated``
(rendered as a mesh with per-vertex normals and curvatures). :data:`GEOMETRY_TYPES` is the registry.
The analytic kinds (not triangulated) carry, in the OpenCV camera frame (mm; ``w2c`` the (4, 4)
world-to-camera matrix): ``surface(w2c, bsdf)``, their Mitsuba surface description; ``highlight(w2c,
light_pos, K, size)``, their highlight in closed form (:mod:`simtest.simulate.truth`; None off the image
or the surface). Every kind has (defaults in :class:`_Kind`) ``texture_axes()``, the tissue texture's (2, 3)
axes (None: the default frame); ``quiet_load``, whether Mitsuba's loader warns falsely on its transform; and
``stamp()``, what besides its keys a cached load depends on (a mesh file's modification time; None).
"""

from __future__ import annotations

import functools
import math
import os
from typing import ClassVar

import numpy as np
from pydantic import Field
from pydantic.dataclasses import dataclass

from simtest._config import CONFIG, Bool, Int, Num, Str, Vec3
from simtest.simulate.truth import cylinder_highlight, plane_highlight, sphere_highlight

__all__ = ["PlaneGeometry", "SphereGeometry", "CylinderGeometry", "SaddleGeometry", "MeshGeometry", "GeometrySpec",
           "GEOMETRY_TYPES", "GEOMETRY_KEYS", "GEOMETRY_KEY_ORDER", "plane_normal_cam", "rotation_from_z"]

#: The kinds' and the scene sections' model settings: frozen, unknown keys refused, NaN and infinity refused.
_frozen = functools.partial(dataclass, frozen=True, config=CONFIG)


#: Keys each geometry type accepts (besides ``type``) and which of them are required.
GEOMETRY_KEYS: dict[str, tuple[tuple[str, ...], tuple[str, ...]]] = {
    # type: (required, optional)
    "plane": (("tilt_deg", "distance_mm"), ("azimuth_deg", "extent_mm")),
    "sphere": (("center_mm", "radius_mm"), ()),
    "cylinder": (("center_mm", "radius_mm"), ("axis", "length_mm")),
    "saddle": (("distance_mm", "radius1_mm", "radius2_mm"), ("extent_mm", "resolution")),
    "mesh": (("path",), ("translate_mm", "rotate_deg", "scale", "flip_normals")),
}


def plane_normal_cam(geometry: PlaneGeometry) -> np.ndarray:
    """Camera-facing unit normal of a plane spec: ``(sin t cos a, sin t sin a, -cos t)``."""
    t = math.radians(geometry.tilt_deg or 0.0)
    a = math.radians(90.0 if geometry.azimuth_deg is None else geometry.azimuth_deg)
    return np.array([math.sin(t) * math.cos(a), math.sin(t) * math.sin(a), -math.cos(t)])


def rotation_from_z(n: np.ndarray) -> np.ndarray:
    """A rotation matrix (3, 3) whose third column is the unit vector ``n``."""
    n = np.asarray(n, dtype=np.float64) / np.linalg.norm(n)
    helper = np.array([1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    a = np.cross(helper, n)
    a /= np.linalg.norm(a)
    return np.column_stack([a, np.cross(n, a), n])


def _in_camera(w2c: np.ndarray, point_mm) -> np.ndarray:
    return (w2c @ np.append(point_mm, 1.0))[:3]


class _Kind:
    """What a kind has unless it says otherwise: the world frame, no triangles, the default texture frame, no
    loader warning, no file."""

    frame: ClassVar[str] = "world"
    triangulated: ClassVar[bool] = False
    quiet_load: ClassVar[bool] = False

    def texture_axes(self) -> np.ndarray | None:
        return None

    def stamp(self) -> float | None:
        return None


@_frozen
class PlaneGeometry(_Kind):
    """An infinite (or ``extent_mm``-limited) plane, world frame.

    Attributes
    ----------
    tilt_deg : float
        Angle between the plane normal and the optical axis, [0, 90); required.
    azimuth_deg : float or None
        Direction of the tilt in the image; the camera-facing normal is
        ``(sin t cos a, sin t sin a, -cos t)``, so with the default 90 the BP lies above the image
        centre.
    distance_mm : float
        Distance from the camera centre to the plane (the paper's V_Z), > 0; required.
    extent_mm : float or None
        Half side of the square patch (default 100 x distance).
    """

    type: ClassVar[str] = "plane"
    frame: ClassVar[str] = "camera"
    tilt_deg: Num | None = Field(None, ge=0.0, lt=90.0)
    azimuth_deg: Num | None = None
    distance_mm: Num | None = Field(None, gt=0.0)
    extent_mm: Num | None = Field(None, gt=0.0)

    def _square(self):  # the camera-facing normal, the foot of the perpendicular, the half side
        n = plane_normal_cam(self)
        return n, -self.distance_mm * n, self.extent_mm if self.extent_mm is not None else 100.0 * self.distance_mm

    def surface(self, w2c, bsdf) -> dict:
        n, foot, half = self._square()
        m = np.eye(4)
        m[:3, :3] = rotation_from_z(n) * half  # rectangle normal +z -> n (faces the camera)
        m[:3, 3] = foot
        return {"type": "rectangle", "to_world": m, "bsdf": bsdf}

    def highlight(self, w2c, light_pos, K, size):
        n, foot, half = self._square()
        hl = plane_highlight(n, self.distance_mm, light_pos, K, size)
        return None if hl is not None and np.max(np.abs(hl.bp_mm - foot)) > half else hl

    def texture_axes(self) -> np.ndarray:  # the plane's own in-plane axes
        return rotation_from_z(plane_normal_cam(self))[:, :2].T.copy()


@_frozen
class SphereGeometry(_Kind):
    """A sphere, world frame.

    Attributes
    ----------
    center_mm : (3,) float
        Centre; required.
    radius_mm : float
        Radius, > 0; required.
    """

    type: ClassVar[str] = "sphere"
    center_mm: Vec3 | None = None
    radius_mm: Num | None = Field(None, gt=0.0)

    def surface(self, w2c, bsdf) -> dict:
        return {"type": "sphere", "center": [float(x) for x in _in_camera(w2c, self.center_mm)],
                "radius": self.radius_mm, "bsdf": bsdf}

    def highlight(self, w2c, light_pos, K, size):
        return sphere_highlight(_in_camera(w2c, self.center_mm), self.radius_mm, light_pos, K, size)


@_frozen
class CylinderGeometry(_Kind):
    """A finite cylinder, world frame.

    Attributes
    ----------
    center_mm : (3,) float
        A point on the axis, the centre of the cylinder; required.
    radius_mm : float
        Radius, > 0; required.
    axis : (3,) float or None
        Axis direction (not the zero vector); default (1, 0, 0).
    length_mm : float or None
        Length (default 20 x radius).
    """

    type: ClassVar[str] = "cylinder"
    quiet_load: ClassVar[bool] = True  # float32 round-off in R diag(r, r, length) reads to Mitsuba as "shearing"
    center_mm: Vec3 | None = None
    radius_mm: Num | None = Field(None, gt=0.0)
    axis: Vec3 | None = None
    length_mm: Num | None = Field(None, gt=0.0)

    def _axis_length(self):
        axis = np.asarray(self.axis if self.axis is not None else (1.0, 0.0, 0.0), dtype=np.float64)
        return axis, self.length_mm if self.length_mm is not None else 20.0 * self.radius_mm

    def surface(self, w2c, bsdf) -> dict:
        axis, length = self._axis_length()
        axis = w2c[:3, :3] @ (axis / np.linalg.norm(axis))
        m = np.eye(4)  # Mitsuba's cylinder: radius 1 about the local z axis, z from 0 to 1
        m[:3, :3] = rotation_from_z(axis) @ np.diag([self.radius_mm, self.radius_mm, length])
        m[:3, 3] = _in_camera(w2c, self.center_mm) - 0.5 * length * axis
        return {"type": "cylinder", "to_world": m, "bsdf": bsdf}

    def highlight(self, w2c, light_pos, K, size):
        axis, length = self._axis_length()
        return cylinder_highlight(_in_camera(w2c, self.center_mm), w2c[:3, :3] @ axis, self.radius_mm, length,
                                  light_pos, K, size)


@_frozen
class SaddleGeometry(_Kind):
    """The saddle ``z = d + x^2 / (2 r1) - y^2 / (2 r2)``, camera frame, ``|x|, |y| <= extent``.

    A grid mesh with analytic normals and curvatures (:func:`simtest.simulate.truth.saddle_mesh`).

    Attributes
    ----------
    distance_mm : float
        Depth d of the apex on the optical axis, > 0; required.
    extent_mm : float or None
        Half side of the square patch (default: the distance).
    radius1_mm, radius2_mm : float
        r1 and r2, > 0; required.
    resolution : int or None
        Vertices per side of the grid mesh, 3 to 4096 (default 129).
    """

    type: ClassVar[str] = "saddle"
    frame: ClassVar[str] = "camera"
    triangulated: ClassVar[bool] = True
    distance_mm: Num | None = Field(None, gt=0.0)
    extent_mm: Num | None = Field(None, gt=0.0)
    radius1_mm: Num | None = Field(None, gt=0.0)
    radius2_mm: Num | None = Field(None, gt=0.0)
    resolution: Int | None = Field(None, ge=3, le=4096)


@_frozen
class MeshGeometry(_Kind):
    """A triangle mesh file in its own world frame.

    Attributes
    ----------
    path : str
        PLY file written by ``simtest.scene.meshes.save_mesh``, relative to the scene file's folder
        or the bundled data (:func:`simtest.resources.data_root`); required.
    translate_mm, rotate_deg, scale : (3,) float, (3,) float, float, or None
        Mesh-to-world transform ``x -> R (scale x) + t``, with ``R = Rz Ry Rx`` from ``rotate_deg``
        (degrees about the world axes, x first) and ``t = translate_mm``; defaults identity.
    flip_normals : bool or None
        Reverse the vertex normals and curvature signs.
    """

    type: ClassVar[str] = "mesh"
    triangulated: ClassVar[bool] = True
    path: Str | None = None
    translate_mm: Vec3 | None = None
    rotate_deg: Vec3 | None = None
    scale: Num | None = Field(None, gt=0.0)
    flip_normals: Bool | None = None

    def stamp(self) -> float:  # a rewritten file is another surface
        return os.path.getmtime(self.path)


#: The one surface of a scene: a union of the kinds, told apart by their class attribute ``type``.
GeometrySpec = PlaneGeometry | SphereGeometry | CylinderGeometry | SaddleGeometry | MeshGeometry

#: The geometry class of each ``geometry.type``.
GEOMETRY_TYPES: dict[str, type] = {cls.type: cls for cls in (
    PlaneGeometry, SphereGeometry, CylinderGeometry, SaddleGeometry, MeshGeometry)}

#: Every geometry key, in the order the files and messages list them (``type`` first).
GEOMETRY_KEY_ORDER = tuple(dict.fromkeys(["type", *(f for cls in GEOMETRY_TYPES.values()
                                                     for f in cls.__pydantic_fields__)]))
