"""The light-aware fits run on detected highlights, given the scope's light rig (:func:`with_light_aware`),
attached to each estimate (``light_aware``) for :func:`~simtest.reconstruct.recommend.recommend`, whose
module docstring gives the rules.

Isophotes of the isocurve fit
-----------------------------
:func:`isocurve_fit` takes its own isophotes, at :data:`ISOCURVE_ISOVALUES` (0.3, 0.5, 0.7) of the
BP's height above the median of the grown ROI's border, extracted from that ROI (the
photometric fit's), not the command line's isovalues, whose two contours near the peak say
little about the distance (measured: ``docs/decisions/light-aware-recommendation.md``).
"""

from __future__ import annotations

import dataclasses
from concurrent.futures import as_completed

import numpy as np

from simtest._lazy import require
from simtest._threads import one_thread_each
from simtest._workers import worker_pool
from simtest.decisions import ISOCURVE_ISOVALUES, SIGMA_MARGIN
from simtest.geometry.lights import LightRig
from simtest.reconstruct import lightaware as _la
from simtest.reconstruct._pixels import Roi
from simtest.reconstruct.detect import luma, noise_sigma
from simtest.reconstruct.isophote import extract_isophote
from simtest.reconstruct.jpeg import jpeg_grid
from simtest.reconstruct.lightaware import (LightAwareEstimate, cubic_patch_fit, isocurve_fit, photometric_fit,
                                            quadric_fit, refine_isophote_points)
from simtest.reconstruct.recommend import (_bp_ray_error_beside, bp_error_depth_mm, bp_ray_error_deg,
                                           depth_within_ceiling)

#: The photometric fit's statuses after which the curved-patch fits run by default (``quadric``,
#: ``cubic`` None in :func:`light_aware_estimates`): those that say the plane is not the ROI's
#: surface (its residual holds a curved patch's pattern, or the fit ran off). After the others
#: a patch fit cannot do better and takes seconds: ``depth_not_observable`` (the plane fits; a
#: patch has more parameters to trade with the depth), ``too_few_points`` (fewer pixels than a
#: patch's parameters too), ``light_behind_plane``.
CURVED_FIT_AFTER = ("plane_misfit", "not_converged")
#: Candidate statuses that never get a light-aware fit, not even with ``fit_rejected`` of
#: :func:`with_light_aware`: too small to fit, or judged no specular highlight of the tissue (the
#: scope's black border, a burnt-in overlay, a peak that is not specular:
#: :mod:`simtest.reconstruct.verify`).
NOT_FITTED = ("too_small", "black_border", "overlay", "not_specular")


def _offset_rig(rig) -> bool:
    return rig is not None and not rig.is_colocated


def _several_lights(rig) -> bool:
    """Whether the rig has at least two lights at different places (their lobes can differ)."""
    return rig is not None and rig.has_separate_lights

