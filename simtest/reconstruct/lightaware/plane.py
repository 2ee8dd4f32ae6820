"""The photometric plane fit: the ROI's intensities fitted with the image of a plane lit by the rig."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from simtest.geometry.angles import angle_between_deg, unit
from simtest.geometry.conics import plane_basis
from simtest.geometry.lights import LightRig
from simtest.tolerances import TOL
from simtest.reconstruct.lightaware.estimate import LightAwareEstimate
from simtest.reconstruct.lightaware.model import (
    _mean_light,
    _normal_derivs,
    _ray_light,
    _rays,
    _rig_arrays,
    _curvature_columns,
    _rig_diffuse,
    _rig_diffuse_grad,
    _rig_grad,
    _rig_value,
    _rig_value_ggx,
    _rig_grad_ggx,
    _roi_grid,
    ggx_alpha_of_phong,
    phong_of_ggx_alpha,
    _roi_samples,
    specular_image,
)
from simtest.reconstruct.lightaware.solve import (
    _ROUGHNESS_RANGE,
    _cluster_covariance,
    _correlated,
    _correlation_area,
    _curvature_score,
    _curvature_shift,
    _finish,
    _hac_covariance,
    _implausible,
    _misfit,
    _solve,
    _light_start,
    _start,
    cluster_blocks,
)


#: The residual of every pixel at a trial point where the model is not finite: far above any
#: residual of the normalised values (at most a few units), so that Levenberg-Marquardt rejects
#: the step and shortens it.
_NOT_FINITE_RESIDUAL = 1e6


#: Gauss-Newton steps on log n alone that refine the photometric fit's start roughness: on the
#: bench's exact highlight (n = 150) three steps from n = 50, 86 or 258 (the regression's starts
#: with cos beta with and without the falloff) end within 0.003 of log 150.
_ROUGHNESS_START_STEPS = 3


#: Phong roughnesses among which the start of a fit under several lights is chosen by its cost
#: (``photometric_fit``'s start roughness): a factor of 4 apart, from a lobe as broad as a
#: diffuse one to the smoothest film's range.
_START_ROUGHNESS_GRID = (4.0, 16.0, 64.0, 256.0, 1024.0, 4096.0)

#: The factor by which the grid's start roughness must lower the start plane's cost to replace
#: the regression's (``photometric_fit``'s start under several lights).
_START_ROUGHNESS_GAIN = 0.5


#: Starts along the BP's constraint of ``photometric_fit``'s second try on the sensor path
#: (``n_start_depths`` None): depths nominal/8 to nominal*8 at factors of 4, the range of a
#: colonoscope's working distances (5 to 50 mm about a nominal 20).
RETRY_START_DEPTHS = 4


#: Noise sigmas above the floor below which a fitted model's pixels are left out
#: (``photometric_fit``'s ``floor_level``): a Gaussian clipped at 3 sigma below its mean is
#: clipped in 0.13 % of draws, and its mean is raised by 0.0004 sigma.
_FLOOR_MARGIN = 3.0


def photometric_fit(values, origin_uv, bp_uv, camera, rig: LightRig, *,
                    clip_level: float | None = None, nominal_depth_mm: float = 20.0,
                    start_normal=None, start_roughness: float | None = None,
                    loss: str = "linear", f_scale: float = 0.02, supersample: int = 1,
                    n_start_depths: int | None = None, diffuse: bool = False, censor: bool = False,
                    max_pixels: int | None = 16384, refine_all: bool = True, max_nfev: int = 200,
                    lobe: str = "phong", floor_level: float | None = None,
                    floor_refit: bool = False, floor_step: float = 0.0,
                    projection: str = "auto", exclude=None,
                    two_channels: bool | None = None) -> LightAwareEstimate:
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
        (:func:`~simtest.reconstruct.lightaware.model.specular_image`: the albedo's texture
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
    clip_level : float or sequence of 3 floats, optional
        Pixels ``>= clip_level`` are left out (e.g. 255 for 8-bit); None keeps every pixel. For
        RGB values, one level or each channel's: a pixel with a clipped channel is censored where
        the projection's weights of its clipped channels are all >= 0 (its projected value is
        then a lower bound), else left out.
    nominal_depth_mm : float
        Depth of the BP assumed for the start's bisector, mm.
    start_normal : array_like of shape (3,), optional
        Start normal (e.g. from :func:`isocurve_fit`).
    start_roughness : float, optional
        Start Phong n.
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
        local minimum (the endoscope suite's flat mucosa at 10 mm: 11.4 deg off, its depth's
        relative sigma 4.7; from the further starts 0.16 deg, distance 1 % short).
    supersample : int
        s x s point samples per pixel, averaged (a renderer's or sensor's box filter; 1: the
        value at the pixel centre, as the exact images of :mod:`simtest.simulate.offset`).
    max_pixels : int or None
        Beyond this many unclipped pixels, the starts are refined on a regular sub-grid (every
        k-th row and column; None: every pixel), and the best of them, with ``refine_all`` and
        where the plane explains the sub-grid (its residuals pass the misfit test), once more on
        every unclipped pixel. Where the plane misfits, the model's error, not the noise,
        dominates and more pixels of it would not help: the sub-grid's fit is kept (on a
        rendered colonoscope frame's sensor image, whose highlights misfit, the refinement
        would take 40 to 440 thousand pixels per fit), and so is it where pixels lie at
        ``floor_level`` (noise clipped there biases the fit, and more pixels would shrink its
        sigma about that bias: an 8-bit plane with 1 % noise on black, epsilon/d 0.033, gave
        its depth 52 % short with a sigma of 17 %, ok, where the sub-grid's sigma withheld it).
        Every pixel of the lobe's
        tails matters: the tilt and the distance trade off along the BP's constraint, and what
        separates them is the lobe's shape down to its faint tails (a fit to the pixels above
        2 % of the peak lost a factor of 3 to 5 in accuracy against the Cramer-Rao bound; on a
        sub-grid of every second row and column the normal's error was 1.4 to 3.2 times the bound
        with 2 % read noise, refined on every pixel 0.9 to 1.2 times).
    refine_all : bool
        Refine the sub-grid's solution on every unclipped pixel (above); False keeps the
        sub-grid's (about k^2 times cheaper, its standard deviations k times larger).
    diffuse : bool
        Add the rig's Lambertian shading of the plane as a column of the model beside the lobes
        and the background (its albedo a linear parameter; Notes): the image of tissue, whose
        diffuse shading under a near light is no linear background. The lobe is then taken for
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
        (where every pixel was fitted). On an exact 8-bit plane on a black background with 1 %
        read noise (epsilon/d 0.033, 20 noise realisations) the normal was otherwise 0.39 deg
        off on average in one direction, its spread 0.44, its sigma 0.31 (77 % of errors within
        2 sigma); refined, 0.19 off, spread 0.51, sigma 0.62. Off by default: on the
        ``lightaware`` suite's noisy renders it cost the tails' information (its
        plane_noise_offset cases' photometric fit 0.21 to 0.31 deg mean at 1 % noise, 1.36 to
        3.28 at 2 %); a censored likelihood (the clipped pixel's probability) would keep it.
    floor_step : float
        The image's quantisation step at the floor (1 for an 8-bit image): the refinement runs
        only where the noise sigma exceeds it (below, the floor's pixels are rounding's, not
        clipped noise, and leaving out the levels near 0 of a noise-free 8-bit render took the
        tails' information: plane_tilt_offset@40 0.024 to 0.072 deg mean).
    projection : {"auto", "border", "least_fluctuation", "darkest_channel"}
        For RGB values, the projection that removes the tissue's body colours
        (:func:`~simtest.reconstruct.lightaware.model.specular_image`): ``"border"`` the one
        orthogonal to the two body colours measured on the ROI's border, or where the border
        tells no second one, the darkest channel; ``"least_fluctuation"`` the least-fluctuation
        weights (``model._least_fluctuation_weights``: the body colours lost in read noise), or
        where they are beyond their bound, the darkest channel; ``"darkest_channel"`` that
        channel alone. ``"auto"`` (default): the border's body colours, and where their fit
        ends without a depth (``depth_not_observable``, ``not_converged``; a misfit stands), the
        least-fluctuation weights' fit in its place where that one is ``ok`` (on an exact 8-bit
        plane of strongly absorbing vessels, one body colours' fit ended 5.4 deg off with its
        depth not observable and a sigma of 0.39 deg); where the border tells no second body
        colour, the least-fluctuation weights, and where the fit on those is not ``ok`` (a
        misfit, a depth not observable), the darkest channel's fit in its place. The weights
        trade the texture they leave in against the noise, and the fit cannot see what they
        leave: it is kept only where it passes with its depth. A JPEG frame whose block grid is
        not seen (at quality 95): its subsampled chroma leaves a pattern in the
        least-fluctuation projection's residual that the curvature test reads as a curved
        patch; on the endoscope suite's flat mucosa, before the border's body colours were told
        there (``model._BODY_SECOND_SNR``), that fit misfit 0.3 deg off, and the recommendation
        fell back to the BP ray, 6 deg off, where the darkest channel's fit passes 0.6 deg off.
        On its colon wall one such fit passed with its depth not observable, 17.5 deg off with
        a sigma of 1.7 deg, and was recommended over the BP ray (2.3 deg).
    exclude : ndarray of shape (H, W) of bool, optional
        ROI pixels left out of the fit, as clipped pixels are without ``censor`` (the albedo's
        dark lines: :func:`~simtest.reconstruct.lightaware.model.albedo_lines`).
    two_channels : bool or None
        For RGB values, the pixels clipped in one channel whose projection weight is negative
        (a red tissue's own reflection beside the lobe): True, valued from their two other
        channels (:func:`~simtest.reconstruct.lightaware.model.specular_image`); False, left out.
        None (default): the fit without them, and where it is ``ok`` on a projection of the
        three channels and the ROI holds such pixels, the fit with them in its place where the
        two agree (:func:`_two_channel_choice`).
    lobe : {"phong", "ggx", "auto"}
        The specular lobe of the model: Phong's ``max(0, cos beta)^n`` (the paper's eq. 1), a GGX
        microfacet lobe under a dielectric film (the renderer's tissue,
        :func:`~simtest.reconstruct.lightaware.model._rig_value_ggx`: roughness alpha, Fresnel
        at :data:`~simtest.reconstruct.lightaware.model.GGX_FILM_IOR`, Smith's shadowing), or
        both fitted and the one chosen by the Bayesian information criterion of the residual
        (Notes). The estimate's ``lobe`` says which; its ``roughness`` is Phong's n, or for GGX
        the Phong n of the same peak curvature (``2 / alpha^2 - 2``).

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
        A values array that is not 2-D and finite.

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
    neither lobe is the image's model and their likelihoods do not rank them. On the endoscope
    suite's sensor frames of flat mucosa both misfit (the albedo's texture dominates the
    residual of a whole-frame ROI, and the lobe inside the clipped core leaves only its contour),
    and the GGX fit's residual sum of squares was the lower by 0.7 % where its normal erred by
    1.03 deg against Phong's 0.58.

    References
    ----------
    .. [5] G. Schwarz, "Estimating the dimension of a model", Ann. Statist. 6(2), 1978.
           https://doi.org/10.1214/aos/1176344136
    """
    if lobe not in ("phong", "ggx", "auto"):
        raise ValueError(f"lobe: {lobe!r} is not one of phong, ggx, auto")
    if projection not in PROJECTIONS:
        raise ValueError(f"projection: {projection!r} is not one of {', '.join(PROJECTIONS)}")
    if n_start_depths is None:
        kw = dict(clip_level=clip_level, nominal_depth_mm=nominal_depth_mm, start_normal=start_normal,
                  start_roughness=start_roughness, loss=loss, f_scale=f_scale, supersample=supersample,
                  diffuse=diffuse, censor=censor, max_pixels=max_pixels, refine_all=refine_all,
                  max_nfev=max_nfev, lobe=lobe, floor_level=floor_level, floor_refit=floor_refit,
                  floor_step=floor_step, exclude=exclude)
        if two_channels is None:
            # without the pixels clipped in one channel, and where the ROI holds some, with them
            # valued from two channels, kept where the two agree (_two_channel_choice)
            plain = photometric_fit(values, origin_uv, bp_uv, camera, rig, projection=projection,
                                    two_channels=False, **kw)
            if (plain.status != "ok" or np.ndim(values) != 3
                    or plain.projection not in ("body_colours", "least_fluctuation")
                    or not _one_channel_clipped(values, clip_level)):
                return plain  # (the other is kept only beside an ok fit without them, on a projection)
            # refined from the plain fit, on its projection: the two are compared, and a fit
            # from further starts that agrees no better costs their time
            same = "border" if plain.projection == "body_colours" else plain.projection
            both = photometric_fit(values, origin_uv, bp_uv, camera, rig, projection=same, two_channels=True,
                                   **{**kw, "start_normal": plain.normal, "start_roughness": plain.roughness})
            return _two_channel_choice(both, plain)
        kw["two_channels"] = two_channels
        first = photometric_fit(values, origin_uv, bp_uv, camera, rig, n_start_depths=0,
                                projection=projection, **kw)
        best = first
        if np.ndim(values) == 3 and first.status in ("depth_not_observable", "not_converged"):
            again = photometric_fit(values, origin_uv, bp_uv, camera, rig,
                                    n_start_depths=RETRY_START_DEPTHS, projection=projection, **kw)
            if again.has_normal and (not first.has_normal or first.residual_rms is None
                                     or (again.residual_rms is not None
                                         and again.residual_rms < first.residual_rms)):
                best = again
        if (np.ndim(values) == 3 and projection == "auto" and best.projection == "body_colours"
                and best.status in ("depth_not_observable", "not_converged")):
            # the body colours' fit found no depth (a misfit is the surface's shape, seen in every
            # projection, and stands): the least-fluctuation weights' fit, kept where it is ok
            lf = photometric_fit(values, origin_uv, bp_uv, camera, rig, projection="least_fluctuation",
                                 **kw)
            if lf.ok and lf.projection == "least_fluctuation":
                why = f"the body colours' fit is not ok ({best.status}: {best.detail})"
                return replace(lf, detail=f"{lf.detail}; {why}" if lf.detail else why)
        if (np.ndim(values) == 3 and projection == "auto" and best.status != "ok"
                and best.projection == "least_fluctuation"):
            chan = photometric_fit(values, origin_uv, bp_uv, camera, rig, projection="darkest_channel", **kw)
            why = f"the least-fluctuation projection's fit is not ok ({best.status}: {best.detail})"
            return replace(chan, detail=f"{chan.detail}; {why}" if chan.detail else why)
        return best
    if lobe == "auto":
        kw = dict(clip_level=clip_level, nominal_depth_mm=nominal_depth_mm, loss=loss, f_scale=f_scale,
                  supersample=supersample, n_start_depths=n_start_depths, diffuse=diffuse, censor=censor,
                  max_pixels=max_pixels, refine_all=refine_all, max_nfev=max_nfev,
                  floor_level=floor_level, floor_refit=floor_refit, floor_step=floor_step,
                  projection=projection, exclude=exclude, two_channels=two_channels)
        pho = photometric_fit(values, origin_uv, bp_uv, camera, rig, start_normal=start_normal,
                              start_roughness=start_roughness, lobe="phong", **kw)
        if ((pho.ok or pho.status in ("depth_not_observable", "too_few_points"))
                and pho.curvature_shift_deg is None):
            return replace(pho, detail=f"{pho.detail}; phong lobe fits" if pho.detail else "phong lobe fits")
        ggx = photometric_fit(values, origin_uv, bp_uv, camera, rig,
                              start_normal=pho.normal if pho.has_normal else start_normal,
                              start_roughness=pho.roughness if pho.has_normal else start_roughness,
                              lobe="ggx", **kw)
        return _choose_lobe(pho, ggx)
    ggx = lobe == "ggx"
    name = "photometric_fit"
    lower = missing = None  # the colour path's per-pixel censoring (lower bounds) and gaps
    colour_detail, how = "", None
    rgb_in, floor_in, clip_in = values, floor_level, clip_level
    if np.ndim(values) == 3:
        values, clip_level, lower, missing, colour_detail, how = _colour_values(values, clip_level,
                                                                                projection, bool(two_channels))
        if lower is not None:
            floor_level = None  # a projection of three channels has no floor of its own
    censor = bool(censor and (clip_level is not None or lower is not None))
    vals, camera, o, uu, vv, keep = _roi_grid(values, camera, origin_uv,
                                              None if censor else clip_level)
    if lower is not None:
        keep &= ~missing if censor else ~(missing | lower)
    if exclude is not None:
        ex = np.asarray(exclude, dtype=bool)
        if ex.shape != keep.shape:
            raise ValueError(f"exclude: shape {ex.shape} is not the ROI's {keep.shape}")
        keep &= ~ex
    H, W = vals.shape
    border = np.concatenate([vals[0], vals[-1], vals[:, 0], vals[:, -1]])
    b_level = float(np.median(border))
    ss = int(supersample)
    if ss < 1:
        raise ValueError(f"supersample: must be >= 1, got {supersample!r}")
    offs = (np.arange(ss) + 0.5) / ss - 0.5
    sub = np.array([(du_, dv_) for dv_ in offs for du_ in offs])  # (ss^2, 2)
    rig_arr = _rig_arrays(rig)
    bp = np.asarray(bp_uv, dtype=np.float64).reshape(2)

    def samples(mp, keep_=keep):
        """The pixels fitted (every one of ``keep_``, or a sub-grid beyond ``mp``) and what the
        model needs of them: ``(sel, step, y, cens, general, dT, rl, yscale, yn, background,
        clipn, design)``."""
        sel_, step_, uv_, y_ = _roi_samples(vals, o, uu, vv, keep_, mp)
        if not censor:
            cens_ = np.zeros(len(y_), bool)
        else:
            cens_ = lower.ravel()[sel_] if lower is not None else y_ >= clip_level
        dT_ = np.ascontiguousarray(_rays(camera, (uv_[:, None, :] + sub[None]).reshape(-1, 2)).T)
        du_ = (uv_[:, 0] - bp[0]) / max(W, H)
        dv_ = (uv_[:, 1] - bp[1]) / max(W, H)
        yscale_ = max(float(np.abs(y_).max()), 1e-12)
        background_ = np.column_stack([np.ones_like(du_), du_, dv_])
        design_ = np.empty((len(y_), 5 if diffuse else 4))
        design_[:, -3:] = background_
        return (sel_, step_, y_, cens_, bool(diffuse or cens_.any() or ggx), dT_,
                _ray_light(rig_arr[0], dT_), yscale_, y_ / yscale_, background_,
                ((y_ / yscale_ if lower is not None else float(clip_level) / yscale_)
                 if censor else np.inf), design_)

    (sel, step, y, cens, general, dT, rl, yscale, yn, background, clipn,
     design) = samples(max_pixels)
    if np.count_nonzero(~cens) < 8 + 1 + int(diffuse):
        return LightAwareEstimate(name, "too_few_points", f"{np.count_nonzero(~cens)} unclipped pixels")
    d_bp, n0, h0 = _start(bp, camera, rig, nominal_depth_mm, start_normal)
    proj = {}  # orthonormal basis of the (weighted) background columns, per weights

    def basis(w):
        """``QT`` (3, M), the background's orthonormal basis (rows), and the projected values."""
        key = None if w is None else w.tobytes()
        if proj.get("key") != key or "QT" not in proj:
            B = background if w is None else background * w[:, None]
            QT = np.ascontiguousarray(np.linalg.qr(B)[0].T)
            yw = yn if w is None else yn * w
            proj.update(key=key, QT=QT, yt=yw - (QT @ yw) @ QT)
        return proj["QT"], proj["yt"]

    def box(v):
        """The mean of each pixel's sub-pixel samples (the last axis)."""
        return v if ss == 1 else v.reshape(*v.shape[:-1], -1, ss * ss).mean(axis=-1)

    state = {}

    def resjac_general(p, nb, e1, e2, grad=True, w=None, kaufman=False):
        """Residuals and Kaufman's Jacobian with the diffuse column and censored rows (Notes).

        Censored rows where the model is at or above the clip level have residual 0 and a zero
        Jacobian row; the others, the model minus the clip level.
        """
        key = (p.tobytes(), nb.tobytes(), None if w is None else w.tobytes(), "general")
        if state.get("key") != key:
            n, dns = _normal_derivs(p, nb, e1, e2)
            h, rough = float(np.exp(p[2])), float(np.exp(p[3]))
            if ggx:
                S, parts = _rig_value_ggx(dT, rl, n, h, rig_arr, rough), None
            else:
                S, parts = _rig_value(dT, rl, n, h, rig_arr, rough)
            design[:, 0] = box(S)
            if diffuse:
                design[:, 1] = box(_rig_diffuse(dT, rl, n, h, rig_arr))
            target = np.where(cens, clipn, yn)
            active = ~cens
            coef = np.zeros(design.shape[1])
            if not np.isfinite(design).all():
                # a trial point where the model overflows (a plane seen edge-on, a lobe run off):
                # residuals that MINPACK rejects, instead of a least squares that LAPACK
                # refuses with a line of its own on stderr
                r = np.full(len(yn), _NOT_FINITE_RESIDUAL)
                state.update(key=key, n=n, dns=dns, h=h, rough=rough, parts=parts, coef=coef,
                             active=active, r=r)
                return (r, np.zeros((len(yn), 4))) if grad else (r, None)
            for _ in range(3):  # the active set of the censored rows: two updates settle it
                A, t = design[active], target[active]
                if w is not None:
                    A, t = A * w[active, None], t * w[active]
                coef = np.linalg.lstsq(A, t, rcond=None)[0]
                model = design @ coef
                new_active = ~cens | (model < clipn)
                if np.array_equal(new_active, active):
                    break
                active = new_active
            r = np.where(active, model - target, 0.0)
            state.update(key=key, n=n, dns=dns, h=h, rough=rough, parts=parts, coef=coef,
                         active=active, r=r)
        if not grad:
            return state["r"], None
        return state["r"], jac_general(p, nb, e1, e2, state["dns"], w)

    def jac_general(p, nb, e1, e2, dns, w):
        st = state
        coef, active = st["coef"], st["active"]
        if ggx:
            G = coef[0] * ggx_grad(st, dns)
        else:
            G = coef[0] * box(_rig_grad(dT, st["parts"], st["n"], dns, st["h"], rig_arr, st["rough"]))
        if diffuse:
            G[:3] += coef[1] * box(_rig_diffuse_grad(dT, rl, p, nb, e1, e2, rig_arr))
        JT = np.zeros_like(G)
        A = design[active]
        Ga = G[:, active]
        if w is not None:
            A, Ga = A * w[active, None], Ga * w[active]
        Q = np.linalg.qr(A)[0]
        Ja = Ga - (Ga @ Q) @ Q.T
        JT[:, active] = Ja if w is None else Ja / w[active]
        return JT.T

    def ggx_grad(st, dns):
        """The GGX lobe image's derivatives in (a, b, log h, log alpha) at the state ``st`` of
        :func:`resjac_general` (:func:`~simtest.reconstruct.lightaware.model._rig_grad_ggx`,
        analytic): (4, M)."""
        return box(_rig_grad_ggx(dT, rl, st["n"], dns, st["h"], rig_arr, st["rough"]))

    def resjac_at(p, nb, e1, e2, grad=True, w=None, kaufman=False):
        if general:
            return resjac_general(p, nb, e1, e2, grad, w, kaufman)
        return resjac_plain(p, nb, e1, e2, grad, w, kaufman)

    def resjac_plain(p, nb, e1, e2, grad=True, w=None, kaufman=False):
        """Residuals of the variable projection (Notes) and their Jacobian in (a, b, log h, log n).

        ``w``: row weights (a robust loss' reweighting): the linear part is solved with them and
        the residual and Jacobian returned are the unweighted ones of that solution. ``kaufman``:
        the Jacobian without its second-order term, ``P (g dS)`` (for the covariance).
        """
        QT, yt = basis(w)
        key = (p.tobytes(), nb.tobytes(), None if w is None else w.tobytes())
        if state.get("key") != key:
            n, dns = _normal_derivs(p, nb, e1, e2)
            h, rough = float(np.exp(p[2])), float(np.exp(p[3]))
            S, parts = _rig_value(dT, rl, n, h, rig_arr, rough)
            S = box(S)
            Sw = S if w is None else S * w
            St = Sw - (QT @ Sw) @ QT
            aa = float(St @ St)
            g = float(St @ yt) / aa if aa > 0 else 0.0
            rw = g * St - yt
            state.update(key=key, n=n, dns=dns, h=h, rough=rough, parts=parts, St=St, aa=aa, g=g,
                         rw=rw, r=rw if w is None else rw / w)
        if not grad:
            return state["r"], None
        return state["r"], jac_of(state["dns"], w, kaufman)

    def jac_of(dns, w, kaufman):
        """The Jacobian (M, 4) at the point of ``state``, the normal's derivatives ``dns``."""
        st = state
        QT = basis(w)[0]
        dS = box(_rig_grad(dT, st["parts"], st["n"], dns, st["h"], rig_arr, st["rough"]))
        if w is not None:
            dS = dS * w
        St, aa, g = st["St"], st["aa"], st["g"]
        if not aa > 0:
            return np.zeros((len(St), 4))
        M = np.empty((4, 4))  # JT = g dS - M @ [QT; St]: the projections in one product
        M[:, :3] = (g * dS) @ QT.T
        M[:, 3] = dS @ St * (g / aa)
        if not kaufman:
            M[:, 3] += dS @ st["rw"] / aa
        JT = g * dS - M @ np.vstack([QT, St])
        return (JT if w is None else JT / w).T

    def start_for(n, h):
        """The start's roughness: Phong's n (:func:`phong_start`), or for GGX its alpha of the same
        peak curvature."""
        rough = phong_start(n, h)
        return ggx_alpha_of_phong(rough) if ggx else rough

    def phong_start(n, h):
        """Start roughness: a log-log regression of the specular part on cos beta, then Gauss-Newton.

        The regression's slope is sensitive to the start plane (log cos beta is small near the
        peak); a few Gauss-Newton steps on log n alone (the plane held, the linear part projected
        out as in the fit) bring it to the least-squares roughness of the start plane.
        """
        if start_roughness is not None:
            return float(start_roughness)
        # cos beta f p and f p (the lobe at n = 1 and n = 0): their ratio is cos beta (one light)
        S1, parts = _rig_value(dT, rl, n, h, rig_arr, 1.0)  # 0 where a ray misses (cb < 0)
        S0 = sum(pt[3] / pt[1] for pt in parts)  # val / cb
        S1, S0 = box(S1), box(S0)
        spec = y - b_level
        selr = (spec > 0.05 * spec.max()) & (S1 > 0)
        log_n = np.log(50.0)
        if np.count_nonzero(selr) >= 3:
            x = np.log(np.clip(S1[selr] / S0[selr], 1e-12, None))
            z = np.log(spec[selr] / S0[selr])
            xc = x - x.mean()
            den = float(xc @ xc)
            slope = float(xc @ (z - z.mean())) / den if den > 0 else np.nan  # least-squares line
            if np.isfinite(slope) and slope > 1:
                log_n = np.log(min(slope, _ROUGHNESS_RANGE[1]))
        QT, yt = basis(None)

        def steps(log_n):
            """Gauss-Newton on log n from ``log_n``, the start plane held."""
            for _ in range(_ROUGHNESS_START_STEPS):
                rough = float(np.exp(log_n))
                S, parts = _rig_value(dT, rl, n, h, rig_arr, rough)
                S, dS = box(S), box(sum(pt[3] * pt[2] for pt in parts) * rough)  # dS / d log n
                St, da = S - (QT @ S) @ QT, dS - (QT @ dS) @ QT
                aa = float(St @ St)
                if not aa > 0:
                    break
                g = float(St @ yt) / aa
                r = g * St - yt
                J = g * (da - St * (float(St @ da) / aa)) - St * (float(r @ da) / aa)
                jj = float(J @ J)
                step = -float(J @ r) / jj if jj > 0 else 0.0
                if not np.isfinite(step):
                    break
                log_n = float(np.clip(log_n + np.clip(step, -1.0, 1.0), *np.log(_ROUGHNESS_RANGE)))
                if abs(step) < 1e-3:
                    break
            return log_n

        def cost(ln):
            """The start plane's variable-projection cost at roughness exp(ln)."""
            S_ = box(_rig_value(dT, rl, n, h, rig_arr, float(np.exp(ln)))[0])
            St_ = S_ - (QT @ S_) @ QT
            aa_ = float(St_ @ St_)
            return float(yt @ yt - (St_ @ yt) ** 2 / aa_) if aa_ > 0 else np.inf

        log_n = steps(log_n)
        if len(rig_arr[0]) > 1:
            # several lights: the ratio above is no lobe's cos beta, and where a second light's
            # lobe enters the ROI the steps ran to a broad lobe over both (n -> 1), from where the
            # fit of an exact plane ran off (h 20 -> 65 mm, guides +-5 mm): the steps again from
            # the least cost of a grid over the range (one evaluation each). That start replaces
            # the first only where it at least halves the start plane's cost (it found the lobe);
            # a lower cost by a few per cent on a flat cost curve says nothing of the basin, and
            # taking it sent a sensor-path fit of an exact plane into a local minimum
            other = steps(min(np.log(_START_ROUGHNESS_GRID), key=cost))
            if cost(other) < _START_ROUGHNESS_GAIN * cost(log_n):
                log_n = other
        return float(np.exp(log_n))

    def screened(starts):
        """The start (n, h) of least cost before any refinement (at its start roughness)."""
        def cost(nh):
            e1_, e2_ = plane_basis(nh[0])
            p0_ = np.array([0.0, 0.0, np.log(nh[1]), np.log(start_for(*nh))])
            r_ = resjac_at(p0_, nh[0], e1_, e2_, grad=False)[0]
            return float(r_ @ r_) if np.isfinite(r_).all() else np.inf
        return min(starts, key=cost)

    # Starts: the given one (or the bisector at the nominal depth), the nominal bisector too when
    # a start was given, and n_start_depths planes along the BP's constraint (each the bisector
    # at a depth from nominal/8 to nominal*8, its distance such that the specular point is the
    # BP). Each is refined; the solution of least cost is kept. A near plane with a rough lobe can
    # mimic a far one with a smooth lobe (a local minimum), which one start may fall into.
    cands = [(n0, h0)]
    if start_normal is None and len(rig_arr[0]) > 1:
        # a highlight is one light's: beside the mean light's bisector, each light's at the
        # nominal depth (the BP that light's specular point), the start of least cost kept. Under
        # guides +-8 mm at 20 mm the mean light's start (the BP ray) is 11 deg off, and from it
        # the fit of an exact plane ran off to h -> 0
        cands = [screened(cands + [_light_start(d_bp, L, nominal_depth_mm) for L in rig_arr[0]])]
    if np.abs(rig_arr[0]).max() > 0:
        Lm = _mean_light(rig)
        depths = (list(nominal_depth_mm * np.geomspace(1 / 8, 8, n_start_depths))
                  if n_start_depths else [])
        if start_normal is not None:
            depths.append(nominal_depth_mm)
        for sdep in depths:
            X = sdep * d_bp
            nc = unit(unit(-X) + unit(Lm - X))
            cands.append((nc, float(-(nc @ X))))
    best = None
    nfev_total = 0
    for nc, hc in cands:
        e1, e2 = plane_basis(nc)
        p0 = np.array([0.0, 0.0, np.log(hc), np.log(start_for(nc, hc))])
        free = np.ones(len(p0), bool)
        free[2] = np.abs(rig_arr[0]).max() > 1e-9 * hc  # all lights at V: no dependence on h
        x, nfev, conv, msg, r = _solve(resjac_at, p0, (nc, e1, e2), loss, f_scale, max_nfev, free,
                                       lazy_jac=True, weighted=True)
        nfev_total += nfev
        cost = float(r @ r) if np.isfinite(r).all() else np.inf
        if best is None or cost < best[0]:
            best = (cost, x, nc, hc, e1, e2, conv, msg, r)
    if not best[0] < 0.25 * _NOT_FINITE_RESIDUAL**2 * len(yn):
        return LightAwareEstimate(name, "not_converged", "the model is not finite about the solution",
                                  n_evaluations=nfev_total)
    _, x, n0, h0, e1, e2, conv, msg, r = best
    clipped_low = floor_level is not None and bool(np.any(y <= floor_level))
    if step > 1 and refine_all and not clipped_low and not _correlated(r, sel, keep.shape, step):
        # the starts were refined on a sub-grid: where the plane explains it (its residuals do
        # not correlate, the error is the noise's) the best is refined on every kept pixel (the
        # sub-grid's covariance is step^2 times the whole ROI's; the two solutions lie apart
        # along the valley where the tilt and the distance trade off, which takes the second
        # fit about as many evaluations as the first); where it misfits, the model's error
        # dominates and more pixels of it would not help; where the ROI's noise is clipped at
        # the floor, that clipping biases the fit (an error its sigma does not hold) and more
        # pixels would only shrink the sigma about it
        (sel, step, y, cens, general, dT, rl, yscale, yn, background, clipn,
         design) = samples(None)
        state.clear()
        proj.clear()
        free = np.ones(len(x), bool)
        free[2] = np.abs(rig_arr[0]).max() > 1e-9 * h0
        x2, nfev, conv2, msg2, r = _solve(resjac_at, x, (n0, e1, e2), loss, f_scale, max_nfev, free,
                                          lazy_jac=True, weighted=True)
        nfev_total += nfev
        if np.isfinite(r).all() and float(r @ r) < 0.25 * _NOT_FINITE_RESIDUAL**2 * len(yn):
            x, conv, msg = x2, conv2, msg2
        else:
            return LightAwareEstimate(name, "not_converged", "the model is not finite about the "
                                      "solution on every pixel", n_evaluations=nfev_total)
    if floor_refit and floor_level is not None and step == 1 and np.any(y <= floor_level):
        # pixels clipped from below (an 8-bit image's 0 under read noise): where the model is
        # within a few noise sigmas of the floor the data's mean is the clipped Gaussian's, above
        # the model; those pixels, chosen by the model (not by their values, which would select
        # their noise), are left out and the fit refined on the rest
        r_ = resjac_at(x, n0, e1, e2, grad=False)[0]
        model_n = yn + r_
        low = y <= floor_level
        s_n = 1.4826 * float(np.median(np.abs(r_[~low]))) if np.any(~low) else 0.0
        drop = model_n <= float(floor_level) / yscale + _FLOOR_MARGIN * s_n
        if (drop.any() and s_n * yscale > floor_step
                and np.count_nonzero(~drop & ~cens) >= 8 + 1 + int(diffuse)):
            keep2 = keep.copy()
            keep2.flat[sel[drop]] = False
            (sel, step, y, cens, general, dT, rl, yscale, yn, background, clipn,
             design) = samples(None, keep2)
            state.clear()
            proj.clear()
            free = np.ones(len(x), bool)
            free[2] = np.abs(rig_arr[0]).max() > 1e-9 * h0
            x2, nfev, conv2, msg2, r = _solve(resjac_at, x, (n0, e1, e2), loss, f_scale, max_nfev,
                                              free, lazy_jac=True, weighted=True)
            nfev_total += nfev
            if not (np.isfinite(r).all() and float(r @ r) < 0.25 * _NOT_FINITE_RESIDUAL**2 * len(yn)):
                return LightAwareEstimate(name, "not_converged", "the model is not finite about the "
                                          "solution above the floor", n_evaluations=nfev_total)
            x, conv, msg = x2, conv2, msg2
    nfev = nfev_total
    n_hat = _normal_derivs(x, n0, e1, e2)[0]
    h_hat = float(np.exp(x[2]))
    with np.errstate(over="ignore"):  # a fit run off to an infinite roughness: implausible below
        rough_hat = phong_of_ggx_alpha(float(np.exp(x[3]))) if ggx else float(np.exp(x[3]))
    bad = _implausible(h_hat, h0, rough_hat, shaded=diffuse)
    if bad:
        return LightAwareEstimate(name, "not_converged", bad, n_evaluations=nfev)
    if np.any(n_hat @ rig_arr[0].T + h_hat <= 0):
        return LightAwareEstimate(name, "light_behind_plane", f"h = {h_hat:.4g} mm", n_evaluations=nfev)

    def at_solution(p_hat, nb, e1_, e2_):
        """Residuals and covariance Jacobian about (nb, e1_, e2_) at the solution x.

        The plane and roughness are x's (``nb`` is x's normal): the model at x, most often the
        solver's last evaluation, is reused and only the derivatives are taken about ``nb``.
        """
        resjac_at(x, n0, e1, e2, grad=False)
        if general:  # the diffuse column's derivative by differences about (nb, e1_, e2_)
            return state["r"], jac_general(p_hat, nb, e1_, e2_,
                                           _normal_derivs(p_hat, nb, e1_, e2_)[1], None)
        return state["r"], jac_of(_normal_derivs(p_hat, nb, e1_, e2_)[1], None, True)

    def curvature(r0, hac=False):
        """The score test for a curved patch (:func:`~simtest.reconstruct.lightaware.solve._curvature_score`):
        the quadric patch of :func:`~simtest.reconstruct.lightaware.patch.quadric_fit` at the
        plane's specular point of the mean light with zero curvature is the plane; its image's
        derivatives in the three curvatures
        (:func:`~simtest.reconstruct.lightaware.model._curvature_columns`) are the columns the
        residual is tested against. Returns ``(verdict, shift)``: the test's (a misfit's
        detail, None where it passes, False where it cannot be made) and, for a misfit, how far
        the pattern would move the plane
        (:func:`~simtest.reconstruct.lightaware.solve._curvature_shift`)."""
        Lm = _mean_light(rig)
        c = float(n_hat @ Lm) + h_hat
        Lp = Lm - 2.0 * c * n_hat  # the mean light's mirror image in the plane
        den = -float(n_hat @ Lp)
        if not (c > 0 and den > 0):
            return False, None
        Xs = Lp * (h_hat / den)
        cols = box(_curvature_columns(dT, rl, n_hat, h_hat, rig_arr, rough_hat, Xs)).T
        J = at_solution(np.concatenate([[0.0, 0.0, np.log(h_hat)], x[3:]]), n_hat,
                        *plane_basis(n_hat))[1]
        span = np.column_stack([J, design] if general else [J, state["St"], background])
        sel_ = sel
        if floor_level is not None and np.any(y <= floor_level):
            # the pixels near the floor hold clipped noise, a pattern of its own: the test reads
            # the rest (chosen by the model, as the floor's refinement chooses them)
            above = y > floor_level
            s_n = 1.4826 * float(np.median(np.abs(r0[above]))) if np.any(above) else 0.0
            rows = yn + r0 > float(floor_level) / yscale + _FLOOR_MARGIN * s_n
            cols, span, r0, sel_ = cols[rows], span[rows], r0[rows], sel[rows]
        verdict = _curvature_score(cols, span, r0, (sel_, keep.shape, step) if hac else None)
        return verdict, (_curvature_shift(cols, span, r0) if verdict else None)

    def post(est, r0):
        """The misfit test, and where neighbouring residuals correlate, the sandwich sigmas.

        Correlated residuals (a texture, a micro-relief, a lobe shape the model lacks, a curved
        patch) make ``s^2 (J^T J)^-1`` too small: the normal's and the depth's sigmas are then
        the larger of it and the sandwich's (:func:`~simtest.reconstruct.lightaware.solve._hac_covariance`).
        The sensor path (the diffuse column, censored pixels or the GGX lobe) is judged by
        :func:`sensor_verdict`.
        """
        if est.status not in ("ok", "depth_not_observable"):
            return est
        if general:
            return sensor_verdict(est, r0)
        if not _correlated(r0, sel, keep.shape, step):
            curved, shift = curvature(r0)
            if curved:
                kept = immaterial(est, r0, curved, shift, False, False)
                return kept if kept is not None else est.without_depth("plane_misfit", curved)
            est = _misfit(est, r0, sel, keep.shape, step)
            return counted(est, r0, False, jackknife=False) if est.status in ("ok", "depth_not_observable") else est
        return _misfit(with_sandwich(est, r0), r0, sel, keep.shape, step)

    def with_sandwich(est, r0):
        """``est`` with the normal's sigma at least the sandwich's."""
        J = at_solution(np.concatenate([[0.0, 0.0, np.log(h_hat)], x[3:]]), n_hat,
                        *plane_basis(n_hat))[1]
        cov, _ = _hac_covariance(J, r0, sel, keep.shape, step)
        if cov is not None:
            sig = math.degrees(math.sqrt(max(float(cov[0, 0] + cov[1, 1]), 0.0)))
            est = replace(est, normal_sigma_deg=max(sig, est.normal_sigma_deg or 0.0))
        return est

    def sensor_verdict(est, r0):
        """The misfit test and the sigmas of the sensor path.

        On a sensor frame the tissue's albedo texture (vessels, mucosal pattern) under the rig's
        diffuse light leaves residuals that correlate between neighbours on an exact plane, so
        the neighbours' correlation says nothing of the surface's shape there. The test is the
        curvature's score test with the residual's own correlated noise
        (:func:`~simtest.reconstruct.lightaware.solve._curvature_score` with its grid): a
        texture passes it, a curved patch does not (``plane_misfit``). One that passes has
        sigmas that count the texture as the noise it is: ``s^2 (J^T J)^-1`` (``s^2`` the
        residual's variance, the texture's included) times the residual's correlation area
        (:func:`~simtest.reconstruct.lightaware.solve._correlation_area`: the fitted pixels per
        independent one), the normal's at least the sandwich's where the residuals correlate;
        a depth whose relative sigma is then above ``TOL.depth_rel_sigma_max`` is withdrawn
        (``depth_not_observable``). Where the test cannot be made (no specular point of the mean
        light on the plane, a degenerate pattern) the neighbours' correlation decides, as on the
        plain path.
        """
        curved, shift = curvature(r0, hac=True)
        correlated = _correlated(r0, sel, keep.shape, step)
        if curved:
            kept = immaterial(est, r0, curved, shift, correlated, True)
            return kept if kept is not None else est.without_depth("plane_misfit", curved)
        if curved is False:
            return _misfit(with_sandwich(est, r0), r0, sel, keep.shape, step) if correlated else est
        return counted(est, r0, correlated)

    def immaterial(est, r0, curved, shift, correlated, jackknife):
        """A fit whose residual holds a curved patch's pattern (``curved``, the score test's
        detail) that moves the plane less than its noise does, or None.

        The score test asks whether the patch is curved at all; under a micro-relief it is, its
        curvatures random over the lobe, and with thousands of pixels the test sees them. What
        the recommendation needs is whether that curvature moves the normal: ``shift`` (the
        normal's shift in degrees and the distance's relative shift, the quadric patch's
        linearised step from the plane,
        :func:`~simtest.reconstruct.lightaware.solve._curvature_shift`). Where the normal's shift
        is at most its sigma (the residual's correlation and, on the sensor path, the cluster
        jackknife counted: ``counted``, over the wider blocks too, as the relief's pattern spans
        the lobe: on the endoscope suite's flat mucosa under 0.005 and 0.01 mm of relief the
        narrow blocks' sigmas covered 15 of 21 and 1 of 4 recommended normals at 2 sigma, the
        wider ones' 20 of 24 and 6 of 6), the fit is kept with its sigmas grown by the shifts
        (the normal's sigma plus its shift; the depth's plus its relative shift times the
        depth, withdrawn above ``TOL.depth_rel_sigma_max``) and the detail saying so. On the
        noisy spheres and a local minimum's leftover pattern the shift is 9 to 16 times the
        sigma, and the fit stays ``plane_misfit``.
        """
        if shift is None:
            return None
        kept = counted(est, r0, correlated, jackknife=jackknife, wide=True)
        sig = kept.normal_sigma_deg
        if kept.status not in ("ok", "depth_not_observable") or sig is None or not shift[0] <= sig:
            return None
        note = (f"{curved}, which moves the normal {shift[0]:.2g} deg, within its sigma: "
                "kept, its sigmas grown by the shift")
        kept = replace(kept, normal_sigma_deg=sig + shift[0], curvature_shift_deg=shift[0],
                       detail=f"{kept.detail}; {note}" if kept.detail else note)
        if kept.depth_sigma_mm is not None and kept.depth_mm:
            return _with_depth_sigma(kept, kept.depth_sigma_mm + shift[1] * abs(kept.depth_mm),
                                     lambda rel: f"{kept.detail}; relative depth sigma {rel:.3g} > "
                                                 f"{TOL.depth_rel_sigma_max}")
        return kept

    def counted(est, r0, correlated, jackknife=True, wide=False):
        """``est`` with sigmas that count the residual's correlation: ``s^2 (J^T J)^-1`` times
        the residual's correlation area (:func:`~simtest.reconstruct.lightaware.solve._correlation_area`:
        the fitted pixels per independent one), the normal's at least the sandwich's where the
        residuals correlate and, with ``jackknife``, at least the cluster jackknife's; the
        depth's grown by the same factor; a depth whose relative sigma is then above
        ``TOL.depth_rel_sigma_max`` is withdrawn (``depth_not_observable``).

        On a sensor frame the residual holds the albedo's texture, weakly correlated over many
        lags, which only the jackknife sees. On the plain path (no diffuse column, censoring or
        GGX lobe) an integer image of a smooth lobe holds its rounding, which is not independent
        from pixel to pixel where the lobe changes by less than a level a pixel: the
        ``lightaware`` suite's 60 noise-free and noisy 8-bit planes at epsilon/d 0.05 to 0.5 had
        40 errors within twice the white sigma (noise-free: 0.05 to 0.35 deg off, sigmas 0.03 to
        0.09), 56 within twice the correlation area's. The jackknife is left out there: with 2 %
        read noise it tripled sigmas that the Cramer-Rao bound already matched (59 of 60
        covered, but the depth of every 2 % plane withdrawn).
        """
        scale = math.sqrt(_correlation_area(r0, sel, keep.shape, step))
        sig = None if est.normal_sigma_deg is None else est.normal_sigma_deg * scale
        est = replace(est, normal_sigma_deg=sig)
        if correlated:
            est = with_sandwich(est, r0)
        if est.normal_sigma_deg and jackknife:
            # at least the cluster jackknife's (the largest over the blocks the ROI holds enough
            # of, wider where one channel keeps the texture): the depth's sigma grows with the
            # normal's by the same factor
            J = at_solution(np.concatenate([[0.0, 0.0, np.log(h_hat)], x[3:]]), n_hat,
                            *plane_basis(n_hat))[1]
            for block in cluster_blocks(keep.shape, texture=wide or how in (None, "darkest_channel")):
                cov = _cluster_covariance(J, r0, sel, keep.shape, block)
                if cov is None:
                    continue
                csig = math.degrees(math.sqrt(max(float(cov[0, 0] + cov[1, 1]), 0.0)))
                if csig > est.normal_sigma_deg:
                    scale *= csig / est.normal_sigma_deg
                    est = replace(est, normal_sigma_deg=csig)
        if est.depth_sigma_mm is not None:
            return _with_depth_sigma(est, est.depth_sigma_mm * scale,
                                     lambda rel: f"relative depth sigma {rel:.3g} with the residual's "
                                                 f"correlation > {TOL.depth_rel_sigma_max}")
        return est

    est = _finish(name, at_solution, n_hat, h_hat, rig, x[3:],
                  TOL.photometric_noise_rel, nfev, conv, roughness=rough_hat,
                  detail="" if conv else msg, n_linear=design.shape[1] if general else 4,
                  post=post)
    if colour_detail:
        est = replace(est, detail=f"{est.detail}; {colour_detail}" if est.detail else colour_detail)
    est = replace(est, lobe="ggx" if ggx else "phong", n_residuals=int(len(yn)), projection=how)
    if lower is not None and est.status in ("ok", "depth_not_observable"):
        # the shape check on the darkest channel: a curved patch is curved in every channel, and
        # the projection's residual can hide it (a JPEG frame's chroma, subsampled and blocky,
        # correlates the projected residual over blocks, against which the score test weighs
        # the curvature's pattern: on the endoscope suite's colon wall every JPEG frame's
        # projected fit passed 6 to 15 deg off, where the darkest channel's misfits)
        c, clip_c = _darkest(rgb_in, clip_in)
        chan = photometric_fit(np.asarray(rgb_in, dtype=np.float64)[..., c], origin_uv, bp_uv, camera,
                               rig, clip_level=clip_c, nominal_depth_mm=nominal_depth_mm,
                               start_normal=est.normal, loss=loss, f_scale=f_scale,
                               supersample=supersample, n_start_depths=0, diffuse=diffuse,
                               censor=censor, max_pixels=max_pixels, refine_all=refine_all,
                               max_nfev=max_nfev, lobe=lobe, floor_level=floor_in,
                               floor_refit=floor_refit, floor_step=floor_step, exclude=exclude)
        if chan.status == "plane_misfit":
            est = est.without_depth("plane_misfit",
                                    f"channel {c}'s fit misfits ({chan.detail}); {est.detail}")
    return est


