"""Ground truth of the analytic surfaces: the brightest point (BP) of planes, spheres, cylinders, and the saddle.

The BP is where the surface normal bisects the directions to the camera (at the origin) and to the
light L (Phong's lobe peaks where the mirror direction of the light points at the camera; Notes of
:func:`simtest.simulate.analytic.plane_bp`): ``n(p) = h(p) = unit(unit(-p) + unit(L - p))``. With a
co-located light it is where the normal is parallel to the viewing ray.

- Plane: mirror the light in the plane; the BP is where the segment from the camera to the mirror
  image crosses the plane (closed form).
- Sphere, cylinder: closed form with a co-located light; otherwise the stationarity condition (the
  tangential part of h vanishes) solved with :func:`scipy.optimize.root` from the co-located BP
  and checked; where that solve does not land on the BP, the BP is found robustly as the
  minimiser of the light path ``|X| + |L - X|`` over the surface (:func:`circle_reflection`),
  which reduces to a bracketed 1-D root on a circle. :class:`HighlightTruthError` when the camera
  is inside the surface (it then sees only the inside, which the one-sided BSDFs leave unlit) or
  when even that solve fails; None (no highlight) when no point of the surface faces both the
  camera and the light.

Why the path minimiser is the BP (camera and light outside a convex body, Fermat's principle):
the gradient of ``f(X) = |X| + |L - X|`` is ``-2 cos(g/2) h(X)``, so a point of the surface where
the outward normal equals h is stationary, and the ellipsoid ``f <= f(X)`` (foci camera and
light) touches the tangent plane there from the outside; the body lies on the other side, so the
point is the unique minimiser of f over the body. Conversely the minimiser over the body is on its
surface (when the segment from the camera to the light misses the body) and has n = h. On a sphere
it lies in the plane of the centre, the camera and the light; on a cylinder, unfolding along the
axis leaves the circle of the cross-section: both are Alhazen's problem on a circle.
- Saddle: the grid mesh of ``z = d + x^2 / (2 r1) - y^2 / (2 r2)`` with its analytic normals and
  principal curvatures (:func:`saddle_mesh`); the renderer finds its BPs as for any mesh
  (:func:`simtest.render.truth.mesh_highlights`).

Numpy and scipy only: the renderer (:mod:`simtest.render`) imports these truths, never the reverse.

Curvature sign convention (the same as :mod:`simtest.scene.meshes`): the eigenvalues of the
Weingarten map dN of the camera-facing normal, so positive where the surface bends away from its
normal (convex toward the camera). A sphere seen from outside has k1 = k2 = +1/R; a cylinder seen
from outside k1 = +1/R, k2 = 0; a tube seen from inside k1 = 0, k2 = -1/R.
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

__all__ = ["HighlightTruth", "HighlightTruthError", "STATIONARY_RESIDUAL_TOL", "bisector",
           "circle_reflection", "pixel_in_frame", "plane_highlight", "sphere_highlight",
           "cylinder_highlight", "saddle_mesh"]


class HighlightTruthError(RuntimeError):
    """The brightest point of an analytic surface could not be found (the root solve failed).

    Raised rather than returning a point that does not satisfy the bisector condition: the message
    names the surface, the light, the solver status and the residual.
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
        return {
            "light": int(self.light),
            "depth_mm": float(self.bp_mm[2]),
            "bp_px": [float(x) for x in self.bp_px],
            "bp_mm": [float(x) for x in self.bp_mm],
            "normal": [float(x) for x in self.normal],
            "k1": float(self.k1),
            "k2": float(self.k2),
            "in_frame": bool(self.in_frame),
        }