def light_aware_estimates(image, est, camera, rig: LightRig, *, nominal_depth_mm: float = 20.0,
                          saturation_level: float | None = None,
                          roi_scale: float = 2.5, quadric_roi_scale: float = 1.5,
                          supersample: int = 1,
                          quadric: bool | None = None,
                          cubic: bool | None = False, response=None,
                          diffuse: bool | None = None,
                          lobe: str | None = None, linear=None, colour: bool | None = None,
                          floor_refit: bool = False) -> dict[str, LightAwareEstimate]:
    """Run the light-aware estimators on one detected highlight.

    ``isocurve_fit`` takes its own isophotes, at :data:`ISOCURVE_ISOVALUES` of the BP's height above
    the grown ROI's border median (refined onto the cubic spline of the image,
    :func:`~simtest.reconstruct.lightaware.refine_isophote_points`; module docstring, "Isophotes
    of the isocurve fit"), whatever isovalues the highlight was detected with; ``photometric_fit`` takes the highlight's
    ROI grown ``roi_scale`` times about the BP (the lobe's tails carry the distance), clipped pixels
    left out, refined from two starts (the bisector at the nominal depth and the isocurve fit's
    normal when it has one) and the better kept, so that one fit's local minimum does not become
    the other's answer.

    Parameters
    ----------
    image : ndarray of shape (H, W) or (H, W, 3)
        The image the highlight was detected in.
    est : SpecularityEstimate
        From :func:`~simtest.reconstruct.reconstruct` or ``reconstruct_roi``.
    camera : array_like of shape (3, 3) or CameraModel
        Intrinsics K, or a camera model with ``pixel_to_ray``.
    rig : LightRig
        The scope's lights, camera frame, mm.
    nominal_depth_mm : float
        Depth assumed for the fits' start, mm.
    saturation_level : float, optional
        Clip level (default: the dtype's maximum for integer images; none for float images).
    roi_scale : float
        Growth of the highlight's ROI for the photometric fit.
    quadric_roi_scale : float
        Growth of the highlight's ROI for the curved-patch fit: smaller than the plane's, as a
        quadric holds over a smaller part of a curved surface than the lobe's faint tails span
        (:mod:`~simtest.reconstruct.recommend`, "Recommendation rule").
    supersample : int
        Sub-pixel samples per pixel side of the photometric model (its box filter).
    quadric : bool or None
        Run the curved-patch fit :func:`~simtest.reconstruct.lightaware.quadric_fit` (on the
        highlight's ROI grown ``quadric_roi_scale`` times about the BP): True always, None
        (default) when the photometric fit's status is in :data:`CURVED_FIT_AFTER` (a plane
        misfit, or a plane fit that ran off on a curved patch: the recommendation then needs
        it), False never (the harness' oracle inputs keep the plane fit only).
    cubic : bool or None
        Run the third-order patch fit
        :func:`~simtest.reconstruct.lightaware.cubic_patch_fit` on the same ROI as the quadric's:
        True always, False (default: it takes about 1 to 5 s per highlight, against a few ms
        for the others) never, None when the photometric fit's status is in
        :data:`CURVED_FIT_AFTER` and the rig has at least two lights at different places (with
        one light its depth, and with it the normal, is not observable: :mod:`~simtest.reconstruct.recommend`);
        ``simtest reconstruct --cubic-patch`` asks for None.
    response : SensorResponse, optional
        The sensor's response (:class:`~simtest.geometry.response.SensorResponse`, a camera
        file's ``"response"``): the fits then run on the linear intensities of the channel where
        the tissue is darkest (:meth:`~simtest.geometry.response.SensorResponse.linearize`), its
        clipped pixels censored (the radiance is at least the clip level), with the rig's diffuse
        shading in the photometric model; ``saturation_level`` is then the response's.
    diffuse : bool or None
        The rig's Lambertian shading as a column of the photometric model
        (:func:`~simtest.reconstruct.lightaware.photometric_fit`'s ``diffuse``); None (default):
        with a ``response`` (a sensor frame of tissue), not without.
    lobe : {"phong", "ggx", "auto"} or None
        The photometric fit's specular lobe (:func:`~simtest.reconstruct.lightaware.photometric_fit`;
        ``"auto"``: GGX where Phong misfits and GGX does not). None (default): "auto" where the
        fit runs on the three channels (the film's own lobes, whose GGX shape Phong's misfits
        once the texture no longer hides it), else Phong: on sensor frames ``"auto"`` has not
        been seen to change a recommendation and costs CPU (``docs/decisions``' light-aware file).
    floor_refit : bool
        Refit the photometric fit without the pixels whose model lies within a few noise sigmas
        of an integer image's 0 (:func:`~simtest.reconstruct.lightaware.photometric_fit`'s
        ``floor_refit``: read noise clipped at 0 biases the fit there). The floor itself is always
        passed: the fit's curvature test reads only the pixels above it.
    colour : bool, optional
        Fit the photometric model on the ROI's three linear channels, the tissue's body colours
        projected out (:func:`colour_fit_applies`; None: decided here, :func:`with_light_aware`
        decides once per frame).
    linear : tuple, optional
        ``response.linearize(image)`` when already at hand (:func:`with_light_aware` computes it
        once per frame: 25 ms on a 1350 x 1080 RGB frame).

    Returns
    -------
    dict
        ``{"isocurve_fit": LightAwareEstimate, "photometric_fit": LightAwareEstimate}`` (the
        isocurve fit is absent when none of its isophotes closes in the grown ROI),
        ``"quadric_fit"`` and ``"cubic_patch_fit"`` as ``quadric`` and ``cubic`` say. Each has
        its depth within :data:`DEPTH_REL_SIGMA_CEILING` (:func:`depth_within_ceiling`) and its
        ``bp_ray_error_deg`` set (:func:`bp_ray_error_deg` at its depth, or at
        ``nominal_depth_mm``); ``"rig_centroid"`` where the highlight is one fused lobe of the
        rig's lights (:func:`~simtest.reconstruct.rig_centroid.rig_centroid`).
    """
    img = np.asarray(image)
    gray, saturation_level, censor, floor, floor_step = _fit_intensities(img, response, linear, saturation_level)
    if diffuse is None:
        diffuse = response is not None
    out: dict[str, LightAwareEstimate] = {}
    roi = Roi(*(int(v) for v in est.roi))
    half = roi_scale * max(roi.shape) / 2.0
    big = Roi.around(est.bp_px, half, img.shape)
    start_n = None
    pts, ts = _isocurve_isophotes(gray, big, est.bp_px, refine=len(rig.lights) == 1)  # (isocurve_fit: one light)
    if pts:
        iso_est = _guarded("isocurve_fit", isocurve_fit, pts, ts, est.bp_px,
                           camera, rig, nominal_depth_mm=nominal_depth_mm)
        out["isocurve_fit"] = iso_est
        if iso_est.has_normal:
            start_n = iso_est.normal
    if colour is None:
        colour = colour_fit_applies(img, response)
    if lobe is None:
        lobe = "auto" if colour else "phong"
    pkw = dict(nominal_depth_mm=nominal_depth_mm,
               start_normal=start_n, supersample=supersample, diffuse=diffuse, censor=censor,
               lobe=lobe, floor_level=floor, floor_refit=floor_refit, floor_step=floor_step)
    out["photometric_fit"] = _photometric(img, gray, big, est, camera, rig, response, colour, saturation_level, pkw)
    _curved_fits(out, gray, img.shape, est, roi, camera, rig, saturation_level=saturation_level,
                 nominal_depth_mm=nominal_depth_mm, quadric_roi_scale=quadric_roi_scale, quadric=quadric,
                 cubic=cubic)
    from simtest.reconstruct.rig_centroid import rig_centroid  # (it imports rig_lobes, which imports this)
    fused = rig_centroid(img, est, camera, rig, out, nominal_depth_mm)
    return out if fused is None else {**out, "rig_centroid": fused}