def _darkest(rgb, clip_level) -> tuple[int, float | None]:
    """The channel of an RGB ROI whose median is least (where the tissue is darkest) and its
    clip level (``clip_level`` one number or each channel's; None)."""
    rgb = np.asarray(rgb, dtype=np.float64)
    c = int(np.argmin(np.median(rgb.reshape(-1, 3), axis=0)))
    clip = None if clip_level is None else float(np.broadcast_to(
        np.asarray(clip_level, dtype=np.float64).reshape(-1), (3,))[c])
    return c, clip


#: The values of ``photometric_fit``'s ``projection``.
PROJECTIONS = ("auto", "border", "least_fluctuation", "darkest_channel")


def _colour_values(rgb, clip_level, projection: str = "auto", two_channels: bool = False):
    """The single image a colour ROI is fitted on (``photometric_fit``'s ``values`` (H, W, 3)).

    Returns ``(values, clip_level, lower, missing, detail, how)``: the body-colour projection of
    :func:`~simtest.reconstruct.lightaware.model.specular_image` (no scalar clip level; its
    censored and missing pixels), or, where it gives none (the border holds one body colour, or
    white lies too near them), the channel whose median is least (where the tissue is darkest)
    with that channel's clip level and no masks; ``how`` is the estimate's ``projection``
    (``"body_colours"``, ``"least_fluctuation"`` or ``"darkest_channel"``).
    """
    rgb = np.asarray(rgb, dtype=np.float64)
    out, how = None, None
    if projection in ("auto", "border"):
        out, how = specular_image(rgb, clip_level, fluctuation=False, two_channels=two_channels), "body_colours"
    if out is None and projection in ("auto", "least_fluctuation"):
        out, how = specular_image(rgb, clip_level, border=False, two_channels=two_channels), "least_fluctuation"
    if out is not None:
        values, lower, missing, w = out
        text = ("body colours projected out" if how == "body_colours"
                else "body colours projected out by the least-fluctuation weights")
        weights = ", ".join(f"{x:.3g}" for x in w)
        return values, None, lower, missing, f"{text} (w = {weights})", how
    c, clip = _darkest(rgb, clip_level)
    why = (f"channel {c} (no two body colours to project out: the border holds one, or white lies "
           "too near them)")
    return rgb[..., c], clip, None, None, why, "darkest_channel"


