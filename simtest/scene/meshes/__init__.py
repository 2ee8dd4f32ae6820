"""Procedural meshes with ground-truth normals and principal curvatures: a colon and a liver.

The package, one module a job: :mod:`~simtest.scene.meshes.curvature` (principal curvatures of
closed-form surfaces by finite differences and exact derivatives),
:mod:`~simtest.scene.meshes.params` (the generators' parameters, their checks and seeds),
:mod:`~simtest.scene.meshes.colon` and :mod:`~simtest.scene.meshes.liver` (the generators),
:mod:`~simtest.scene.meshes.files` (PLY and JSON sidecar files). Everything public is importable
from ``simtest.scene.meshes``.

Two seeded generators build the anatomical surfaces the renderer places in its scenes:
- :func:`build_colon`: a tube of radius about 25 mm along a smooth, gently three-dimensional centre
  line, with haustral folds (ridges that narrow the lumen) of adjustable depth, spacing and
  sharpness, and three taeniae. Normals face the lumen. Open at both ends.
- :func:`build_haustral_colon`: the colon as CT colonography measures it, with thin semilunar
  folds pinched at three taeniae, haustra bulging between them, a varying diameter and a centre
  line with a rotation-minimising frame; curvatures exact by automatic differentiation
  (:mod:`~simtest.scene.meshes.haustral`, its sources in :class:`HaustralParams`).
- :func:`build_liver`: a smooth, lobed, closed (watertight) surface about 180 mm across: an
  ellipsoid deformed radially by the exponential of a seeded polynomial of the direction (a
  spherical-harmonic-like expansion up to degree 4) with a deterministic wedge (a thick and a
  thin lobe). Normals face outward.

Every vertex carries its position (mm), unit normal and principal curvatures ``k1 >= k2`` (1/mm),
stored as ``mesh.vertex_normals`` and ``mesh.vertex_attributes["k1"]``, ``["k2"]`` (float64
arrays rounded to float32 precision, as the files store them).

Sign convention
---------------
Principal curvatures are the eigenvalues of the Weingarten map ``dN`` (the derivative of the unit
normal N along the surface), so **a curvature is positive where the surface bends away from its
normal** (convex as seen from the side N points to) and negative where it bends toward its normal
(concave). Examples: a sphere of radius R with outward normals has ``k1 = k2 = +1/R``; a cylinder
of radius R seen from inside (normals toward the axis, as in the colon) has ``k1 = 0``,
``k2 = -1/R``. Because the renderer's normals face the camera, positive means convex toward the
camera (a fold crest, the liver) and negative concave toward the camera (the colon wall between
folds). For a parametrised surface X(u, v) this is ``II_ij = -X_ij . N``; for an implicit surface
F = 0 with ``N = grad F / |grad F|`` it is ``P Hess(F) P / |grad F|`` restricted to the tangent
plane (P the tangent projector). Trimesh's discrete curvature measures (the tests' independent
check) agree: their mean curvature is positive across convex edges of the face winding, and both
generators wind their faces so that face normals agree with the vertex normals.

How the ground truth is computed
--------------------------------
Both surfaces are given in closed form (the colon as a parametrisation X(t, phi), the liver as an
implicit function F(x) = 0 whose zero set contains the vertices exactly). Their first and second
derivatives are taken by fourth-order central finite differences of that closed form in float64
(steps 1e-2 mm, or 1e-2 mm / R in angle), from which the first and second fundamental forms
(colon) or the gradient and Hessian (liver) follow. Truncation error is O(h^4) (below 1e-10 /mm
here) and rounding error about eps |X| / h^2 (below 1e-9 /mm): the values are exact to about
1e-8 /mm, which the tests check by doubling the step and against a torus and an ellipsoid whose
curvatures are known in closed form. The vertices themselves lie exactly on the closed-form
surface; only the triangles between them are a piecewise-flat approximation.

Files
-----
:func:`save_mesh` writes a binary little-endian PLY with float32 properties ``x y z nx ny nz
k1_0 k2_0`` (the ``_0`` suffix is Mitsuba 3's convention for a one-channel vertex attribute:
Mitsuba's PLY loader exposes them as mesh attributes ``vertex_k1`` and ``vertex_k2``, which
``shape.eval_attribute_1`` interpolates at an intersection) and a JSON sidecar ``<name>.json``
with the generator, its parameters, the seed, and for the colon the sampled centre line.
:func:`load_mesh` reads both back. ``simtest meshes build`` writes ``meshes/colon.ply``,
``meshes/liver.ply``, ``meshes/liver_abdomen.ply`` (the liver with the wall behind it,
:mod:`~simtest.scene.meshes.abdomen`) and their sidecars.

Centre line of the colon
------------------------
``mesh.metadata["centerline"]`` holds, for each ring of vertices, ``t`` (the curve parameter: the
z coordinate of the centre point, mm), ``arclength_mm``, ``points`` (N, 3) mm, ``tangents`` (N, 3)
unit, and ``radius_min_mm`` / ``radius_max_mm`` (the smallest and largest wall distance of that
ring from its centre point: a camera placed on the centre line is inside the lumen by at least
``radius_min_mm``). :func:`colon_centerline` evaluates the same curve at any arc length, from the
mesh or from its generator record. Ring i of the mesh holds vertices ``i * n_around`` to
``(i + 1) * n_around - 1``.

Frame: the meshes live in their own *world* frame (mm); a scene places the OpenCV camera in it
(:class:`simtest.scene.spec.CameraSpec`), and the renderer turns normals into the camera frame.

References
----------
.. [1] M. P. do Carmo, Differential Geometry of Curves and Surfaces, 1976, sec. 3-3 (fundamental
       forms, :func:`parametric_curvature`).
.. [2] R. Goldman, "Curvature formulas for implicit curves and surfaces", CAGD 22, 2005
       (:func:`implicit_curvature`).
"""