def _fit_intensities(img: np.ndarray, response, linear, saturation_level):
    """``(gray, saturation_level, censor, floor, floor_step)`` of :func:`light_aware_estimates`:
    the values the fits read (a sensor frame's linear channel, else the luma), their clip level,
    whether clipped pixels are censored, and an integer image's floor and its step."""
    censor = False
    # an unsigned integer image's 0 is a floor its read noise is clipped at (0 in the linear
    # image too: every response curve maps 0 to 0), its quantisation step 1 (in the linear
    # image, the linear value of 1)
    floor = 0.0 if img.dtype.kind == "u" else None
    floor_step = 1.0
    if response is not None:
        gray, saturation_level, ch = response.linearize(img) if linear is None else linear
        censor = True
        if floor is not None:
            floor_step = float(np.ravel(response.linear(np.ones(1), ch, response.full_scale(img)))[0])
    else:
        if saturation_level is None and img.dtype.kind == "u":
            saturation_level = float(np.iinfo(img.dtype).max)
        gray = luma(img)
    return gray, saturation_level, censor, floor, floor_step


def _photometric(img, gray, big: Roi, est, camera, rig, response, colour: bool, saturation_level,
                 pkw: dict) -> LightAwareEstimate:
    """The photometric fit of :func:`light_aware_estimates` on the ROI ``big``, its depth within
    the ceiling: on the three linear channels where ``colour`` (the least-fluctuation projection's
    or the darkest channel's fit standing in where the body colours' cannot), else on ``gray``."""
    fit_values, fit_clip = gray[big.slices], saturation_level
    if colour:
        # the ROI's three linear channels: the fit projects the tissue's body colours out
        # (photometric_fit's values (H, W, 3)), which takes the albedo's texture with them
        fs = response.full_scale(img)
        sub = img[big.slices]
        fit_values = np.stack([response.linear(sub[..., c], c, fs) for c in range(3)], axis=-1)
        fit_clip = [float(response.linear(fs, c, fs)) for c in range(3)]
    pkw = dict(clip_level=fit_clip, **pkw)
    if response is not None and not colour and img.ndim == 3:
        # one channel of a sensor frame whose colours cannot be projected out (a JPEG grid):
        # the albedo's dark lines (vessels) are left out of the fit (model.albedo_lines)
        y = luma(img[big.slices])
        pkw["exclude"] = _la.model.albedo_lines(y, 1.0 if img.dtype.kind in "ui" else 0.0,
                                                noise_sigma(y) if min(y.shape) >= 3 else 0.0)

    def fitted(projection: str) -> LightAwareEstimate:
        """The photometric fit on ``projection``, guarded, before the depth ceiling."""
        return _guarded("photometric_fit", photometric_fit, fit_values, (big.col0, big.row0), est.bp_px,
                        camera, rig, projection=projection, **pkw)

    first = fitted("auto")
    # its depth within the ceiling before the curved fits' turn is decided by its status
    pf = depth_within_ceiling(first)
    if colour and first.ok and not pf.ok and first.projection == "body_colours":
        # the body colours' depth above the ceiling: the least-fluctuation weights' fit where it
        # is ok within it (as photometric_fit's "auto" projection does for a fit without depth)
        lf = depth_within_ceiling(fitted("least_fluctuation"))
        if lf.ok and lf.projection == "least_fluctuation":
            why = "the body colours' depth is above the ceiling"
            pf = dataclasses.replace(lf, detail=f"{lf.detail}; {why}" if lf.detail else why)
    if colour and ((not pf.ok and pf.projection == "least_fluctuation")
                   or (pf.projection == "body_colours" and pf.curvature_shift_deg is None
                       and pf.status in ("depth_not_observable", "not_converged"))):
        # the darkest channel's fit stands in for a least-fluctuation fit without its depth within
        # the ceiling and for a body colours' fit without its depth; a misfit of theirs stands
        # (rule 4 may confirm its normal), as does a fit kept with a curved patch's pattern
        # (docs/decisions/light-aware-recommendation.md, "The projections' fallbacks")
        why = f"the {pf.projection.replace('_', ' ')} projection's fit: {pf.status}"
        chan = depth_within_ceiling(fitted("darkest_channel"))
        pf = dataclasses.replace(chan, detail=f"{chan.detail}; {why}" if chan.detail else why)
    return pf


