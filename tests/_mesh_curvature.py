"""Principal curvatures at mesh vertices from the triangles alone (trimesh's discrete curvature
measures over a ball): an estimator independent of the generators' closed-form ground truth, which
the mesh tests check against it. Sign convention: :mod:`simtest.scene.meshes`."""

from __future__ import annotations

import itertools
import math
from typing import Any

import numpy as np
import trimesh
from scipy.spatial import cKDTree
from trimesh.curvature import discrete_mean_curvature_measure

from simtest.scene.meshes.curvature import _principal_from_h_k


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

    Notes
    -----
    Both measures are averages over the ball, so the estimate is the ball average of H and K:
    it smooths features narrower than ``radius``. The mean-curvature measure is the normal-cycle
    measure of Cohen-Steiner and Morvan (SoCG 2003, doi:10.1145/777792.777839); the Gaussian
    one is the angle defect.
    """

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
