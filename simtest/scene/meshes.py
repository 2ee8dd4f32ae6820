"""Procedural meshes with ground-truth normals and principal curvatures: a colon and a liver.

Two seeded generators build the anatomical surfaces the renderer places in its scenes:
- :func:`build_colon`: a tube of radius about 25 mm along a smooth, gently three-dimensional centre
  line, with haustral folds (ridges that narrow the lumen) of adjustable depth, spacing and
  sharpness, and three taeniae. Normals face the lumen. Open at both ends.
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
plane (P the tangent projector). The trimesh estimator (:func:`principal_curvatures`) agrees: its
mean curvature is positive across convex edges of the face winding, and both generators wind their
faces so that face normals agree with the vertex normals.

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
``meshes/liver.ply`` and their sidecars.

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
.. [3] D. Cohen-Steiner, J.-M. Morvan, "Restricted Delaunay triangulations and normal cycle",
       SoCG 2003. https://doi.org/10.1145/777792.777839 (the discrete curvature measures
       integrated over a ball that trimesh implements, :func:`principal_curvatures`).
"""

from __future__ import annotations

import dataclasses
import itertools
import json
import math
import os
import re
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np
import trimesh
from scipy.spatial import ConvexHull, cKDTree
from trimesh.curvature import discrete_mean_curvature_measure

from simtest._io import atomic_write_bytes, jsonable

__all__ = [
    "ColonParams",
    "LiverParams",
    "MeshError",
    "build_colon",
    "build_liver",
    "build_mesh",
    "colon_centerline",
    "implicit_curvature",
    "load_mesh",
    "parametric_curvature",
    "principal_curvatures",
    "save_mesh",
]

#: Seed of the committed meshes (``simtest meshes build`` default).
DEFAULT_SEED = 0

#: Stable integer keys mixed with the root seed (np.random.SeedSequence([seed, key])).
_SEED_KEYS = {"colon": 1001, "liver": 1002}

#: Finite-difference step of the closed-form ground truth, mm (angles use this over a radius).
FD_STEP_MM = 1e-2

_FORMAT_VERSION = 1


class MeshError(ValueError):
    """Bad mesh parameters or a bad mesh file; the message names the file or parameter.

    A subclass of ValueError, so callers that catch ValueError also catch it.
    """


# ------------------------------------------------------------------------------------------------
# Differential geometry of closed-form surfaces (finite differences, fourth order)
# ------------------------------------------------------------------------------------------------

# Fourth-order central stencils: offsets (in steps) and weights.
_D1 = ((-2, 1.0 / 12.0), (-1, -8.0 / 12.0), (1, 8.0 / 12.0), (2, -1.0 / 12.0))
_D2 = ((-2, -1.0 / 12.0), (-1, 16.0 / 12.0), (0, -30.0 / 12.0), (1, 16.0 / 12.0), (2, -1.0 / 12.0))