def bisector(p: np.ndarray, light: np.ndarray) -> np.ndarray:
    """Unit bisector of the directions from surface points to the camera and to the light.

    ``h(p) = unit(unit(-p) + unit(L - p))``, the camera at the origin; a surface point is a BP when
    its normal equals ``h`` (Notes of :func:`simtest.simulate.analytic.plane_bp`; with a co-located
    light ``h = unit(-p)``).

    Parameters
    ----------
    p : array_like of shape (..., 3)
        Surface points, camera frame (OpenCV), mm; not at the camera centre nor at the light.
    light : array_like of shape (3,) or (..., 3)
        Point-light position, camera frame, mm (broadcast against ``p``).

    Returns
    -------
    ndarray of shape (..., 3), float64
        Unit bisectors, camera frame. NaN where ``p`` is the camera centre or the light, or where
        the two directions are opposite (without numpy's warning: a root search that steps onto
        the segment from the camera to a light behind the body reads the NaN and steps back).
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

    The BP is where the segment from the camera centre to the mirror image ``L'`` of the light
    crosses the plane (closed form; there the normal bisects the directions to the camera and the
    light): :func:`simtest.simulate.analytic.plane_bp`. With a co-located light
    it is the foot of the perpendicular from the camera centre.

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
        ``k1 = k2 = 0``; None if the light is on or behind the plane (no highlight).
    """
    n = unit(normal, axis=-1)
    if np.dot(n, np.asarray(light, dtype=np.float64)) + distance_mm <= 0:
        return None
    return _highlight(plane_bp(normal, distance_mm, light), n, 0.0, 0.0, K, size)


#: Largest accepted residual of the stationarity solve (the sine of the angle between the normal and
#: the bisector). Converged solves measure <= 1.2e-14 (6000 random spheres and cylinders, lights up to
#: 20 mm off), 8e-11 with the camera 0.2 mm from a 179 mm sphere; failed ones 1e-2 to 0.9. 1e-9 rad
#: (6e-8 deg) is far below any angle a test or a user resolves.
STATIONARY_RESIDUAL_TOL = 1e-9


def _solve_stationary(surface: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]],
                      x0: np.ndarray, light: np.ndarray, what: str = "surface") -> np.ndarray:
    """Parameters x where the tangential part of the bisector vanishes on ``surface(x) -> (p, n)``.

    The solve is accepted on its residual, not on ``sol.success``: with ``xtol = 1e-14`` MINPACK's
    hybrd often stops at round-off with status 3 ("xtol too small") or 5 ("not making good
    progress") although the residual is ~1e-16. The solution must also face the camera and the
    light (``h . n > 0``, not the anti-bisector).

    Raises
    ------
    HighlightTruthError
        If the residual exceeds :data:`STATIONARY_RESIDUAL_TOL` or the point faces away, e.g. when
        the camera or the light is inside a cylinder.
    """

    f1 = np.array([1.0, 0.0, 0.0])
    _, n0 = surface(x0)
    if abs(n0[0]) > 0.9:
        f1 = np.array([0.0, 0.0, 1.0])
    e1 = unit(f1 - np.dot(f1, n0) * n0, axis=-1)
    e2 = np.cross(n0, e1)

    def residual(x):
        p, n = surface(x)
        h = bisector(p, light)
        t = h - np.dot(h, n) * n
        return np.array([np.dot(t, e1), np.dot(t, e2)])

    sol = optimize.root(residual, x0, method="hybr", options={"xtol": 1e-14})
    x = sol.x
    if np.all(np.isfinite(x)):
        p, n = surface(x)
        cos = float(np.dot(bisector(p, light), n))
        res = float(np.max(np.abs(residual(x))))
    else:
        cos, res = math.nan, math.inf
    if not (res <= STATIONARY_RESIDUAL_TOL and cos > 0.0):
        raise HighlightTruthError(
            f"{what}: no brightest point found for the light at "
            f"{np.round(np.asarray(light, dtype=np.float64), 4).tolist()} mm: the normal does not "
            f"bisect the directions to the camera and the light (residual {res:.3g} > "
            f"{STATIONARY_RESIDUAL_TOL:g} or n . h = {cos:.4g} <= 0; scipy root status "
            f"{sol.status}: {' '.join(str(sol.message).split())})")
    return x


#: Grid of start angles of :func:`circle_reflection`: the minimiser of the path length lies within
#: one grid step of the grid's best point (the path length is unimodal on the arc facing both
#: points, and the grid holds the direction of the first point itself, where a camera very near
#: the circle puts the minimiser); 256 steps of 1.4 deg cost ~20 us.
_CIRCLE_GRID = 256


