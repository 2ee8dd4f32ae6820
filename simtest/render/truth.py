"""Ground truth per highlight: the brightest point (BP) of each specularity, numpy only.

The BP is where the surface normal bisects the directions to the camera (at the origin) and to the
light L (Phong's lobe peaks where the mirror direction of the light points at the camera; Notes of
:func:`simtest.simulate.analytic.plane_bp`): ``n(p) = h(p) = unit(unit(-p) + unit(L - p))``. With a
co-located light it is where the normal is parallel to the viewing ray.

- Plane: mirror the light in the plane; the BP is where the segment from the camera to the mirror
  image crosses the plane (closed form).
- Sphere, cylinder: closed form with a co-located light; otherwise the stationarity condition (the
  tangential part of h vanishes) solved with :func:`scipy.optimize.root` on the analytic surface,
  and checked: :class:`HighlightTruthError` when the solve does not reach a BP.
- Meshes: candidate pixels where the rendered ground-truth normals nearly bisect, refined by ray
  casting through sub-pixel grids (the normal is the barycentric interpolation of the vertex
  normals, as Mitsuba shades it); k1 and k2 are the barycentric interpolation of the vertex values.

Curvature sign convention (the same as :mod:`simtest.scene.meshes`): the eigenvalues of the
Weingarten map dN of the camera-facing normal, so positive where the surface bends away from its
normal (convex toward the camera). A sphere seen from outside has k1 = k2 = +1/R; a cylinder seen
from outside k1 = +1/R, k2 = 0; a tube seen from inside k1 = 0, k2 = -1/R.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import cv2
import numpy as np
from scipy import ndimage, optimize
from skimage.feature import peak_local_max

from simtest.geometry.angles import unit
from simtest.geometry.camera import project_points
from simtest.reconstruct.detect import ellipticity
from simtest.simulate.analytic import plane_bp

__all__ = [
    "HighlightTruth",
    "HighlightTruthError",
    "STATIONARY_RESIDUAL_TOL",
    "bisector",
    "bisector_cos_image",
    "plane_highlight",
    "sphere_highlight",
    "cylinder_highlight",
    "mesh_highlights",
    "highlight_complete",
    "HighlightTarget",
    "highlight_targets",
]


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
        the two directions are opposite.
    """
    p = np.asarray(p, dtype=np.float64)
    return unit(unit(-p, axis=-1) + unit(np.asarray(light, dtype=np.float64) - p, axis=-1), axis=-1)


def bisector_cos_image(normals: np.ndarray, position: np.ndarray, mask: np.ndarray,
                       light: np.ndarray) -> np.ndarray:
    """Cosine between each pixel's normal and its bisector, ``n . h(p)``, in float32.

    The BP condition (the normal equals the bisector, :func:`bisector`) holds where this is 1; :func:`mesh_highlights` starts its
    searches at its local maxima. Float32 like the render's AOVs; the co-located branch skips the
    light arithmetic and gives the general formula's bits (tested).

    Parameters
    ----------
    normals : ndarray of shape (H, W, 3)
        Unit normals, camera frame, facing the camera (values outside ``mask`` are ignored).
    position : ndarray of shape (H, W, 3)
        Surface points, camera frame, mm (values outside ``mask`` are ignored).
    mask : ndarray of shape (H, W), bool
        Pixels with a surface.
    light : array_like of shape (3,)
        Point-light position, camera frame, mm; all zeros for a light at the camera centre.

    Returns
    -------
    ndarray of shape (H, W)
        ``n . h`` in [-1, 1] (float32 round-off aside) inside ``mask``; -1 outside.
    """
    p = np.where(mask[..., None], position, 1.0).astype(np.float32)
    to_cam = -p / np.sqrt(np.einsum("ijk,ijk->ij", p, p))[..., None]
    if not np.any(np.asarray(light, dtype=np.float32)):
        # Co-located: to_light equals to_cam bit for bit, and (to_cam + to_light) / |...| equals
        # to_cam / |to_cam| bit for bit (scaling by 2 is exact in floating point).
        h = to_cam / np.sqrt(np.einsum("ijk,ijk->ij", to_cam, to_cam))[..., None]
    else:
        to_light = np.asarray(light, dtype=np.float32) - p
        to_light /= np.sqrt(np.einsum("ijk,ijk->ij", to_light, to_light))[..., None]
        h = to_cam + to_light
        h /= np.sqrt(np.einsum("ijk,ijk->ij", h, h))[..., None]
    n = np.where(mask[..., None], normals, 0.0).astype(np.float32)
    return np.where(mask, np.einsum("ijk,ijk->ij", n, h), -1.0)


