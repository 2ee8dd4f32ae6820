"""Ground truth per highlight of a render: the brightest points (BPs) found on its images and meshes.

The BP is where the surface normal bisects the directions to the camera and to the light. Meshes: candidate
pixels refined by ray casting (Mitsuba's interpolated vertex normals; k1, k2 interpolated barycentrically).
:func:`highlight_targets` gives the highlights a person sees. No Mitsuba here: the renderer passes its caster.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import cv2
import numpy as np
from scipy import ndimage
from scipy.spatial import cKDTree
from skimage.feature import peak_local_max

from simtest.geometry.angles import unit
from simtest.reconstruct.detect import ellipticity
from simtest.simulate.truth import HighlightTruth, bisector, pixel_in_frame

__all__ = ["Caster", "bisector_cos_image", "mesh_highlight_candidates", "mesh_highlights", "ReliefHighlight",
           "relief_highlights", "HighlightTarget", "highlight_targets",
           "LOBE_MATCH_PX", "lobe_peak", "smoothed_specular"]


def bisector_cos_image(normals: np.ndarray, position: np.ndarray, mask: np.ndarray, light: np.ndarray) -> np.ndarray:
    """Cosine between each pixel's normal and its bisector, ``n . h(p)``, in float32.

    Parameters
    ----------
    normals : ndarray of shape (H, W, 3)
        Unit normals, camera frame, facing the camera (ignored outside ``mask``).
    position : ndarray of shape (H, W, 3)
        Surface points, camera frame, mm (ignored outside ``mask``).
    mask : ndarray of shape (H, W), bool
        Pixels with a surface.
    light : array_like of shape (3,)
        Point-light position, camera frame, mm; zeros for a light at the camera centre.

    Returns
    -------
    ndarray of shape (H, W)
        ``n . h`` inside ``mask``; -1 outside (NaN at a masked pixel at the camera centre).
    """
    mask = np.asarray(mask, dtype=bool)
    light32 = np.asarray(light, dtype=np.float32).reshape(3)
    out = np.full(mask.shape, -1.0, dtype=np.float32)
    flat = np.flatnonzero(mask)
    p, n = (_masked_rows(a, flat) for a in (position, normals))
    with np.errstate(divide="ignore", invalid="ignore"):
        h = -p / np.sqrt(_dot_rows(p, p))  # toward the camera
        if np.any(light32):
            to_light = light32[:, None] - p
            to_light /= np.sqrt(_dot_rows(to_light, to_light))
            h += to_light
        # co-located: to_light is h itself, and (h + h) / |h + h| is h / |h| bit for bit
        h /= np.sqrt(_dot_rows(h, h))
    out.reshape(-1)[flat] = _dot_rows(n, h)
    return out


def _masked_rows(a, flat: np.ndarray) -> np.ndarray:
    """Values of an (H, W, 3) array at flat pixel indices, float32, as contiguous (3, N)."""
    rows = np.take(np.asarray(a).reshape(-1, 3), flat, axis=0).astype(np.float32, copy=False)
    return np.ascontiguousarray(rows.T)


def _dot_rows(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``sum_i a[i] b[i]`` of two (3, N) arrays, summed left to right: (N,)."""
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def mesh_highlight_candidates(normals: np.ndarray, position: np.ndarray, mask: np.ndarray, light: np.ndarray, *,
                              candidate_deg: float = 3.0, max_highlights: int = 64) -> np.ndarray:
    """Pixels where a mesh BP search starts: local maxima of :func:`bisector_cos_image`.

    Parameters
    ----------
    normals, position, mask, light
        As :func:`bisector_cos_image`.
    candidate_deg : float
        Pixels whose normal is within this angle of the bisector and locally best start a search.
    max_highlights : int
        At most this many candidates, the best first.

    Returns
    -------
    ndarray of shape (N, 2), float64
        Pixel coordinates (u, v) of the candidates; (0, 2) when none.
    """
    g = bisector_cos_image(normals, position, mask, light)
    peaks = peak_local_max(g, min_distance=2, threshold_abs=math.cos(math.radians(candidate_deg)),
                           exclude_border=False, num_peaks=max_highlights)
    return peaks[:, ::-1].astype(np.float64).reshape(-1, 2)  # (row, col) -> (u, v)


#: Caster signature: uv (N, 2) pixel coordinates -> dict with ``hit`` (N,) bool, ``p`` (N, 3),
#: ``n`` (N, 3) unit camera-facing shading normals, ``prim`` (N,) int triangle index.
Caster = Callable[[np.ndarray], dict]


