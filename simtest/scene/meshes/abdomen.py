"""The liver in its abdomen: the liver mesh and, behind it, a wall of neighbouring tissue.

A laparoscope sees the liver against the wall of the abdomen, never a void.
:func:`build_liver_in_abdomen` joins the liver of :func:`~simtest.scene.meshes.liver.build_liver`
with the inside of a spherical cap (the "wall") of radius ``wall_radius_mm``, centred on the line
from the liver's centre toward the scope (``wall_axis``) as far toward it as keeps the liver
``gap_mm`` inside the sphere; from a scope inside, every ray that misses the liver meets the wall.
The cap's normals point to the centre, ``k1 = k2 = -1 / wall_radius_mm`` exactly; the texture
tells wall from liver by the distance from the centre (``material.wall_tissue``).

Optionally a gallbladder, a closed ellipsoid against the liver's inferior surface (70 to 100 mm by
30 to 40 mm, Standring, "Gray's Anatomy", 41st ed., ch. 68), with closed-form normals and
curvatures (:func:`ellipsoid_curvature`, ``material.organ_tissue``); and a second lobe with the
thin inferior margin a laparoscope sees, a wedge-shaped ellipsoid (:func:`lobe_implicit`) whose
curvatures come from :func:`~simtest.scene.meshes.curvature.implicit_curvature`. Both are sunk
into the liver, so every visible point keeps its own surface's truth.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import trimesh
from scipy.spatial import ConvexHull

from simtest.scene.meshes.curvature import FD_STEP_MM, _principal_from_h_k, implicit_curvature
from simtest.scene.meshes.files import _assemble
from simtest.scene.meshes.liver import _fibonacci_sphere, _hull_faces, _wound, build_liver
from simtest.scene.meshes.params import MeshError

__all__ = ["LAPAROSCOPE_WALL_AXIS", "LAPAROSCOPE_ABDOMEN", "wall_sphere", "ellipsoid_curvature", "lobe_implicit",
           "build_liver_in_abdomen"]

#: The wall's axis of meshes/liver_abdomen.ply: the unit direction from the liver's bounding-box
#: centre toward the scope of scenes/laparoscope_liver.toml.
LAPAROSCOPE_WALL_AXIS = (-0.5022907830486957, -0.5249903665151608, -0.6870873920620324)

#: The organs of meshes/liver_abdomen.ply beside the liver (mm, liver frame), placed for the view of
#: scenes/laparoscope_liver.toml: the gallbladder (80 x 32 x 32 mm) at the lower right, a lobe
#: (100 x 60 mm, 28 mm thick, 15 mm at its margin) over the upper right. The wall's 8 mm spacing
#: keeps the file under 2 MB (interpolated normals within 0.3 deg on the 400 mm sphere).
LAPAROSCOPE_ABDOMEN = {"gallbladder_centre_mm": (0.3, -27.4, -67.8), "gallbladder_axes_mm": (40.0, 16.0, 16.0),
                       "lobe_centre_mm": (20.1, -64.2, -39.6), "lobe_normal": (-0.23, -0.92, -0.317),
                       "lobe_edge": (-0.541, 0.391, -0.745), "lobe_axes_mm": (50.0, 30.0, 14.0), "lobe_wedge": 0.6,
                       "wall_spacing_mm": 8.0}


def wall_sphere(liver_vertices: np.ndarray, wall_axis, wall_radius_mm: float, gap_mm: float) -> tuple[np.ndarray, float]:
    """Centre (3,) and radius of the wall's sphere for a liver's vertices (module notes).

    Raises
    ------
    MeshError
        If the axis is zero or the radius does not exceed the liver's reach plus the gap.
    """
    u = np.asarray(wall_axis, dtype=np.float64)
    if not np.linalg.norm(u) > 0:
        raise MeshError("build_liver_in_abdomen: wall_axis must be a non-zero vector")
    u = u / np.linalg.norm(u)
    v = np.asarray(liver_vertices, dtype=np.float64)
    mid = 0.5 * (v.min(axis=0) + v.max(axis=0))
    target = wall_radius_mm - gap_mm

    def reach(t: float) -> float:
        return float(np.max(np.linalg.norm(v - (mid + t * u), axis=1)))

    if reach(0.0) > target:
        raise MeshError(f"build_liver_in_abdomen: wall_radius_mm {wall_radius_mm} is too small: the liver reaches "
                        f"{reach(0.0):.1f} mm from its centre (needs at most wall_radius_mm - gap_mm = {target})")
    # the centre as far toward the scope as the gap allows: reach(t) grows with t past the liver
    lo, hi = 0.0, float(wall_radius_mm)
    for _ in range(60):
        mid_t = 0.5 * (lo + hi)
        lo, hi = (mid_t, hi) if reach(mid_t) <= target else (lo, mid_t)
    centre = mid + lo * u
    return centre, float(wall_radius_mm)


def ellipsoid_curvature(points: np.ndarray, centre, axes) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Outward unit normals and principal curvatures (k1 >= k2 > 0, 1/mm) of an ellipsoid.

    ``points`` (N, 3) on the ellipsoid ``sum(((x - centre) / axes)^2) = 1`` (semi-axes along the
    frame's axes, mm). Closed forms: the normal is ``grad`` of that quadric normalised; with
    ``h^2 = sum(y_i^2 / a_i^4)`` (``y = x - centre``), the Gaussian curvature is
    ``K = 1 / ((a b c)^2 h^4)`` and the mean curvature ``H = (a^2 + b^2 + c^2 - |y|^2) / (2 (a b c)^2 h^3)``
    (Goldman 2005, doi:10.1016/j.cagd.2005.06.005, applied to the quadric), ``k = H +- sqrt(H^2 - K)``.
    """
    a = np.asarray(axes, dtype=np.float64)
    y = np.asarray(points, dtype=np.float64) - np.asarray(centre, dtype=np.float64)
    g = y / a**2
    h = np.linalg.norm(g, axis=1)
    abc2 = float(np.prod(a)) ** 2
    K = 1.0 / (abc2 * h**4)
    H = (float(np.sum(a * a)) - np.sum(y * y, axis=1)) / (2.0 * abc2 * h**3)
    return (g / h[:, None], *_principal_from_h_k(H, K))


