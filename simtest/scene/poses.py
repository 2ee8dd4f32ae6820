"""Camera poses in and around the bundled meshes, shared by the harness and the dataset.

- :func:`colon_pose`: inside the colon, on its centre line.
- :func:`liver_orbit_pose`: outside the liver, on a sphere about it, aimed at its centre (harness).
- :func:`liver_surface_pose`: at a set distance from one liver surface point, tilted off its
  normal (dataset).

Each returns a :class:`CameraPose` in the mesh's world frame (mm); the arithmetic is each caller's
original, operation for operation, so committed results and dataset fingerprints do not move.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np
import trimesh

from simtest.geometry.angles import unit
from simtest.geometry.conics import plane_basis
from simtest.resources import bundled_mesh_path
from simtest.scene.meshes import colon_centerline, haustral_pose, load_mesh

__all__ = ["CameraPose", "MeshPlacement", "camera_up", "colon_pose", "liver_orbit_pose",
           "liver_surface_pose", "mesh_placement"]

#: The basis axes of :func:`simtest.geometry.conics.plane_basis` every placement here starts its
#: "up" and its sideways directions from: z, or x when the direction is within 26 deg of z.
_AXES = (2, 0)


@dataclass(frozen=True)
class CameraPose:
    """A camera placed in the world frame of a mesh.

    Attributes
    ----------
    path : str
        The mesh file (``meshes/<name>.ply``).
    position : ndarray of shape (3,)
        Camera centre, mm.
    look_at : ndarray of shape (3,)
        A point on the optical axis in front of the camera, mm.
    up : ndarray of shape (3,)
        Unit vector that appears up in the image (before Mitsuba's look-at orthogonalises it).
    """

    path: str
    position: np.ndarray
    look_at: np.ndarray
    up: np.ndarray

    def camera_keys(self) -> dict[str, list[float]]:
        """The scene's camera keys: ``position_mm``, ``look_at_mm`` and ``up`` as lists of floats."""
        return {"position_mm": [float(x) for x in self.position], "look_at_mm": [float(x) for x in self.look_at],
                "up": [float(x) for x in self.up]}


@dataclass(frozen=True)
class MeshPlacement:
    """What a placement needs from a bundled mesh (:func:`mesh_placement`).

    Attributes
    ----------
    path : str
        The mesh file.
    mesh : trimesh.Trimesh
        The mesh, with its sidecar metadata (the colon's centre line).
    centre : ndarray of shape (3,)
        Centre of its axis-aligned bounding box, mm.
    bounding_radius : float
        Largest vertex distance from ``centre``, mm.
    arc, radius_min : ndarray of shape (R,) or None
        Colon only: arc length and smallest wall distance of each centre-line ring, mm.
    """

    path: str
    mesh: trimesh.Trimesh
    centre: np.ndarray
    bounding_radius: float
    arc: np.ndarray | None = None
    radius_min: np.ndarray | None = None


@functools.lru_cache(maxsize=4)
def mesh_placement(name: str) -> MeshPlacement:
    """Load the bundled mesh ``name`` and what the placements need of it (cached per process).

    Parameters
    ----------
    name : {"colon", "colon_haustral", "liver"}
        The bundled mesh (``meshes/<name>.ply``).

    Returns
    -------
    MeshPlacement

    Raises
    ------
    FileNotFoundError
        If the mesh file is missing (``simtest meshes build`` writes it).
    ValueError
        If the colon mesh carries no centre line in its metadata.
    """
    path = bundled_mesh_path(name)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: bundled {name} mesh missing (build it with `simtest meshes build`)")
    mesh = load_mesh(path)
    centre = np.asarray(mesh.bounds, dtype=np.float64).mean(axis=0)
    radius = float(np.max(np.linalg.norm(np.asarray(mesh.vertices) - centre, axis=1)))
    arc = radius_min = None
    if name in ("colon", "colon_haustral"):
        line = mesh.metadata.get("centerline")
        if not isinstance(line, dict) or ("arclength_mm" if name == "colon" else "points") not in line:
            raise ValueError(f"{path}: metadata: no colon centre line ('centerline')")
        radius_min = np.asarray(line["radius_min_mm"], dtype=np.float64)
        # haustral: the polyline through the ring stations c(v_i), <= 0.4 mm apart (chord = arc to 1e-6 mm)
        arc = (np.asarray(line["arclength_mm"], dtype=np.float64) if name == "colon" else np.concatenate(
            [[0.0], np.cumsum(np.linalg.norm(np.diff(np.asarray(line["points"]), axis=0), axis=1))]))
    return MeshPlacement(str(path), mesh, centre, radius, arc, radius_min)


def camera_up(forward: np.ndarray, roll_deg: float | None = None) -> np.ndarray:
    """The image's up direction for a camera looking along ``forward``.

    Parameters
    ----------
    forward : ndarray of shape (3,)
        Viewing direction (unit length, or nearly).
    roll_deg : float or None
        None: the first vector of ``plane_basis(forward)`` (z x forward, or x x forward near z),
        as the harness places its cameras. A number: ``forward`` is first normalised, and the up
        is that basis turned by ``roll_deg`` about it, as the dataset draws it; 0 gives the same
        direction as None up to the last bits, which is why both are kept.

    Returns
    -------
    ndarray of shape (3,)
        Unit vector perpendicular to ``forward``.
    """
    if roll_deg is None:
        return plane_basis(forward, axes=_AXES)[0]
    e1, e2 = plane_basis(unit(forward), axes=_AXES)
    r = math.radians(roll_deg)
    return math.cos(r) * e1 + math.sin(r) * e2


def colon_pose(station: float, view_deg: float, *, azimuth_deg: float | None = None, radial_offset: float = 0.3,
               roll_deg: float | None = None, mesh: str = "colon") -> CameraPose:
    """Camera inside the bundled colon, on its centre line, looking off the tangent.

    At arc length ``s = s0 + station (s1 - s0)``, with tangent ``t`` and basis ``(e1, e2)`` across it,
    the camera looks along ``cos(view) t + sin(view) r``, ``r = cos(azimuth) e1 + sin(azimuth) e2``, from
    the centre-line point moved by ``-radial_offset x r_min(s) x r`` (``r_min``: the ring's smallest wall
    distance).

    Parameters
    ----------
    station : float
        Fraction of the centre line's arc length, in [0, 1].
    view_deg : float
        Angle of the viewing direction off the tangent, degrees.
    azimuth_deg : float or None
        Direction of the tilt about the tangent, degrees from ``e1``; None: ``r = e1`` exactly.
    radial_offset : float
        Offset from the centre line, fraction of the ring's smallest wall distance.
    roll_deg : float or None
        Roll of the image about the viewing direction (:func:`camera_up`).
    mesh : {"colon", "colon_haustral"}
        The smooth tube, or the haustral colon (:func:`_haustral_pose`).

    Returns
    -------
    CameraPose
        ``look_at`` is one millimetre ahead of the camera.

    Raises
    ------
    FileNotFoundError, ValueError
        As :func:`mesh_placement`; ValueError also for another ``mesh``.
    """
    if mesh == "colon_haustral":
        return _haustral_pose(station, view_deg, azimuth_deg, radial_offset, roll_deg)
    if mesh != "colon":
        raise ValueError(f"colon_pose: mesh: {mesh!r} is not 'colon' or 'colon_haustral'")
    info = mesh_placement("colon")
    arc = info.arc
    s = float(arc[0] + station * (arc[-1] - arc[0]))
    line = colon_centerline(info.mesh, np.array([s]))
    centre = np.asarray(line["points"][0], dtype=np.float64)
    tangent = unit(line["tangents"][0])
    e1, e2 = plane_basis(tangent, axes=_AXES)
    if azimuth_deg is None:
        radial = e1
    else:
        az = math.radians(azimuth_deg)
        radial = math.cos(az) * e1 + math.sin(az) * e2
    view = math.radians(view_deg)
    forward = math.cos(view) * tangent + math.sin(view) * radial
    r_min = float(np.interp(s, arc, info.radius_min))
    position = centre - radial_offset * r_min * radial
    return CameraPose(info.path, position, position + forward, camera_up(forward, roll_deg))


def _haustral_pose(station: float, view_deg: float, azimuth_deg: float | None, radial_offset: float,
                   roll_deg: float | None) -> CameraPose:
    """:func:`colon_pose` in the haustral colon (:func:`~simtest.scene.meshes.haustral_pose`).

    The offset's unit is the smallest wall distance of the rings within half a fold spacing.
    """
    info = mesh_placement("colon_haustral")
    gen = info.mesh.metadata["generator"]
    arc, line = info.arc, info.mesh.metadata["centerline"]
    s = float(arc[0] + station * (arc[-1] - arc[0]))
    v = float(np.interp(s, arc, np.asarray(line["v"], dtype=np.float64)))
    near = np.abs(arc - s) <= 0.5 * float(gen["params"]["fold_spacing_mm"])
    r_min = float(info.radius_min[near].min()) if near.any() else float(np.interp(s, arc, info.radius_min))
    r0 = 0.5 * float(gen["params"]["diameter_mm"])
    pose = haustral_pose(info.mesh, v, view_deg, 0.0 if azimuth_deg is None else azimuth_deg,
                         radial_offset * r_min / r0, look_mm=1.0)
    position, look_at = np.asarray(pose["position_mm"]), np.asarray(pose["look_at_mm"])
    up = np.asarray(pose["up"]) if roll_deg is None else camera_up(look_at - position, roll_deg)
    return CameraPose(info.path, position, look_at, up)


def liver_orbit_pose(azimuth_deg: float, elevation_deg: float, distance_mm: float) -> CameraPose:
    """Camera outside the bundled liver, on a sphere about it, aimed at its bounding-box centre.

    The camera stands at ``c + (R + distance_mm) d``, with ``c`` the bounding-box centre, ``R`` the
    bounding-sphere radius about it and ``d = (cos el cos az, cos el sin az, sin el)``, and looks
    along ``-d``; up from :func:`camera_up` without roll.

    Parameters
    ----------
    azimuth_deg, elevation_deg : float
        Direction ``d`` of the camera from the centre, degrees.
    distance_mm : float
        Distance outside the bounding sphere, mm.

    Returns
    -------
    CameraPose
        ``look_at`` is one millimetre ahead of the camera.

    Raises
    ------
    FileNotFoundError
        As :func:`mesh_placement`.
    """
    info = mesh_placement("liver")
    az, el = math.radians(azimuth_deg), math.radians(elevation_deg)
    direction = np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)])
    position = info.centre + (info.bounding_radius + distance_mm) * direction
    forward = -direction
    return CameraPose(info.path, position, position + forward, camera_up(forward))