def mesh_highlights(cast: Caster, normals: np.ndarray, position: np.ndarray, mask: np.ndarray, light: np.ndarray,
                    K: np.ndarray, vertices: np.ndarray, faces: np.ndarray, k1_v: np.ndarray, k2_v: np.ndarray, *,
                    candidate_deg: float = 3.0, accept_deg: float = 0.01, max_highlights: int = 64,
                    candidates: np.ndarray | None = None) -> list[HighlightTruth]:
    """BPs of a triangle mesh with interpolated vertex normals, from a render's ground truth.

    Candidates (:func:`mesh_highlight_candidates`) are refined by 16 rounds of 7 x 7 sub-pixel ray grids, the
    step shrinking by 3 each round, and kept if the normal is within ``accept_deg`` of the bisector.

    Parameters
    ----------
    cast : callable
        Ray caster (see ``Caster``); the renderer passes Mitsuba's ``scene.ray_intersect``.
    normals, position, mask, light
        As :func:`bisector_cos_image` (``mask``: fully covered pixels).
    K : ndarray of shape (3, 3)
        Intrinsics (``cast`` uses the same).
    vertices : ndarray of shape (V, 3)
        Mesh vertices, camera frame, mm.
    faces : ndarray of shape (F, 3), int
        Triangles as vertex indices (``cast``'s ``prim`` indexes them).
    k1_v, k2_v : ndarray of shape (V,)
        Vertex principal curvatures, 1/mm, camera-facing sign convention.
    candidate_deg, max_highlights
        As :func:`mesh_highlight_candidates`.
    accept_deg : float
        A refined BP is kept if its normal is within this angle of the bisector.
    candidates : ndarray of shape (N, 2), optional
        Start pixels already found; ``normals`` and ``position`` are then not read.

    Returns
    -------
    list of HighlightTruth
        Sorted by v then u; duplicates (within 0.5 px) merged.
    """
    H, W = mask.shape
    if candidates is None:
        candidates = mesh_highlight_candidates(normals, position, mask, light, candidate_deg=candidate_deg,
                                               max_highlights=max_highlights)
    if len(candidates) == 0:
        return []
    uv, res = _refine(cast, candidates, light)
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
        k1, k2 = (float(np.dot(w, k_v[f])) for k_v in (k1_v, k2_v))
        hl = HighlightTruth(uv[i].copy(), p.copy(), n, max(k1, k2), min(k1, k2), pixel_in_frame(uv[i], (W, H)))
        if all(np.hypot(*(hl.bp_px - o.bp_px)) > 0.5 for o in out):
            out.append(hl)
    out.sort(key=lambda h: (h.bp_px[1], h.bp_px[0]))
    return out


def _refine(cast: Caster, candidates: np.ndarray, light: np.ndarray, step: float = 1.0,
            rounds: int = 16) -> tuple[np.ndarray, dict]:
    """Climb from each start pixel to where ``cast``'s normal best bisects camera and light.

    ``rounds`` 7 x 7 sub-pixel grids, the step starting at ``step`` px and shrinking by 3 each round.
    Returns the final pixels (N, 2) and ``cast``'s result there.
    """
    uv = np.asarray(candidates, dtype=np.float64)
    offs = np.arange(-3, 4, dtype=np.float64)
    grid = np.stack(np.meshgrid(offs, offs, indexing="xy"), axis=-1).reshape(-1, 2)  # (49, 2)
    for _ in range(rounds):
        cand = uv[:, None, :] + step * grid[None, :, :]  # (N, 49, 2)
        res = cast(cand.reshape(-1, 2))
        cos = np.full(len(res["hit"]), -np.inf)
        hit = res["hit"]
        cos[hit] = np.sum(res["n"][hit] * bisector(res["p"][hit], light), axis=-1)
        cos = cos.reshape(len(uv), -1)
        j = np.argmax(cos, axis=1)
        uv = cand[np.arange(len(uv)), j]
        step /= 3.0
    return uv, cast(uv)


def _peaks(img: np.ndarray, threshold: float, num: int) -> np.ndarray:
    """(row, col) of the at most ``num`` highest local maxima of ``img`` at or above ``threshold``, highest first."""
    rows, cols = np.nonzero(img >= threshold)
    if len(rows) == 0:
        return np.zeros((0, 2), dtype=np.int64)
    r0, r1 = max(int(rows.min()) - 1, 0), min(int(rows.max()) + 2, img.shape[0])
    c0, c1 = max(int(cols.min()) - 1, 0), min(int(cols.max()) + 2, img.shape[1])
    crop = img[r0:r1, c0:c1]
    pk = peak_local_max(crop, min_distance=1, threshold_abs=threshold, exclude_border=False, num_peaks=num)
    return pk.reshape(-1, 2) + np.array([r0, c0])