def _one_channel_clipped(rgb, clip_level) -> bool:
    """Whether an RGB ROI holds a pixel clipped in exactly one channel (``clip_level`` one
    number or each channel's; None: nothing is clipped)."""
    if clip_level is None:
        return False
    clip = np.broadcast_to(np.asarray(clip_level, dtype=np.float64).reshape(-1), (3,))
    return bool(np.any(np.count_nonzero(np.asarray(rgb) >= clip, axis=2) == 1))


#: The number of sigmas of the difference between the fits with and without the pixels valued
#: from two channels within which :func:`_two_channel_choice` keeps the former (2: about 95 %).
TWO_CHANNEL_Z = 2.0


def _two_channel_choice(both: LightAwareEstimate, plain: LightAwareEstimate) -> LightAwareEstimate:
    """The fit with the pixels clipped in one channel valued from the other two (``both``:
    :func:`~simtest.reconstruct.lightaware.model.specular_image`'s ``two_channels``), or the fit
    without them (``plain``), returned unchanged.

    ``both`` is kept where both fits are ``ok`` (``both`` on a projection of the three channels,
    its normal's sigma below the plain one's) and they agree as a Hausman test asks of an
    efficient and a consistent estimator [8]_: under the plane model both are consistent, the
    one with more pixels has the smaller variance, and their difference has the variance of
    the plain one's less the other's; the normals' angle and the depths' difference within
    ``TWO_CHANNEL_Z`` of those sigmas. Why a test: those pixels hold the second body colour's
    texture, which their two channels cannot remove; where a plane is not the surface, the
    fit with them can pass the curvature test with a smaller sigma and a wrong plane (on the
    endoscope suite's colon wall, plane fits 4 to 5 deg off with depths 55 % short and sigmas
    of 2 deg passed, where the plain fits' depths were not observable); on flat mucosa at 0.5 %
    read noise, where the red channel clips by the tissue's own reflection beside the lobe,
    the fits with them erred 0.02 to 0.1 deg where the plain ones erred 0.1 to 2 deg.

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


def _with_depth_sigma(est: LightAwareEstimate, dsig: float, why) -> LightAwareEstimate:
    """``est`` with the depth's 1-sigma ``dsig`` (mm), or without its depth
    (``depth_not_observable``, its detail ``why(rel)`` of the relative sigma) where ``dsig``
    exceeds ``TOL.depth_rel_sigma_max`` of a nonzero depth."""
    if est.depth_mm and dsig > TOL.depth_rel_sigma_max * abs(est.depth_mm):
        return est.without_depth("depth_not_observable", why(dsig / abs(est.depth_mm)))
    return replace(est, depth_sigma_mm=dsig)


def _choose_lobe(pho: LightAwareEstimate, ggx: LightAwareEstimate) -> LightAwareEstimate:
    """The Phong or the GGX fit (``photometric_fit``'s Notes, ``lobe="auto"``); its detail names
    the other lobe's residual RMS."""
    def rank(e):
        failed = e.status == "not_converged" or not e.has_normal
        misfit = e.status == "plane_misfit"
        # a fit whose residual holds a curved patch's pattern (a misfit, or a fit kept with it:
        # curvature_shift_deg) after one whose residual holds none; of two such fits Phong
        # (neither lobe is the image's model, and their likelihoods do not rank them: on the
        # endoscope suite's flat mucosa under a 0.002 mm relief a GGX fit kept with it erred
        # 0.62 deg with a sigma of 0.24, where Phong's misfit was 0.21 deg off); else the
        # lower BIC
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
