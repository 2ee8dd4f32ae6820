"""Ground truth of the analytic surfaces: the brightest point (BP) of planes, spheres, cylinders and the saddle.

The BP is where the surface normal equals the bisector ``h(p) = unit(unit(-p) + unit(L - p))`` of
the directions to the camera (at the origin) and to the light L (Notes of
:func:`simtest.simulate.analytic.plane_bp`).

- Plane: closed form (the light mirrored in the plane).
- Sphere, cylinder: closed form with a co-located light; otherwise a root solve of the
  stationarity condition from the co-located BP, falling back to the minimiser of the light path
  ``|X| + |L - X|`` over the surface (Fermat: for camera and light outside a convex body the
  minimiser is the unique point with n = h), which reduces to Alhazen's problem on a circle
  (:func:`circle_reflection`).
- Saddle: a grid mesh with analytic normals and curvatures (:func:`saddle_mesh`), whose BPs the
  renderer finds as for any mesh.

Numpy and scipy only: :mod:`simtest.render` imports these truths, never the reverse. Curvature
sign as in :mod:`simtest.scene.meshes`: positive where the surface bends away from its
camera-facing normal (a sphere seen from outside has k1 = k2 = +1/R).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import numpy as np
from scipy import optimize

from simtest.geometry.angles import unit
from simtest.geometry.camera import project_points
from simtest.simulate.analytic import plane_bp

__all__ = ["HighlightTruth", "HighlightTruthError", "STATIONARY_RESIDUAL_TOL", "bisector", "circle_reflection",
           "pixel_in_frame", "plane_highlight", "sphere_highlight", "cylinder_highlight", "saddle_mesh"]


class HighlightTruthError(RuntimeError):
    """The brightest point of an analytic surface could not be found; the message names the surface,
    the light, the solver status and the residual.
    """


@dataclass(frozen=True)
class HighlightTruth:
    """Ground truth of one specular highlight.

    Attributes
    ----------
    bp_px : ndarray of shape (2,)
        BP pixel [u, v] (pixel centres at integers).
    bp_mm : ndarray of shape (3,)
        BP in the camera frame, mm.
    normal : ndarray of shape (3,)
        Unit surface normal at the BP, camera frame, facing the camera.
    k1, k2 : float
        Principal curvatures at the BP, 1/mm, ``k1 >= k2``; positive where the surface bends away
        from its normal (convex toward the camera), as in :mod:`simtest.scene.meshes`.
    in_frame : bool
        The BP pixel lies inside the image (``-0.5 <= u < W - 0.5``, same for v).
    light : int
        Index of the light (in the render's light rig) whose highlight this is.
    """

    bp_px: np.ndarray
    bp_mm: np.ndarray
    normal: np.ndarray
    k1: float
    k2: float
    in_frame: bool
    light: int = 0

    def to_dict(self) -> dict:
        """JSON-ready form, as written to ``highlights.json``.

        Returns
        -------
        dict
            ``bp_px`` [u, v] px, ``bp_mm`` (the specular point) and ``normal`` [x, y, z] (camera
            frame; mm, unit), ``depth_mm`` (z of the point), ``k1``, ``k2`` (1/mm), ``in_frame``
            (bool), ``light`` (index in the light rig); lists of floats.
        """
        return {"light": int(self.light), "depth_mm": float(self.bp_mm[2]), "bp_px": [float(x) for x in self.bp_px],
                "bp_mm": [float(x) for x in self.bp_mm], "normal": [float(x) for x in self.normal],
                "k1": float(self.k1), "k2": float(self.k2), "in_frame": bool(self.in_frame)}


def bisector(p: np.ndarray, light: np.ndarray) -> np.ndarray:
    """Unit bisector ``h(p) = unit(unit(-p) + unit(L - p))`` of the directions to the camera and the light.

    Parameters
    ----------
    p : array_like of shape (..., 3)
        Surface points, camera frame (OpenCV), mm.
    light : array_like of shape (3,) or (..., 3)
        Point-light position, camera frame, mm (broadcast against ``p``).

    Returns
    -------
    ndarray of shape (..., 3), float64
        Unit bisectors; NaN (without a warning) where ``p`` is the camera or the light, or the two
        directions are opposite.
    """
    p = np.asarray(p, dtype=np.float64)
    with np.errstate(invalid="ignore", divide="ignore"):
        return unit(unit(-p, axis=-1) + unit(np.asarray(light, dtype=np.float64) - p, axis=-1), axis=-1)


def pixel_in_frame(uv: np.ndarray, size: tuple[int, int]) -> bool:
    """Whether the pixel ``uv`` = [u, v] lies in a W x H image: ``-0.5 <= u < W - 0.5``, same for v.

    Parameters
    ----------
    uv : ndarray of shape (2,)
        Pixel coordinates (pixel centres at integers); NaN or infinite is outside.
    size : tuple of int
        (W, H) in pixels.

    Returns
    -------
    bool
    """
    w, h = size
    return bool(np.all(np.isfinite(uv)) and -0.5 <= uv[0] < w - 0.5 and -0.5 <= uv[1] < h - 0.5)


def _highlight(p, n, k1, k2, K, size) -> HighlightTruth:
    uv = project_points(p, K)
    return HighlightTruth(np.asarray(uv, float), np.asarray(p, float), unit(n, axis=-1),
                          float(max(k1, k2)), float(min(k1, k2)), pixel_in_frame(uv, size))


def plane_highlight(normal: np.ndarray, distance_mm: float, light: np.ndarray, K: np.ndarray,
                    size: tuple[int, int]) -> HighlightTruth | None:
    """BP of the plane ``{X : normal . X = -distance_mm}`` (``normal`` faces the camera).

    Closed form (:func:`simtest.simulate.analytic.plane_bp`); with a co-located light, the foot of
    the perpendicular from the camera centre.

    Parameters
    ----------
    normal : array_like of shape (3,)
        Plane normal, camera frame, facing the camera (need not be unit).
    distance_mm : float
        Distance from the camera centre to the plane, mm (> 0).
    light : array_like of shape (3,)
        Point-light position, camera frame, mm.
    K : ndarray of shape (3, 3)
        Intrinsics.
    size : tuple of int
        Image size (W, H) in pixels, for ``in_frame``.

    Returns
    -------
    HighlightTruth or None
        ``k1 = k2 = 0``; None if the light is on or behind the plane.
    """
    n = unit(normal, axis=-1)
    if np.dot(n, np.asarray(light, dtype=np.float64)) + distance_mm <= 0:
        return None
    return _highlight(plane_bp(normal, distance_mm, light), n, 0.0, 0.0, K, size)


#: Largest accepted residual of the stationarity solve (sine of the angle between normal and
#: bisector): converged solves measure <= 8e-11, failed ones 1e-2 to 0.9.
STATIONARY_RESIDUAL_TOL = 1e-9


def _solve_stationary(surface: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]],
                      x0: np.ndarray, light: np.ndarray, what: str = "surface") -> np.ndarray:
    """Parameters x where the tangential part of the bisector vanishes on ``surface(x) -> (p, n)``.

    Accepted on the residual (the sine of the angle between n and h at x), not ``sol.success`` (hybrd
    often stops at round-off with status 3 or 5), and only if ``h . n > 0``; else :class:`HighlightTruthError`.
    """
    _, n0 = surface(x0)
    f1 = np.array([0.0, 0.0, 1.0] if abs(n0[0]) > 0.9 else [1.0, 0.0, 0.0])
    e1 = unit(f1 - np.dot(f1, n0) * n0, axis=-1)
    e2 = np.cross(n0, e1)

    def residual(x):
        p, n = surface(x)
        h = bisector(p, light)
        t = h - np.dot(h, n) * n
        return np.array([np.dot(t, e1), np.dot(t, e2)])

    sol = optimize.root(residual, x0, method="hybr", options={"xtol": 1e-14})
    x = sol.x
    if np.all(np.isfinite(x)):  # judged at x (x0's basis can miss a tangent part along n0: the normal turned)
        res, cos = _facing(*surface(x), light)
    else:
        cos, res = math.nan, math.inf
    if not (res <= STATIONARY_RESIDUAL_TOL and cos > 0.0):
        raise HighlightTruthError(f"{what}: no brightest point found for the light at "
                                  f"{np.round(np.asarray(light, dtype=np.float64), 4).tolist()} mm: the normal does "
                                  f"not bisect the directions to the camera and the light (residual {res:.3g} > "
                                  f"{STATIONARY_RESIDUAL_TOL:g} or n . h = {cos:.4g} <= 0; scipy root status "
                                  f"{sol.status}: {' '.join(str(sol.message).split())})")
    return x


#: Grid of start angles of :func:`circle_reflection`: the path length is unimodal on the arc facing
#: both points, so its minimiser lies within one step of the grid's best point.
_CIRCLE_GRID = 256


def circle_reflection(a: np.ndarray, b: np.ndarray, radius: float) -> np.ndarray | None:
    """Alhazen's problem: the point of a circle (centre at the origin) where a ray from ``a`` reflects to ``b``.

    It minimises the path length ``|P - a| + |P - b|`` over the circle: a grid of
    :data:`_CIRCLE_GRID` angles, then :func:`scipy.optimize.brentq` on the derivative between the best
    grid point's neighbours.

    Parameters
    ----------
    a, b : array_like of shape (2,)
        The two points (camera and light), outside the circle, same unit as ``radius``.
    radius : float
        Circle radius, > 0.

    Returns
    -------
    ndarray of shape (2,) or None
        Unit direction ``w`` of the point ``radius * w``; None when the segment from ``a`` to ``b``
        meets the closed disk.

    Raises
    ------
    ValueError
        If ``a`` or ``b`` is not outside the circle, or the bracket fails.
    """
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    R = float(radius)
    if not (np.hypot(*a) > R and np.hypot(*b) > R):
        raise ValueError(f"circle_reflection: points {a.tolist()}, {b.tolist()} must lie outside the "
                         f"circle of radius {R:g}")
    ab = b - a
    L2 = float(ab @ ab)
    t = 0.0 if L2 == 0.0 else min(1.0, max(0.0, float(-(a @ ab) / L2)))
    if np.hypot(*(a + t * ab)) <= R:
        return None
    phi = math.atan2(a[1], a[0])

    def path(x):
        th = phi + x
        P = R * np.stack([np.cos(th), np.sin(th)], axis=-1)
        return np.linalg.norm(P - a, axis=-1) + np.linalg.norm(P - b, axis=-1)

    def slope(x):  # d/dx of path(x): the tangent times the sum of the unit vectors from a and b
        th = phi + x
        w = np.array([math.cos(th), math.sin(th)])
        P = R * w
        da, db = P - a, P - b
        g = da / math.hypot(*da) + db / math.hypot(*db)
        return R * (-w[1] * g[0] + w[0] * g[1])

    grid = np.linspace(-math.pi, math.pi, _CIRCLE_GRID, endpoint=False)
    k = int(np.argmin(path(grid)))
    step = 2.0 * math.pi / _CIRCLE_GRID
    lo, hi = grid[k] - step, grid[k] + step
    glo, ghi = slope(lo), slope(hi)
    if glo == 0.0:
        x = lo
    elif ghi == 0.0:
        x = hi
    elif glo < 0.0 < ghi:
        # xtol far below 1e-15: the root sits ~d/R from 0 for a camera d from the circle.
        try:
            x = optimize.brentq(slope, lo, hi, xtol=1e-22, rtol=4.0 * np.finfo(float).eps, maxiter=400)
        except RuntimeError as exc:  # not converged within maxiter: not seen
            raise ValueError(f"circle_reflection: {exc}") from None
    else:
        raise ValueError(f"circle_reflection: no bracket around the grid's best angle "
                         f"(slopes {glo:.3g}, {ghi:.3g})")
    return np.array([math.cos(phi + x), math.sin(phi + x)])


def _facing(p: np.ndarray, n: np.ndarray, light: np.ndarray) -> tuple[float, float]:
    """(residual, cos) of a candidate BP: the sine of the angle between n and h, and ``n . h``."""
    h = bisector(p, light)
    return float(np.linalg.norm(h - np.dot(h, n) * n)), float(np.dot(h, n))


def _bp(what: str, minimiser, surface, light: np.ndarray):
    """``(p, n)`` from the root solve at the co-located BP; None if nothing faces both.

    After a failed root solve, the path-length ``minimiser()`` polished by a root solve started
    there: the candidate with the smaller residual is kept and checked, else
    :class:`HighlightTruthError` naming the first failure.
    """
    try:
        return surface(_solve_stationary(surface, np.zeros(2), light, what=what))
    except HighlightTruthError as exc:
        first = exc
    try:
        x = minimiser()
    except ValueError as exc:
        raise HighlightTruthError(f"{first}; the path-length minimiser failed too: {exc}") from None
    if x is None:
        return None
    cands = [surface(x)]
    try:
        cands.append(surface(_solve_stationary(surface, np.asarray(x, dtype=np.float64), light, what)))
    except HighlightTruthError:
        pass
    scored = sorted(((*_facing(p, n, light), k) for k, (p, n) in enumerate(cands)))
    res, cos, k = scored[0]
    if not (res <= STATIONARY_RESIDUAL_TOL and cos > 0.0):
        raise HighlightTruthError(f"{first}; the path-length minimiser gives residual {res:.3g}, n . h = {cos:.4g}")
    return cands[k]


def sphere_highlight(center: np.ndarray, radius: float, light: np.ndarray, K: np.ndarray,
                     size: tuple[int, int]) -> HighlightTruth | None:
    """BP of a sphere seen from outside (normals outward, k1 = k2 = +1/R).

    Co-located light (``light`` all zeros): the point nearest the camera centre. Otherwise the root
    solve, or the path minimiser in the plane of the centre, the camera and the light (module notes).

    Parameters
    ----------
    center : array_like of shape (3,)
        Sphere centre, camera frame, mm.
    radius : float
        Radius R, mm.
    light, K, size
        As in :func:`plane_highlight`.

    Returns
    -------
    HighlightTruth or None
        None when the light is inside the sphere and the camera outside, or the segment from the
        camera to the light crosses the sphere.

    Raises
    ------
    HighlightTruthError
        If the camera is inside the sphere or on it, or neither solve reaches the BP.
    """
    c = np.asarray(center, dtype=np.float64)
    L = np.asarray(light, dtype=np.float64)
    if np.linalg.norm(L - c) <= radius < np.linalg.norm(c):
        return None  # light inside, camera outside: the side the camera sees is unlit
    what = f"sphere (centre {np.round(c, 4).tolist()} mm, R {radius:g} mm)"
    if not np.linalg.norm(c) > radius:
        raise HighlightTruthError(f"{what}: the camera is inside the sphere (centre at "
                                  f"{np.linalg.norm(c):.4g} mm <= R): it sees only the inside, which "
                                  "the one-sided surface leaves unlit; no brightest point")
    n0 = -unit(c, axis=-1)
    k = 1.0 / radius
    if not np.any(L):  # exactly co-located (allclose would take a 1e-8 mm offset for none)
        return _highlight(c + radius * n0, n0, k, k, K, size)
    e1 = unit(np.cross(n0, [0.0, 1.0, 0.0] if abs(n0[1]) < 0.9 else [1.0, 0.0, 0.0]), axis=-1)
    e2 = np.cross(n0, e1)

    def surface(x):
        n = unit(n0 + x[0] * e1 + x[1] * e2, axis=-1)
        return c + radius * n, n

    def minimiser():  # parameters of surface(): the tangent-plane coordinates of the normal
        dc = float(np.linalg.norm(c))
        wp = L - np.dot(L, n0) * n0  # (L - c) across n0, from L alone (c lies along n0): no cancellation
        if np.linalg.norm(wp) <= 1e-15 * np.linalg.norm(L - c):  # light on the line of camera and centre
            return np.zeros(2) if dc + np.dot(L, n0) > radius else None
        f2 = unit(wp, axis=-1)
        om = circle_reflection([dc, 0.0], [dc + np.dot(L, n0), np.dot(L, f2)], radius)
        if om is None:
            return None
        if not om[0] > 0.0:  # beyond the tangent parametrisation (the far hemisphere)
            raise ValueError(f"the minimiser lies {math.degrees(math.acos(om[0])):.1f} deg from the "
                             "point nearest the camera")
        n = om[0] * n0 + om[1] * f2
        return np.array([np.dot(n, e1), np.dot(n, e2)]) / om[0]

    got = _bp(what, minimiser, surface, L)
    return None if got is None else _highlight(*got, k, k, K, size)


def cylinder_highlight(center: np.ndarray, axis: np.ndarray, radius: float, length: float,
                       light: np.ndarray, K: np.ndarray, size: tuple[int, int]) -> HighlightTruth | None:
    """BP of a finite cylinder seen from outside (k1 = +1/R, k2 = 0); None if off its length.

    Co-located light: the point of the generator line nearest the camera. Otherwise the root solve
    over (position along the axis, angle), or the path minimiser: Alhazen's problem on the
    cross-section, the axial position dividing the camera's and light's in the ratio of their distances.

    Parameters
    ----------
    center : array_like of shape (3,)
        Middle of the axis, camera frame, mm.
    axis : array_like of shape (3,)
        Axis direction, camera frame (need not be unit).
    radius : float
        Radius R, mm.
    length : float
        Length along the axis, mm, centred on ``center``.
    light, K, size
        As in :func:`plane_highlight`.

    Returns
    -------
    HighlightTruth or None
        None when the BP lies beyond the length, the light lies within the radius of the axis and the
        camera outside, or the segment from the camera to the light crosses the cylinder.

    Raises
    ------
    HighlightTruthError
        If the camera is inside the (infinite) cylinder or on it (the dataset sampler redraws such
        poses), or neither solve reaches the BP.
    """
    c = np.asarray(center, dtype=np.float64)
    a = unit(axis, axis=-1)
    L = np.asarray(light, dtype=np.float64)

    def within_radius(x):
        xc = x - c
        return bool(np.linalg.norm(xc - np.dot(xc, a) * a) <= radius)

    if within_radius(L) and not within_radius(np.zeros(3)):
        # every point of the outside has the light behind its tangent plane
        return None
    what = f"cylinder (axis through {np.round(c, 4).tolist()} mm, R {radius:g} mm)"
    q = c - np.dot(c, a) * a  # foot of the perpendicular from the camera centre to the axis
    if not np.linalg.norm(q) > radius * (1.0 + 8.0 * np.finfo(float).eps):  # on it, to rounding, too
        raise HighlightTruthError(f"{what}: the camera is inside the cylinder ({np.linalg.norm(q):.4g} mm from its "
                                  "axis <= R): it sees only the inside of the tube, which the one-sided surface "
                                  "leaves unlit; no brightest point")
    n0 = unit(-q, axis=-1)
    s0 = np.dot(q - c, a)
    if np.any(L):
        e = np.cross(a, n0)

        def surface(x):
            n = math.cos(x[1]) * n0 + math.sin(x[1]) * e
            return c + (s0 + x[0]) * a + radius * n, n

        def minimiser():
            uc = np.array([np.linalg.norm(q), 0.0])  # the camera in the cross-section (n0, e)
            w = L - c
            ul = np.array([np.dot(w, n0), np.dot(w, e)])
            om = circle_reflection(uc, ul, radius)
            if om is None:
                return None
            d1, d2 = np.hypot(*(radius * om - uc)), np.hypot(*(radius * om - ul))
            tc, tl = -np.dot(c, a), np.dot(w, a)
            return np.array([tc + (tl - tc) * d1 / (d1 + d2) - s0, math.atan2(om[1], om[0])])

        got = _bp(what, minimiser, surface, L)
        if got is None:
            return None
        p, n = got
        s = float(np.dot(p - c, a))
    else:
        p, n, s = q + radius * n0, n0, s0
    return None if abs(s) > 0.5 * length else _highlight(p, n, 1.0 / radius, 0.0, K, size)


def saddle_mesh(distance_mm: float, radius1_mm: float, radius2_mm: float, extent_mm: float,
                resolution: int) -> dict[str, np.ndarray]:
    """Grid mesh of ``z = d + x^2 / (2 r1) - y^2 / (2 r2)`` in the camera frame, |x|, |y| <= e.

    Returns
    -------
    dict
        ``vertices`` (V, 3), ``faces`` (F, 3), ``normals`` (V, 3) facing the camera (-z side),
        ``k1``, ``k2`` (V,) analytic principal curvatures (1/mm, positive where the surface bends
        away from its normal, as in :mod:`simtest.scene.meshes`; at the apex k1 = 1/r1,
        k2 = -1/r2).
    """
    s = np.linspace(-extent_mm, extent_mm, resolution)
    x, y = np.meshgrid(s, s, indexing="xy")
    fx, fy = x / radius1_mm, -y / radius2_mm
    fxx, fyy = 1.0 / radius1_mm, -1.0 / radius2_mm
    z = distance_mm + 0.5 * x * x / radius1_mm - 0.5 * y * y / radius2_mm
    w = np.sqrt(1.0 + fx * fx + fy * fy)
    n = np.stack([fx, fy, -np.ones_like(x)], axis=-1) / w[..., None]
    # Fundamental forms of a graph; second form II_ij = -X_ij . N with N the camera-facing normal.
    E, F, G = 1.0 + fx * fx, fx * fy, 1.0 + fy * fy
    L, M, N = fxx / w, np.zeros_like(x), fyy / w
    det = E * G - F * F
    Kg = (L * N - M * M) / det
    Hm = (E * N - 2.0 * F * M + G * L) / (2.0 * det)
    disc = np.sqrt(np.maximum(Hm * Hm - Kg, 0.0))
    idx = np.arange(resolution * resolution).reshape(resolution, resolution)
    a, b, c, d = idx[:-1, :-1], idx[:-1, 1:], idx[1:, :-1], idx[1:, 1:]
    faces = np.concatenate([np.stack([a, b, d], -1).reshape(-1, 3), np.stack([a, d, c], -1).reshape(-1, 3)])
    return {"vertices": np.stack([x, y, z], -1).reshape(-1, 3), "faces": faces.astype(np.int64),
            "normals": n.reshape(-1, 3), "k1": (Hm + disc).ravel(), "k2": (Hm - disc).ravel()}