@dataclass(frozen=True)
class ReliefHighlight(HighlightTruth):
    """A glint: a point whose *shading* normal (micro-relief) bisects the directions to camera and light.

    ``normal`` is the shading normal, ``macro_normal`` the surface's; ``k1``, ``k2`` are NaN.
    """

    macro_normal: np.ndarray | None = None

    def to_dict(self) -> dict:
        """:meth:`HighlightTruth.to_dict` with ``kind`` "micro_relief", ``macro_normal`` and null ``k1``, ``k2``."""
        d = super().to_dict()
        d.update(kind="micro_relief", k1=None, k2=None,
                 macro_normal=[float(x) for x in self.macro_normal] if self.macro_normal is not None else None)
        return d


def relief_highlights(cast: Caster, shading_normals: np.ndarray, position: np.ndarray, mask: np.ndarray,
                      light: np.ndarray, *, specular: np.ndarray | None = None, candidate_deg: float = 3.0,
                      accept_deg: float = 0.01, max_highlights: int = 128,
                      max_bright: int = 64) -> list[ReliefHighlight]:
    """Specular points of the micro-relief (glints) of one light, from a render's shading normals.

    Parameters
    ----------
    cast : callable
        Ray caster whose ``n`` is the shading normal and ``n_macro`` the surface's normal.
    shading_normals, position, mask, light
        As :func:`bisector_cos_image`.
    specular : ndarray of shape (H, W), optional
        The render's specular image: its ``max_bright`` brightest local maxima start searches too (a glint
        finer than a pixel can be bright where the pixel centre's normal misses the bisector).
    candidate_deg, accept_deg
        As :func:`mesh_highlights`.
    max_highlights : int
        At most this many candidates, nearest the bisector first, are refined.

    Returns
    -------
    list of ReliefHighlight
        Sorted by v then u; duplicates (within 0.5 px) merged. ``light`` is 0: the caller sets it.
    """
    H, W = mask.shape
    g = bisector_cos_image(shading_normals, position, mask, light)
    peaks = _peaks(g, math.cos(math.radians(candidate_deg)), max_highlights)
    if specular is not None and max_bright > 0:
        sp = np.where(mask, np.asarray(specular, dtype=np.float32), 0.0)
        top = float(sp.max())
        if top > 0:  # the brightest local maxima, down to a quarter of the brightest pixel
            peaks = np.unique(np.vstack([peaks, _peaks(sp, 0.25 * top, max_bright)]), axis=0)
    if len(peaks) == 0:
        return []
    # glints lie close together: a first step of 1/6 px keeps each search in its own pixel
    uv, res = _refine(cast, peaks[:, ::-1].astype(np.float64), light, step=1.0 / 6.0, rounds=12)
    hit = res["hit"]
    ns = unit(np.where(hit[:, None], res["n"], np.nan), axis=-1)
    cos = np.sum(ns * bisector(np.where(hit[:, None], res["p"], np.nan), light), axis=-1)
    ok = hit & (cos >= math.cos(math.radians(accept_deg)))
    idx = np.flatnonzero(ok)
    idx = idx[np.argsort(-cos[idx], kind="stable")]  # the best of merged duplicates stays
    keep: list[int] = []
    if len(idx):
        tree = cKDTree(uv[idx])
        taken = np.zeros(len(idx), dtype=bool)
        for j in range(len(idx)):
            near = tree.query_ball_point(uv[idx[j]], 0.5)
            if not taken[near].any():
                keep.append(int(idx[j]))
                taken[j] = True
    out = [ReliefHighlight(uv[i].copy(), res["p"][i].copy(), ns[i], math.nan, math.nan,
                           pixel_in_frame(uv[i], (W, H)), macro_normal=unit(res["n_macro"][i], axis=-1))
           for i in keep]
    out.sort(key=lambda h: (h.bp_px[1], h.bp_px[0]))
    return out