def _in_frame(uv: np.ndarray, size: tuple[int, int]) -> bool:
    w, h = size
    return bool(np.all(np.isfinite(uv)) and -0.5 <= uv[0] < w - 0.5 and -0.5 <= uv[1] < h - 0.5)


def _highlight(p, n, k1, k2, K, size) -> HighlightTruth:
    uv = project_points(p, K)
    return HighlightTruth(np.asarray(uv, float), np.asarray(p, float), unit(n, axis=-1),
                          float(max(k1, k2)), float(min(k1, k2)), _in_frame(uv, size))


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


#: Largest accepted residual of the stationarity solve (tangential part of the unit bisector, i.e.
#: the sine of the angle between the normal and the bisector). Converged solves measure <= 1.2e-14
#: (6000 random spheres and cylinders, offset lights up to 20 mm); failed ones 1e-2 to 0.9. 1e-12
#: rad (6e-11 deg) is 100x above round-off and far below any angle a test or a user resolves.
STATIONARY_RESIDUAL_TOL = 1e-12


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


def sphere_highlight(center: np.ndarray, radius: float, light: np.ndarray, K: np.ndarray,
                     size: tuple[int, int]) -> HighlightTruth | None:
    """BP of a sphere seen from outside (normals outward, k1 = k2 = +1/R).

    Co-located light (``light`` all zeros): the point of the sphere nearest the camera centre,
    closed form. Otherwise the point where the outward normal bisects the directions to the camera
    and the light (:func:`bisector`), solved with :func:`scipy.optimize.root` (hybr) in a tangent
    parametrisation around the nearest point and checked (see :data:`STATIONARY_RESIDUAL_TOL`).

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
        None when the light is inside the sphere (or on it) and the camera outside: the side the
        camera sees is then unlit.

    Raises
    ------
    HighlightTruthError
        If the root solve does not converge to a point whose normal bisects the two directions.
    """
    c = np.asarray(center, dtype=np.float64)
    L = np.asarray(light, dtype=np.float64)
    if np.linalg.norm(L - c) <= radius < np.linalg.norm(c):
        return None  # light inside, camera outside: the side the camera sees is unlit
    n0 = -unit(c, axis=-1)
    k = 1.0 / radius
    if np.allclose(L, 0.0):
        return _highlight(c + radius * n0, n0, k, k, K, size)
    e1 = unit(np.cross(n0, [0.0, 1.0, 0.0] if abs(n0[1]) < 0.9 else [1.0, 0.0, 0.0]), axis=-1)
    e2 = np.cross(n0, e1)

    def surface(x):
        n = unit(n0 + x[0] * e1 + x[1] * e2, axis=-1)
        return c + radius * n, n

    x = _solve_stationary(surface, np.zeros(2), L,
                          what=f"sphere (centre {np.round(c, 4).tolist()} mm, R {radius:g} mm)")
    p, n = surface(x)
    return _highlight(p, n, k, k, K, size)