from __future__ import annotations

from typing import Any

import trimesh

from simtest.scene.meshes.abdomen import LAPAROSCOPE_ABDOMEN, LAPAROSCOPE_WALL_AXIS, build_liver_in_abdomen
from simtest.scene.meshes.colon import build_colon, colon_centerline
from simtest.scene.meshes.curvature import (
    FD_STEP_MM,
    implicit_curvature,
    parametric_curvature,
)
from simtest.scene.meshes.files import load_mesh, save_mesh
from simtest.scene.meshes.haustral import build_haustral_colon, haustral_pose
from simtest.scene.meshes.liver import build_liver
from simtest.scene.meshes.params import (
    DEFAULT_SEED,
    ColonParams,
    HaustralParams,
    LiverParams,
    MeshError,
)

__all__ = [
    "DEFAULT_SEED",
    "FD_STEP_MM",
    "ColonParams",
    "HaustralParams",
    "LiverParams",
    "MeshError",
    "build_colon",
    "build_haustral_colon",
    "build_liver",
    "build_mesh",
    "colon_centerline",
    "haustral_pose",
    "implicit_curvature",
    "load_mesh",
    "parametric_curvature",
    "save_mesh",
]


def build_mesh(name: str, seed: int, **params: Any) -> trimesh.Trimesh:
    """Build ``"colon"``, ``"colon_haustral"``, ``"liver"`` or ``"liver_abdomen"`` (dispatch to
    :func:`build_colon`, :func:`build_haustral_colon`, :func:`build_liver`,
    :func:`~simtest.scene.meshes.abdomen.build_liver_in_abdomen`).

    Parameters
    ----------
    name : {"colon", "colon_haustral", "liver", "liver_abdomen"}
        The generator. ``"liver_abdomen"`` is the liver with the wall behind it of
        meshes/liver_abdomen.ply (the laparoscope scene's): its wall's axis and its organs
        default to :data:`~simtest.scene.meshes.abdomen.LAPAROSCOPE_WALL_AXIS` and
        :data:`~simtest.scene.meshes.abdomen.LAPAROSCOPE_ABDOMEN`.
    seed : int
        Root seed (>= 0; 0 is valid).
    **params
        Fields of :class:`ColonParams`, :class:`HaustralParams` or :class:`LiverParams` (lengths
        in mm); for
        ``"liver_abdomen"`` also the wall's keywords of ``build_liver_in_abdomen``.

    Returns
    -------
    trimesh.Trimesh
        As returned by the generator: vertices in mm, unit ``vertex_normals``,
        ``vertex_attributes["k1"]``, ``["k2"]`` in 1/mm (k1 >= k2, module sign convention).

    Raises
    ------
    MeshError
        Unknown name, unknown or out-of-range parameter, or a bad seed.
    """
    def liver_abdomen(seed: int, **p: Any) -> trimesh.Trimesh:
        return build_liver_in_abdomen(seed, **{"wall_axis": LAPAROSCOPE_WALL_AXIS, **LAPAROSCOPE_ABDOMEN, **p})

    builders = {"colon": build_colon, "colon_haustral": build_haustral_colon, "liver": build_liver,
                "liver_abdomen": liver_abdomen}
    if name not in builders:
        raise MeshError(f"build_mesh: name: unknown mesh {name!r}; known: {sorted(builders)}")
    return builders[name](seed, **params)