#: :func:`highlight_targets`: Gaussian sigma, px, of the specular image before its regions are taken
#: (about the largest smoothing the detector's noise rule chooses, 2.5 px)
TARGET_SIGMA_PX = 2.0
#: :func:`highlight_targets`: a region is where the smoothed image is at least this fraction of its BP value
TARGET_REL = 0.5
#: :func:`highlight_targets`: the detector's bound on ellipticity, applied to the region
TARGET_ELLIPTICITY_MIN = 0.75
#: :func:`lobe_peak`: how far a lobe's smoothed peak may lie from a detection's BP, px: twice
#: :data:`TARGET_SIGMA_PX`, as smoothing moves an asymmetric lobe's peak by up to about sigma and the BP is the
#: sensor image's brightest pixel, not the specular image's (a geometric bound, not tuned on any data)
LOBE_MATCH_PX = 2.0 * TARGET_SIGMA_PX
#: :func:`specular_pixels`: the least share of a pixel's linear radiance that specular reflection holds for the
#: pixel to show a specular structure: half, where the specular term outweighs the diffuse one (a convention of
#: the truth's labels, as :data:`TARGET_REL` is; not tuned on any data)
SPECULAR_SHARE = 0.5


def specular_pixels(specular: np.ndarray, linear: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """Where a render's light is mostly specular reflection: its glints, streaks and sheens, isolated or not.

    Parameters
    ----------
    specular, linear : ndarray of shape (H, W)
        The render's specular-only and total (specular + diffuse) linear radiance, in one unit.
    valid : ndarray of shape (H, W), bool
        Pixels that show the surface within the scope's field stop.

    Returns
    -------
    ndarray of shape (H, W), bool
        The pixels of ``valid`` whose specular radiance is positive and at least :data:`SPECULAR_SHARE` of the linear.
    """
    sp = np.asarray(specular, dtype=np.float64)
    return np.asarray(valid, dtype=bool) & (sp > 0) & (sp >= SPECULAR_SHARE * np.asarray(linear, dtype=np.float64))


@dataclass(frozen=True)
class HighlightTarget:
    """One highlight a person sees in a render: the ground-truth BPs of the lights it gathers.

    Attributes
    ----------
    bp_px : ndarray of shape (k, 2)
        [u, v] of its ground-truth BPs, px (several when the highlights of several lights run together).
    lights : tuple of int
        Their lights' indices in the rig.
    highlights : tuple of HighlightTruth
        The ground truth, brightest first.
    peak_px : ndarray of shape (2,)
        [u, v] of the smoothed specular image's local maximum reached from the BP, px.
    area_px : int
        Pixels of its half-maximum region (holes filled).
    """

    bp_px: np.ndarray
    lights: tuple[int, ...]
    highlights: tuple[HighlightTruth, ...]
    peak_px: np.ndarray
    area_px: int

    def distance_px(self, uv) -> float:
        """Distance, px, from ``uv`` [u, v] to the convex hull of :attr:`bp_px` and :attr:`peak_px`."""
        q = np.asarray(uv, dtype=np.float64)
        pts = np.unique(np.vstack([self.bp_px, self.peak_px[None]]).astype(np.float64), axis=0)
        if len(pts) >= 3:
            hull = cv2.convexHull(pts.astype(np.float32)).reshape(-1, 2).astype(np.float64)
            if len(hull) >= 3 and cv2.pointPolygonTest(hull.astype(np.float32), (float(q[0]), float(q[1])), False) >= 0:
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


def _half_max_region(sm: np.ndarray, valid: np.ndarray, r: int, c: int, level: float,
                     ellipticity_min: float) -> tuple[np.ndarray, bool]:
    """The 8-connected region of ``sm >= level`` holding (r, c), holes filled, and whether it is an isolated
    elliptical highlight: within ``valid``, off the image border, ellipticity in [e_min, 1 / e_min]."""
    H, W = sm.shape
    lab, _ = ndimage.label(sm >= level, structure=np.ones((3, 3), bool))
    region = ndimage.binary_fill_holes(lab == lab[r, c])
    rr, cc = np.nonzero(region)
    inside = bool(valid[region].all()) and rr.min() > 0 and cc.min() > 0 and rr.max() < H - 1 and cc.max() < W - 1
    return region, inside and bool(ellipticity_min <= ellipticity(region) <= 1.0 / ellipticity_min)


def smoothed_specular(specular: np.ndarray, sigma_px: float = TARGET_SIGMA_PX) -> np.ndarray:
    """The specular-only image smoothed by a Gaussian of ``sigma_px`` (reflected border), float32, (H, W)."""
    return cv2.GaussianBlur(np.nan_to_num(np.asarray(specular, dtype=np.float32)), (0, 0), float(sigma_px),
                            borderType=cv2.BORDER_REFLECT)


def lobe_peak(sm: np.ndarray, valid: np.ndarray, uv, *, radius_px: float = LOBE_MATCH_PX, rel: float = TARGET_REL,
              ellipticity_min: float = TARGET_ELLIPTICITY_MIN) -> np.ndarray | None:
    """The peak of an isolated specular lobe at ``uv``: where a curved surface's normal comes near the bisector
    without reaching it, the specular reflection still makes a highlight, with no exact BP to list.

    The smoothed specular image is climbed (steepest ascent) from ``uv``; the maximum reached is a lobe peak
    when it lies within ``radius_px`` of ``uv`` and its half-maximum region passes :func:`highlight_targets`'s
    rules (1) and (2): inside ``valid``, off the border, elliptical. A speckle field of micro-relief fails them
    (its half-maximum regions run together), as does a detection on diffuse texture (no specular peak near).

    Parameters
    ----------
    sm : ndarray of shape (H, W)
        :func:`smoothed_specular` of the render.
    valid : ndarray of shape (H, W), bool
        Pixels that show the surface within the scope's field stop.
    uv : array_like of shape (2,)
        [u, v] of a detection's BP, px.
    radius_px, rel, ellipticity_min : float
        See :data:`LOBE_MATCH_PX`, :data:`TARGET_REL`, :data:`TARGET_ELLIPTICITY_MIN`.

    Returns
    -------
    ndarray of shape (2,) or None
        [u, v] of the lobe's peak, px; None where there is none.
    """
    H, W = sm.shape
    r, c = int(round(float(uv[1]))), int(round(float(uv[0])))
    if not (0 <= r < H and 0 <= c < W):
        return None
    pr, pc = _climb(sm, r, c)
    if not sm[pr, pc] > 0 or math.hypot(pr - r, pc - c) > radius_px or not valid[pr, pc]:
        return None
    _, fair = _half_max_region(sm, np.asarray(valid, dtype=bool), pr, pc, rel * float(sm[pr, pc]), ellipticity_min)
    return np.array([pc, pr], dtype=np.float64) if fair else None


def highlight_targets(highlights: list[HighlightTruth], specular: np.ndarray, valid: np.ndarray,
                      *, sigma_px: float = TARGET_SIGMA_PX, rel: float = TARGET_REL,
                      ellipticity_min: float = TARGET_ELLIPTICITY_MIN) -> list[HighlightTarget]:
    """The ground-truth highlights a person sees as isolated elliptical highlights in a render.

    The specular image is smoothed by ``sigma_px`` (about the micro-relief's speckle grain). Taking BPs brightest
    first, a BP's region is the 8-connected component of ``smoothed >= rel * (value at the BP)`` holding it,
    holes filled; a BP inside a brighter target's region joins that target (overlapping lights of a scope). A
    target is kept when its region (1) lies within ``valid`` and off the image border, (2) has an ellipticity
    (:func:`simtest.reconstruct.detect.ellipticity`) within [``ellipticity_min``, 1 / ``ellipticity_min``], and
    (3) holds at most one BP of each light (several mean a sheen or sparkle, not a highlight).

    Parameters
    ----------
    highlights : list of HighlightTruth
        A render's ground truth (every light's BPs).
    specular : ndarray of shape (H, W)
        The render's specular-only linear image (every light).
    valid : ndarray of shape (H, W), bool
        Pixels that show the surface within the scope's field stop.
    sigma_px, rel, ellipticity_min : float
        See :data:`TARGET_SIGMA_PX`, :data:`TARGET_REL`, :data:`TARGET_ELLIPTICITY_MIN`.

    Returns
    -------
    list of HighlightTarget
        Brightest first.
    """
    H, W = specular.shape
    sm = smoothed_specular(specular, sigma_px)
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
        region, fair = _half_max_region(sm, valid, r, c, rel * peak, ellipticity_min)
        pr, pc = _climb(sm, r, c)
        groups.append({"region": region, "members": [h], "fair": fair, "peak": np.array([pc, pr], dtype=np.float64)})
    return [HighlightTarget(np.array([m.bp_px for m in g["members"]], dtype=np.float64),
                            tuple(int(m.light) for m in g["members"]), tuple(g["members"]),
                            g["peak"], int(g["region"].sum()))
            for g in groups  # rule 3: no light has two of a target's BPs
            if g["fair"] and len({int(m.light) for m in g["members"]}) == len(g["members"])]