def cylinder_highlight(center: np.ndarray, axis: np.ndarray, radius: float, length: float,
                       light: np.ndarray, K: np.ndarray, size: tuple[int, int]) -> HighlightTruth | None:
    """BP of a finite cylinder seen from outside (k1 = +1/R, k2 = 0); None if off its length.

    Co-located light: the point of the generator line nearest the camera centre, closed form.
    Otherwise the point where the outward normal bisects the directions to the camera and the light
    (:func:`bisector`), solved with :func:`scipy.optimize.root` over (position along the axis,
    angle around it) and checked (see :data:`STATIONARY_RESIDUAL_TOL`).

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
        None when the BP of the infinite cylinder lies beyond the finite length, or when the light
        is inside the cylinder and the camera outside (the side the camera sees is then unlit).

    Raises
    ------
    HighlightTruthError
        If the root solve does not converge to a point whose normal bisects the two directions
        (e.g. the camera or light inside the cylinder, or the axis nearly along the view).
    """
    c = np.asarray(center, dtype=np.float64)
    a = unit(axis, axis=-1)
    L = np.asarray(light, dtype=np.float64)

    def inside(x):
        xc = x - c
        return bool(np.linalg.norm(xc - np.dot(xc, a) * a) <= radius and abs(np.dot(xc, a)) <= 0.5 * length)

    if inside(L) and not inside(np.zeros(3)):
        return None  # light inside the tube, camera outside: the side the camera sees is unlit
    q = c - np.dot(c, a) * a  # foot of the perpendicular from the camera centre to the axis
    n0 = unit(-q, axis=-1)
    s0 = np.dot(q - c, a)
    if not np.allclose(L, 0.0):
        e = np.cross(a, n0)

        def surface(x):
            n = math.cos(x[1]) * n0 + math.sin(x[1]) * e
            return c + (s0 + x[0]) * a + radius * n, n

        x = _solve_stationary(surface, np.zeros(2), L,
                              what=f"cylinder (axis through {np.round(c, 4).tolist()} mm, R {radius:g} mm)")
        p, n = surface(x)
        s = s0 + x[0]
    else:
        p, n, s = q + radius * n0, n0, s0
    if abs(s) > 0.5 * length:
        return None
    return _highlight(p, n, 1.0 / radius, 0.0, K, size)


#: Caster signature: uv (N, 2) pixel coordinates -> dict with ``hit`` (N,) bool, ``p`` (N, 3),
#: ``n`` (N, 3) unit camera-facing shading normals, ``prim`` (N,) int triangle index.
Caster = Callable[[np.ndarray], dict]


