"""The photometric plane fit: the ROI's intensities fitted with the image of a plane lit by the rig.

:func:`photometric_fit` runs in stages, each its own function or module: the choice among the
colour projections, start depths and two-channel pixels (:func:`_fit_projections`), the choice
of lobe (:func:`_fit_lobes`), and one fit (:func:`_fit_plane`): the projection of a colour ROI
onto one image (:func:`_colour_values`), the lobe model on its pixels
(:mod:`~simtest.reconstruct.lightaware.plane_model`), the starts and the solve
(:mod:`~simtest.reconstruct.lightaware.plane_solve`), the covariance and the misfit tests
(:mod:`~simtest.reconstruct.lightaware.plane_sigma`). Its options travel as one
:class:`FitSettings`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from simtest.decisions import TWO_CHANNEL_Z
from simtest.geometry.angles import angle_between_deg
from simtest.geometry.lights import LightRig
from simtest.tolerances import TOL
from simtest.reconstruct.lightaware.estimate import LightAwareEstimate
from simtest.reconstruct.lightaware.colour import per_channel, specular_image
from simtest.reconstruct.lightaware.model import _normal_derivs, phong_of_ggx_alpha
from simtest.reconstruct.lightaware.plane_model import PlaneModel
from simtest.reconstruct.lightaware.plane_sigma import PlaneVerdict
from simtest.reconstruct.lightaware.plane_solve import solve_plane, start_planes
from simtest.reconstruct.lightaware.solve import _finish, _implausible, _start


#: Starts along the BP's constraint of ``photometric_fit``'s second try on the sensor path
#: (``n_start_depths`` None): depths nominal/8 to nominal*8 at factors of 4, the range of a
#: colonoscope's working distances (5 to 50 mm about a nominal 20).
RETRY_START_DEPTHS = 4

#: The values of ``photometric_fit``'s ``projection``.
PROJECTIONS = ("auto", "border", "least_fluctuation", "darkest_channel")

#: The values of ``photometric_fit``'s ``lobe``.
LOBES = ("phong", "ggx", "auto")


@dataclass(frozen=True, eq=False, kw_only=True)
class FitSettings:
    """The options of :func:`photometric_fit`, which travel together through its stages.

    Attributes
    ----------
    clip_level : float or sequence of 3 floats, optional
        Pixels ``>= clip_level`` are left out (e.g. 255 for 8-bit); None keeps every pixel. For
        RGB values, one level or each channel's: a pixel with a clipped channel is censored where
        the projection's weights of its clipped channels are all >= 0 (its projected value is
        then a lower bound), else left out.
    clip_margin : float or sequence of 3 floats, optional
        RGB values: a channel within this of its clip level counts as clipped too, as
        ``clip_level``'s units (the body colours are measured on what the clip itself left;
        :func:`~simtest.reconstruct.lightaware.colour.specular_image`'s ``censor_margin``). None: 0.
    nominal_depth_mm : float
        Depth of the BP assumed for the start's bisector, mm.
    start_normal : array_like of shape (3,), optional
        Start normal (e.g. from :func:`isocurve_fit`).
    start_roughness : float, optional
        Start Phong n.
    pair_starts : tuple of (int, int, float)
        (i, j, d): the BP as light i's specular point at depth d (mm along its ray) puts light j's
        where another highlight lies (:func:`~simtest.reconstruct.rig_pairs.pair_starts`):
        without a start normal, light i's start at d is refined beside the start at the nominal
        depth, the solution of least cost kept.
    loss : str
        ``linear`` (Gaussian sensor noise), or ``soft_l1``, ``huber``, ``cauchy`` (reweighted).
    f_scale : float
        Soft margin of a robust loss, relative to the ROI's maximum.
    n_start_depths : int or None
        Further starts along the BP's constraint (depths nominal/8 to nominal*8), each refined;
        the solution of least cost is kept (0: the start, and the nominal bisector when a start is
        given). None (default): 0, and for RGB values (the sensor path), where that fit ends
        without a depth (``depth_not_observable``, ``not_converged``), once more with
        :data:`RETRY_START_DEPTHS` starts, the one of the lower residual kept: a sensor frame's
        clipped cores leave the lobes' flanks, on which a start at the nominal depth can end in a
        local minimum (measured: ``docs/decisions/light-aware-recommendation.md``).
    supersample : int
        s x s point samples per pixel, averaged (a renderer's or sensor's box filter; 1: the
        value at the pixel centre, as the exact images of :mod:`simtest.simulate.offset`).
    max_pixels : int or None
        Beyond this many unclipped pixels, the starts are refined on a regular sub-grid (every
        k-th row and column; None: every pixel), and the best of them, with ``refine_all`` and
        where the plane explains the sub-grid (its residuals pass the misfit test), once more on
        every unclipped pixel. Where the plane misfits, the model's error, not the noise,
        dominates and more pixels of it would not help: the sub-grid's fit is kept, and so is
        it where pixels lie at ``floor_level`` (noise clipped there biases the fit, and more
        pixels would shrink its sigma about that bias). Every pixel of the lobe's tails matters:
        the tilt and the distance trade off along the BP's constraint, and what separates them
        is the lobe's shape down to its faint tails (measured: ``docs/decisions``' light-aware file).
    refine_all : bool
        Refine the sub-grid's solution on every unclipped pixel (above); False keeps the
        sub-grid's (about k^2 times cheaper, its standard deviations k times larger).
    diffuse : bool
        Add the rig's Lambertian shading of the plane as a column of the model beside the lobes
        and the background (its albedo a linear parameter; :func:`photometric_fit`, Notes): the
        image of tissue, whose diffuse shading under a near light is no linear background. The lobe is then taken for
        real only up to :data:`~simtest.reconstruct.lightaware.solve.ROUGHEST_FILM_ALPHA`
        (GGX alpha 0.5, Phong n 6): broader, it is as broad as the shading, the two columns
        trade one for the other, and the fit is ``not_converged`` (its detail names the
        roughness).
    censor : bool
        Keep the pixels at or above ``clip_level`` as censored data (the pixel's radiance is at
        least the clip level: a residual only where the model falls below it) instead of leaving
        them out.
    max_nfev : int
        Evaluation budget.
    floor_level : float, optional
        The image's floor (e.g. 0 for an 8-bit image): pixels at or below it are clipped from
        below, their noise cut off, and where the model lies within ``_FLOOR_MARGIN`` (3) noise
        sigmas of the floor (the noise sigma from the residuals' median absolute deviation) the
        mean of the clipped data is above the model's, a bias proportional to the noise. The
        curvature test (Returns) reads only the pixels above that margin. None: no floor.
    floor_refit : bool
        With ``floor_level``, refine the fit once more without the pixels within the margin
        (where every pixel was fitted): it halves the floor's bias, and is off by default as on
        the ``lightaware`` suite's noisy renders it cost the tails' information (measured:
        ``docs/decisions``' light-aware file); a censored likelihood would keep it.
    floor_step : float
        The image's quantisation step at the floor (1 for an 8-bit image): the refinement runs
        only where the noise sigma exceeds it (below, the floor's pixels are rounding's, not
        clipped noise, whose levels near 0 carry the tails' information).
    projection : {"auto", "border", "least_fluctuation", "darkest_channel"}
        For RGB values, the projection that removes the tissue's body colours
        (:func:`~simtest.reconstruct.lightaware.colour.specular_image`): ``"border"`` the one
        orthogonal to the two body colours measured on the ROI's border, or where the border
        tells no second one, the darkest channel; ``"least_fluctuation"`` the least-fluctuation
        weights (``colour._least_fluctuation_weights``: the body colours lost in read noise), or
        where they are beyond their bound, the darkest channel; ``"darkest_channel"`` that
        channel alone. ``"auto"`` (default): the border's body colours, and where their fit
        ends without a depth (``depth_not_observable``, ``not_converged``; a misfit stands), the
        least-fluctuation weights' fit in its place where that one is ``ok``; where the border
        tells no second body colour, the least-fluctuation weights, and where the fit on those
        is not ``ok`` (a misfit, a depth not observable), the darkest channel's fit in its place.
        The weights trade the texture they leave in against the noise, and the fit cannot see
        what they leave: it is kept only where it passes with its depth. A JPEG frame whose
        block grid is not seen (at quality 95): its subsampled chroma leaves a pattern in the
        least-fluctuation projection's residual that the curvature test reads as a curved patch
        (measured: ``docs/decisions/light-aware-recommendation.md``).
    exclude : ndarray of shape (H, W) of bool, optional
        ROI pixels left out of the fit, as clipped pixels are without ``censor`` (the albedo's
        dark lines: :func:`~simtest.reconstruct.lightaware.model.albedo_lines`).
    two_channels : bool or None
        For RGB values, the pixels clipped in one channel whose projection weight is negative
        (a red tissue's own reflection beside the lobe): True, valued from their two other
        channels (:func:`~simtest.reconstruct.lightaware.colour.specular_image`); False, left out.
        None (default): the fit without them, and where it is ``ok`` on a projection of the
        three channels and the ROI holds such pixels, the fit with them in its place where the
        two agree (:func:`_two_channel_choice`).
    lobe : {"phong", "ggx", "auto"}
        The specular lobe of the model: Phong's ``max(0, cos beta)^n`` (the paper's eq. 1), a GGX
        microfacet lobe under a dielectric film (the renderer's tissue,
        :func:`~simtest.reconstruct.lightaware.model._rig_value_ggx`: roughness alpha, Fresnel
        at :data:`~simtest.reconstruct.lightaware.model.GGX_FILM_IOR`, Smith's shadowing), or
        both fitted and the one chosen by the Bayesian information criterion of the residual
        (:func:`photometric_fit`, Notes). The estimate's ``lobe`` says which; its ``roughness``
        is Phong's n, or for GGX the Phong n of the same peak curvature (``2 / alpha^2 - 2``).

    Raises
    ------
    ValueError
        A ``lobe`` or ``projection`` not among :data:`LOBES` and :data:`PROJECTIONS`.
    """

    clip_level: Any = None
    clip_margin: Any = None
    nominal_depth_mm: float = 20.0
    start_normal: Any = None
    start_roughness: float | None = None
    pair_starts: tuple = ()
    loss: str = "linear"
    f_scale: float = 0.02
    supersample: int = 1
    n_start_depths: int | None = None
    diffuse: bool = False
    censor: bool = False
    max_pixels: int | None = 16384
    refine_all: bool = True
    max_nfev: int = 200
    lobe: str = "phong"
    floor_level: float | None = None
    floor_refit: bool = False
    floor_step: float = 0.0
    projection: str = "auto"
    exclude: Any = None
    two_channels: bool | None = None

    def __post_init__(self):
        if self.lobe not in LOBES:
            raise ValueError(f"lobe: {self.lobe!r} is not one of phong, ggx, auto")
        if self.projection not in PROJECTIONS:
            raise ValueError(f"projection: {self.projection!r} is not one of {', '.join(PROJECTIONS)}")


def photometric_fit(values, origin_uv, bp_uv, camera, rig: LightRig, settings: FitSettings | None = None,
                    **options) -> LightAwareEstimate:
    """Fit the intensities of an ROI with the image of a plane lit by the whole rig.

    Model (package docstring): ``I = g sum_j w_j max(0, cos beta_j)^n f_j p_j + b0 + b1 du + b2 dv``
    per pixel centre; the linear parameters (g, b0, b1, b2) are solved for each value of the
    nonlinear ones (a, b, log h, log n) by linear least squares (variable projection, Notes), and
    those four are fitted by Levenberg-Marquardt (MINPACK through
    :func:`scipy.optimize.leastsq`, analytic Jacobian). Pixels at or above ``clip_level`` are left
    out (a saturated plateau carries no shape). A two-light rig's merged highlight is one model.
    The roughness starts from a log-log regression of the ROI's specular part on the start's
    cos beta (``log(I - b) - log(f p) = log g + n log cos beta``), refined by a few Gauss-Newton
    steps on log n alone with the start plane held, unless given.

    Parameters
    ----------
    values : ndarray of shape (H, W) or (H, W, 3)
        ROI intensities (float, any unit); or the ROI's linear RGB with the white balance undone
        (the specular reflection white), which is fitted on its specular image: the tissue's
        body colours, measured on the ROI's border, projected out
        (:func:`~simtest.reconstruct.lightaware.colour.specular_image`: the albedo's texture
        leaves the fit), or where they are too near white, the channel where the tissue is
        darkest. The estimate's detail says which. A projected fit that passes is checked on
        the darkest channel too (started from its solution): where that fit misfits, so does
        the estimate (a curved patch is curved in every channel).
    origin_uv : array_like of shape (2,)
        Pixel (u, v) of ``values[0, 0]`` in the image.
    bp_uv : array_like of shape (2,)
        Brightest point, undistorted px (for the start).
    camera : array_like of shape (3, 3) or CameraModel
        Intrinsics K, or a camera model with ``pixel_to_ray``.
    rig : LightRig
        The lights, camera frame, mm.
    settings : FitSettings, optional
        The fit's options (defaults: ``FitSettings()``).
    **options
        Any of :class:`FitSettings`' attributes by name (``clip_level``, ``lobe``, ``diffuse``,
        ...), over ``settings``'.

    Returns
    -------
    LightAwareEstimate
        ``estimator="photometric_fit"``, with ``roughness``. Status ``plane_misfit`` (normal kept,
        depth withdrawn) when the plane model does not explain the ROI (a curved patch, whose
        lobe the plane model reproduces by trading the curvature for roughness and distance, and
        so misses the normal). Without the diffuse column, censored pixels and the GGX lobe: when
        the residuals of neighbouring pixels correlate (``_misfit``), or the residual holds the
        pattern a curvature of the patch would make (the score test of
        :func:`~simtest.reconstruct.lightaware.solve._curvature_score`, which sees a sphere at
        1 % noise where the neighbours' correlation does not). With them (the sensor path), by
        that score test alone, scored against the residual's own spatially correlated noise: a
        textured albedo under the rig's diffuse light correlates neighbouring residuals of an
        exact plane, which that test tells from a curvature. On both paths the sigmas of a fit
        that passes count the residual's correlation area (an integer image's rounding of a
        smooth lobe correlates its residual too), on the sensor path also the cluster
        jackknife's (``counted`` in the source). A curved patch's pattern that would move the
        normal by no more than that sigma (a micro-relief's random curvatures over the lobe,
        which the score test sees on thousands of pixels) does not make a misfit: the fit is
        kept with its sigmas grown by the shift, which ``curvature_shift_deg`` gives
        (:func:`~simtest.reconstruct.lightaware.solve._curvature_shift`); ``lobe="auto"`` then
        tries the GGX lobe too, and prefers a lobe whose residual holds no such pattern.

    Raises
    ------
    ValueError
        A values array that is not 2-D and finite, or an option out of its range
        (:class:`FitSettings`).

    Notes
    -----
    Variable projection [3]_. The background columns ``B = [1, du, dv]`` (M, 3) do not depend on
    the nonlinear parameters p: with Q an orthonormal basis of B and ``P = I - Q Q^T``, the values
    and the lobe image S(p) (M,) are projected once each, ``y~ = P y`` and ``a = P S``; the gain
    is then ``g = a . y~ / a . a`` and the residual ``r = g a - y~`` is exactly that of the full
    linear least squares in (g, b0, b1, b2) at p (pixel by pixel, so the residual tests of
    ``_misfit`` read it unchanged). Its exact Jacobian (Golub and Pereyra) with ``da = P dS``:
    ``dr = g (da - a (a . da) / (a . a)) - a (r . da) / (a . a)``; the first term alone
    (Kaufman's), which is ``P_[S, B] (g dS)``, gives the covariance, equal to the (a, b, log h,
    log n) block of the full eight-parameter ``s^2 (J^T J)^-1`` (a Schur complement), the
    residual variance counting all eight parameters. A robust loss reweights the rows: the
    linear part is then solved with the weights. Four parameters instead of eight, and the
    linear ones always at their optimum, take Levenberg-Marquardt fewer steps; with the start's
    roughness refined first it converges in about five evaluations on an exact image.

    With ``diffuse`` or censored pixels the linear part has a second column that depends on p
    (the shading ``D(p)``, :func:`~simtest.reconstruct.lightaware.model._rig_diffuse`) and an
    active set (a censored pixel enters, with the clip level as its value, where the model falls
    below it): the linear parameters are solved by least squares on the active rows at each p,
    and the Jacobian is Kaufman's, ``P_[S, D, B] (g dS + k dD)`` (k the albedo), for the fit and
    for the covariance alike.

    With ``lobe="auto"`` the Phong fit runs first; where its residuals say the model is wrong
    (``plane_misfit``) or it does not converge, the GGX fit runs, started from its plane and
    from the GGX roughness of the same peak curvature. The one kept (:func:`_choose_lobe`): a
    fit that converged over one that did not; a fit whose residuals pass the misfit test over
    one whose residuals do not; of two that pass, the lower Bayesian information criterion
    ``BIC = m log(RSS / m) + k log m`` over the m fitted residuals (a Gaussian likelihood with
    its variance profiled out [5]_: both models have the same k parameters, the plane, the
    roughness and the same linear part, so it keeps the lower residual sum of squares); of two
    that misfit, Phong. Why not the BIC there too: when the residuals of both correlate,
    neither lobe is the image's model and their likelihoods do not rank them (measured:
    ``docs/decisions/light-aware-recommendation.md``).

    References
    ----------
    .. [5] G. Schwarz, "Estimating the dimension of a model", Ann. Statist. 6(2), 1978.
           https://doi.org/10.1214/aos/1176344136
    """
    s = FitSettings(**options) if settings is None else replace(settings, **options)
    if s.n_start_depths is None:
        return _fit_projections(values, origin_uv, bp_uv, camera, rig, s)
    return _fit_lobes(values, origin_uv, bp_uv, camera, rig, s)


def _note(est: LightAwareEstimate, why: str) -> LightAwareEstimate:
    """``est`` with ``why`` appended to its detail."""
    return replace(est, detail=f"{est.detail}; {why}" if est.detail else why)


def _fit_projections(values, origin_uv, bp_uv, camera, rig, s: FitSettings) -> LightAwareEstimate:
    """``photometric_fit`` with ``n_start_depths`` None: the two-channel pixels' choice, the
    retry from further starts, and the colour projections' fallbacks (``FitSettings``'
    ``two_channels``, ``n_start_depths`` and ``projection``)."""
    fit = (values, origin_uv, bp_uv, camera, rig)
    rgb = np.ndim(values) == 3
    if s.two_channels is None:
        # without the pixels clipped in one channel, and where the ROI holds some, with them
        # valued from two channels, kept where the two agree (_two_channel_choice)
        plain = _fit_projections(*fit, replace(s, two_channels=False))
        if (plain.status != "ok" or not rgb
                or plain.projection not in ("body_colours", "least_fluctuation")
                or not _one_channel_clipped(values, s.clip_level)):
            return plain  # (the other is kept only beside an ok fit without them, on a projection)
        # refined from the plain fit, on its projection: the two are compared, and a fit
        # from further starts that agrees no better costs their time
        same = "border" if plain.projection == "body_colours" else plain.projection
        both = _fit_projections(*fit, replace(s, projection=same, two_channels=True,
                                              start_normal=plain.normal, start_roughness=plain.roughness))
        return _two_channel_choice(both, plain)
    first = _fit_lobes(*fit, replace(s, n_start_depths=0))
    best = first
    if rgb and first.status in ("depth_not_observable", "not_converged"):
        again = _fit_lobes(*fit, replace(s, n_start_depths=RETRY_START_DEPTHS))
        if again.has_normal and (not first.has_normal or first.residual_rms is None
                                 or (again.residual_rms is not None
                                     and again.residual_rms < first.residual_rms)):
            best = again
    if (rgb and s.projection == "auto" and best.projection == "body_colours"
            and best.status in ("depth_not_observable", "not_converged")):
        # the body colours' fit found no depth (a misfit is the surface's shape, seen in every
        # projection, and stands): the least-fluctuation weights' fit, kept where it is ok
        lf = _fit_projections(*fit, replace(s, projection="least_fluctuation"))
        if lf.ok and lf.projection == "least_fluctuation":
            return _note(lf, f"the body colours' fit is not ok ({best.status}: {best.detail})")
    if (rgb and s.projection == "auto" and best.status != "ok"
            and best.projection == "least_fluctuation"):
        chan = _fit_projections(*fit, replace(s, projection="darkest_channel"))
        return _note(chan, f"the least-fluctuation projection's fit is not ok ({best.status}: {best.detail})")
    return best


def _fit_lobes(values, origin_uv, bp_uv, camera, rig, s: FitSettings) -> LightAwareEstimate:
    """One lobe's fit (:func:`_fit_plane`), or with ``lobe="auto"`` Phong's, and where it does
    not fit, GGX's from its plane too, the one kept by :func:`_choose_lobe`."""
    fit = (values, origin_uv, bp_uv, camera, rig)
    if s.lobe != "auto":
        return _fit_plane(*fit, s)
    pho = _fit_plane(*fit, replace(s, lobe="phong"))
    if ((pho.ok or pho.status in ("depth_not_observable", "too_few_points"))
            and pho.curvature_shift_deg is None):
        return _note(pho, "phong lobe fits")
    ggx = _fit_plane(*fit, replace(s, start_normal=pho.normal if pho.has_normal else s.start_normal,
                                   start_roughness=pho.roughness if pho.has_normal else s.start_roughness,
                                   lobe="ggx"))
    return _choose_lobe(pho, ggx)


def _project(values, s: FitSettings):
    """The projection stage: the single image of a colour ROI (:func:`_colour_values`), or
    ``values`` itself. Returns ``(values, clip_level, lower, missing, detail, how, floor_level)``
    (the colour path's per-pixel censoring and gaps, or None; no floor on a projection of three
    channels)."""
    lower = missing = None
    detail, how = "", None
    clip_level, floor_level = s.clip_level, s.floor_level
    if np.ndim(values) == 3:
        values, clip_level, lower, missing, detail, how = _colour_values(values, clip_level, s.projection,
                                                                         bool(s.two_channels), s.clip_margin)
        if lower is not None:
            floor_level = None  # a projection of three channels has no floor of its own
    return values, clip_level, lower, missing, detail, how, floor_level


def _fit_plane(values, origin_uv, bp_uv, camera, rig, s: FitSettings) -> LightAwareEstimate:
    """One fit of one lobe (``s.lobe`` "phong" or "ggx") from ``s``'s starts: projection, lobe
    model, starts, solve, covariance; a projected fit that passes, checked on the darkest
    channel."""
    name = "photometric_fit"
    one, clip_level, lower, missing, colour_detail, how, floor_level = _project(values, s)
    m = PlaneModel(one, origin_uv, bp_uv, camera, rig, s, clip_level, lower, missing, s.lobe == "ggx")
    if np.count_nonzero(~m.cens) < 8 + 1 + int(s.diffuse):
        return LightAwareEstimate(name, "too_few_points", f"{np.count_nonzero(~m.cens)} unclipped pixels")
    d_bp, n0, h0 = _start(m.bp, m.camera, rig, s.nominal_depth_mm, s.start_normal)
    solved = solve_plane(m, start_planes(m, rig, d_bp, n0, h0, s), s, floor_level)
    if isinstance(solved, LightAwareEstimate):  # (its projection, for the fallbacks that read it)
        return replace(solved, projection=how)
    x, n0, h0, e1, e2, conv, msg, nfev = solved
    n_hat = _normal_derivs(x, n0, e1, e2)[0]
    h_hat = float(np.exp(x[2]))
    with np.errstate(over="ignore"):  # a fit run off to an infinite roughness: implausible below
        rough_hat = phong_of_ggx_alpha(float(np.exp(x[3]))) if m.ggx else float(np.exp(x[3]))
    bad = _implausible(h_hat, h0, rough_hat, shaded=s.diffuse)
    if bad:
        return LightAwareEstimate(name, "not_converged", bad, n_evaluations=nfev, projection=how)
    if np.any(n_hat @ m.rig_arr[0].T + h_hat <= 0):
        return LightAwareEstimate(name, "light_behind_plane", f"h = {h_hat:.4g} mm", n_evaluations=nfev)
    verdict = PlaneVerdict(m, rig, x, n0, e1, e2, n_hat, h_hat, rough_hat, how, floor_level)
    est = _finish(name, verdict.at_solution, n_hat, h_hat, rig, x[3:],
                  TOL.photometric_noise_rel, nfev, conv, roughness=rough_hat,
                  detail="" if conv else msg, n_linear=m.design.shape[1] if m.general else 4,
                  post=verdict.post)
    if colour_detail:
        est = _note(est, colour_detail)
    est = replace(est, lobe="ggx" if m.ggx else "phong", n_residuals=int(len(m.yn)), projection=how)
    if lower is not None and est.status in ("ok", "depth_not_observable"):
        # the shape check on the darkest channel: a curved patch is curved in every channel, and
        # the projection's residual can hide it (a JPEG frame's chroma, subsampled and blocky,
        # correlates the projected residual over blocks, against which the score test weighs
        # the curvature's pattern: on the colon wall JPEG frames' projected fits passed 6-15 deg off)
        c, clip_c = _darkest(values, s.clip_level, s.clip_margin)
        chan = _fit_lobes(np.asarray(values, dtype=np.float64)[..., c], origin_uv, bp_uv, m.camera, rig,
                          replace(s, clip_level=clip_c, clip_margin=None, start_normal=est.normal, start_roughness=None,
                                  n_start_depths=0, projection="auto", two_channels=None))
        if chan.status == "plane_misfit":
            est = est.without_depth("plane_misfit",
                                    f"channel {c}'s fit misfits ({chan.detail}); {est.detail}")
    return est


def _darkest(rgb, clip_level, margin=None) -> tuple[int, float | None]:
    """The channel of an RGB ROI whose median is least (where the tissue is darkest) and the
    level it is censored at: its clip level (``clip_level`` one number or each channel's; None)
    less its ``margin`` (``FitSettings.clip_margin``)."""
    rgb = np.asarray(rgb, dtype=np.float64)
    c = int(np.argmin(np.median(rgb.reshape(-1, 3), axis=0)))
    clip = None if clip_level is None else float(per_channel(clip_level)[c])
    if clip is not None and margin is not None:
        clip -= float(per_channel(margin)[c])
    return c, clip


def _colour_values(rgb, clip_level, projection: str = "auto", two_channels: bool = False, margin=None):
    """The single image a colour ROI is fitted on (``photometric_fit``'s ``values`` (H, W, 3)).

    Returns ``(values, clip_level, lower, missing, detail, how)``: the body-colour projection of
    :func:`~simtest.reconstruct.lightaware.colour.specular_image` (no scalar clip level; its
    censored and missing pixels), or, where it gives none (the border holds one body colour, or
    white lies too near them), the channel whose median is least (where the tissue is darkest)
    with that channel's clip level and no masks; ``how`` is the estimate's ``projection``
    (``"body_colours"``, ``"least_fluctuation"`` or ``"darkest_channel"``).
    """
    rgb = np.asarray(rgb, dtype=np.float64)
    out, how = None, None
    if projection in ("auto", "border"):
        out, how = specular_image(rgb, clip_level, fluctuation=False, two_channels=two_channels,
                                  censor_margin=margin), "body_colours"
    if out is None and projection in ("auto", "least_fluctuation"):
        out, how = specular_image(rgb, clip_level, border=False, two_channels=two_channels,
                                  censor_margin=margin), "least_fluctuation"
    if out is not None:
        values, lower, missing, w = out
        text = ("body colours projected out" if how == "body_colours"
                else "body colours projected out by the least-fluctuation weights")
        weights = ", ".join(f"{x:.3g}" for x in w)
        return values, None, lower, missing, f"{text} (w = {weights})", how
    c, clip = _darkest(rgb, clip_level, margin)
    why = (f"channel {c} (no two body colours to project out: the border holds one, or white lies "
           "too near them)")
    return rgb[..., c], clip, None, None, why, "darkest_channel"


def _one_channel_clipped(rgb, clip_level) -> bool:
    """Whether an RGB ROI holds a pixel clipped in exactly one channel (``clip_level`` one
    number or each channel's; None: nothing is clipped)."""
    if clip_level is None:
        return False
    return bool(np.any(np.count_nonzero(np.asarray(rgb) >= per_channel(clip_level), axis=2) == 1))


def _two_channel_choice(both: LightAwareEstimate, plain: LightAwareEstimate) -> LightAwareEstimate:
    """The fit with the pixels clipped in one channel valued from the other two (``both``:
    :func:`~simtest.reconstruct.lightaware.colour.specular_image`'s ``two_channels``), or the fit
    without them (``plain``), returned unchanged.

    ``both`` is kept where both fits are ``ok`` (``both`` on a projection of the three channels,
    its normal's sigma below the plain one's) and they agree as a Hausman test asks of an
    efficient and a consistent estimator [8]_: under the plane model both are consistent, the
    one with more pixels has the smaller variance, and their difference has the variance of
    the plain one's less the other's; the normals' angle and the depths' difference within
    ``TWO_CHANNEL_Z`` of those sigmas. Why a test: those pixels hold the second body colour's
    texture, which their two channels cannot remove; where a plane is not the surface, the
    fit with them can pass the curvature test with a smaller sigma and a wrong plane
    (measured: ``docs/decisions/light-aware-recommendation.md``).

    References
    ----------
    .. [8] J. A. Hausman, "Specification tests in econometrics", Econometrica 46(6), 1251-1271,
           1978. https://doi.org/10.2307/1913827
    """
    if not (plain.status == "ok" and both.status == "ok" and plain.has_normal and both.has_normal
            and both.projection in ("body_colours", "least_fluctuation")):
        return plain  # (on one channel no pixel is valued from two)
    sp, sb = plain.normal_sigma_deg, both.normal_sigma_deg
    dp, db = plain.depth_sigma_mm, both.depth_sigma_mm
    if None in (sp, sb, dp, db, plain.depth_mm, both.depth_mm) or not sb < sp:
        return plain  # (no more precise: nothing gained)
    gap = float(angle_between_deg(both.normal, plain.normal))
    room = TWO_CHANNEL_Z * math.sqrt(max(sp * sp - sb * sb, 0.0))
    dgap = abs(float(both.depth_mm) - float(plain.depth_mm))
    droom = TWO_CHANNEL_Z * math.sqrt(max(dp * dp - db * db, 0.0))
    if not (gap <= room and dgap <= droom):
        return plain
    why = (f"pixels clipped in one channel valued from the other two (the fit without them "
           f"agrees: {gap:.2g} deg and {dgap:.2g} mm apart, within {room:.2g} deg and {droom:.2g} mm)")
    return replace(both, detail=f"{both.detail}; {why}" if both.detail else why)


def _bic(est: LightAwareEstimate) -> float:
    """``m log(RSS / m)`` of a fit (its ``residual_rms`` over ``n_residuals``); the ``k log m``
    term is the same for both lobes (``photometric_fit``, Notes). +inf without a normal."""
    if not est.has_normal or est.residual_rms is None or not est.n_residuals:
        return math.inf
    return est.n_residuals * math.log(max(est.residual_rms, 1e-300) ** 2)


def _choose_lobe(pho: LightAwareEstimate, ggx: LightAwareEstimate) -> LightAwareEstimate:
    """The Phong or the GGX fit (``photometric_fit``'s Notes, ``lobe="auto"``); its detail names
    the other lobe's residual RMS."""
    def rank(e):
        failed = e.status == "not_converged" or not e.has_normal
        misfit = e.status == "plane_misfit"
        # a fit whose residual holds a curved patch's pattern (a misfit, or a fit kept with it:
        # curvature_shift_deg) after one whose residual holds none; of two such fits Phong
        # (neither lobe is the image's model, and their likelihoods do not rank them: measured
        # in docs/decisions); else the lower BIC
        flawed = misfit or e.curvature_shift_deg is not None
        return (failed, flawed, 0.0 if flawed and e is pho else (1.0 if flawed else _bic(e)))

    best, other = (pho, ggx) if rank(pho) <= rank(ggx) else (ggx, pho)
    if best is ggx and pho.status == "plane_misfit" and _bic(ggx) > _bic(pho):
        # the GGX fit, judged by the sensor path's test (which takes a correlated residual for a
        # texture), passes with a larger residual than the Phong fit that misfits: no better
        # model of the image, and Phong's misfit stands
        best, other = pho, ggx
    why = (f"{best.lobe} lobe: residual RMS {best.residual_rms:.4g} against {other.lobe}'s "
           f"{other.residual_rms:.4g}" if other.residual_rms is not None and best.residual_rms is not None
           else f"{best.lobe} lobe")
    return replace(best, detail=f"{best.detail}; {why}" if best.detail else why)