def _principal_from_h_k(h: np.ndarray, k: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """k1, k2 = H +- sqrt(max(H^2 - K, 0)) (k1 >= k2)."""
    disc = np.sqrt(np.maximum(h * h - k, 0.0))
    return h + disc, h - disc


def parametric_curvature(
    surface: Callable[[np.ndarray, np.ndarray], np.ndarray],
    u: np.ndarray,
    v: np.ndarray,
    h_u: float,
    h_v: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Position, unit normal and principal curvatures of a parametrised surface X(u, v).

    Parameters
    ----------
    surface : callable
        ``surface(u, v) -> ndarray of shape (..., 3)``, vectorised, broadcasting ``u`` and ``v``.
    u, v : ndarray
        Parameters (broadcastable to one shape S).
    h_u, h_v : float
        Finite-difference steps in ``u`` and ``v`` (in parameter units).

    Returns
    -------
    position : ndarray of shape S + (3,)
    normal : ndarray of shape S + (3,)
        ``X_u x X_v / |X_u x X_v|`` (the orientation follows the parametrisation).
    k1, k2 : ndarray of shape S
        Principal curvatures (k1 >= k2) in the module's sign convention (positive where the
        surface bends away from ``normal``), in 1 / (unit of X).

    Notes
    -----
    Derivatives by fourth-order central differences of ``surface``; then
    ``E, F, G = X_u.X_u, X_u.X_v, X_v.X_v``; ``L, M, N = -X_uu.n, -X_uv.n, -X_vv.n``;
    ``K = (LN - M^2) / (EG - F^2)``, ``H = (EN - 2FM + GL) / (2 (EG - F^2))`` (do Carmo,
    Differential Geometry of Curves and Surfaces, 1976, sec. 3-3).
    """
    u = np.asarray(u, dtype=np.float64)
    v = np.asarray(v, dtype=np.float64)
    x0 = surface(u, v)
    xu = sum(w * surface(u + i * h_u, v) for i, w in _D1) / h_u
    xv = sum(w * surface(u, v + j * h_v) for j, w in _D1) / h_v
    xuu = sum(w * (x0 if i == 0 else surface(u + i * h_u, v)) for i, w in _D2) / h_u**2
    xvv = sum(w * (x0 if j == 0 else surface(u, v + j * h_v)) for j, w in _D2) / h_v**2
    xuv = sum(wi * wj * surface(u + i * h_u, v + j * h_v) for i, wi in _D1 for j, wj in _D1) / (
        h_u * h_v
    )
    n = np.cross(xu, xv)
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    e = np.einsum("...i,...i", xu, xu)
    f = np.einsum("...i,...i", xu, xv)
    g = np.einsum("...i,...i", xv, xv)
    ll = -np.einsum("...i,...i", xuu, n)
    mm = -np.einsum("...i,...i", xuv, n)
    nn = -np.einsum("...i,...i", xvv, n)
    det = e * g - f * f
    gauss = (ll * nn - mm * mm) / det
    mean = (e * nn - 2.0 * f * mm + g * ll) / (2.0 * det)
    k1, k2 = _principal_from_h_k(mean, gauss)
    return x0, n, k1, k2


def implicit_curvature(
    func: Callable[[np.ndarray], np.ndarray], points: np.ndarray, h: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Unit normal and principal curvatures of the level set of ``func`` through each point.

    Parameters
    ----------
    func : callable
        ``func(x) -> ndarray of shape (...)`` for ``x`` of shape ``(..., 3)``; smooth near the points.
    points : ndarray of shape (N, 3)
        Points on the level set.
    h : float
        Finite-difference step (units of the points).

    Returns
    -------
    normal : ndarray of shape (N, 3)
        ``grad F / |grad F|`` (toward increasing F).
    k1, k2 : ndarray of shape (N,)
        Principal curvatures (k1 >= k2), positive where the surface bends away from ``normal``:
        the eigenvalues of ``P Hess(F) P / |grad F|`` on the tangent plane, P = I - n n^T
        (Goldman, "Curvature formulas for implicit curves and surfaces", CAGD 22, 2005,
        doi:10.1016/j.cagd.2005.06.005).

    Notes
    -----
    Gradient and Hessian by fourth-order central differences of ``func``.
    """
    p = np.asarray(points, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3:
        raise MeshError(f"implicit_curvature: points must have shape (N, 3), got {p.shape}")
    eye = np.eye(3)
    f0 = func(p)
    grad = np.empty_like(p)
    hess = np.empty(p.shape[:1] + (3, 3))
    for a in range(3):
        grad[:, a] = sum(w * func(p + i * h * eye[a]) for i, w in _D1) / h
        hess[:, a, a] = sum(w * (f0 if i == 0 else func(p + i * h * eye[a])) for i, w in _D2) / h**2
        for b in range(a + 1, 3):
            hab = sum(
                wi * wj * func(p + (i * eye[a] + j * eye[b]) * h) for i, wi in _D1 for j, wj in _D1
            ) / (h * h)
            hess[:, a, b] = hess[:, b, a] = hab
    gnorm = np.linalg.norm(grad, axis=1)
    n = grad / gnorm[:, None]
    # Orthonormal tangent basis (t1, t2) at each point.
    ref = np.where(np.abs(n[:, :1]) < 0.9, eye[0], eye[1])
    t1 = np.cross(n, ref)
    t1 /= np.linalg.norm(t1, axis=1, keepdims=True)
    t2 = np.cross(n, t1)
    a11 = np.einsum("ni,nij,nj->n", t1, hess, t1) / gnorm
    a12 = np.einsum("ni,nij,nj->n", t1, hess, t2) / gnorm
    a22 = np.einsum("ni,nij,nj->n", t2, hess, t2) / gnorm
    mean = 0.5 * (a11 + a22)
    disc = np.sqrt((0.5 * (a11 - a22)) ** 2 + a12 * a12)
    return n, mean + disc, mean - disc


# ------------------------------------------------------------------------------------------------
# Parameters
# ------------------------------------------------------------------------------------------------


def _check_params(obj: Any, rules: Mapping[str, tuple[float | None, float | None, bool]]) -> None:
    """Raise MeshError naming the first field outside its range (lo, hi, lo inclusive)."""
    name = type(obj).__name__
    for field in dataclasses.fields(obj):
        value = getattr(obj, field.name)
        want_int = field.type in ("int", int)
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise MeshError(f"{name}: {field.name}: expected a number, got {value!r}")
        if want_int and not float(value).is_integer():
            raise MeshError(f"{name}: {field.name}: expected an integer, got {value!r}")
        if not math.isfinite(value):
            raise MeshError(f"{name}: {field.name}: must be finite, got {value!r}")
        lo, hi, lo_incl = rules.get(field.name, (None, None, True))
        if lo is not None and (value < lo or (value == lo and not lo_incl)):
            op = ">=" if lo_incl else ">"
            raise MeshError(f"{name}: {field.name}: must be {op} {lo}, got {value!r}")
        if hi is not None and value > hi:
            raise MeshError(f"{name}: {field.name}: must be <= {hi}, got {value!r}")


@dataclasses.dataclass(frozen=True)
class ColonParams:
    """Parameters of :func:`build_colon` (lengths in mm).

    Attributes
    ----------
    length_mm : float
        Extent of the centre line along z (its parameter t runs over [0, length_mm]).
    radius_mm : float
        Wall distance from the centre line between folds and away from the taeniae.
    bend_mm : float
        Lateral amplitude of the centre line in x (in y it is ``bend_3d`` times this).
    bend_wavelength_mm : float
        Wavelength of the lateral meander in x (the y meander has 1/0.7 times this).
    bend_3d : float
        Ratio of the y amplitude to the x amplitude (0: a planar centre line).
    fold_depth_mm : float
        How far a fold crest reaches into the lumen (0: no folds).
    fold_spacing_mm : float
        Mean arc-length distance between folds.
    fold_sharpness : float
        von Mises concentration kappa of the fold profile exp(kappa (cos theta - 1)); larger is
        narrower (crest curvature about depth * kappa * (2 pi / spacing)^2).
    fold_jitter : float
        Relative variation of the local fold spacing, in [0, 0.9] (seeded phase).
    taenia_count : int
        Number of taeniae (longitudinal bands) around the wall.
    taenia_relief : float
        Fraction of the fold depth removed on a taenia (folds are crescents between taeniae).
    taenia_indent : float
        Fractional inward pull of the wall on a taenia (a rounded-polygon cross-section).
    n_around : int
        Vertices per ring.
    n_along : int
        Number of rings.
    ring_curvature_weight_mm : float
        Ring placement: rings are equally spaced in w(t) = wall length + this * turning angle of
        the mean wall profile, so folds get denser rings (0: equal wall length).
    """

    length_mm: float = 240.0
    radius_mm: float = 25.0
    bend_mm: float = 18.0
    bend_wavelength_mm: float = 260.0
    bend_3d: float = 0.5
    fold_depth_mm: float = 5.0
    fold_spacing_mm: float = 32.0
    fold_sharpness: float = 1.5
    fold_jitter: float = 0.2
    taenia_count: int = 3
    taenia_relief: float = 0.6
    taenia_indent: float = 0.04
    n_around: int = 96
    n_along: int = 300
    ring_curvature_weight_mm: float = 40.0

    def validate(self) -> None:
        """Check every field against its range.

        Raises
        ------
        MeshError
            Naming the parameter that is out of range and its value.
        """
        _check_params(
            self,
            {
                "length_mm": (0.0, None, False),
                "radius_mm": (0.0, None, False),
                "bend_mm": (0.0, None, True),
                "bend_wavelength_mm": (0.0, None, False),
                "bend_3d": (0.0, None, True),
                "fold_depth_mm": (0.0, None, True),
                "fold_spacing_mm": (0.0, None, False),
                "fold_sharpness": (0.0, None, False),
                "fold_jitter": (0.0, 0.9, True),
                "taenia_count": (1, 12, True),
                "taenia_relief": (0.0, 1.0, True),
                "taenia_indent": (0.0, 0.5, True),
                "n_around": (8, 4096, True),
                "n_along": (4, 100000, True),
                "ring_curvature_weight_mm": (0.0, None, True),
            },
        )
        r_min = self.radius_mm * (1.0 - self.taenia_indent) - self.fold_depth_mm
        limit = self.radius_mm * (0.9 - self.taenia_indent)
        if r_min <= 0.1 * self.radius_mm:
            raise MeshError(
                f"ColonParams: fold_depth_mm: {self.fold_depth_mm!r} closes the lumen "
                f"(smallest wall distance {r_min:.3g} mm with radius_mm={self.radius_mm!r}, "
                f"taenia_indent={self.taenia_indent!r}); keep it below {limit:.3g}"
            )
        # Largest centre-line curvature: |x''| + |y''| bound, parameter t ~ arc length.
        w = 2.0 * math.pi / self.bend_wavelength_mm
        kappa_max = self.bend_mm * w * w * (1.0 + self.bend_3d * 0.49)
        if kappa_max * self.radius_mm >= 0.8:
            raise MeshError(
                f"ColonParams: bend_mm: the centre line bends too sharply for the tube "
                f"(curvature up to {kappa_max:.3g} /mm times radius {self.radius_mm!r} mm >= 0.8 "
                f"would fold the wall); lower bend_mm or raise bend_wavelength_mm"
            )


@dataclasses.dataclass(frozen=True)
class LiverParams:
    """Parameters of :func:`build_liver`.

    Attributes
    ----------
    extent_mm : float
        Largest extent of the mesh's axis-aligned bounding box (the mesh is scaled to it).
    axis_y, axis_z : float
        Semi-axes of the base ellipsoid relative to the x semi-axis (left-right).
    lobe_amplitude : float
        Standard deviation of the degree-1 coefficients of the seeded radial log-deformation
        (degree d gets lobe_amplitude / d).
    lobe_degree : int
        Highest polynomial degree of the seeded deformation (spherical harmonics up to it).
    taper : float
        Deterministic left-right asymmetry: log-radius + taper * w_x (w the unit direction).
    wedge : float
        Deterministic wedge: log-radius - wedge * w_x * w_z^2, so the surface is thick on the
        -x side (a large lobe) and thin on the +x side (a small lobe), as a liver is.
    bulge : float
        Deterministic top-bottom asymmetry: log-radius + bulge * (w_z^2 - w_z^3) / 2, so the -z
        side bulges more than the +z side.
    n_vertices : int
        Number of vertices (a spherical Fibonacci lattice of directions, triangulated by its
        convex hull, i.e. a spherical Delaunay triangulation).
    density_exponent : float
        Vertex placement between uniform in direction (0; the most even normal change per edge
        on the default shapes) and uniform in the normal of the base ellipsoid (1: density
        proportional to its Gaussian curvature).
    """

    extent_mm: float = 180.0
    axis_y: float = 0.72
    axis_z: float = 0.45
    lobe_amplitude: float = 0.2
    lobe_degree: int = 4
    taper: float = 0.25
    wedge: float = 0.8
    bulge: float = 0.3
    n_vertices: int = 16000
    density_exponent: float = 0.0

    def validate(self) -> None:
        """Check every field against its range.

        Raises
        ------
        MeshError
            Naming the parameter that is out of range and its value.
        """
        _check_params(
            self,
            {
                "extent_mm": (0.0, None, False),
                "axis_y": (0.05, 20.0, True),
                "axis_z": (0.05, 20.0, True),
                "lobe_amplitude": (0.0, 0.5, True),
                "lobe_degree": (0, 8, True),
                "taper": (-1.0, 1.0, True),
                "wedge": (-2.0, 2.0, True),
                "bulge": (-1.0, 1.0, True),
                "n_vertices": (12, 2_000_000, True),
                "density_exponent": (0.0, 1.0, True),
            },
        )


def _make_params(cls: type, params: Mapping[str, Any], where: str) -> Any:
    known = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(set(params) - known)
    if unknown:
        raise MeshError(f"{where}: unknown parameter(s) {unknown}; known: {sorted(known)}")
    coerced = {}
    for field in dataclasses.fields(cls):
        if field.name not in params:
            continue
        value = params[field.name]
        is_number = isinstance(value, int | float | np.integer | np.floating)
        if is_number and not isinstance(value, bool):
            if field.type in ("int", int) and float(value).is_integer():
                value = int(value)
            elif field.type in ("float", float):
                value = float(value)
        coerced[field.name] = value
    obj = cls(**coerced)
    obj.validate()
    return obj


def _check_seed(seed: Any, where: str) -> int:
    if isinstance(seed, bool) or not isinstance(seed, int | np.integer) or seed < 0:
        raise MeshError(f"{where}: seed: expected a non-negative integer, got {seed!r}")
    return int(seed)


def _rng(seed: int, name: str) -> np.random.Generator:
    return np.random.default_rng(np.random.SeedSequence([seed, _SEED_KEYS[name]]))


# ------------------------------------------------------------------------------------------------
# Colon
# ------------------------------------------------------------------------------------------------

# Gauss-Legendre nodes for the arc length of the centre line (a smooth function of t).
_GL_X, _GL_W = np.polynomial.legendre.leggauss(48)


class _Colon:
    """Closed form of the colon surface X(t, phi) = c(t) + r(t, phi) (cos phi e1 + sin phi e2)."""

    def __init__(self, p: ColonParams, seed: int) -> None:
        self.p = p
        rng = _rng(seed, "colon")
        # Draw order is part of the format: do not reorder.
        self.psi_x, self.psi_y, self.fold_phase, self.jitter_phase, self.taenia_phase = rng.uniform(
            0.0, 2.0 * math.pi, size=5
        )
        self.wx = 2.0 * math.pi / p.bend_wavelength_mm
        self.wy = 0.7 * self.wx
        self.ay = p.bend_mm * p.bend_3d

    # centre line c(t) = (x(t), y(t), t), starting at the origin
    def _c(self, t: np.ndarray) -> np.ndarray:
        p = self.p
        x = p.bend_mm * (np.sin(self.wx * t + self.psi_x) - math.sin(self.psi_x))
        y = self.ay * (np.sin(self.wy * t + self.psi_y) - math.sin(self.psi_y))
        return np.stack([x, y, t], axis=-1)

    def _dc(self, t: np.ndarray) -> np.ndarray:
        dx = self.p.bend_mm * self.wx * np.cos(self.wx * t + self.psi_x)
        dy = self.ay * self.wy * np.cos(self.wy * t + self.psi_y)
        return np.stack([dx, dy, np.ones_like(t)], axis=-1)

    def arclength(self, t: np.ndarray) -> np.ndarray:
        """Arc length of the centre line from t = 0 (Gauss-Legendre, 48 nodes: exact to ~1e-13)."""
        t = np.asarray(t, dtype=np.float64)
        nodes = 0.5 * t[..., None] * (1.0 + _GL_X)
        speed = np.linalg.norm(self._dc(nodes), axis=-1)
        return 0.5 * t * np.sum(_GL_W * speed, axis=-1)

    def frame(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Centre point, unit tangent, and normal-plane basis (e1, e2) with e2 = T x e1."""
        c = self._c(t)
        tan = self._dc(t)
        tan = tan / np.linalg.norm(tan, axis=-1, keepdims=True)
        ref = np.array([1.0, 0.0, 0.0])
        e1 = ref - tan[..., :1] * tan
        e1 = e1 / np.linalg.norm(e1, axis=-1, keepdims=True)
        e2 = np.cross(tan, e1)
        return c, tan, e1, e2

    def fold_angle(self, s: np.ndarray) -> np.ndarray:
        """Fold phase theta(s): crests where theta = 0 mod 2 pi; d theta/ds > 0 when jitter < 1."""
        p = self.p
        lam2 = 2.7 * p.fold_spacing_mm
        return (
            2.0 * math.pi * s / p.fold_spacing_mm
            + self.fold_phase
            + p.fold_jitter
            * (lam2 / p.fold_spacing_mm)
            * np.sin(2.0 * math.pi * s / lam2 + self.jitter_phase)
        )

    def radius(self, t: np.ndarray, phi: np.ndarray) -> np.ndarray:
        p = self.p
        band = (0.5 * (1.0 + np.cos(p.taenia_count * (phi - self.taenia_phase)))) ** 2
        base = p.radius_mm * (1.0 - p.taenia_indent * band)
        fold = np.exp(p.fold_sharpness * (np.cos(self.fold_angle(self.arclength(t))) - 1.0))
        return base - p.fold_depth_mm * fold * (1.0 - p.taenia_relief * band)

    def surface(self, t: np.ndarray, phi: np.ndarray) -> np.ndarray:
        # t of shape (n, 1) and phi of shape (1, m) keep the centre line work per ring.
        t, phi = np.asarray(t, dtype=np.float64), np.asarray(phi, dtype=np.float64)
        c, _, e1, e2 = self.frame(t)
        r = self.radius(t, phi)[..., None]
        return c + r * (np.cos(phi)[..., None] * e1 + np.sin(phi)[..., None] * e2)

    def ring_parameters(self) -> np.ndarray:
        """Ring positions t_i: equally spaced in wall length + weight * profile turning angle."""
        p = self.p
        t = np.linspace(0.0, p.length_mm, 20 * p.n_along + 1)
        phi = np.linspace(0.0, 2.0 * math.pi, 24, endpoint=False)
        r = self.radius(t[:, None], phi[None, :]).mean(axis=1)
        s = self.arclength(t)
        dr = np.gradient(r, s)
        wall = np.sqrt(1.0 + dr * dr)
        turning = np.abs(np.gradient(np.arctan(dr), s))
        w = wall + p.ring_curvature_weight_mm * turning
        cum = np.concatenate([[0.0], np.cumsum(0.5 * (w[1:] + w[:-1]) * np.diff(t))])
        return np.interp(np.linspace(0.0, cum[-1], p.n_along), cum, t)


def _tube_faces(n_along: int, n_around: int) -> np.ndarray:
    """Triangles of a ring grid (ring-major vertex order), wound so face normals follow X_t x X_phi."""
    i, j = np.meshgrid(np.arange(n_along - 1), np.arange(n_around), indexing="ij")
    a = i * n_around + j
    b = (i + 1) * n_around + j
    c = i * n_around + (j + 1) % n_around
    d = (i + 1) * n_around + (j + 1) % n_around
    return np.concatenate(
        [np.stack([a, b, c], -1).reshape(-1, 3), np.stack([c, b, d], -1).reshape(-1, 3)]
    ).astype(np.int64)


def build_colon(seed: int, **params: Any) -> trimesh.Trimesh:
    """Build a seeded colon: a folded tube along a curved centre line, normals facing the lumen.

    Parameters
    ----------
    seed : int
        Root seed (>= 0). It draws the centre-line meander phases, the fold phase and its jitter,
        and the taenia orientation (generator from SeedSequence([seed, 1001])).
    **params
        Fields of :class:`ColonParams` (lengths in mm).

    Returns
    -------
    trimesh.Trimesh
        ``n_along * n_around`` vertices (ring-major) in mm, open at both ends, faces wound so face
        normals point into the lumen, ``vertex_normals`` unit and facing the lumen,
        ``vertex_attributes["k1"]``, ``["k2"]`` (float64, 1/mm, k1 >= k2, module sign convention:
        the wall between folds has k2 about -1/radius), ``metadata["generator"]`` (name, seed,
        params, method) and ``metadata["centerline"]`` (see the module notes).

    Raises
    ------
    MeshError
        Unknown or out-of-range parameter, or a bad seed; the message names it.
    """
    seed = _check_seed(seed, "build_colon")
    p: ColonParams = _make_params(ColonParams, params, "build_colon")
    colon = _Colon(p, seed)
    t = colon.ring_parameters()
    phi = np.arange(p.n_around) * (2.0 * math.pi / p.n_around)
    pos, nrm, k1, k2 = parametric_curvature(
        colon.surface, t[:, None], phi[None, :], FD_STEP_MM, FD_STEP_MM / p.radius_mm
    )
    faces = _tube_faces(p.n_along, p.n_around)
    mesh = _assemble(pos.reshape(-1, 3), faces, nrm.reshape(-1, 3), k1.ravel(), k2.ravel())

    centre, tangent, _, _ = colon.frame(t)
    dist = np.linalg.norm(pos - centre[:, None, :], axis=-1)
    mesh.metadata["generator"] = _generator_record("colon", seed, p)
    mesh.metadata["centerline"] = {
        "t": t.tolist(),
        "arclength_mm": colon.arclength(t).tolist(),
        "points": centre.tolist(),
        "tangents": tangent.tolist(),
        "radius_min_mm": dist.min(axis=1).tolist(),
        "radius_max_mm": dist.max(axis=1).tolist(),
    }
    return mesh


def colon_centerline(
    source: trimesh.Trimesh | Mapping[str, Any], arclength_mm: np.ndarray | float | None = None
) -> dict[str, np.ndarray]:
    """Centre line of a colon built by :func:`build_colon`, at any arc length.

    Parameters
    ----------
    source : trimesh.Trimesh or dict
        A colon mesh (from :func:`build_colon` or :func:`load_mesh`) or its
        ``metadata["generator"]`` record.
    arclength_mm : array_like of shape (N,), float or None
        Arc lengths from the start of the centre line (mm), within [0, total length]. None: the
        stations of the mesh rings.

    Returns
    -------
    dict
        ``arclength_mm`` (N,), ``t`` (N,) the curve parameter (mm, the z coordinate),
        ``points`` (N, 3) mm, ``tangents`` (N, 3) unit (direction of increasing arc length),
        ``length_mm`` (float, the total arc length).

    Raises
    ------
    MeshError
        The source is not a colon, or an arc length is outside the centre line.
    """
    gen = source.metadata.get("generator") if isinstance(source, trimesh.Trimesh) else source
    if not isinstance(gen, Mapping) or gen.get("name") != "colon":
        raise MeshError("colon_centerline: source has no colon generator record (metadata['generator'])")
    p: ColonParams = _make_params(ColonParams, gen["params"], "colon_centerline")
    colon = _Colon(p, _check_seed(gen["seed"], "colon_centerline"))
    total = float(colon.arclength(np.array(p.length_mm)))
    if arclength_mm is None:
        t = colon.ring_parameters()
        s = colon.arclength(t)
    else:
        s = np.atleast_1d(np.asarray(arclength_mm, dtype=np.float64))
        bad = (s < 0.0) | (s > total) | ~np.isfinite(s)
        if bad.any():
            raise MeshError(
                f"colon_centerline: arclength_mm: {s[bad][0]!r} is outside [0, {total:.6g}] mm"
            )
        # Newton on s(t) = target from a linear guess; ds/dt = |c'(t)| >= 1.
        t = s * (p.length_mm / total)
        for _ in range(50):
            step = (colon.arclength(t) - s) / np.linalg.norm(colon._dc(t), axis=-1)
            t = np.clip(t - step, 0.0, p.length_mm)
            if np.max(np.abs(step)) < 1e-12 * max(1.0, p.length_mm):
                break
    c, tan, _, _ = colon.frame(t)
    return {"arclength_mm": s, "t": t, "points": c, "tangents": tan, "length_mm": total}


# ------------------------------------------------------------------------------------------------
# Liver
# ------------------------------------------------------------------------------------------------


def _monomial_exponents(max_degree: int) -> np.ndarray:
    """Exponents (i, j, k) with 1 <= i + j + k <= max_degree, in a fixed order."""
    out = [
        (i, j, d - i - j)
        for d in range(1, max_degree + 1)
        for i in range(d, -1, -1)
        for j in range(d - i, -1, -1)
    ]
    return np.array(out, dtype=np.int64).reshape(-1, 3)


def _fibonacci_sphere(n: int) -> np.ndarray:
    """n nearly uniform unit vectors (spherical Fibonacci lattice, golden-angle spiral)."""
    i = np.arange(n) + 0.5
    z = 1.0 - 2.0 * i / n
    r = np.sqrt(1.0 - z * z)
    a = math.pi * (3.0 - math.sqrt(5.0)) * np.arange(n)
    return np.stack([r * np.cos(a), r * np.sin(a), z], axis=1)


class _Liver:
    """Star-shaped surface x = A g(w) w (unit direction w), implicit F(x) = |y| - g(y/|y|), y = A^-1 x."""

    def __init__(self, p: LiverParams, seed: int) -> None:
        self.p = p
        self.axes = np.array([1.0, p.axis_y, p.axis_z])
        self.exps = _monomial_exponents(p.lobe_degree)
        rng = _rng(seed, "liver")
        degree = self.exps.sum(axis=1)
        self.coef = rng.standard_normal(len(self.exps)) * (p.lobe_amplitude / np.maximum(degree, 1))

    def log_g(self, w: np.ndarray) -> np.ndarray:
        """Log of the radial factor for unit directions w (..., 3)."""
        p = self.p
        wx, wz = w[..., 0], w[..., 2]
        out = p.taper * wx - p.wedge * wx * wz * wz + 0.5 * p.bulge * (wz * wz - wz**3)
        if len(self.exps):
            # powers[a][k] = w_a ** k by repeated products (integer powers, no pow()).
            powers = [[np.ones_like(w[..., a])] for a in range(3)]
            for a in range(3):
                for _ in range(self.p.lobe_degree):
                    powers[a].append(powers[a][-1] * w[..., a])
            mono = np.stack(
                [powers[0][i] * powers[1][j] * powers[2][k] for i, j, k in self.exps], axis=-1
            )
            out = out + mono @ self.coef
        return out

    def implicit(self, x: np.ndarray) -> np.ndarray:
        y = x / self.axes
        ry = np.linalg.norm(y, axis=-1)
        return ry - np.exp(self.log_g(y / ry[..., None]))

    def point(self, w: np.ndarray) -> np.ndarray:
        return self.axes * (np.exp(self.log_g(w))[..., None] * w)


def build_liver(seed: int, **params: Any) -> trimesh.Trimesh:
    """Build a seeded liver-like closed surface with outward normals.

    Parameters
    ----------
    seed : int
        Root seed (>= 0); draws the lobe coefficients (generator from SeedSequence([seed, 1002])).
    **params
        Fields of :class:`LiverParams`.

    Returns
    -------
    trimesh.Trimesh
        Watertight, centred near the origin (the star centre of the surface is the origin), in mm,
        with its largest bounding-box extent equal to ``extent_mm``; faces wound outward; unit
        outward ``vertex_normals``; ``vertex_attributes["k1"]``, ``["k2"]`` (float64, 1/mm,
        k1 >= k2, positive where convex); ``metadata["generator"]``.

    Raises
    ------
    MeshError
        Unknown or out-of-range parameter, or a bad seed; the message names it.
    """
    seed = _check_seed(seed, "build_liver")
    p: LiverParams = _make_params(LiverParams, params, "build_liver")
    liver = _Liver(p, seed)
    q = _fibonacci_sphere(p.n_vertices)
    # Directions w = normalize(A^gamma q): gamma = 1 gives normals of the base ellipsoid uniform.
    w = q * liver.axes**p.density_exponent
    w /= np.linalg.norm(w, axis=1, keepdims=True)

    faces = ConvexHull(w).simplices.astype(np.int64)
    tri = w[faces]
    outward = np.einsum("ij,ij->i", np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), tri.sum(1))
    faces[outward < 0] = faces[outward < 0][:, ::-1]
    # Canonical face order (independent of qhull's output order).
    first = np.argmin(faces, axis=1)[:, None]
    faces = np.take_along_axis(faces, (first + np.arange(3)) % 3, axis=1)  # keeps the winding
    faces = faces[np.lexsort(faces.T[::-1])]

    unit = liver.point(w)
    scale = p.extent_mm / float(np.max(np.ptp(unit, axis=0)))
    x = unit * scale

    def implicit_mm(q: np.ndarray) -> np.ndarray:
        return scale * liver.implicit(q / scale)  # F in mm, so the FD step is in mm

    nrm, k1, k2 = implicit_curvature(implicit_mm, x, FD_STEP_MM)
    mesh = _assemble(x, faces, nrm, k1, k2)
    mesh.metadata["generator"] = _generator_record("liver", seed, p)
    mesh.metadata["generator"]["scale"] = scale
    return mesh


# ------------------------------------------------------------------------------------------------
# Assembly, files
# ------------------------------------------------------------------------------------------------

_CURVATURE_METHOD = (
    "closed form; derivatives by 4th-order central finite differences, step "
    f"{FD_STEP_MM} mm; k positive where the surface bends away from its normal"
)


def _generator_record(name: str, seed: int, params: Any) -> dict[str, Any]:
    return {
        "name": name,
        "function": f"simtest.scene.meshes.build_{name}",
        "format": _FORMAT_VERSION,
        "seed": seed,
        "params": dataclasses.asdict(params),
        "curvature": _CURVATURE_METHOD,
    }


def _assemble(
    vertices: np.ndarray, faces: np.ndarray, normals: np.ndarray, k1: np.ndarray, k2: np.ndarray
) -> trimesh.Trimesh:
    """A Trimesh whose per-vertex data are float64 arrays holding float32-representable values.

    The files store float32 (what Mitsuba uses); rounding here makes a saved and reloaded mesh
    equal to the built one, bit for bit (the rounding is below 1e-5 mm and 1e-7 relative).
    """

    def f32(a: np.ndarray) -> np.ndarray:
        return np.ascontiguousarray(np.asarray(a, dtype=np.float64).astype(np.float32), np.float64)

    mesh = trimesh.Trimesh(
        vertices=f32(vertices),
        faces=np.ascontiguousarray(faces, dtype=np.int64),
        process=False,
        validate=False,
    )
    n = np.asarray(normals, dtype=np.float64)
    mesh.vertex_normals = f32(n / np.linalg.norm(n, axis=1, keepdims=True))
    mesh.vertex_attributes["k1"] = f32(k1)
    mesh.vertex_attributes["k2"] = f32(k2)
    return mesh


def build_mesh(name: str, seed: int, **params: Any) -> trimesh.Trimesh:
    """Build ``"colon"`` or ``"liver"`` (dispatch to :func:`build_colon` / :func:`build_liver`).

    Parameters
    ----------
    name : {"colon", "liver"}
        The generator.
    seed : int
        Root seed (>= 0; 0 is valid).
    **params
        Fields of :class:`ColonParams` or :class:`LiverParams` (lengths in mm).

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
    builders = {"colon": build_colon, "liver": build_liver}
    if name not in builders:
        raise MeshError(f"build_mesh: name: unknown mesh {name!r}; known: {sorted(builders)}")
    return builders[name](seed, **params)


_PLY_FIELDS = ("x", "y", "z", "nx", "ny", "nz", "k1_0", "k2_0")


def save_mesh(mesh: trimesh.Trimesh, path: str | os.PathLike[str]) -> Path:
    """Write a mesh with normals and curvatures to a binary PLY and its JSON sidecar.

    Parameters
    ----------
    mesh : trimesh.Trimesh
        Must carry ``vertex_attributes["k1"]`` and ``["k2"]``; ``vertex_normals`` are written as
        they are. ``metadata["generator"]`` and ``["centerline"]`` (if present) go to the sidecar.
    path : path-like
        Output ``.ply`` path; the sidecar is the same path with suffix ``.json``.

    Returns
    -------
    Path
        The PLY path. Both files are written to a temporary name, then renamed (os.replace).

    Raises
    ------
    MeshError
        The mesh lacks k1 or k2, or the path does not end in ``.ply``.
    """
    path = Path(path)
    if path.suffix.lower() != ".ply":
        raise MeshError(f"save_mesh: {path}: expected a .ply path")
    for key in ("k1", "k2"):
        if key not in mesh.vertex_attributes:
            raise MeshError(f"save_mesh: {path}: mesh has no vertex attribute {key!r}")
    v = np.asarray(mesh.vertices, dtype=np.float64)
    cols = [
        v,
        np.asarray(mesh.vertex_normals, dtype=np.float64),
        np.asarray(mesh.vertex_attributes["k1"], dtype=np.float64)[:, None],
        np.asarray(mesh.vertex_attributes["k2"], dtype=np.float64)[:, None],
    ]
    data = np.ascontiguousarray(np.concatenate(cols, axis=1), dtype="<f4")
    faces = np.asarray(mesh.faces)
    face_rec = np.empty(len(faces), dtype=[("n", "u1"), ("idx", "<i4", (3,))])
    face_rec["n"] = 3
    face_rec["idx"] = faces
    header = (
        "ply\nformat binary_little_endian 1.0\n"
        "comment simtest procedural mesh; units mm; k1_0 k2_0: principal curvatures 1/mm, "
        "positive where the surface bends away from its normal\n"
        f"element vertex {len(v)}\n"
        + "".join(f"property float {name}\n" for name in _PLY_FIELDS)
        + f"element face {len(faces)}\nproperty list uchar int vertex_indices\nend_header\n"
    )
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(path, header.encode("ascii") + data.tobytes() + face_rec.tobytes())
    side = {
        key: mesh.metadata[key] for key in ("generator", "centerline") if key in mesh.metadata
    }
    side["n_vertices"] = int(len(v))
    side["n_faces"] = int(len(faces))
    side["ply_vertex_properties"] = list(_PLY_FIELDS)
    side["units"] = "positions mm; k1, k2 1/mm (k1 >= k2, positive where bending away from N)"
    text = json.dumps(jsonable(side), indent=1, sort_keys=True)
    # One line per innermost list of numbers (a point, a tangent, a list of arc lengths).
    text = _NUMBER_LIST.sub(lambda m: "[" + ", ".join(x.strip() for x in m[1].split(",")) + "]", text)
    text += "\n"
    atomic_write_bytes(path.with_suffix(".json"), text.encode("utf-8"))
    return path


_NUMBER_LIST = re.compile(r"\[\s*([-+0-9.eE,\s]+?)\s*\]")


def load_mesh(path: str | os.PathLike[str]) -> trimesh.Trimesh:
    """Read a PLY written by :func:`save_mesh` (or any PLY with k1, k2 vertex properties).

    Parameters
    ----------
    path : path-like
        The ``.ply`` file. A sidecar ``.json`` next to it, if present, fills ``metadata``
        (``generator``, ``centerline``).

    Returns
    -------
    trimesh.Trimesh
        Vertices in file order (``process=False``), ``vertex_normals`` from nx ny nz,
        ``vertex_attributes["k1"]``, ``["k2"]`` float64.

    Raises
    ------
    FileNotFoundError
        The file does not exist (the message names the path).
    MeshError
        The file is not a triangle mesh with normals and k1/k2 (``k1_0`` or ``k1``) properties.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"load_mesh: {path}: no such mesh file")
    try:
        loaded = trimesh.load(path, file_type="ply", process=False)
    except Exception as exc:  # trimesh raises assorted types on corrupt files
        raise MeshError(f"load_mesh: {path}: not a readable PLY ({exc})") from exc
    if not isinstance(loaded, trimesh.Trimesh) or len(loaded.faces) == 0:
        raise MeshError(f"load_mesh: {path}: not a triangle mesh")
    raw = loaded.metadata.get("_ply_raw", {}).get("vertex", {}).get("data")
    names = raw.dtype.names if raw is not None and raw.dtype.names else ()
    attrs = {}
    for key in ("k1", "k2"):
        field = next((f for f in (f"{key}_0", key) if f in names), None)
        if field is None:
            raise MeshError(f"load_mesh: {path}: vertex property {key!r} (or {key}_0) missing")
        attrs[key] = np.asarray(raw[field], dtype=np.float64).ravel()
    if not all(f in names for f in ("nx", "ny", "nz")):
        raise MeshError(f"load_mesh: {path}: vertex normals (nx, ny, nz) missing")
    normals = np.stack([np.asarray(raw[f], dtype=np.float64).ravel() for f in ("nx", "ny", "nz")], 1)
    mesh = trimesh.Trimesh(
        vertices=np.asarray(loaded.vertices, dtype=np.float64),
        faces=np.asarray(loaded.faces, dtype=np.int64),
        process=False,
        validate=False,
    )
    mesh.vertex_normals = normals
    mesh.vertex_attributes["k1"] = attrs["k1"]
    mesh.vertex_attributes["k2"] = attrs["k2"]
    side = path.with_suffix(".json")
    if side.is_file():
        try:
            meta = json.loads(side.read_text(encoding="utf-8"))
        except json.JSONDecodeError as exc:
            raise MeshError(f"load_mesh: {side}: invalid JSON ({exc})") from exc
        for key in ("generator", "centerline"):
            if key in meta:
                mesh.metadata[key] = meta[key]
    return mesh


# ------------------------------------------------------------------------------------------------
# Curvature estimated from the triangles (trimesh)
# ------------------------------------------------------------------------------------------------


def _ball_pairs(tree: Any, points: np.ndarray, radius: float) -> tuple[np.ndarray, np.ndarray]:
    """(owner, index) pairs: tree points within ``radius`` of each query point, flattened."""
    hits = tree.query_ball_point(points, radius)
    counts = np.fromiter((len(h) for h in hits), dtype=np.intp, count=len(hits))
    index = np.fromiter(itertools.chain.from_iterable(hits), dtype=np.intp, count=int(counts.sum()))
    return np.repeat(np.arange(len(points)), counts), index


def principal_curvatures(
    mesh: trimesh.Trimesh, radius: float, vertex_indices: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Principal curvatures at mesh vertices estimated from the triangles alone (trimesh).

    Parameters
    ----------
    mesh : trimesh.Trimesh
        Triangle mesh, mm. Signs follow its face winding (positive across edges that are convex
        as seen from the side the face normals point to).
    radius : float
        Radius of the ball (mm) over which the curvature measures are integrated: at least about
        three edge lengths (fewer edges in the ball give errors of tens of percent), and small
        against the radii of curvature (the estimate is a ball average).
    vertex_indices : array_like of int, optional
        Vertices to evaluate (default: all).

    Returns
    -------
    k1, k2 : ndarray of shape (N,)
        ``H +- sqrt(max(H^2 - K, 0))`` (1/mm, k1 >= k2) where H is the mean curvature measure of
        the ball (trimesh.curvature.discrete_mean_curvature_measure, R-tree via ``rtree``) divided by the ball
        area pi r^2, and K the sum of the vertex angle defects in the ball
        (trimesh.curvature.discrete_gaussian_curvature_measure) divided by the area those vertices
        stand for (a third of their incident triangle areas, which removes the jitter of counting
        whole vertices). NaN where the ball holds a boundary vertex (open meshes: the measures
        are not defined there).

    Raises
    ------
    MeshError
        ``radius`` is not a positive finite number.

    Notes
    -----
    Both measures are averages over the ball, so the estimate is the ball average of H and K:
    it smooths features narrower than ``radius``. The mean-curvature measure is the normal-cycle
    measure of Cohen-Steiner and Morvan [3]; the Gaussian one is the angle defect.
    """

    if not (isinstance(radius, int | float) and math.isfinite(radius) and radius > 0):
        raise MeshError(f"principal_curvatures: radius: must be a positive number, got {radius!r}")
    idx = np.arange(len(mesh.vertices)) if vertex_indices is None else np.asarray(vertex_indices)
    pts = np.asarray(mesh.vertices)[idx]

    h = discrete_mean_curvature_measure(mesh, pts, float(radius)) / (math.pi * radius * radius)

    defects = np.asarray(mesh.vertex_defects, dtype=np.float64)
    vert_area = np.zeros(len(mesh.vertices))
    np.add.at(vert_area, np.asarray(mesh.faces).ravel(), np.repeat(mesh.area_faces / 3.0, 3))
    boundary = np.zeros(len(mesh.vertices), dtype=bool)
    edges = np.asarray(mesh.edges_sorted)
    uniq, count = np.unique(edges, axis=0, return_counts=True)
    boundary[uniq[count == 1].ravel()] = True

    owner, near = _ball_pairs(cKDTree(np.asarray(mesh.vertices)), pts, float(radius))
    k_sum = np.bincount(owner, weights=defects[near], minlength=len(pts))
    a_sum = np.bincount(owner, weights=vert_area[near], minlength=len(pts))
    near_boundary = np.bincount(owner, weights=boundary[near], minlength=len(pts)) > 0
    with np.errstate(invalid="ignore", divide="ignore"):
        k = k_sum / a_sum
    k1, k2 = _principal_from_h_k(h, k)
    k1[near_boundary] = np.nan
    k2[near_boundary] = np.nan
    return k1, k2
