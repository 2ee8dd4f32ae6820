"""Ground truth per highlight of a render: the brightest points (BPs) found on its images and meshes.

The BP is where the surface normal bisects the directions to the camera and to the light
(:func:`simtest.simulate.truth.bisector`). The analytic surfaces' BPs are closed forms or checked
root solves in :mod:`simtest.simulate.truth`; this module finds them where only a render knows the
surface:

- Meshes: candidate pixels where the rendered ground-truth normals nearly bisect, refined by ray
  casting through sub-pixel grids (the normal is the barycentric interpolation of the vertex
  normals, as Mitsuba shades it); k1 and k2 are the barycentric interpolation of the vertex values.
- The highlights a person sees as isolated elliptical highlights in a render, each with the
  ground-truth BPs it gathers (:func:`highlight_targets`).

No Mitsuba here: the renderer passes its ray caster in.
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

__all__ = [
    "Caster",
    "bisector_cos_image",
    "mesh_highlight_candidates",
    "mesh_highlights",
    "ReliefHighlight",
    "relief_highlights",
    "HighlightTarget",
    "highlight_targets",
]


def bisector_cos_image(normals: np.ndarray, position: np.ndarray, mask: np.ndarray,
                       light: np.ndarray) -> np.ndarray:
    """Cosine between each pixel's normal and its bisector, ``n . h(p)``, in float32.

    The BP condition (the normal equals the bisector, :func:`bisector`) holds where this is 1; :func:`mesh_highlights` starts its
    searches at its local maxima. Float32 like the render's AOVs, computed on the masked pixels
    only, one coordinate at a time (no (H, W, 3) temporaries).

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
        ``n . h`` in [-1, 1] (float32 round-off aside) inside ``mask``; -1 outside (NaN at a
        masked pixel at the camera centre, whose directions are undefined).
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
    """The (H, W, 3) array's values at the flat pixel indices ``flat``, float32, as (3, N) with
    each coordinate's row contiguous (``take`` with indices: a boolean mask on (H, W, 3) is
    several times slower)."""
    rows = np.take(np.asarray(a).reshape(-1, 3), flat, axis=0).astype(np.float32, copy=False)
    return np.ascontiguousarray(rows.T)


def _dot_rows(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``sum_i a[i] b[i]`` of two (3, N) arrays, summed left to right: (N,)."""
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def mesh_highlight_candidates(normals: np.ndarray, position: np.ndarray, mask: np.ndarray,
                              light: np.ndarray, *, candidate_deg: float = 3.0,
                              max_highlights: int = 64) -> np.ndarray:
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
    candidates: np.ndarray | None = None,
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
    candidates : ndarray of shape (N, 2), optional
        The start pixels, when :func:`mesh_highlight_candidates` already gave them (with the same
        arguments); ``normals`` and ``position`` are then not read.

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
        k1 = float(np.dot(w, k1_v[f]))
        k2 = float(np.dot(w, k2_v[f]))
        hl = HighlightTruth(uv[i].copy(), p.copy(), n, max(k1, k2), min(k1, k2),
                            pixel_in_frame(uv[i], (W, H)))
        if all(np.hypot(*(hl.bp_px - o.bp_px)) > 0.5 for o in out):
            out.append(hl)
    out.sort(key=lambda h: (h.bp_px[1], h.bp_px[0]))
    return out


def _refine(cast: Caster, candidates: np.ndarray, light: np.ndarray, step: float = 1.0,
            rounds: int = 16) -> tuple[np.ndarray, dict]:
    """Climb from each start pixel to where ``cast``'s normal best bisects camera and light.

    Casts 7 x 7 sub-pixel grids of rays ``rounds`` times, keeping the ray whose normal is nearest
    the bisector; the step starts at ``step`` px (1: the search reaches 3 px) and shrinks by 3
    each time (1 px and 16 rounds end at ~1e-7 px). Returns the final pixel positions (N, 2) and
    ``cast``'s result there.
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
    """(row, col) of the at most ``num`` highest local maxima (8-neighbourhood) of ``img`` at or
    above ``threshold``, highest first; found on the bounding box of the pixels above it."""
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
    """A specular point of the tissue's micro-relief: its *shading* normal bisects the directions to
    the camera and to the light (a glint), where a :class:`HighlightTruth` is the macro surface's.

    ``normal`` is the shading normal (camera frame, facing the camera), ``macro_normal`` the
    surface's normal at the same point; ``k1``, ``k2`` are NaN (the relief's curvature is not
    given). :meth:`to_dict` writes them as null and adds ``kind = "micro_relief"``.
    """

    macro_normal: np.ndarray | None = None

    def to_dict(self) -> dict:
        """:meth:`HighlightTruth.to_dict` with ``kind`` "micro_relief", ``macro_normal`` [x, y, z]
        and ``k1``, ``k2`` null."""
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
        Ray caster (see ``Caster``) whose ``n`` is the *shading* normal (the relief's, evaluated
        with the function the renderer shades with) and ``n_macro`` the surface's normal.
    shading_normals : ndarray of shape (H, W, 3)
        Per-pixel shading normals, camera frame (values outside ``mask`` are ignored).
    position : ndarray of shape (H, W, 3)
        Per-pixel surface points, camera frame, mm (values outside ``mask`` are ignored).
    mask : ndarray of shape (H, W), bool
        Pixels with surface truth.
    light : ndarray of shape (3,)
        Light position, camera frame, mm.
    specular : ndarray of shape (H, W), optional
        The render's specular image: its ``max_bright`` brightest local maxima start searches too
        (a glint finer than a pixel can be bright where the pixel centre's normal misses the
        bisector).
    candidate_deg : float
        Pixels whose shading normal is within this angle of the bisector and locally best (among
        their 8 neighbours) start a search.
    accept_deg : float
        A refined point is kept if its shading normal is within this angle of the bisector.
    max_highlights : int
        At most this many candidates, those nearest the bisector first, are refined: on a
        relief finer than a pixel the glints are many, and the labels are those found, not all.

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
    # Glints lie closer together than a macro surface's BPs: the search stays within 0.5 px of
    # its start pixel (a first step of 1/6 px), so each start finds the glint in its own pixel.
    # 12 rounds from 1/6 px end at ~1e-6 px, well inside the acceptance angle.
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

    (3) Its region holds at most one BP of each light. Where one light has several specular
    points within one visible highlight, the surface's normal turns back and forth on a scale
    finer than the highlight: micro-relief breaks a lobe into sparkle (the endoscope suite's
    relief of 5 um RMS and more gathers 4 BPs of two lights into a sheen of 4800 to 18500 px),
    or a rough film spreads it into a broad sheen over a curved wall (GGX alpha 0.1 and 0.2 on
    the colon wall: 4300 and 8300 px). No locally planar patch gives that image, and a person
    sees a sheen, not a highlight. The highlights of different lights that run together (a
    scope's guides, a laparoscope's ring of eight) stay a target.

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
            for g in groups  # rule 3: no light has two of a target's BPs
            if g["fair"] and len({int(m.light) for m in g["members"]}) == len(g["members"])]
