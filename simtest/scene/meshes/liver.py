"""The liver generator: a smooth, lobed, watertight surface, the zero set of a closed-form F (:func:`build_liver`)."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import trimesh
from scipy.spatial import ConvexHull

from simtest.scene.meshes.curvature import FD_STEP_MM, implicit_curvature
from simtest.scene.meshes.files import _assemble, _generator_record
from simtest.scene.meshes.params import LiverParams, _check_seed, _make_params, _rng


def _monomial_exponents(max_degree: int) -> np.ndarray:
    """Exponents (i, j, k) with 1 <= i + j + k <= max_degree, in a fixed order."""
    out = [(i, j, d - i - j) for d in range(1, max_degree + 1) for i in range(d, -1, -1) for j in range(d - i, -1, -1)]
    return np.array(out, dtype=np.int64).reshape(-1, 3)


def _fibonacci_sphere(n: int) -> np.ndarray:
    """n nearly uniform unit vectors (spherical Fibonacci lattice, golden-angle spiral)."""
    i = np.arange(n) + 0.5
    z = 1.0 - 2.0 * i / n
    r = np.sqrt(1.0 - z * z)
    a = math.pi * (3.0 - math.sqrt(5.0)) * np.arange(n)
    return np.stack([r * np.cos(a), r * np.sin(a), z], axis=1)


def _wound(faces: np.ndarray, d: np.ndarray, inward: bool = False) -> np.ndarray:
    """``faces`` of points ``d`` about the origin, flipped in place to wind outward (or inward)."""
    tri = d[faces]
    outward = np.einsum("ij,ij->i", np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), tri.sum(1))
    flip = outward > 0 if inward else outward < 0
    faces[flip] = faces[flip][:, ::-1]
    return faces


def _hull_faces(d: np.ndarray) -> np.ndarray:
    """Faces of the convex hull of unit vectors ``d``, wound outward."""
    return _wound(ConvexHull(d).simplices.astype(np.int64), d)


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
            mono = np.stack([powers[0][i] * powers[1][j] * powers[2][k] for i, j, k in self.exps], axis=-1)
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
        Watertight, star centre at the origin, mm, largest bounding-box extent ``extent_mm``; faces
        and unit ``vertex_normals`` outward; ``vertex_attributes["k1"]``, ``["k2"]`` (1/mm, k1 >= k2,
        positive where convex); ``metadata["generator"]``.

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
    faces = _hull_faces(w)
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
