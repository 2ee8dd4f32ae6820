"""A rig's lobes on a curved patch: one patch fit gives each guide's row.

The rig's curves (:mod:`simtest.reconstruct.rig_pairs`) place the other guides' highlights as a plane would. A convex
patch draws the guides' specular points together (a mirror ball's images of two lamps lie closer than a flat mirror's),
a concave one pushes them apart: on the bundled liver seen from 64 mm, two guides 19 mm either side of the lens light
points 14 px apart where every plane through the BP puts the other 40 px or more away. The verifier then counts the
other guide's lobe as another peak (``cluster``, ``merged``), or, closer still, the two lobes fuse into one region whose
isophote is no ellipse (``bad_fit``, ``not_an_ellipse``), and no light-aware fit runs.

Rule. Under separate lights, a group of candidates still rejected for such a reason after the other steps
(:data:`CURVED_LOBE_STATUSES`), each pair of them one's BP in the other's ROI, at most one per place of the rig's
lights, no other candidate's BP in the ROI the fit reads (whatever its status: a smooth patch shows one lobe per place
of the lights, a glint field many peaks) and, where several, their isophotes alike in extent in every direction
(:data:`~simtest.decisions.LOBE_TWIN_EXTENT_RATIO`: the lobes of one patch image its one shape), is fitted as one curved
patch: the quadric, then the third-order patch (:mod:`simtest.reconstruct.lightaware`), on the ROI that holds every
member's lobe. The first fit that is ``ok`` with each guide's specular point (its light normals and depths,
:func:`~simtest.reconstruct.rig_pairs.patch_specular_points`) and puts the points on the group confirms it: each
member's BP within :data:`~simtest.decisions.PAIR_TOL_PX` plus its wander of a guide's point, no two on one point; a
lone candidate (fused lobes) with two or more guides' points in its bright region, ``PAIR_TOL_PX`` apart, one on its BP.
Each such point becomes that guide's row (status ``ok``, BP at the point, the fit's normals); a group the fit does not
confirm keeps its rejections. Texture or a glint field seldom puts a second lobe where one patch's shading explains
both; the fit decides, not the spacing.
"""

from __future__ import annotations

import cv2
import numpy as np

from simtest._threads import one_thread_each
from simtest.decisions import LOBE_TWIN_EXTENT_RATIO, PAIR_TOL_PX
from simtest.reconstruct._pixels import Roi
from simtest.reconstruct.detect_pixels import luma
from simtest.reconstruct.light_fits import _peaks_in, _reach, _roi_union, patch_fit
from simtest.reconstruct.rig_lobes import _bright_region, _inside, _own_guide, _row
from simtest.reconstruct.rig_pairs import estimate_wander_px, patch_specular_points

__all__ = ["CURVED_LOBE_STATUSES", "curved_lobe_rows"]

#: Rejections a curved patch's guide lobes earn (module docstring): another guide's lobe counted as
#: another peak (``cluster``, ``merged``) or the lobes fused into one region that is no ellipse.
CURVED_LOBE_STATUSES = ("cluster", "merged", "bad_fit", "not_an_ellipse")

#: The patch fits tried, in order (the quadric is the cheaper; the third-order patch holds a patch whose
#: curvature changes between the guides' specular points).
_PATCH_FITS = ("quadric_fit", "cubic_patch_fit")


def _near(a, b) -> bool:
    """Whether either candidate's ROI holds the other's BP (a lobe's ROI may stop short of the other's peak)."""
    return _peaks_in(b.bp_px, Roi(*a.roi)) + _peaks_in(a.bp_px, Roi(*b.roi)) > 0


def _extents(est) -> np.ndarray:
    """The second-moment matrix (2, 2) of a candidate's primary isophote (its area), px^2."""
    m = cv2.moments(np.asarray(est.primary.points_uv, np.float32).reshape(-1, 1, 2))
    return np.array([[m["mu20"], m["mu11"]], [m["mu11"], m["mu02"]]]) / max(m["m00"], 1e-12)


def _twins(estimates, members: list[int]) -> bool:
    """Whether every two members' isophotes agree in extent in every direction within
    :data:`~simtest.decisions.LOBE_TWIN_EXTENT_RATIO` (the lobes of one patch image its one shape)."""
    if any(estimates[m].primary.points_uv is None or not estimates[m].primary.closed for m in members):
        return False
    mom = [_extents(estimates[m]) for m in members]
    for a in range(len(mom)):
        for b in range(a + 1, len(mom)):
            try:
                ev = np.linalg.eigvals(np.linalg.solve(mom[a], mom[b])).real
            except np.linalg.LinAlgError:
                return False
            if not (ev > 0).all() or max(np.sqrt(ev.max()), 1.0 / np.sqrt(ev.min())) > LOBE_TWIN_EXTENT_RATIO:
                return False
    return True


