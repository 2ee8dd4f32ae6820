"""The kinds of surface a scene holds: one frozen pydantic class per ``geometry.type`` (its own keys only).

Class attributes tell the renderer how to treat a kind: ``type`` (its name in the scene file),
``frame`` (``"world"``, or ``"camera"`` when placed relative to the camera) and ``triangulated``
(rendered as a mesh with per-vertex normals and curvatures). :data:`GEOMETRY_TYPES` is the registry.
"""

from __future__ import annotations

import functools
from typing import ClassVar

from pydantic import Field
from pydantic.dataclasses import dataclass

from simtest._config import CONFIG, Bool, Int, Num, Str, Vec3

__all__ = ["PlaneGeometry", "SphereGeometry", "CylinderGeometry", "SaddleGeometry", "MeshGeometry", "GeometrySpec",
           "GEOMETRY_TYPES", "GEOMETRY_KEYS", "GEOMETRY_KEY_ORDER"]

#: The kinds' model settings: frozen, unknown keys refused, NaN and infinity refused.
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


@_frozen
class PlaneGeometry:
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
    triangulated: ClassVar[bool] = False
    tilt_deg: Num | None = Field(None, ge=0.0, lt=90.0)
    azimuth_deg: Num | None = None
    distance_mm: Num | None = Field(None, gt=0.0)
    extent_mm: Num | None = Field(None, gt=0.0)


@_frozen
class SphereGeometry:
    """A sphere, world frame.

    Attributes
    ----------
    center_mm : (3,) float
        Centre; required.
    radius_mm : float
        Radius, > 0; required.
    """

    type: ClassVar[str] = "sphere"
    frame: ClassVar[str] = "world"
    triangulated: ClassVar[bool] = False
    center_mm: Vec3 | None = None
    radius_mm: Num | None = Field(None, gt=0.0)


@_frozen
class CylinderGeometry:
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
    frame: ClassVar[str] = "world"
    triangulated: ClassVar[bool] = False
    center_mm: Vec3 | None = None
    radius_mm: Num | None = Field(None, gt=0.0)
    axis: Vec3 | None = None
    length_mm: Num | None = Field(None, gt=0.0)


@_frozen
class SaddleGeometry:
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
class MeshGeometry:
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
    frame: ClassVar[str] = "world"
    triangulated: ClassVar[bool] = True
    path: Str | None = None
    translate_mm: Vec3 | None = None
    rotate_deg: Vec3 | None = None
    scale: Num | None = Field(None, gt=0.0)
    flip_normals: Bool | None = None


#: The one surface of a scene: a union of the kinds, told apart by their class attribute ``type``.
GeometrySpec = PlaneGeometry | SphereGeometry | CylinderGeometry | SaddleGeometry | MeshGeometry

#: The geometry class of each ``geometry.type``.
GEOMETRY_TYPES: dict[str, type] = {cls.type: cls for cls in (
    PlaneGeometry, SphereGeometry, CylinderGeometry, SaddleGeometry, MeshGeometry)}

#: Every geometry key, in the order the files and messages list them (``type`` first).
GEOMETRY_KEY_ORDER = tuple(dict.fromkeys(["type", *(f for cls in GEOMETRY_TYPES.values()
                                                     for f in cls.__pydantic_fields__)]))