def _curved_fits(out: dict, gray, shape, est, roi: Roi, camera, rig, *, saturation_level, nominal_depth_mm,
                 quadric_roi_scale, quadric, cubic) -> None:
    """The curved-patch fits of :func:`light_aware_estimates` added to ``out`` (which holds the
    photometric fit) as ``quadric`` and ``cubic`` say, and every fit of ``out`` released: its depth
    within the ceiling, the BP ray's error beside it set."""
    near = Roi.around(est.bp_px, quadric_roi_scale * max(roi.shape) / 2.0, shape)
    curved = out["photometric_fit"].status in CURVED_FIT_AFTER
    # a misfitting curved patch's sigma is read only where the plane misfits (rule 4), and only
    # below what rule 4 could take (docs/decisions/light-aware-recommendation.md, "The curved
    # fits' sigma")
    ray = _la.model._rays(camera, np.asarray(est.bp_px, dtype=np.float64)[None])[0]

    def released(r: LightAwareEstimate) -> LightAwareEstimate:
        """``r`` as returned: its depth within the ceiling, the BP ray's error beside it set."""
        r = depth_within_ceiling(_la.estimate.light_behind_surface(r, ray, rig.positions))
        return dataclasses.replace(
            r, bp_ray_error_deg=bp_ray_error_deg(ray, bp_error_depth_mm(r, nominal_depth_mm), rig))

    misfit_sigma: bool | float = bool(quadric)
    if out["photometric_fit"].status == "plane_misfit" and not quadric:
        # the plane as rule 4 reads it
        misfit_sigma = min(90.0, _bp_ray_error_beside(est, released(out["photometric_fit"])) / SIGMA_MARGIN)
    if quadric or (quadric is None and curved):
        out["quadric_fit"] = _guarded(
            "quadric_fit", quadric_fit, gray[near.slices], (near.col0, near.row0), est.bp_px, camera, rig,
            clip_level=saturation_level, nominal_depth_mm=nominal_depth_mm, misfit_sigma=misfit_sigma)
    if cubic or (cubic is None and curved and _several_lights(rig)):
        out["cubic_patch_fit"] = _guarded(
            "cubic_patch_fit", cubic_patch_fit, gray[near.slices], (near.col0, near.row0), est.bp_px, camera, rig,
            clip_level=saturation_level, nominal_depth_mm=nominal_depth_mm, misfit_sigma=bool(cubic))
    for name, r in out.items():
        out[name] = released(r)