def liver_surface_pose(azimuth_deg: float, elevation_deg: float, distance_mm: float,
                       view_deg: float, roll_deg: float) -> CameraPose:
    """Camera looking at one surface point of the bundled liver from a set distance.

    The point is the vertex whose direction from the bounding-box centre is closest to
    ``d = (cos el cos az, cos el sin az, sin el)``; with ``n`` its outward normal and ``(e1, e2)``
    the basis across it, the camera stands at ``p + distance_mm b`` with
    ``b = cos(view) n + sin(view) (cos(roll) e1 + sin(roll) e2)`` and looks at ``p``.

    Parameters
    ----------
    azimuth_deg, elevation_deg : float
        Direction of the surface point from the centre, degrees.
    distance_mm : float
        Camera to surface point, mm.
    view_deg : float
        Tilt of the line of sight off the normal, degrees.
    roll_deg : float
        Direction of that tilt about the normal, degrees; the image's up is the tilt's side
        direction made perpendicular to the line of sight (the side direction itself at no tilt).

    Returns
    -------
    CameraPose
        ``look_at`` is the surface point.

    Raises
    ------
    FileNotFoundError
        As :func:`mesh_placement`.
    """
    info = mesh_placement("liver")
    mesh = info.mesh
    az, el = math.radians(azimuth_deg), math.radians(elevation_deg)
    direction = np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)])
    v = np.asarray(mesh.vertices, dtype=np.float64) - info.centre
    k = int(np.argmax((v @ direction) / np.linalg.norm(v, axis=1)))
    target = np.asarray(mesh.vertices[k], dtype=np.float64)
    normal = unit(np.asarray(mesh.vertex_normals[k], dtype=np.float64))
    if normal @ v[k] < 0:  # outward
        normal = -normal
    e1, e2 = plane_basis(normal, axes=_AXES)
    roll = math.radians(roll_deg)
    side = math.cos(roll) * e1 + math.sin(roll) * e2
    view = math.radians(view_deg)
    back = math.cos(view) * normal + math.sin(view) * side
    position = target + distance_mm * back
    up = unit(np.cross(back, np.cross(side, back))) if view > 0 else side
    return CameraPose(info.path, position, target, up)