def mesh_highlights(
    cast: Caster,
    normals: np.ndarray,
    position: np.ndarray,
    mask: np.ndarray,
    light: np.ndarray,
    K: np.ndarray,
    vertices: np.ndarray,
    faces: np.ndarray,
    k1_v: np.ndarray,
    k2_v: np.ndarray,
    *,
    candidate_deg: float = 3.0,
    accept_deg: float = 0.01,
    max_highlights: int = 64,
) -> list[HighlightTruth]:
    """BPs of a triangle mesh with interpolated vertex normals, from a render's ground truth.

    A BP is where the shading normal bisects the directions to the camera and the light
    (:func:`bisector`). Candidates are the local maxima of :func:`bisector_cos_image` above
    ``cos(candidate_deg)``; each is refined by casting 7 x 7 sub-pixel grids of rays 16 times
    (the step shrinks by 3 each time, to ~1e-7 px) and kept if its normal is within ``accept_deg``
    of the bisector.

    Parameters
    ----------
    cast : callable
        Ray caster (see ``Caster``); the renderer passes Mitsuba's ``scene.ray_intersect``.
    normals : ndarray of shape (H, W, 3)
        Per-pixel unit normals, camera frame, facing the camera (zero outside ``mask``).
    position : ndarray of shape (H, W, 3)
        Per-pixel surface points, camera frame, mm (zero outside ``mask``).
    mask : ndarray of shape (H, W), bool
        Fully covered pixels.
    light : ndarray of shape (3,)
        Light position, camera frame, mm.
    K : ndarray of shape (3, 3)
        Intrinsics (``cast`` uses the same).
    vertices : ndarray of shape (V, 3)
        Mesh vertices, camera frame, mm.
    faces : ndarray of shape (F, 3), int
        Triangles as vertex indices (``cast``'s ``prim`` indexes them).
    k1_v, k2_v : ndarray of shape (V,)
        Vertex principal curvatures (1/mm, camera-facing sign convention).
    candidate_deg : float
        Pixels whose normal is within this angle of the bisector and locally best start a search.
    accept_deg : float
        A refined BP is kept if its normal is within this angle of the bisector.
    max_highlights : int
        At most this many candidates (the best first) are refined.

    Returns
    -------
    list of HighlightTruth
        Sorted by v then u; duplicates (within 0.5 px) merged.
    """

    H, W = mask.shape
    g = bisector_cos_image(normals, position, mask, light)
    peaks = peak_local_max(g, min_distance=2, threshold_abs=math.cos(math.radians(candidate_deg)),
                           exclude_border=False, num_peaks=max_highlights)
    if len(peaks) == 0:
        return []
    uv = peaks[:, ::-1].astype(np.float64)  # (row, col) -> (u, v)
    step = 1.0
    offs = np.arange(-3, 4, dtype=np.float64)
    grid = np.stack(np.meshgrid(offs, offs, indexing="xy"), axis=-1).reshape(-1, 2)  # (49, 2)
    for _ in range(16):
        cand = uv[:, None, :] + step * grid[None, :, :]  # (N, 49, 2)
        res = cast(cand.reshape(-1, 2))
        cos = np.full(len(res["hit"]), -np.inf)
        hit = res["hit"]
        cos[hit] = np.sum(res["n"][hit] * bisector(res["p"][hit], light), axis=-1)
        cos = cos.reshape(len(uv), -1)
        j = np.argmax(cos, axis=1)
        uv = cand[np.arange(len(uv)), j]
        step /= 3.0
    res = cast(uv)
    out: list[HighlightTruth] = []
    vertices = np.asarray(vertices, dtype=np.float64)
    for i in range(len(uv)):
        if not res["hit"][i]:
            continue
        p, n = res["p"][i], unit(res["n"][i], axis=-1)
        angle = math.degrees(math.acos(min(1.0, float(np.dot(n, bisector(p, light))))))
        if angle > accept_deg:
            continue
        f = faces[int(res["prim"][i])]
        a, b, c = vertices[f]
        # Barycentric coordinates of p in triangle (a, b, c) by least squares.
        T = np.column_stack([b - a, c - a])
        w12, *_ = np.linalg.lstsq(T, p - a, rcond=None)
        w = np.array([1.0 - w12.sum(), w12[0], w12[1]])
        k1 = float(np.dot(w, k1_v[f]))
        k2 = float(np.dot(w, k2_v[f]))
        hl = HighlightTruth(uv[i].copy(), p.copy(), n, max(k1, k2), min(k1, k2),
                            _in_frame(uv[i], (W, H)))
        if all(np.hypot(*(hl.bp_px - o.bp_px)) > 0.5 for o in out):
            out.append(hl)
    out.sort(key=lambda h: (h.bp_px[1], h.bp_px[0]))
    return out


def highlight_complete(specular: np.ndarray, bp_px: np.ndarray, t: float = 0.1) -> bool:
    """Whether the highlight at ``bp_px`` and its isophote at level ``t`` lie inside the image.

    The region is the connected component of ``specular >= t * specular[BP]`` holding the BP
    pixel; the highlight is complete when that region does not touch the image border.

    Parameters
    ----------
    specular : ndarray of shape (H, W)
        Specular-only linear image.
    bp_px : ndarray of shape (2,)
        [u, v].
    t : float
        Isovalue as a fraction of the BP's intensity.

    Returns
    -------
    bool
        False also when the BP pixel is outside the image or dark (``specular <= 0``).
    """

    H, W = specular.shape
    u, v = int(round(bp_px[0])), int(round(bp_px[1]))
    if not (0 <= u < W and 0 <= v < H) or specular[v, u] <= 0:
        return False
    labels, _ = ndimage.label(specular >= t * specular[v, u])
    region = labels == labels[v, u]
    border = region[0, :].any() or region[-1, :].any() or region[:, 0].any() or region[:, -1].any()
    return not border


#: :func:`highlight_targets`: Gaussian sigma, px, of the specular image before its regions are
#: taken; the largest smoothing the detector's noise rule chooses (2.5 px) is about it: speckle
#: finer than this is not a set of separate highlights to a viewer or to the detector.
TARGET_SIGMA_PX = 2.0
#: :func:`highlight_targets`: a highlight's region is where the smoothed specular image is at
#: least this fraction of its value at the BP (the half-maximum region of the lobe).
TARGET_REL = 0.5
#: :func:`highlight_targets`: the detector's bound on ellipticity (``not_elliptical`` outside
#: [0.75, 1 / 0.75]), applied to the region.
TARGET_ELLIPTICITY_MIN = 0.75