def colour_fit_applies(image, response) -> bool:
    """Whether the photometric fit runs on a frame's three linear channels (the tissue's body
    colours projected out, :func:`~simtest.reconstruct.lightaware.colour.specular_image`): an RGB
    frame with a sensor response that shows no JPEG block grid
    (:func:`~simtest.reconstruct.jpeg.jpeg_grid`). A JPEG's chroma is subsampled (4:2:0) and
    blocky, and the projection is a colour difference: on the endoscope suite's colon wall at
    JPEG quality 50 to 75 the projected fits passed 6 to 17 deg off, where the darkest channel's
    misfit and the BP ray stood."""
    img = np.asarray(image)
    if response is None or img.ndim != 3:
        return False
    return img.dtype != np.uint8 or jpeg_grid(img) is None

def _isocurve_isophotes(gray, big: Roi, bp_uv, refine: bool = True) -> tuple[list[np.ndarray], list[float]]:
    """The isophotes :func:`isocurve_fit` is given (module docstring, "Isophotes of the isocurve
    fit"): at each of :data:`ISOCURVE_ISOVALUES` of the BP's height above the median of the
    ROI's border, the closed contour about the BP, its points refined onto the image's cubic
    spline (as ``refine`` says); levels whose contour is cut or too short are left out.

    Returns
    -------
    (list of ndarray of shape (N_k, 2), list of float)
        The points (u, v), px, and their isovalues.
    """
    vals = np.asarray(gray[big.slices], dtype=np.float64)
    border = np.concatenate([vals[0], vals[-1], vals[:, 0], vals[:, -1]])
    base = float(np.median(border))
    c, r = int(round(bp_uv[0])) - big.col0, int(round(bp_uv[1])) - big.row0
    peak = float(vals[max(r - 1, 0):r + 2, max(c - 1, 0):c + 2].max())
    if not peak > base:
        return [], []
    origin = (big.col0, big.row0)
    pts, ts = [], []
    for t in ISOCURVE_ISOVALUES:
        level = base + t * (peak - base)
        iso = extract_isophote(vals, level, bp_uv, origin_rc=(big.row0, big.col0), image_shape=gray.shape)
        if not iso or iso.points_uv is None or len(iso.points_uv) < 6:
            continue
        pts.append(refine_isophote_points(vals, level, iso.points_uv, origin) if refine else iso.points_uv)
        ts.append(t)
    return pts, ts

def _guarded(name: str, fit, *args, **kwargs) -> LightAwareEstimate:
    """``fit(*args, **kwargs)``, or a ``not_converged`` estimate named ``name`` when the solver
    refuses the highlight (scipy raises ValueError for residuals that are not finite at the
    start; a singular or overflowing model raises LinAlgError or an ArithmeticError): one
    highlight's failure is a status, never the frame's."""
    try:
        return fit(*args, **kwargs)
    # ArithmeticError: FloatingPointError, OverflowError and a ZeroDivisionError of a fit run off
    except (ValueError, np.linalg.LinAlgError, ArithmeticError) as exc:
        return LightAwareEstimate(name, "not_converged", f"{type(exc).__name__}: {exc}")