def circle_reflection(a: np.ndarray, b: np.ndarray, radius: float) -> np.ndarray | None:
    """Alhazen's problem: the point of a circle where a ray from ``a`` reflects to ``b``.

    The circle has its centre at the origin; the point returned minimises the path length
    ``|P - a| + |P - b|`` over the circle, i.e. the point of the closed disk nearest to both in
    that sense, where the outward normal bisects the directions to ``a`` and ``b`` (see the
    module notes). Found by a grid of :data:`_CIRCLE_GRID` angles around the circle (from the
    direction of ``a``) and :func:`scipy.optimize.brentq` on the derivative of the path length
    between the best grid point's neighbours, so it never leaves the right basin.

    Parameters
    ----------
    a, b : array_like of shape (2,)
        The two points (camera and light), outside the circle, in the circle's plane (any
        length unit, the same as ``radius``).
    radius : float
        Circle radius, > 0.

    Returns
    -------
    ndarray of shape (2,) or None
        Unit direction ``w`` of the point ``radius * w`` from the centre; None when the segment
        from ``a`` to ``b`` meets the closed disk (no point of the circle faces both).

    Raises
    ------
    ValueError
        If ``a`` or ``b`` is inside the circle or on it, or the bracket fails (not seen: it
        would mean a non-unimodal path length near its minimum).
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
        # xtol far below 1e-15: the root sits ~d/R from 0 for a camera d from a circle of radius
        # R, and needs float64's relative precision there too.
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
    """The BP: the root solve from the co-located BP (parameters 0), else :func:`_robust_bp`.

    Returns
    -------
    tuple of ndarray or None
        ``(p, n)``, or None when no point faces both the camera and the light.
    """
    try:
        return surface(_solve_stationary(surface, np.zeros(2), light, what=what))
    except HighlightTruthError as first:
        return _robust_bp(what, minimiser, surface, light, first)


def _robust_bp(what: str, solve, surface, light: np.ndarray, first: HighlightTruthError):
    """The BP from the path-length minimiser after a failed root solve from the co-located BP.

    ``solve() -> x or None`` gives the minimiser's parameters in ``surface``'s parametrisation
    (None: no point faces both). The point is polished by the root solve started there (a camera
    a fraction of a millimetre from a large sphere amplifies the angle's round-off ~R/d times in
    the residual); the candidate with the smaller residual is kept and checked like the root solve.

    Returns
    -------
    tuple of ndarray or None
        ``(p, n)``, or None when no point faces both the camera and the light.

    Raises
    ------
    HighlightTruthError
        Naming ``first`` (the failed root solve) and why the minimiser failed too.
    """
    try:
        x = solve()
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
        raise HighlightTruthError(f"{first}; the path-length minimiser gives residual {res:.3g}, "
                                  f"n . h = {cos:.4g}")
    return cands[k]


def sphere_highlight(center: np.ndarray, radius: float, light: np.ndarray, K: np.ndarray,
                     size: tuple[int, int]) -> HighlightTruth | None:
    """BP of a sphere seen from outside (normals outward, k1 = k2 = +1/R).

    Co-located light (``light`` all zeros): the point of the sphere nearest the camera centre,
    closed form. Otherwise the point where the outward normal bisects the directions to the camera
    and the light (:func:`bisector`): solved with :func:`scipy.optimize.root` (hybr) in a tangent
    parametrisation around the nearest point and checked (see :data:`STATIONARY_RESIDUAL_TOL`);
    where that solve does not land on the BP, it is the minimiser of the light path in the plane of
    the centre, the camera and the light (:func:`circle_reflection`; module notes), checked the
    same way. Both give the same point where both succeed (the facing stationary point is unique).

    Parameters
    ----------
    center : array_like of shape (3,)
        Sphere centre, camera frame, mm; the camera is outside the sphere.
    radius : float
        Radius R, mm.
    light : array_like of shape (3,)
        Point-light position, camera frame, mm.
    K : ndarray of shape (3, 3)
        Intrinsics.
    size : tuple of int
        Image size (W, H) in pixels, for ``in_frame``.

    Returns
    -------
    HighlightTruth or None
        None when the light is inside the sphere (or on it) and the camera outside (the side the
        camera sees is then unlit), or when the segment from the camera to the light crosses the
        sphere (no point faces both).

    Raises
    ------
    HighlightTruthError
        If the camera is inside the sphere or on it (it sees only the inside, unlit by the
        one-sided BSDFs), or if neither solve reaches a point whose normal bisects the two
        directions (not seen over the property tests' draws).
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
        w = L - c
        wp = w - np.dot(w, n0) * n0
        if np.linalg.norm(wp) <= 1e-15 * np.linalg.norm(w):  # light on the line of camera and centre
            return np.zeros(2) if np.dot(w, n0) > radius else None
        f2 = unit(wp, axis=-1)
        om = circle_reflection([np.linalg.norm(c), 0.0], [np.dot(w, n0), np.dot(w, f2)], radius)
        if om is None:
            return None
        if not om[0] > 0.0:  # beyond the tangent parametrisation (the far hemisphere)
            raise ValueError(f"the minimiser lies {math.degrees(math.acos(om[0])):.1f} deg from the "
                             "point nearest the camera")
        n = om[0] * n0 + om[1] * f2
        return np.array([np.dot(n, e1), np.dot(n, e2)]) / om[0]

    got = _bp(what, minimiser, surface, L)
    if got is None:
        return None
    p, n = got
    return _highlight(p, n, k, k, K, size)


def cylinder_highlight(center: np.ndarray, axis: np.ndarray, radius: float, length: float,
                       light: np.ndarray, K: np.ndarray, size: tuple[int, int]) -> HighlightTruth | None:
    """BP of a finite cylinder seen from outside (k1 = +1/R, k2 = 0); None if off its length.

    Co-located light: the point of the generator line nearest the camera centre, closed form.
    Otherwise the point where the outward normal bisects the directions to the camera and the light
    (:func:`bisector`): solved with :func:`scipy.optimize.root` over (position along the axis,
    angle around it) from the co-located BP and checked (see :data:`STATIONARY_RESIDUAL_TOL`);
    where that solve does not land on the BP, it is the minimiser of the light path: unfolded along
    the axis, the angle solves Alhazen's problem on the cross-section's circle
    (:func:`circle_reflection`) and the position along the axis divides the camera's and the
    light's axial positions in the ratio of their distances to the point's generator line; checked
    the same way.

    Parameters
    ----------
    center : array_like of shape (3,)
        A point of the axis (the middle of the cylinder's length), camera frame, mm.
    axis : array_like of shape (3,)
        Axis direction, camera frame (need not be unit).
    radius : float
        Radius R, mm; the camera is outside the cylinder.
    length : float
        Length along the axis, mm, centred on ``center``.
    light : array_like of shape (3,)
        Point-light position, camera frame, mm.
    K : ndarray of shape (3, 3)
        Intrinsics.
    size : tuple of int
        Image size (W, H) in pixels, for ``in_frame``.

    Returns
    -------
    HighlightTruth or None
        None when the BP of the infinite cylinder lies beyond the finite length, when the light
        lies within the radius of the axis (inside the tube, or beyond its end) and the camera
        outside (no point of the outside is lit), or
        when the segment from the camera to the light crosses the cylinder (no point faces both).

    Raises
    ------
    HighlightTruthError
        If the camera is inside the (infinite) cylinder or on it: it sees only the inside of the
        tube, which the one-sided BSDFs leave unlit, so there is no brightest point (the dataset
        sampler redraws such poses: :func:`simtest.dataset.sample.draw_parameters`); or if
        neither solve reaches a point whose normal bisects the two directions (not seen over the
        property tests' draws).
    """
    c = np.asarray(center, dtype=np.float64)
    a = unit(axis, axis=-1)
    L = np.asarray(light, dtype=np.float64)

    def within_radius(x):
        xc = x - c
        return bool(np.linalg.norm(xc - np.dot(xc, a) * a) <= radius)

    if within_radius(L) and not within_radius(np.zeros(3)):
        # the light within the tube's radius of its axis, the camera outside: every point of the
        # outside has the light behind its tangent plane (n . (L - p) <= |L - c|_radial - R <= 0),
        # wherever the light lies along the axis, beyond the tube's end too (that case reached the
        # cross-section's reflection, which needs both points outside the circle, and failed)
        return None
    what = f"cylinder (axis through {np.round(c, 4).tolist()} mm, R {radius:g} mm)"
    q = c - np.dot(c, a) * a  # foot of the perpendicular from the camera centre to the axis
    if not np.linalg.norm(q) > radius:
        raise HighlightTruthError(
            f"{what}: the camera is inside the cylinder ({np.linalg.norm(q):.4g} mm from its axis "
            f"<= R): it sees only the inside of the tube, which the one-sided surface leaves unlit; "
            "no brightest point")
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
    faces = np.concatenate([np.stack([a, b, d], -1).reshape(-1, 3),
                            np.stack([a, d, c], -1).reshape(-1, 3)])
    return {
        "vertices": np.stack([x, y, z], -1).reshape(-1, 3),
        "faces": faces.astype(np.int64),
        "normals": n.reshape(-1, 3),
        "k1": (Hm + disc).ravel(),
        "k2": (Hm - disc).ravel(),
    }