@dataclass(frozen=True)
class HighlightTarget:
    """One highlight a person sees in a render: the ground-truth BPs of the lights it gathers.

    Attributes
    ----------
    bp_px : ndarray of shape (k, 2)
        [u, v] of the ground-truth BPs it holds, px (k >= 1; several when the highlights of
        several lights run together).
    lights : tuple of int
        Their lights' indices in the rig.
    highlights : tuple of HighlightTruth
        The ground truth itself, brightest first.
    peak_px : ndarray of shape (2,)
        [u, v] of the maximum of the smoothed specular image over its region, px: where the
        image shows the highlight's peak (off the BPs on micro-relief, see
        :func:`highlight_targets`).
    area_px : int
        Pixels of its half-maximum region (holes filled).
    """

    bp_px: np.ndarray
    lights: tuple[int, ...]
    highlights: tuple[HighlightTruth, ...]
    peak_px: np.ndarray
    area_px: int

    def distance_px(self, uv) -> float:
        """Distance, px, from the point ``uv`` [u, v] to the convex hull of :attr:`bp_px` and
        :attr:`peak_px`.

        The peak of several lobes that run together lies between their BPs, and micro-relief
        moves it off them to :attr:`peak_px`: for one point this is the distance to it, for two
        the distance to the segment, for more to their hull.
        """
        q = np.asarray(uv, dtype=np.float64)
        pts = np.unique(np.vstack([self.bp_px, self.peak_px[None]]).astype(np.float64), axis=0)
        if len(pts) >= 3:
            hull = cv2.convexHull(pts.astype(np.float32)).reshape(-1, 2).astype(np.float64)
            if len(hull) >= 3 and cv2.pointPolygonTest(hull.astype(np.float32),
                                                       (float(q[0]), float(q[1])), False) >= 0:
                return 0.0
            pts = hull
        if len(pts) == 1:
            return float(np.hypot(*(q - pts[0])))
        best = np.inf
        for a, b in zip(pts, np.roll(pts, -1, axis=0)):
            ab = b - a
            s = 0.0 if not ab.any() else float(np.clip(np.dot(q - a, ab) / np.dot(ab, ab), 0.0, 1.0))
            best = min(best, float(np.hypot(*(q - a - s * ab))))
        return best


def _climb(values: np.ndarray, r: int, c: int) -> tuple[int, int]:
    """The local maximum of ``values`` reached from (r, c) by steepest ascent over 8-neighbours."""
    H, W = values.shape
    while True:
        r0, r1, c0, c1 = max(r - 1, 0), min(r + 2, H), max(c - 1, 0), min(c + 2, W)
        win = values[r0:r1, c0:c1]
        i, j = np.unravel_index(int(np.argmax(win)), win.shape)
        if win[i, j] <= values[r, c]:
            return r, c
        r, c = r0 + int(i), c0 + int(j)