def with_light_aware(image, estimates, camera, rig: LightRig | None, *, on_highlight=None,
                     fit_rejected: bool = False, workers: int = 1, **kwargs) -> list:
    """The estimates with their light-aware results attached (``light_aware``).

    Nothing is run, and the estimates are returned unchanged, without a rig or with every light at
    the camera centre (the cone axes and the BP ray are then the estimators of choice,
    :mod:`~simtest.reconstruct.recommend`). By default only the accepted highlights (status ``ok``) are fitted: a rejected
    candidate keeps its status whatever its fits give, so its normal is not one to use, and on a
    whole frame the rejected candidates' fits are most of its time and end in misfits
    (``docs/decisions/light-aware-recommendation.md``). With ``fit_rejected`` every candidate the
    paper's ellipse rejected is fitted too (the fits need no ellipse: a two-light rig's lobes that
    merge into one highlight, or the harness scoring the estimators on every rendered highlight it
    matched), but never those whose status says they are no specular highlight of the tissue
    (:data:`NOT_FITTED`).

    Parameters
    ----------
    image : ndarray
        The image.
    estimates : sequence of SpecularityEstimate
        From :func:`~simtest.reconstruct.reconstruct`.
    camera : array_like of shape (3, 3) or CameraModel
        Intrinsics K or a camera model.
    rig : LightRig or None
        The scope's lights.
    on_highlight : callable, optional
        Called as ``on_highlight(done, total)`` after each highlight's fits (the command line's
        progress bar: the curved fits take up to seconds per highlight).
    fit_rejected : bool, optional
        Fit also the candidates rejected for a reason other than :data:`NOT_FITTED` (default: the
        accepted ones only).
    workers : int
        Worker processes the highlights' fits are shared among (1: in this process). Each
        highlight's fits read the image in its own ROI only, so the results are the same, bit for
        bit, whatever the number (``tests/test_lightaware_workers.py``); the image, camera, rig
        and arguments go to each worker once, the highlights one by one. This process and the
        workers run BLAS on one thread each (:func:`simtest._threads.one_thread_each`), with one
        worker too.
    **kwargs
        Passed to :func:`light_aware_estimates`.

    Returns
    -------
    list of SpecularityEstimate
        In the order of ``estimates``.

    Raises
    ------
    ValueError
        If ``workers`` is below 1.
    """
    if workers < 1:
        raise ValueError(f"workers must be at least 1, got {workers}")
    if not _offset_rig(rig):
        return list(estimates)
    def fitted(est) -> bool:
        return est.ok or (fit_rejected and est.status not in NOT_FITTED)

    if kwargs.get("response") is not None and "linear" not in kwargs:
        kwargs = dict(kwargs, linear=kwargs["response"].linearize(np.asarray(image)))
    if "colour" not in kwargs:
        kwargs = dict(kwargs, colour=colour_fit_applies(image, kwargs.get("response")))
    out = list(estimates)
    todo = [i for i, est in enumerate(out) if fitted(est)]
    # the others are marked with no fits ({}): under a rig off the camera centre the co-located
    # estimators' normals are not recommended (rule 1: the BP ray), as for a fitted highlight
    # whose fits all fail (a rejected candidate with a joint cone axis would otherwise get it)
    skipped = set(range(len(out))).difference(todo)
    for i in sorted(skipped):
        if out[i].light_aware is None:
            out[i] = dataclasses.replace(out[i], light_aware={})
    # one BLAS thread here as in the workers: a product summed over many pixels on several
    # threads differs in its last bits, which a fit's iterations carry to its results
    with one_thread_each():
        if workers > 1 and len(todo) > 1:
            for name in ("scipy.optimize", "scipy.ndimage"):  # imported once here, not in each worker
                require(name)
            with worker_pool(min(workers, len(todo)), initializer=_fit_context,
                             initargs=(image, camera, rig, kwargs)) as pool:
                futures = {pool.submit(_fits_in_context, out[i]): i for i in todo}
                for done, fut in enumerate(as_completed(futures), 1):
                    i = futures[fut]
                    out[i] = dataclasses.replace(out[i], light_aware=fut.result())
                    if on_highlight is not None:
                        on_highlight(done, len(todo))
            return out
        for done, i in enumerate(todo, 1):
            out[i] = dataclasses.replace(out[i], light_aware=light_aware_estimates(image, out[i], camera,
                                                                                  rig, **kwargs))
            if on_highlight is not None:
                on_highlight(done, len(todo))
    return out


#: A worker's image, camera, rig and arguments of :func:`with_light_aware` (:func:`_fit_context`).
_CONTEXT: dict = {}


def _fit_context(image, camera, rig, kwargs) -> None:
    """A worker's initializer: what every highlight's fits share, received once."""
    _CONTEXT.update(image=image, camera=camera, rig=rig, kwargs=kwargs)


def _fits_in_context(est) -> dict[str, LightAwareEstimate]:
    """:func:`light_aware_estimates` of one highlight in a worker (:func:`_fit_context`)."""
    c = _CONTEXT
    return light_aware_estimates(c["image"], est, c["camera"], c["rig"], **c["kwargs"])