def _gallbladder(centre, axes, spacing_mm: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Vertices, outward-wound faces, normals, k1, k2 of the closed ellipsoid (module notes)."""
    a = np.asarray(axes, dtype=np.float64)
    if a.shape != (3,) or not (a > 0).all():
        raise MeshError(f"build_liver_in_abdomen: gallbladder_axes_mm must be three positive lengths, got {axes}")
    p = (a[0] * a[1]) ** 1.6 + (a[0] * a[2]) ** 1.6 + (a[1] * a[2]) ** 1.6
    area = 4.0 * math.pi * (p / 3.0) ** (1 / 1.6)  # Knud Thomsen's approximation, within 1.1 %
    n = max(200, int(area / (0.5 * math.sqrt(3) * spacing_mm**2) / 2))
    d = _fibonacci_sphere(n)
    faces = _hull_faces(d)  # a positive scaling keeps the winding outward
    v = np.asarray(centre, dtype=np.float64) + a * d
    nrm, k1, k2 = ellipsoid_curvature(v, centre, a)
    return v, faces, nrm, k1, k2


def _lobe_frame(normal, edge) -> np.ndarray:
    """(3, 3) rotation whose columns are the lobe's axes: x along its margin, y toward its thin
    margin (``edge`` made orthogonal to ``normal``), z its ``normal`` (right-handed)."""
    z = np.asarray(normal, dtype=np.float64)
    z = z / np.linalg.norm(z)
    y = np.asarray(edge, dtype=np.float64)
    y = y - (y @ z) * z
    if not np.linalg.norm(y) > 1e-9:
        raise MeshError("build_liver_in_abdomen: lobe_edge must not be parallel to lobe_normal")
    y = y / np.linalg.norm(y)
    return np.stack([np.cross(y, z), y, z], axis=1)


def lobe_implicit(x: np.ndarray, centre, frame: np.ndarray, axes, wedge: float) -> np.ndarray:
    """The lobe's implicit function, mm (negative inside; module notes), at points ``x`` (..., 3).

    In the lobe's frame ``(X, Y, Z) = frame^T (x - centre)``, ``F = c (|(X / a, Y / b, Z / (c
    exp(-wedge Y / b)))| - 1)``: an ellipsoid whose half-thickness ``c`` shrinks by ``exp(-2
    wedge)`` from its back (``Y = -b``) to its thin margin (``Y = +b``), scaled by ``c`` so that
    F is about a distance in mm near the surface.
    """
    a, b, c = (float(v) for v in axes)
    q = (np.asarray(x, dtype=np.float64) - np.asarray(centre, dtype=np.float64)) @ frame
    t = c * np.exp(-wedge * q[..., 1] / b)
    return c * (np.sqrt((q[..., 0] / a) ** 2 + (q[..., 1] / b) ** 2 + (q[..., 2] / t) ** 2) - 1.0)


def _lobe(centre, normal, edge, axes, wedge: float, n: int):
    """Vertices, outward-wound faces, normals, k1, k2 of the lobe: the unit sphere's points ``u``
    mapped to ``centre + frame (a u_x, b u_y, c exp(-wedge u_y) u_z)``, exactly on F = 0
    (:func:`lobe_implicit`); normals and curvatures from F (:func:`implicit_curvature`)."""
    frame = _lobe_frame(normal, edge)
    a, b, c = (float(v) for v in axes)
    u = _fibonacci_sphere(n)
    faces = _hull_faces(u)  # the map's Jacobian is positive: winding kept
    local = np.stack([a * u[:, 0], b * u[:, 1], c * np.exp(-wedge * u[:, 1]) * u[:, 2]], axis=1)
    v = np.asarray(centre, dtype=np.float64) + local @ frame.T
    nrm, k1, k2 = implicit_curvature(lambda x: lobe_implicit(x, centre, frame, axes, wedge), v, FD_STEP_MM)
    return v, faces, nrm, k1, k2


def build_liver_in_abdomen(seed: int, *, wall_axis=(-0.5, -0.5, -0.7), wall_radius_mm: float = 400.0,
                           gap_mm: float = 15.0, cap_deg: float = 80.0, wall_spacing_mm: float = 6.0,
                           gallbladder_centre_mm=None, gallbladder_axes_mm=None, gallbladder_spacing_mm: float = 1.5,
                           lobe_centre_mm=None, lobe_normal=None, lobe_edge=None, lobe_axes_mm=None,
                           lobe_wedge: float = 0.6, lobe_vertices: int = 3000, **liver_params: Any) -> trimesh.Trimesh:
    """The liver (:func:`build_liver` with ``seed`` and ``liver_params``) and the wall behind it.

    Parameters
    ----------
    seed : int
        Root seed of the liver.
    wall_axis : (3,) array_like
        Direction from the liver toward the scope, mesh frame (need not be unit).
    wall_radius_mm, gap_mm : float
        Radius of the wall's sphere and least distance between it and the liver, mm.
    cap_deg : float
        Half-angle of the cap about ``-wall_axis`` seen from the sphere's centre, degrees.
    wall_spacing_mm, gallbladder_spacing_mm : float
        Typical vertex spacing of the wall and of the gallbladder, mm.
    gallbladder_centre_mm, gallbladder_axes_mm : (3,) array_like or None
        The gallbladder's ellipsoid, mm in the liver's frame; None: no gallbladder.
    lobe_centre_mm, lobe_normal, lobe_edge, lobe_axes_mm : (3,) array_like or None
        The lobe (:func:`lobe_implicit`): centre (mm), upper-surface normal, direction of its thin
        margin, semi-axes (along the margin, toward it, half-thickness), mm. None: no lobe.
    lobe_wedge : float
        The lobe's thickness falls by ``exp(-2 lobe_wedge)`` from its back to its margin.
    lobe_vertices : int
        Vertices of the lobe.

    Returns
    -------
    trimesh.Trimesh
        Liver faces first, then the lobe's and the gallbladder's (if any), then the wall's; unit
        ``vertex_normals``, ``vertex_attributes["k1"]``, ``["k2"]`` (1/mm); ``metadata["generator"]``
        with ``wall_centre_mm`` and ``wall_radius_mm``.

    Raises
    ------
    MeshError
        Bad liver parameters, or a wall that would cut the liver.
    """
    liver = build_liver(seed, **liver_params)
    if (gallbladder_centre_mm is None) != (gallbladder_axes_mm is None):
        raise MeshError("build_liver_in_abdomen: gallbladder_centre_mm and gallbladder_axes_mm go together")
    organ = None if gallbladder_centre_mm is None else _gallbladder(gallbladder_centre_mm, gallbladder_axes_mm,
                                                                     gallbladder_spacing_mm)
    lobe = None if lobe_centre_mm is None else _lobe(lobe_centre_mm, lobe_normal, lobe_edge, lobe_axes_mm,
                                                     float(lobe_wedge), int(lobe_vertices))
    inner = np.vstack([liver.vertices] + [pt[0] for pt in (lobe, organ) if pt is not None])
    centre, R = wall_sphere(inner, wall_axis, wall_radius_mm, gap_mm)
    u = np.asarray(wall_axis, dtype=np.float64)
    u /= np.linalg.norm(u)
    cap = math.radians(cap_deg)
    area = 4.0 * math.pi * R * R
    n = max(200, int(area / (0.5 * math.sqrt(3) * wall_spacing_mm**2) / 2))  # ~ spacing on the sphere
    d = _fibonacci_sphere(n)
    faces = ConvexHull(d).simplices.astype(np.int64)
    inside = (d @ -u) >= math.cos(cap)
    used, faces = np.unique(faces[inside[faces].all(axis=1)], return_inverse=True)  # the cap's vertices only
    d = d[used]
    faces = _wound(faces.reshape(-1, 3), d, inward=True)  # toward the centre, as the vertex normals
    wall_v = centre + R * d
    k = np.full(len(d), -1.0 / R)
    parts = [(liver.vertices, np.asarray(liver.faces), liver.vertex_normals, liver.vertex_attributes["k1"],
              liver.vertex_attributes["k2"])]
    parts += [pt for pt in (lobe, organ) if pt is not None]
    parts.append((wall_v, faces, -d, k, k))
    offsets = np.cumsum([0] + [len(pt[0]) for pt in parts])
    mesh = _assemble(np.vstack([pt[0] for pt in parts]),
                     np.vstack([pt[1] + off for pt, off in zip(parts, offsets)]),
                     *(np.concatenate([pt[i] for pt in parts]) for i in (2, 3, 4)))
    gen = dict(liver.metadata["generator"])
    gen.update({"name": "liver_in_abdomen", "function": "simtest.scene.meshes.abdomen.build_liver_in_abdomen",
                "liver_faces": int(len(liver.faces)), "wall_axis": [float(x) for x in u],
                "wall_centre_mm": [float(x) for x in centre], "wall_radius_mm": R, "gap_mm": float(gap_mm),
                "cap_deg": float(cap_deg), "wall_spacing_mm": float(wall_spacing_mm),
                "liver_vertices": int(len(liver.vertices)),
                "curvature": gen.get("curvature", "") + "; wall: exact, -1 / wall_radius_mm"})
    if lobe is not None:
        gen.update({"lobe_centre_mm": [float(x) for x in lobe_centre_mm], "lobe_normal": [float(x) for x in lobe_normal],
                    "lobe_edge": [float(x) for x in lobe_edge], "lobe_axes_mm": [float(x) for x in lobe_axes_mm],
                    "lobe_wedge": float(lobe_wedge), "lobe_vertices": int(len(lobe[0])),
                    "curvature": gen["curvature"] + "; lobe: closed-form F, the same finite differences"})
    if organ is not None:
        gen.update({"gallbladder_centre_mm": [float(x) for x in gallbladder_centre_mm],
                    "gallbladder_axes_mm": [float(x) for x in gallbladder_axes_mm],
                    "gallbladder_spacing_mm": float(gallbladder_spacing_mm),
                    "gallbladder_vertices": int(len(organ[0])), "gallbladder_faces": int(len(organ[1])),
                    "curvature": gen["curvature"] + "; gallbladder: exact, the ellipsoid's closed forms"})
    mesh.metadata["generator"] = gen
    return mesh