def highlight_targets(highlights: list[HighlightTruth], specular: np.ndarray, valid: np.ndarray,
                      *, sigma_px: float = TARGET_SIGMA_PX, rel: float = TARGET_REL,
                      ellipticity_min: float = TARGET_ELLIPTICITY_MIN) -> list[HighlightTarget]:
    """The ground-truth highlights a person sees as isolated elliptical highlights in a render.

    Parameters
    ----------
    highlights : list of HighlightTruth
        A render's ground truth (every light's BPs, :attr:`RenderResult.highlights`).
    specular : ndarray of shape (H, W)
        The render's specular-only linear image (every light).
    valid : ndarray of shape (H, W), bool
        Pixels that show the surface: the surface mask within the scope's field stop.
    sigma_px, rel, ellipticity_min : float
        See :data:`TARGET_SIGMA_PX`, :data:`TARGET_REL`, :data:`TARGET_ELLIPTICITY_MIN`.

    Returns
    -------
    list of HighlightTarget
        Brightest first.

    Notes
    -----
    The ground-truth BP is where the *macro* normal (the smooth mesh or analytic surface, the
    normal a reconstruction is scored against) bisects the directions to the camera and the
    light; that stays the target's BP and normal. The tissue's micro-relief tilts the shading
    normal by about a degree (0.003 mm at 1 mm on the colonoscope scenes) and the rendered lobe
    is broken into speckle around the macro BP. The shading normal is no target: it changes from
    pixel to pixel, every glint of the speckle is one of its BPs, and no isophote of the image
    follows it. What a person sees is the speckle's envelope, the lobe of the macro surface
    widened by the relief's slopes, so the specular image is smoothed by ``sigma_px`` (about the
    speckle's grain) before its regions are taken. The relief's slopes at the scale of the
    highlight also move the envelope's peak off the macro BP, far along a direction in which the
    bisector condition changes slowly (the surface's curvature there is close to that of the
    bisector field, about 1 / distance): 9 px along the streak of the full-size colonoscope's
    pair. The target keeps
    that peak too, :attr:`HighlightTarget.peak_px`, the local maximum of the smoothed image
    reached from the BP by steepest ascent (not the region's maximum: the region of a lobe on a
    bright wall can hold brighter light nearer the camera).

    A BP is a fair target when the image shows an isolated elliptical highlight there. Its region
    is the 8-connected component of ``smoothed specular >= rel * (its value at the BP)`` holding
    the BP, holes filled. The BP is a target when that region (1) lies within ``valid`` and off
    the image border (a highlight cut by the field stop or the frame has no closed isophote),
    and (2) has an ellipticity (:func:`simtest.reconstruct.detect.ellipticity`, the detector's
    measure) within [``ellipticity_min``, 1 / ``ellipticity_min``]: on a concave wall seen from
    near its centre of curvature the bisector condition nearly holds over a large patch and the
    specular image is a broad irregular sheen holding several BPs of one light, not a highlight
    with elliptical isophotes. BPs out of frame, outside ``valid`` or without specular light are
    dropped.

    The lights of a scope are a few millimetres apart: at working distances their highlights
    overlap and a person (and the detector) sees one. BPs are taken brightest first; a BP that
    lies inside the region of a brighter target joins it, and a target then holds several BPs
    (a pair of colonoscope light guides, a laparoscope's ring). An estimate reconstructs a
    target when its BP lies near the convex hull of the target's BPs and peak
    (:meth:`HighlightTarget.distance_px`): the peak of lobes that run together lies between
    their BPs, and the relief moves it to the peak.
    """
    H, W = specular.shape
    sm = cv2.GaussianBlur(np.asarray(specular, dtype=np.float32), (0, 0), float(sigma_px),
                          borderType=cv2.BORDER_REFLECT)
    valid = np.asarray(valid, dtype=bool)
    cand = []
    for h in highlights:
        if not (h.in_frame and np.all(np.isfinite(h.bp_px))):
            continue
        r, c = int(round(h.bp_px[1])), int(round(h.bp_px[0]))
        if not (0 <= r < H and 0 <= c < W) or not valid[r, c] or not sm[r, c] > 0:
            continue
        cand.append((float(sm[r, c]), r, c, h))
    cand.sort(key=lambda x: -x[0])
    groups: list[dict] = []
    for peak, r, c, h in cand:
        home = next((g for g in groups if g["region"][r, c]), None)
        if home is not None:
            home["members"].append(h)
            continue
        lab, _ = ndimage.label(sm >= rel * peak, structure=np.ones((3, 3), bool))
        region = ndimage.binary_fill_holes(lab == lab[r, c])
        rr, cc = np.nonzero(region)
        inside = bool(valid[region].all()) and rr.min() > 0 and cc.min() > 0 \
            and rr.max() < H - 1 and cc.max() < W - 1
        e = ellipticity(region)
        fair = inside and bool(ellipticity_min <= e <= 1.0 / ellipticity_min)
        pr, pc = _climb(sm, r, c)
        groups.append({"region": region, "members": [h], "fair": fair,
                       "peak": np.array([pc, pr], dtype=np.float64)})
    return [HighlightTarget(np.array([m.bp_px for m in g["members"]], dtype=np.float64),
                            tuple(int(m.light) for m in g["members"]), tuple(g["members"]),
                            g["peak"], int(g["region"].sum()))
            for g in groups if g["fair"]]
