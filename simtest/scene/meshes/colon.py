"""The colon generator: a tube along a smooth centre line with haustral folds and taeniae (:func:`build_colon`)."""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np
import trimesh

from simtest.scene.meshes.curvature import FD_STEP_MM, parametric_curvature
from simtest.scene.meshes.files import _assemble, _generator_record
from simtest.scene.meshes.params import ColonParams, MeshError, _check_seed, _make_params, _rng


# Gauss-Legendre nodes for the arc length of the centre line (a smooth function of t).
_GL_X, _GL_W = np.polynomial.legendre.leggauss(48)


class _Meander:
    """The colons' centre line ``c(u) = (A (sin(w u + px) - sin px), A bend_3d (sin(0.7 w u + py) - sin py), u)``,
    ``A = p.bend_mm``, ``w = 2 pi / p.bend_wavelength_mm``, seeded phases ``px, py``: it starts at the origin."""

    def __init__(self, p: Any, psi_x: float, psi_y: float) -> None:
        self.p, self.psi_x, self.psi_y = p, psi_x, psi_y
        self.wx = 2.0 * math.pi / p.bend_wavelength_mm
        self.wy = 0.7 * self.wx
        self.ay = p.bend_mm * p.bend_3d

    def curve(self, u: np.ndarray) -> tuple[np.ndarray, ...]:
        """``c, c', c'', c'''`` at parameters u (arrays of shape u.shape + (3,))."""
        u = np.asarray(u, dtype=np.float64)
        a, ay, wx, wy = self.p.bend_mm, self.ay, self.wx, self.wy
        sx, cx = np.sin(wx * u + self.psi_x), np.cos(wx * u + self.psi_x)
        sy, cy = np.sin(wy * u + self.psi_y), np.cos(wy * u + self.psi_y)
        zero = np.zeros_like(u)
        c = np.stack([a * (sx - math.sin(self.psi_x)), ay * (sy - math.sin(self.psi_y)), u], -1)
        c1 = self.velocity(u)
        c2 = np.stack([-a * wx**2 * sx, -ay * wy**2 * sy, zero], -1)
        c3 = np.stack([-a * wx**3 * cx, -ay * wy**3 * cy, zero], -1)
        return c, c1, c2, c3

    def velocity(self, u: np.ndarray) -> np.ndarray:
        """``c'`` alone (the arc length's integrand: cheaper than :meth:`curve`)."""
        dx = self.p.bend_mm * self.wx * np.cos(self.wx * u + self.psi_x)
        dy = self.ay * self.wy * np.cos(self.wy * u + self.psi_y)
        return np.stack([dx, dy, np.ones_like(u)], axis=-1)


class _Colon(_Meander):
    """Closed form of the colon surface X(t, phi) = c(t) + r(t, phi) (cos phi e1 + sin phi e2)."""

    def __init__(self, p: ColonParams, seed: int) -> None:
        rng = _rng(seed, "colon")
        # Draw order is part of the format: do not reorder.
        psi_x, psi_y, self.fold_phase, self.jitter_phase, self.taenia_phase = rng.uniform(0.0, 2.0 * math.pi, size=5)
        super().__init__(p, psi_x, psi_y)

    def arclength(self, t: np.ndarray) -> np.ndarray:
        """Arc length of the centre line from t = 0 (Gauss-Legendre, 48 nodes: exact to ~1e-13)."""
        t = np.asarray(t, dtype=np.float64)
        nodes = 0.5 * t[..., None] * (1.0 + _GL_X)
        speed = np.linalg.norm(self.velocity(nodes), axis=-1)
        return 0.5 * t * np.sum(_GL_W * speed, axis=-1)

    def frame(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Centre point, unit tangent, and normal-plane basis (e1, e2) with e2 = T x e1."""
        c, tan = self.curve(t)[:2]
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
        return (2.0 * math.pi * s / p.fold_spacing_mm + self.fold_phase
                + p.fold_jitter * (lam2 / p.fold_spacing_mm) * np.sin(2.0 * math.pi * s / lam2 + self.jitter_phase))

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


def _tube(pos: np.ndarray, nrm: np.ndarray, k1: np.ndarray, k2: np.ndarray,
          centre: np.ndarray) -> tuple[trimesh.Trimesh, dict[str, list]]:
    """The mesh of a ring grid (arrays of shape (n_along, n_around, ...), ring-major vertex order), its triangles
    wound so face normals follow X_t x X_phi, and each ring's least and greatest distance from its centre point."""
    n_along, n_around = pos.shape[:2]
    i, j = np.meshgrid(np.arange(n_along - 1), np.arange(n_around), indexing="ij")
    a = i * n_around + j
    b = (i + 1) * n_around + j
    c = i * n_around + (j + 1) % n_around
    d = (i + 1) * n_around + (j + 1) % n_around
    tris = [np.stack([a, b, c], -1).reshape(-1, 3), np.stack([c, b, d], -1).reshape(-1, 3)]
    faces = np.concatenate(tris).astype(np.int64)
    mesh = _assemble(pos.reshape(-1, 3), faces, nrm.reshape(-1, 3), k1.ravel(), k2.ravel())
    dist = np.linalg.norm(pos - centre[:, None, :], axis=-1)
    return mesh, {"radius_min_mm": dist.min(axis=1).tolist(), "radius_max_mm": dist.max(axis=1).tolist()}


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
        ``n_along * n_around`` vertices (ring-major) in mm, open at both ends, faces and unit
        ``vertex_normals`` facing the lumen, ``vertex_attributes["k1"]``, ``["k2"]`` (1/mm,
        k1 >= k2), ``metadata["generator"]`` and ``metadata["centerline"]`` (:mod:`simtest.scene.meshes`).

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
    pos, nrm, k1, k2 = parametric_curvature(colon.surface, t[:, None], phi[None, :], FD_STEP_MM,
                                            FD_STEP_MM / p.radius_mm)
    centre, tangent, _, _ = colon.frame(t)
    mesh, radii = _tube(pos, nrm, k1, k2, centre)
    mesh.metadata["generator"] = _generator_record("colon", seed, p)
    mesh.metadata["centerline"] = {"t": t.tolist(), "arclength_mm": colon.arclength(t).tolist(),
                                   "points": centre.tolist(), "tangents": tangent.tolist(), **radii}
    return mesh


def colon_centerline(source: trimesh.Trimesh | Mapping[str, Any],
                     arclength_mm: np.ndarray | float | None = None) -> dict[str, np.ndarray]:
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
            raise MeshError(f"colon_centerline: arclength_mm: {s[bad][0]!r} is outside [0, {total:.6g}] mm")
        # Newton on s(t) = target from a linear guess; ds/dt = |c'(t)| >= 1.
        t = s * (p.length_mm / total)
        for _ in range(50):
            step = (colon.arclength(t) - s) / np.linalg.norm(colon.velocity(t), axis=-1)
            t = np.clip(t - step, 0.0, p.length_mm)
            if np.max(np.abs(step)) < 1e-12 * max(1.0, p.length_mm):
                break
    c, tan, _, _ = colon.frame(t)
    return {"arclength_mm": s, "t": t, "points": c, "tangents": tan, "length_mm": total}