def _groups(estimates, places: int, shape, roi_scale: float) -> list[tuple[list[int], Roi]]:
    """The groups of rejected candidates the rule fits (module docstring), each the brightest member first, and the
    ROI its fit reads."""
    pool = [i for i, e in enumerate(estimates) if e.status in CURVED_LOBE_STATUSES and e.primary is not None]
    groups, seen = [], set()
    for i in pool:
        if i in seen:
            continue
        members = sorted([i] + [j for j in pool if j != i and _near(estimates[i], estimates[j])],
                         key=lambda k: -float(estimates[k].bp_intensity))
        closed = all(_near(estimates[a], estimates[b]) for a in members for b in members if a != b)
        # a smooth patch shows one lobe per place of the lights: any other candidate's peak in the ROI the fit
        # would read (a square of the first member's curved-fit size about each member's BP) says it is not one
        half = _reach(estimates[members[0]], roi_scale)
        at = _roi_union(*(Roi.around(estimates[m].bp_px, half, shape) for m in members))
        alone = not _peaks_in([e.bp_px for k, e in enumerate(estimates) if k not in members], at)
        fused = len(members) == 1 and estimates[i].status != "cluster"  # (a lone cluster: its peak no candidate)
        if closed and alone and len(members) <= places and (fused or len(members) > 1 and _twins(estimates, members)):
            groups.append((members, at))
        seen.update(members)
    return groups


def _placed(pts: np.ndarray, members: list[int], estimates, gray) -> list[tuple[int, int]] | None:
    """``[(member, guide), ...]``: where the guides' points ``pts`` (J, 2) confirm the group (module docstring),
    a lone member once per guide whose point lies in its bright region; else None."""
    guides = [_own_guide(pts, estimates[m].bp_px, PAIR_TOL_PX + estimate_wander_px(estimates[m])) for m in members]
    if None in guides or len(set(guides)) < len(members):
        return None
    if len(members) > 1:
        return list(zip(members, guides))
    region = _bright_region(gray, estimates[members[0]])
    if region is None:
        return None
    ok = np.isfinite(pts).all(axis=1)
    inside = np.flatnonzero(ok & _inside(region, np.where(ok[:, None], pts, -1.0)))
    apart = np.linalg.norm(pts[inside][:, None] - pts[inside][None], axis=-1)[np.triu_indices(len(inside), 1)]
    if len(inside) < 2 or apart.min() < PAIR_TOL_PX:
        return None
    return [(members[0], int(j)) for j in inside]


def curved_lobe_rows(image, estimates, camera, rig, fit_kwargs: dict, *, gray=None) -> list:
    """The estimates with each group of a curved patch's guide lobes made the guides' rows (module docstring).

    Parameters
    ----------
    image : ndarray of shape (H, W) or (H, W, 3)
        The frame the estimates were made on.
    estimates : sequence of SpecularityEstimate
        After the rig's other steps (:func:`~simtest.reconstruct.rig_centroid.light_aware_with_rig`).
    camera : array_like of shape (3, 3) or CameraModel
        Intrinsics K or a camera model.
    rig : LightRig or None
        The scope's lights (None, or fewer than two places: returned unchanged).
    fit_kwargs : dict
        The frame's arguments of :func:`~simtest.reconstruct.light_fits.light_aware_estimates`.
    gray : ndarray of shape (H, W), optional
        The frame's luma when at hand.

    Returns
    -------
    list of SpecularityEstimate
        In the order of ``estimates``, a confirmed lone candidate's rows in the rig's order in its place.
    """
    if rig is None or not rig.has_separate_lights:
        return list(estimates)
    out = [[e] for e in estimates]
    shape = np.asarray(image).shape
    for members, at in _groups(estimates, rig.light_places, shape, fit_kwargs.get("quadric_roi_scale", 1.5)):
        anchor = estimates[members[0]]
        for name in _PATCH_FITS:
            with one_thread_each():  # as with_light_aware's fits: the same bits on any number of workers
                fit = patch_fit(name, image, anchor, camera, rig, at, **fit_kwargs)
            if not fit.ok or fit.light_normals is None or fit.light_depths_mm is None:
                continue
            pts = patch_specular_points(camera, rig, fit.light_normals, fit.light_depths_mm)
            gray = luma(np.asarray(image)) if gray is None else gray
            placed = _placed(pts, members, estimates, gray)
            if placed is None:
                continue
            how = f"BP at its specular point, normals from one {name} of the patch holding the guides' lobes"
            la = {name: fit}
            for m in members:
                out[m] = []
            for m, j in placed:
                what = (f"guide {j + 1}'s lobe of {len(placed)} fused on a curved patch" if len(members) == 1
                        else f"guide {j + 1}'s lobe on a curved patch")
                out[m].append(_row(estimates[m], camera, pts[j], what, how, light_aware=la))
            break
    return [e for rows in out for e in rows]
