"""The photometric plane fit: the ROI's intensities fitted with the image of a plane lit by the rig.

Stages: the colour projections, start depths and two-channel pixels (:func:`_fit_projections`),
the lobe (:func:`_fit_lobes`), one fit (:func:`_fit_plane`) with its model (``plane_model``),
starts and solve (``plane_solve``), covariance and misfit tests (``plane_sigma``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from simtest.decisions import PAIR_DEPTH_MAX_MM, SIGNIFICANCE_MIN, TWO_CHANNEL_Z
from simtest.geometry.angles import angle_between_deg
from simtest.geometry.lights import LightRig
from simtest.tolerances import TOL
from simtest.reconstruct._pixels import border_ring
from simtest.reconstruct.detect_pixels import noise_sigma_of_differences, second_differences
from simtest.reconstruct.lightaware.estimate import LightAwareEstimate
from simtest.reconstruct.lightaware.colour import per_channel, specular_image
from simtest.reconstruct.lightaware.model import _normal_derivs
from simtest.reconstruct.lightaware.plane_model import PlaneModel
from simtest.reconstruct.lightaware.plane_sigma import PlaneVerdict
from simtest.reconstruct.lightaware.plane_solve import solve_plane, start_planes
from simtest.reconstruct.lightaware.solve import _finish, _implausible, _ran_off_near, _start


#: Starts along the BP's constraint of ``photometric_fit``'s second try, on three channels or one
#: (nominal/8 to nominal*8 at factors of 4: a colonoscope's 5 to 50 mm about a nominal 20).
RETRY_START_DEPTHS = 4

#: The values of ``photometric_fit``'s ``projection``.
PROJECTIONS = ("auto", "border", "least_fluctuation", "darkest_channel")

#: The values of ``photometric_fit``'s ``lobe``.
LOBES = ("phong", "ggx", "blinn", "auto")


@dataclass(frozen=True, eq=False, kw_only=True)
class FitSettings:
    """The options of :func:`photometric_fit`, which travel together through its stages.

    Attributes
    ----------
    clip_level : float or sequence of 3 floats, optional
        Pixels ``>= clip_level`` are left out (e.g. 255 for 8-bit); None keeps every pixel. For RGB, one
        level or each channel's; a pixel is censored where the weights of its clipped channels are >= 0.
    clip_margin : float or sequence of 3 floats, optional
        RGB: a channel within this of its clip level counts as clipped too (``specular_image``'s
        ``censor_margin``). None: 0.
    nominal_depth_mm : float
        Depth of the BP assumed for the start's bisector, mm.
    start_normal : array_like of shape (3,), optional
        Start normal (e.g. from :func:`isocurve_fit`).
    start_roughness : float, optional
        Start Phong n.
    start_distance_mm : float, optional
        Start plane distance h, mm, with ``start_normal`` (another lobe's fit from a fitted plane); None:
        from the BP and the nominal depth.
    pair_starts : tuple of (int, int, float)
        (i, j, d): light i's start at depth d mm along the BP ray, refined too without a start normal
        (:func:`~simtest.reconstruct.rig_pairs.pair_starts`).
    guide_starts : tuple of (int, float)
        (i, d): where given, the fit's only starts, light i's bisector plane at depth d mm along the BP
        ray (one guide's hypothesis of a lone lobe: :mod:`~simtest.reconstruct.lone_lobes`).
    loss : str
        ``linear`` (Gaussian sensor noise), or ``soft_l1``, ``huber``, ``cauchy`` (reweighted).
    f_scale : float
        Soft margin of a robust loss, relative to the ROI's maximum.
    n_start_depths : int or None
        Further starts along the BP's constraint (nominal/8 to nominal*8), the least cost kept. None:
        0, and where that fit runs off towards the camera (RGB: runs off either way or has no depth), once more
        with :data:`RETRY_START_DEPTHS` starts (:func:`~simtest.reconstruct.lightaware.solve._ran_off_near`).
    supersample : int
        s x s point samples per pixel, averaged (1: the value at the pixel centre).
    max_pixels : int or None
        Beyond this many unclipped pixels (2 / L of it under L > 2 lights) the starts are refined on a regular
        sub-grid, the best once more on every pixel (``refine_all``) where the plane fits and nothing lies at
        ``floor_level``.
    refine_all : bool
        Refine the sub-grid's solution on every unclipped pixel (above).
    diffuse : bool
        Add the rig's Lambertian shading of the plane as a linear column; a lobe broader than
        :data:`~simtest.decisions.ROUGHEST_FILM_ALPHA` is then ``not_converged``.
    censor : bool
        Keep clipped pixels as censored data (a residual only where the model falls below the clip).
    max_nfev : int
        Evaluation budget.
    floor_level : float, optional
        The image's floor (e.g. 0 for 8-bit): the curvature test reads only the pixels ``_FLOOR_MARGIN``
        noise sigmas above it. None: no floor.
    floor_refit : bool
        With ``floor_level``, refine once more without the pixels within the margin.
    floor_step : float
        The image's quantisation step at the floor: the refit runs only where the noise sigma exceeds it.
    projection : {"auto", "border", "least_fluctuation", "darkest_channel"}
        RGB: the projection that removes the tissue's body colours
        (:func:`~simtest.reconstruct.lightaware.colour.specular_image`): the border's two body colours,
        the least-fluctuation weights (each else the darkest channel), or the darkest channel. ``"auto"``:
        the border's, replaced by an ``ok`` least-fluctuation fit where it has no depth; where the border
        tells one body colour, the least-fluctuation weights, replaced by the darkest channel where not ``ok``.
    exclude : ndarray of shape (H, W) of bool, optional
        ROI pixels left out of the fit (:func:`~simtest.reconstruct.lightaware.model.albedo_lines`).
    two_channels : bool or None
        RGB pixels clipped in one channel of negative weight: True, valued from their two other
        channels; False, left out; None: both fits, chosen by :func:`_two_channel_choice`.
    lobe : {"phong", "ggx", "blinn", "auto"}
        Phong's ``max(0, cos beta)^n`` (eq. 1), a GGX lobe under a dielectric film
        (:func:`~simtest.reconstruct.lightaware.model._rig_value_ggx`), Blinn's ``max(0, n . H)^n``
        (:func:`~simtest.reconstruct.lightaware.model._blinn_cos`), or those of the three that
        ``photometric_fit``'s Notes try, chosen by :func:`_choose_lobe`. ``roughness`` is always a Phong n.

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
    start_distance_mm: float | None = None
    pair_starts: tuple = ()
    guide_starts: tuple = ()
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
            raise ValueError(f"lobe: {self.lobe!r} is not one of {', '.join(LOBES)}")
        if self.projection not in PROJECTIONS:
            raise ValueError(f"projection: {self.projection!r} is not one of {', '.join(PROJECTIONS)}")


def photometric_fit(values, origin_uv, bp_uv, camera, rig: LightRig, settings: FitSettings | None = None,
                    **options) -> LightAwareEstimate:
    """Fit the intensities of an ROI with the image of a plane lit by the whole rig.

    Model (package docstring): ``I = g sum_j w_j max(0, cos beta_j)^n f_j p_j + b0 + b1 du + b2 dv``
    per pixel centre; the linear parameters are solved for each value of (a, b, log h, log n),
    which Levenberg-Marquardt fits. Clipped pixels are left out (or censored). The roughness starts
    from a log-log regression of the specular part on the start's cos beta, unless given.

    Parameters
    ----------
    values : ndarray of shape (H, W) or (H, W, 3)
        ROI intensities (float, any unit); or linear RGB with the white balance undone, fitted on its
        specular image (:func:`~simtest.reconstruct.lightaware.colour.specular_image`) or the darkest
        channel; a projected fit that passes is checked on the darkest channel too.
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
        Any of :class:`FitSettings`' attributes by name, over ``settings``'.

    Returns
    -------
    LightAwareEstimate
        ``estimator="photometric_fit"``, with ``roughness``. Status ``plane_misfit`` (depth
        withdrawn) when the plane does not explain the ROI: neighbouring residuals correlate
        (``_misfit``; not with the diffuse column, censoring or GGX) or the residual holds a curved
        patch's pattern (:func:`~simtest.reconstruct.lightaware.solve._curvature_score`). A pattern
        that moves the normal by no more than its sigma keeps the fit, its sigma grown by
        ``curvature_shift_deg``. ``not_converged`` where, under separate guides, an ok fit's plane lies
        beyond :data:`~simtest.decisions.PAIR_DEPTH_MAX_MM` (their lobes coincide: no parallax).

    Raises
    ------
    ValueError
        A values array that is not 2-D and finite, or an option out of its range.

    Notes
    -----
    Variable projection [3]_: with ``P`` the projector off the background columns ``[1, du, dv]``,
    ``a = P S(p)`` and ``y~ = P y``, the gain is ``g = a . y~ / a . a`` and ``r = g a - y~``; Kaufman's
    Jacobian ``P_[S, B] (g dS)`` gives the fit and the covariance. With ``diffuse`` or censored pixels
    the linear part (with the shading column ``D(p)``) is solved on the active rows at each p.

    With ``lobe="auto"`` the GGX fit runs where Phong's leaves a curved pattern or (colour) fails, and Blinn's
    where the better of the two leaves a curved pattern (a lobe of the half vector: its peak is
    Phong's, its shape stretches away from the axis [6]_); kept (:func:`_choose_lobe`): converged
    over not, passing over misfitting, then the lower ``BIC = m log(RSS / m) + k log m`` [5]_; of misfits, and
    of Phong's curved fit and another lobe's of a higher BIC, Phong.

    References
    ----------
    .. [5] G. Schwarz, "Estimating the dimension of a model", Ann. Statist. 6(2), 1978.
           https://doi.org/10.1214/aos/1176344136
    .. [6] J. F. Blinn, "Models of light reflection for computer synthesized pictures", SIGGRAPH
           Comput. Graph. 11(2), 1977. https://doi.org/10.1145/965141.563893
    """
    s = FitSettings(**options) if settings is None else replace(settings, **options)
    fit = (_fit_projections if s.n_start_depths is None else _fit_lobes)(values, origin_uv, bp_uv, camera, rig, s)
    return _in_depth_of_field(fit, rig)


def _in_depth_of_field(est: LightAwareEstimate, rig: LightRig) -> LightAwareEstimate:
    """``est``, or ``not_converged`` where under separate guides it is ok with its plane beyond
    :data:`~simtest.decisions.PAIR_DEPTH_MAX_MM`: their lobes coincide there, no parallax holds the depth, and
    a lobe fitted there as every guide's at once is no endoscope's plane. Applied to the final fit only (the
    fallbacks may start from a far plane); a ``depth_not_observable`` fit stays one (the pair's refit reads it)."""
    h = est.fitted_distance_mm
    if not (rig.has_separate_lights and est.ok and h is not None and h > PAIR_DEPTH_MAX_MM):
        return est
    why = f"fitted distance {h:.4g} mm beyond the scope's depth of field ({PAIR_DEPTH_MAX_MM:g} mm)"
    return LightAwareEstimate(est.estimator, "not_converged", f"{why}: {est.status}, {est.detail}",
                              n_evaluations=est.n_evaluations, projection=est.projection)


def _fit_projections(values, origin_uv, bp_uv, camera, rig, s: FitSettings) -> LightAwareEstimate:
    """``photometric_fit`` with ``n_start_depths`` None: the two-channel choice, the retry from further
    starts, and the projections' fallbacks."""
    fit = (values, origin_uv, bp_uv, camera, rig)
    rgb = np.ndim(values) == 3
    if s.two_channels is None:
        plain = _fit_projections(*fit, replace(s, two_channels=False))
        if (plain.status != "ok" or not rgb or plain.projection not in ("body_colours", "least_fluctuation")
                or not _one_channel_clipped(values, s.clip_level)):
            return plain  # (the other is kept only beside an ok fit without them, on a projection)
        # refined from the plain fit, on its projection
        same = "border" if plain.projection == "body_colours" else plain.projection
        both = _fit_projections(*fit, replace(s, projection=same, two_channels=True,
                                              start_normal=plain.normal, start_roughness=plain.roughness))
        return _two_channel_choice(both, plain, lambda: _fit_projections(
            *fit, replace(s, projection="darkest_channel", two_channels=False)))
    first = _fit_lobes(*fit, replace(s, n_start_depths=0))
    best = first
    if (rgb and first.status in ("not_converged", "depth_not_observable")) or first.run_off_near:
        again = _fit_lobes(*fit, replace(s, n_start_depths=RETRY_START_DEPTHS))
        if again.has_normal and (not first.has_normal or first.residual_rms is None
                                 or (again.residual_rms is not None and again.residual_rms < first.residual_rms)):
            best = again
    if (rgb and s.projection == "auto" and best.projection == "body_colours"
            and best.status in ("depth_not_observable", "not_converged")):
        # no depth on the body colours (a misfit stands): the least-fluctuation fit where it is ok
        lf = _fit_projections(*fit, replace(s, projection="least_fluctuation"))
        if lf.ok and lf.projection == "least_fluctuation":
            return lf.noted(f"the body colours' fit is not ok ({best.status}: {best.detail})")
    if rgb and s.projection == "auto" and best.status != "ok" and best.projection == "least_fluctuation":
        chan = _fit_projections(*fit, replace(s, projection="darkest_channel"))
        return chan.noted(f"the least-fluctuation projection's fit is not ok ({best.status}: {best.detail})")
    return best


def _curved(est: LightAwareEstimate) -> bool:
    """Whether a fit's residual holds a curved patch's pattern: a misfit, or a pattern kept within its sigma."""
    return est.status == "plane_misfit" or est.curvature_shift_deg is not None


def _fit_lobes(values, origin_uv, bp_uv, camera, rig, s: FitSettings) -> LightAwareEstimate:
    """One lobe's fit, or with ``lobe="auto"`` Phong's, where it fails (one channel: leaves a curved pattern) GGX's,
    where the better of the two leaves a curved pattern Blinn's too (:func:`_choose_lobe`), each from Phong's fit."""
    fit = (values, origin_uv, bp_uv, camera, rig)
    if s.lobe != "auto":
        return _fit_plane(*fit, s)
    colour = (_colour_values(values, s.clip_level, s.projection, bool(s.two_channels), s.clip_margin)
              if np.ndim(values) == 3 else None)  # each lobe's fit reads the same projection
    pho = _fit_plane(*fit, replace(s, lobe="phong"), colour)
    # no other lobe needed: passing (or too few pixels to tell) with no curved pattern
    if (pho.ok or pho.status in ("depth_not_observable", "too_few_points")) and pho.curvature_shift_deg is None:
        return pho.noted("phong lobe fits")
    if colour is None and not _curved(pho):  # (a run-off fit shows no lobe's shape)
        return pho
    start = (dict(start_normal=pho.normal, start_roughness=pho.roughness, start_distance_mm=pho.fitted_distance_mm)
             if pho.has_normal else dict(start_normal=s.start_normal, start_roughness=s.start_roughness))
    ggx = _fit_plane(*fit, replace(s, lobe="ggx", **start), colour)
    best = _choose_lobe(pho, ggx)
    if not _curved(best):
        return best  # (a fit that runs off tells nothing of the lobe's shape)
    return _choose_lobe(pho, ggx, _fit_plane(*fit, replace(s, lobe="blinn", **start), colour))


def _fit_plane(values, origin_uv, bp_uv, camera, rig, s: FitSettings, colour=None) -> LightAwareEstimate:
    """One fit of one lobe: projection (``colour``: :func:`_colour_values`' if at hand), model, starts, solve,
    covariance; a projected fit that passes is checked on the darkest channel."""
    name = "photometric_fit"
    one, clip_level, floor_level = values, s.clip_level, s.floor_level
    lower = missing = how = None
    colour_detail = ""
    if np.ndim(values) == 3:  # the single image a colour ROI is fitted on
        one, clip_level, lower, missing, colour_detail, how = colour or _colour_values(
            values, clip_level, s.projection, bool(s.two_channels), s.clip_margin)
        if lower is not None:
            floor_level = None  # a projection of three channels has no floor of its own
    m = PlaneModel(one, origin_uv, bp_uv, camera, rig, s, clip_level, lower, missing, s.lobe == "ggx")
    if np.count_nonzero(~m.cens) < 8 + 1 + int(s.diffuse):
        return LightAwareEstimate(name, "too_few_points", f"{np.count_nonzero(~m.cens)} unclipped pixels")
    d_bp, n0, h0 = _start(m.bp, m.camera, rig, s.nominal_depth_mm, s.start_normal)
    if s.start_normal is not None and s.start_distance_mm is not None and s.start_distance_mm > 0:
        h0 = float(s.start_distance_mm)  # the plane another lobe's fit found
    solved = solve_plane(m, start_planes(m, rig, d_bp, n0, h0, s), s, floor_level)
    if isinstance(solved, LightAwareEstimate):  # (its projection, for the fallbacks that read it)
        return replace(solved, projection=how)
    x, n0, h0, e1, e2, conv, msg, nfev = solved
    n_hat = _normal_derivs(x, n0, e1, e2)[0]
    with np.errstate(over="ignore"):  # a fit run off to an infinite h or roughness: implausible below
        h_hat, rough_hat = float(np.exp(x[2])), m.phong_n(x[3])
    bad = _implausible(h_hat, h0, rough_hat, shaded=s.diffuse)
    if bad:
        return LightAwareEstimate(name, "not_converged", bad, n_evaluations=nfev, projection=how,
                                  run_off_near=_ran_off_near(h_hat, h0, rough_hat, shaded=s.diffuse))
    if np.any(n_hat @ m.rig_arr[0].T + h_hat <= 0):
        return LightAwareEstimate(name, "light_behind_plane", f"h = {h_hat:.4g} mm", n_evaluations=nfev)
    verdict = PlaneVerdict(m, rig, x, n0, e1, e2, n_hat, h_hat, rough_hat, how, floor_level)
    est = _finish(name, verdict.at_solution, n_hat, h_hat, rig, x[3:], TOL.photometric_noise_rel, nfev, conv,
                  roughness=rough_hat, detail="" if conv else msg, n_linear=m.design.shape[1] if m.general else 4,
                  post=verdict.post)
    if colour_detail:
        est = est.noted(colour_detail)
    est = replace(est, lobe=s.lobe, n_residuals=int(len(m.yn)), projection=how, fitted_distance_mm=h_hat)
    if lower is not None and est.status in ("ok", "depth_not_observable"):
        # the shape check on the darkest channel: a curved patch is curved in every channel, and
        # the projection's residual can hide it (a JPEG frame's blocky chroma)
        c, clip_c = _darkest(values, s.clip_level, s.clip_margin)
        chan = _fit_lobes(np.asarray(values, dtype=np.float64)[..., c], origin_uv, bp_uv, m.camera, rig,
                          replace(s, clip_level=clip_c, clip_margin=None, start_normal=est.normal, start_roughness=None,
                                  start_distance_mm=h_hat, n_start_depths=0, projection="auto", two_channels=None))
        if chan.status == "plane_misfit":
            est = est.without_depth("plane_misfit", f"channel {c}'s fit misfits ({chan.detail}); {est.detail}")
    return est


def _darkest(rgb, clip_level, margin=None) -> tuple[int, float | None]:
    """The channel of an RGB ROI whose median is least, and its clip level less ``margin`` (None
    without a clip level)."""
    rgb = np.asarray(rgb, dtype=np.float64)
    c = int(np.argmin(np.median(rgb.reshape(-1, 3), axis=0)))
    clip = None if clip_level is None else float(per_channel(clip_level)[c])
    if clip is not None and margin is not None:
        clip -= float(per_channel(margin)[c])
    return c, clip


def _colour_values(rgb, clip_level, projection: str = "auto", two_channels: bool = False, margin=None):
    """The single image a colour ROI is fitted on: ``(values, clip_level, lower, missing, detail, how)``. The projection
    of :func:`~simtest.reconstruct.lightaware.colour.specular_image`, or the darkest channel with its clip level
    where none exists or the pixels the projection values no longer show the lobe (:func:`_sees_lobe`: a channel
    it weighs negatively clipped over it); ``how`` is the estimate's ``projection``."""
    rgb = np.asarray(rgb, dtype=np.float64)
    out, how = None, None
    if projection in ("auto", "border"):
        out, how = specular_image(rgb, clip_level, fluctuation=False, two_channels=two_channels,
                                  censor_margin=margin), "body_colours"
    if out is None and projection in ("auto", "least_fluctuation"):
        out, how = specular_image(rgb, clip_level, border=False, two_channels=two_channels,
                                  censor_margin=margin), "least_fluctuation"
    hidden = out is not None and not _sees_lobe(out[0], out[2])
    out = None if hidden else out  # (hidden: the projection's clipped channel hides the lobe; the darkest reads it)
    if out is not None:
        values, lower, missing, w = out
        text = "body colours projected out" + ("" if how == "body_colours" else " by the least-fluctuation weights")
        weights = ", ".join(f"{x:.3g}" for x in w)
        return values, None, lower, missing, f"{text} (w = {weights})", how
    c, clip = _darkest(rgb, clip_level, margin)
    why = (f"channel {c} (the {how.replace('_', ' ')} projection's valued pixels show no lobe: a channel it "
           "weighs negatively clipped over it)" if hidden else f"channel {c}" if projection == "darkest_channel" else
           f"channel {c} (no two body colours to project out: the border holds one, or white lies too near them)")
    return rgb[..., c], clip, None, None, why, "darkest_channel"


def _sees_lobe(values, missing) -> bool:
    """Whether a projection's image ``values`` (H, W), ``missing`` (H, W) bool left out, still shows the lobe:
    its largest valued pixel at least :data:`SIGNIFICANCE_MIN` times the noise above the border's median
    (the noise from the second differences along rows of valued pixels; True where nothing is missing)."""
    if missing is None or not missing.any():
        return True
    v = np.where(missing, np.nan, np.asarray(values, dtype=np.float64))
    border = border_ring(v)
    d = second_differences(v).ravel()
    d, border = d[np.isfinite(d)], border[np.isfinite(border)]
    noise = noise_sigma_of_differences(d) if len(d) >= 3 else 0.0
    return len(border) > 0 and bool(np.nanmax(v) - float(np.median(border)) > SIGNIFICANCE_MIN * noise)


def _one_channel_clipped(rgb, clip_level) -> bool:
    """Whether an RGB ROI holds a pixel clipped in exactly one channel."""
    return clip_level is not None and bool(np.any(np.count_nonzero(np.asarray(rgb) >= per_channel(clip_level), 2) == 1))


def _two_channel_choice(both: LightAwareEstimate, plain: LightAwareEstimate, darkest=None) -> LightAwareEstimate:
    """``both`` (one-channel-clipped pixels valued from two channels) or ``plain`` (without them):
    ``both`` where both are ``ok`` on a projection, its normal sigma smaller, and they agree as a
    Hausman test asks (J. A. Hausman, Econometrica 46(6), 1978, https://doi.org/10.2307/1913827):
    angle and depth gaps within ``TWO_CHANNEL_Z`` times ``sqrt(sigma_plain^2 - sigma_both^2)``.
    Where they disagree one of them misreads the lobe (the two channels a textured tissue's second
    colour, or ``plain`` the lobe's core, whose pixels it lost), and ``darkest()``, the darkest
    channel's fit, which needs neither, referees where it is ``ok``: the more precise of the two that
    agrees with it by the same test, else it stands in (``plain`` without it)."""
    if not (plain.status == "ok" and both.status == "ok" and plain.has_normal and both.has_normal
            and both.projection in ("body_colours", "least_fluctuation")):
        return plain  # (on one channel no pixel is valued from two)
    if None in (plain.normal_sigma_deg, both.normal_sigma_deg, plain.depth_sigma_mm, both.depth_sigma_mm,
                plain.depth_mm, both.depth_mm) or not both.normal_sigma_deg < plain.normal_sigma_deg:
        return plain  # (no more precise: nothing gained)
    agree, apart = _hausman(both, plain)
    if agree:
        return both.noted("pixels clipped in one channel valued from the other two (the fit without them "
                          f"agrees: {apart.format('within')})")
    chan = None if darkest is None else darkest()
    if chan is None or not chan.ok:
        return plain
    why = f"the fits with and without the pixels clipped in one channel disagree ({apart.format('beyond')})"
    sure = None not in (chan.normal_sigma_deg, chan.depth_sigma_mm, chan.depth_mm)
    for e, how in ((both, "with"), (plain, "without")):  # (both the more precise)
        if sure and _hausman(e, chan)[0]:
            return e.noted(f"{why}; the darkest channel's fit agrees with the one {how} them")
    return chan.noted(why)


def _hausman(eff: LightAwareEstimate, other: LightAwareEstimate) -> tuple[bool, str]:
    """Whether two fits agree as :func:`_two_channel_choice`'s test asks (``eff`` the more precise), and how
    far apart they lie against the rooms ``TWO_CHANNEL_Z sqrt(sigma_other^2 - sigma_eff^2)`` (deg, mm)."""
    gap, dgap = float(angle_between_deg(eff.normal, other.normal)), abs(float(eff.depth_mm) - float(other.depth_mm))
    room, droom = (TWO_CHANNEL_Z * math.sqrt(max(o * o - e * e, 0.0)) for o, e in (
        (other.normal_sigma_deg, eff.normal_sigma_deg), (other.depth_sigma_mm, eff.depth_sigma_mm)))
    return gap <= room and dgap <= droom, f"{gap:.2g} deg and {dgap:.2g} mm apart, {{}} {room:.2g} deg and " \
                                          f"{droom:.2g} mm"


def _bic(est: LightAwareEstimate) -> float:
    """``m log(RSS / m)`` of a fit (the ``k log m`` term is the same for both lobes); +inf without a normal."""
    if not est.has_normal or est.residual_rms is None or not est.n_residuals:
        return math.inf
    return est.n_residuals * math.log(max(est.residual_rms, 1e-300) ** 2)


def _choose_lobe(pho: LightAwareEstimate, *others: LightAwareEstimate) -> LightAwareEstimate:
    """The Phong fit or one of the other lobes' (``photometric_fit``'s Notes); its detail names the others' RMS."""
    def rank(e):  # a curved pattern in the residual (_curved) ranks last; of such, Phong
        failed, flawed = e.status == "not_converged" or not e.has_normal, _curved(e)
        return (failed, flawed, 0.0 if flawed and e is pho else (1.0 if flawed else _bic(e)))

    best = min((pho, *others), key=rank)  # (a tie keeps the first: Phong)
    if best is not pho and _curved(pho) and _bic(best) > _bic(pho):
        best = pho  # another lobe passing with a larger residual than Phong's curved fit: no lobe's pattern
    rms = [f"{e.lobe}'s {e.residual_rms:.4g}" for e in (pho, *others) if e is not best and e.residual_rms is not None]
    why = (f"{best.lobe} lobe: residual RMS {best.residual_rms:.4g} against {', '.join(rms)}"
           if rms and best.residual_rms is not None else f"{best.lobe} lobe")
    return best.noted(why)
