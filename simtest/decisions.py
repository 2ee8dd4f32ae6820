"""Every decision number of the reconstruction, with its unit, its physical reason and its provenance.

A decision number is one that decides what a user gets: which bright components become candidates,
which candidates earn ``ok``, when a light-aware fit is believed, which normal is recommended.
Each lives here once, as :func:`~simtest.provenance.decision` ``(name, value, unit, why, basis,
chosen_on, n)``; the modules that apply it import it by name (``simtest.reconstruct.verify.CONTRAST_MIN``
is this module's). Numerical settings that change no outcome (solver step sizes, block sizes for speed)
stay beside the code they tune. Where a value comes from (``basis``, the datasets of
:data:`~simtest.provenance.DATA` and their sides): :mod:`simtest.provenance`.
"""

from __future__ import annotations

import numpy as np

from simtest.provenance import DATA, DECISIONS, TUNING_ROOT_SEEDS, DataSet, Decision, data_side, decision

__all__ = ["DATA", "DECISIONS", "TUNING_ROOT_SEEDS", "DataSet", "Decision", "data_side", "decision"]


_D = "detection"
_V = "verification"
_L = "light-aware"
_R = "recommendation"

# --- Detection -----------------------------------------------------------------------------------

BRIGHTNESS_REL = decision(
    "BRIGHTNESS_REL", 0.7, "fraction of full scale",
    "Full-scale detection (the paper's synthetic protocol): a pixel is bright when its luma is at "
    "least this fraction of full scale. The bar only separates highlights from the diffuse level: "
    "each component gives its maximum (the BP), and the isophotes are grown beyond the component.",
    basis="convention", stage=_D)
MIN_AREA_PX = decision(
    "MIN_AREA_PX", 4, "px",
    "Bright components smaller than 2 x 2 px hold no isophote the pixel grid resolves "
    "(``too_small``).", basis="physics", stage=_D)
PEAK_REL = decision(
    "PEAK_REL", 0.6, "fraction of the peak's height above its local background",
    "Local-peak detection cuts each highlight's core at this fraction of its height: for a "
    "Gaussian-like lobe the core's radius is 1.01 sigma (sqrt(2 ln(1 / 0.6))), outside the "
    "primary isophote of FRAME_ISOVALUES (t = 0.7: 0.84 sigma).", basis="physics", stage=_D)
TOPHAT_MIN_REL = decision(
    "TOPHAT_MIN_REL", 0.08, "fraction of full scale",
    "Local-peak detection takes a pixel only where it stands this far above the diffuse background "
    "(the grey opening): below, the pale texture of tissue, 8-bit quantisation and JPEG's ringing "
    "about bright folds give components by the hundred on a real frame. Chosen with the "
    "local-peak detection itself, on the real frames and renders then at hand (e2b9f46). Pixels "
    "clipped white are exempt: the ceiling cuts their height (local_peak_mask's censored).",
    basis="tuned", stage=_D, chosen_on=("banner-labelled", "banner-tiles", "bundled-renders"),
    n="24 banner frames, 3 tiles, every bundled scene at seed 0")
SCOPE_BORDER_LEVEL_REL = decision(
    "SCOPE_BORDER_LEVEL_REL", 0.08, "fraction of full scale",
    "The endoscope's black border (the mask outside its field stop) lies below this luma: the "
    "mask is unlit, so it shows the sensor's black level, read noise and JPEG's ringing only, a "
    "few percent; lit tissue at the field's edge, vignetted, stays above it.", basis="tuned", stage=_D,
    chosen_on=("banner-labelled",), n="the 24 banner frames' borders and their burnt-in text")
FRAME_ISOVALUES = decision(
    "FRAME_ISOVALUES", (0.7, 0.85), "isovalue t, relative to the height above the local background",
    "0.7 lies inside the core that detection cuts out (PEAK_REL 0.6), away from neighbouring "
    "highlights and tissue texture; 0.85 adds a nested isophote for the joint cone axis. Lower "
    "primaries (0.5, 0.6) merged the lobes of the colon render's highlight and cut the isophotes "
    "of the stomach tile's highlights on bright folds.", basis="tuned", stage=_D,
    chosen_on=("bundled-renders", "bench-frames", "banner-labelled", "banner-tiles"),
    n="every bundled scene at seed 0, 2 bench frames, 24 banner frames, 3 tiles")
AUTO_LOCAL_BACKGROUND_REL = decision(
    "AUTO_LOCAL_BACKGROUND_REL", 0.1, "fraction of the BP intensity",
    "Normalisation 'auto' subtracts the ROI border's median when it is at least this fraction of "
    "the BP intensity: a diffuse background of a tenth of the BP moves the t I_bp isophote by "
    "more than the fit's noise (the isophote of t = 0.7 moves to t = 0.73).",
    basis="physics", stage=_D)
MIN_FIT_POINTS = decision(
    "MIN_FIT_POINTS", 6, "contour points",
    "An ellipse has 5 degrees of freedom; one more point gives a residual.",
    basis="physics", stage=_D)
MAX_AXIS_TO_SPREAD = decision(
    "MAX_AXIS_TO_SPREAD", 10.0, "semi-major axis over the points' largest distance from their mean",
    "A fitted ellipse this much longer than its points' spread is not bounded by them (a line, "
    "parallel lines, a short flat arc); an arc of 60 deg of a circle already gives under 4.",
    basis="physics", stage=_D)
ELLIPTICITY_MIN_AREA_PX = decision(
    "ELLIPTICITY_MIN_AREA_PX", 12, "px",
    "Components of at least this area get the ellipticity check: a smaller one's second moments "
    "are too coarse (a 3 x 3 square and a plus sign differ by one pixel).",
    basis="physics", stage=_D)
BACKGROUND_DIV = decision(
    "BACKGROUND_DIV", 10, "frame's shorter side over the background square's side",
    "The local background of local-peak detection is a grey opening over a square of min(H, W) / "
    "10 px (at least 31): wider than any specular lobe of a frame (lobes are a few percent of the "
    "field), narrower than the shading's variation over folds.", basis="physics", stage=_D)
CLIP_MARGIN_REL = decision(
    "CLIP_MARGIN_REL", 0.04, "fraction of an integer frame's full scale",
    "A clipped top is read with the pixels joined to its pixels at the ceiling (every channel) "
    "whose every channel lies within this margin of it (and whose luma lies within "
    "CLIP_LUMA_MARGIN_REL): a lossy codec breaks a clipped top (JPEG's luma quantisation rings, its "
    "4:2:0 chroma bleeds the tissue's colour into the top's edge), so that counted at the ceiling "
    "alone it falls into pieces ('merged') or leaves a single pixel there, and its centroid, the "
    "BP, goes to the largest piece's. Measured with OpenCV's libjpeg on 48 sensor-like plane frames (two guides, sRGB, 1 % "
    "noise): of the pixels clipped before encoding, 2 to 28 % stay at 255 in every channel at "
    "qualities 40 to 98, and 87, 95, 98, 99.8, 99.9, 100 % within 10 levels (4 % of 255) at 40, 60, "
    "75, 90, 95, 98. A whole top gains only its rim within the margins.",
    basis="tuned", stage=_D, chosen_on=("libjpeg-encodes",),
    n="48 frames of tests/test_rig_pairs.sensor_plane, 8 per quality")
CLIP_LUMA_MARGIN_REL = decision(
    "CLIP_LUMA_MARGIN_REL", 0.01, "fraction of an integer frame's full scale",
    "... and whose luma (Rec. 601, as JPEG codes it) lies within this margin of the ceiling: JPEG "
    "codes the luma at full resolution and its error on a flat top is a few tenths of a level, so a "
    "broken top stays near the ceiling in luma where its chroma does not, while the sheen around a "
    "top falls off in luma too (a codec-broken top and a sheen holding a few clipped pixels told "
    "apart). Measured with OpenCV's libjpeg at qualities 60, 80 and 95 on 8 sensor-like plane "
    "frames of random poses (tilt 10 to 35 deg, 14 to 28 mm, every other one with a +-30 % albedo "
    "texture; seeds 1000 to 1007, none a test's): 84 to 100 % of the pixels clipped before "
    "encoding keep a luma of at least 253 (1 % of 255), and at most 8 pixels a frame farther than "
    "2 px from the clipped top do. A top clipped in its main channels only (red and green) is as "
    "flat there: its BP is the centroid of its pixels within the margin.",
    basis="tuned", stage=_D, chosen_on=("libjpeg-encodes",),
    n="24 encodes of 8 tests/test_rig_pairs.sensor_plane frames")
CODEC_CEILING_SPIKE = decision(
    "CODEC_CEILING_SPIKE", 5.0, "times the median count of the levels within CLIP_MARGIN_REL",
    "On a frame with a JPEG grid the clipped tops sit at the levels their flat blocks' quantised DC "
    "decodes to, which may lie below the ceiling (libjpeg at quality 50: 254, with 0.1 % of the top "
    "at 255; at 90 a top split between 254 and 255). The ceiling is the lowest level whose count of "
    "pixels (darkest channel) is a spike: at least this many times the median count of the levels "
    "in the margin, and one 16 x 16 MCU or more. Tops' levels gave 10.0 to 27 on a 480 px frame "
    "(qualities 15 to 95; the rim's levels count more beside a small top) and 23 to 97 on 1280 px "
    "frames (quality 50); the banner's levels, with no top, 1.8: 5 lies between.",
    basis="tuned", stage=_D, chosen_on=("sensor-like-generated", "banner-labelled"),
    n="libjpeg encodes of 9 two-guide plane frames (sensor_plane seed 9015; 8 outside) and the banner")
BACKGROUND_PLATEAU_FACTOR = decision(
    "BACKGROUND_PLATEAU_FACTOR", 2, "times the widest clipped plateau",
    "The background square is at least twice the widest clipped plateau, so that the opening "
    "never fits inside a saturated highlight and takes it for background.",
    basis="physics", stage=_D)
BROAD_LOBE_SCALE = decision(
    "BROAD_LOBE_SCALE", 3, "times the background square",
    "Rough tissue seen close makes lobes wider than the background square: a Blinn-Phong lobe of "
    "exponent m spans 2 f tan(acos(q^(1/m))) at the candidates' level (0.6 of the peak in sRGB, "
    "q = 0.3 in linear light), 114 px for m = 200 (Phong n = 50, the paper's default) at f = 520 px, "
    "against a 72 px square on a 960 x 720 frame. Such a lobe is searched again with a square 3 times "
    "wider, which holds it at twice its width (the plateau factor's rule); rougher lobes stay cut.", basis="physics", stage=_D)
BROAD_ISOPHOTE_REL = decision(
    "BROAD_ISOPHOTE_REL", 0.5, "primary isophote's major axis over the background square's side",
    "A candidate of the wider square replaces the first pass only where its primary isophote (t = 0.7) "
    "is at least half the first square across: the foot of a Gaussian lobe (0.1 of its height) is "
    "sqrt(ln 10 / ln(1 / 0.7)) = 2.5 times wider than its 0.7 isophote, so the first square then "
    "fits inside the lobe's foot. A smaller highlight was measured well by the first square and its "
    "verdict stands. The rule was added after a false ok on a banner tile (tuning data), an isophote "
    "2 px across; its value is the Gaussian foot's, not fitted to that tile.", basis="physics", stage=_D)
MULTIRES_SIGMA_MIN_PX = decision(
    "MULTIRES_SIGMA_MIN_PX", 2.0, "px (Gaussian sigma)",
    "Frames smoothed by at least this sigma are searched at half resolution twice over: the "
    "Gaussian of 2 px leaves 0.6 % of the amplitude at the reduced frame's Nyquist frequency.",
    basis="physics", stage=_D)
MULTIRES_SIDE_MIN_PX = decision(
    "MULTIRES_SIDE_MIN_PX", 256, "px",
    "... on frames whose sides are at least this long (a small frame costs little at full "
    "resolution).", basis="convention", stage=_D)
SMOOTH_NOISE_MIN_REL = decision(
    "SMOOTH_NOISE_MIN_REL", 0.005, "fraction of full scale (the noise's standard deviation)",
    "Detection and contouring are not smoothed below this pixel noise (noise_sigma): renders and clean "
    "frames, 8-bit JPEG ringing included, read below it, and smoothing them only blurs small highlights. "
    "Chosen with the local-peak detection itself, on the real frames and renders then at hand (e2b9f46). "
    "On an 8-bit luma the estimate moves in steps of 0.24 % (its MAD counts half levels): the bar lies "
    "between the steps 0.47 % and 0.71 %.", basis="tuned", stage=_D,
    chosen_on=("banner-labelled", "banner-tiles", "bundled-renders"),
    n="24 banner frames, 3 tiles, every bundled scene at seed 0")
SMOOTH_NOISE_PER_PX_REL = decision(
    "SMOOTH_NOISE_PER_PX_REL", 0.01, "fraction of full scale per px of Gaussian sigma",
    "Above that bar the sigma is 1 px plus 1 px per this much noise: a Gaussian of sigma s divides "
    "white noise by 2 s sqrt(pi), so 2 px at 1 % of full scale leave 0.14 %, below the bar.",
    basis="physics", stage=_D)
SMOOTH_SIGMA_MAX_PX = decision(
    "SMOOTH_SIGMA_MAX_PX", 2.5, "px (Gaussian sigma)",
    "... and at most this (reached at 1.5 % noise): 2 px already keep one highlight in one component; "
    "a wider Gaussian blurs small highlights away (e2b9f46).", basis="convention", stage=_D)

ROI_GROWTH_FACTOR = decision(
    "ROI_GROWTH_FACTOR", 2.0, "factor of the ROI's side",
    "An ROI whose lowest isophote is cut by a side inside the image grows by this factor (a lobe's "
    "isophote radii scale with sqrt(ln(1 / t)), so doubling the side reaches the level t^4).",
    basis="convention", stage=_D)
ROI_MAX_GROWTHS = decision(
    "ROI_MAX_GROWTHS", 4, "growths",
    "... at most this many times (16 times the first side); an isophote still cut is reported "
    "``contour_cut``.", basis="convention", stage=_D)

# --- Verification ----------------------------------------------------------------------------------

PALENESS_MAX = decision(
    "PALENESS_MAX", 0.6, "peak chroma over the tissue's chroma",
    "A dielectric reflects the illuminant's colour (the dichromatic model, Shafer 1985, "
    "doi:10.1002/col.5080100409), so a specular peak is paler than the tissue around it:  adding white s to a tissue colour of largest channel M scales its chroma by "
    "M / (M + s), at most 0.6 once s >= 2 M / 3. Under a rig of separate guides a weaker white lobe "
    "with its rig twin (another guide's lobe where the rig puts it: rig_pairs.rig_twins) is exempt.",
    basis="physics", stage=_V)
WHITE_CHROMA = decision(
    "WHITE_CHROMA", 0.08, "chroma 1 - min(RGB) / max(RGB)",
    "A peak whose chroma is below this is near-white, whatever the tissue's colour: 8-bit "
    "rounding and white balance leave a white reflection within a few percent of grey.",
    basis="convention", stage=_V)
WHITE_SHARE_MIN = decision(
    "WHITE_SHARE_MIN", 0.5, "share of the excess over the background",
    "A specular peak's light above the diffuse background is the illuminant's (the dichromatic "
    "model): in linear light, its white part at least equals the tissue-coloured part in the "
    "tissue's brightest channel. Diffuse texture brightens in the tissue's colour (share near 0). "
    "The banner's isolated highlights that were ok: 8 % below 0.5; the 23 candidates a "
    "white-only surround let through (mostly texture): 74 %.",
    basis="tuned", stage=_V, chosen_on=("banner-labelled",),
    n="181 ok estimates of the 24 banner frames, 52 isolated; 23 such candidates")
SIGNIFICANCE_MIN = decision(
    "SIGNIFICANCE_MIN", 8.0, "single-pixel noise standard deviations at the background's level",
    "Smallest top-hat height at the BP pixel (unsmoothed): the largest of a million Gaussian pixel "
    "noises reaches about 5 sigma, so 8 leaves a margin for noise that is not Gaussian (texture, JPEG). "
    "The light-aware fits hold a colour projection to the same bar: its valued pixels must show the lobe.",
    basis="physics", stage=_V)
CONTRAST_MIN = decision(
    "CONTRAST_MIN", 0.6, "fraction of the room the sensor leaves at the BP",
    "A specular lobe multiplies the irradiance and fills most of the room (background, or the "
    "headroom above it where smaller); a lighter patch of tissue adds tens of percent. The "
    "isolated lobes of the endoscope suite's renders fill 0.75 to 1, the tip of a broad sheen "
    "0.56 to 0.58; on the labelled banner a bar of 0.6 rather than 0.5 refuses 11 ok estimates. Under a rig "
    "of separate guides a white peak with its rig twin is exempt where its light-aware fit finds its plane "
    "with a depth: what the bar asks of the peak's height, the rig's geometry and the fit then show.",
    basis="tuned", stage=_V, chosen_on=("suite-endoscope", "banner-labelled"),
    n="endoscope suite renders at seed 0; 180 ok estimates of 24 banner frames")
PANEL_STD_REL = decision(
    "PANEL_STD_REL", 0.5, "image noise standard deviations (luma std over 5 x 5 px)",
    "A flat-panel pixel varies less than the sensor could image it, so it was drawn (an overlay); a noise-free "
    "render has no panels. Next to a channel at the sensor's ceiling every channel must be that flat: a clipped "
    "channel has no noise, a drawn panel is flat in all of them. A pixel at the ceiling in every channel is no "
    "panel: the clip, not a drawing, flattened it (a white specular plateau).",
    basis="physics", stage=_V)
PANEL_MIN_AREA = decision(
    "PANEL_MIN_AREA", 0.005, "fraction of the frame's pixels",
    "Smallest flat panel: a box or the scope's surround, not a smooth patch of tissue.", basis="convention", stage=_V)
PANEL_FRACTION_MAX = decision(
    "PANEL_FRACTION_MAX", 0.1, "fraction of the isophote region's pixels",
    "Largest share of panel pixels in a candidate's isophote region before it is an overlay.",
    basis="convention", stage=_V)
NEIGHBOUR_REL = decision(
    "NEIGHBOUR_REL", 0.7, "fraction of the peak's top-hat height",
    "A neighbouring specular peak counts toward 'cluster' from this fraction of the peak's height: it then "
    "reaches into the primary isophote's level and bends its contour.", basis="physics", stage=_V)
NEIGHBOUR_AREA_REL = decision(
    "NEIGHBOUR_AREA_REL", 0.1, "fraction of the candidate's own area",
    "... with at least this much area above the valley level (a glint of comparable size; the "
    "micro-relief's sparkle on a broad lobe is not a cluster).", basis="convention", stage=_V)
VALLEY_REL = decision(
    "VALLEY_REL", 0.5, "fraction of the peak's height",
    "... separated from the candidate's lobe by a valley below this fraction of its height (one "
    "lobe has no valley).", basis="physics", stage=_V)
VALLEY_NOISE = decision(
    "VALLEY_NOISE", 3.0, "noise standard deviations",
    "... less this many noise sigmas: a dip the noise could make (0.13 % one-sided) is no valley.",
    basis="physics", stage=_V)
NEIGHBOUR_REACH = decision(
    "NEIGHBOUR_REACH", 3.0, "semi-major axes of the primary isophote",
    "... within this reach: at t = 0.7 of a Phong lobe the t = 0.1 isophote that bounds the "
    "region the method contours is about 2.8 times wider.", basis="physics", stage=_V)
OWN_RADIUS_PX = decision(
    "OWN_RADIUS_PX", 2.0, "px", "... plus this margin, the smoothing's blur.", basis="physics", stage=_V)
GLINT_FIELD_DEG = decision(
    "GLINT_FIELD_DEG", 4.0, "deg of view about the BP's ray (px: the camera's scale at its principal point)",
    "... and, under one light place, never within this angle: the micro-relief's glints on a broad lobe lie where "
    "its facets' slopes (a few degrees) turn the bisector, about twice those slopes of view about the macro "
    "specular point whatever the depth, where a smooth patch's next specular point needs a fold's bend. The "
    "camera's scale at its principal point: exact for an equidistant lens, a wide pinhole's least.",
    basis="tuned", stage=_V, chosen_on=("banner-labelled",),
    n="the largest of 3, 4, 5 deg that keeps every isolated ok of the banner's 24 frames (51 of 120 ok, 54 on "
      "glint clusters)")
GLINT_FIELD_VALLEY_REL = decision(
    "GLINT_FIELD_VALLEY_REL", 0.7, "fraction of the peak's height",
    "... and, under one light place, below this one (NEIGHBOUR_REL's): two lobes of one smooth patch need two "
    "light places, so a dip below the isophote's own level is a glint field's, whose sheen joins glints above "
    "half their height; under separate guides their two lobes of one curved patch can join that high.",
    basis="physics", stage=_V)
SURROUND_REL = decision(
    "SURROUND_REL", 0.5, "fraction of the peak's top-hat height",
    "The surround's light is counted from this fraction of the peak's height.", basis="convention", stage=_V)
OWN_REL = decision(
    "OWN_REL", 0.2, "fraction of the highlight's own height",
    "The surround starts where the highlight's own lobe falls below this level (its primary "
    "isophote scaled by the Gaussian lobe's ratio of radii); well below SURROUND_REL because "
    "Phong and GGX lobes have heavier tails than the Gaussian model.", basis="physics", stage=_V)
SURROUND_FRACTION_MAX = decision(
    "SURROUND_FRACTION_MAX", 0.1, "fraction of the surround's pixels",
    "A highlight whose surround holds more than this share of bright light is one of a cluster, "
    "or a glint on a sheen.", basis="convention", stage=_V)
RESIDUAL_MAX_REL = decision(
    "RESIDUAL_MAX_REL", 0.3, "RMS isophote residual over the semi-minor axis",
    "Nested ellipses: an isophote whose points stray by 30 % of its minor axis is no ellipse (two lobes, a "
    "streak, texture).", basis="physics", stage=_V)
MINOR_AXIS_MIN_PX = decision(
    "MINOR_AXIS_MIN_PX", 0.5, "px",
    "An isophote narrower than one pixel is traced between pixel centres: its shape is the "
    "sampling's, not the highlight's.", basis="physics", stage=_V)
QUANTISATION_SIGMA_LSB = decision(
    "QUANTISATION_SIGMA_LSB", 1.0 / np.sqrt(12.0), "least significant bits",
    "The smallest noise an integer image is judged against: rounding, uniform over one step, has standard "
    "deviation 1 / sqrt(12) (JPEG and noise-free renders would otherwise measure 0).", basis="physics", stage=_V)
NOISE_LEVEL_BINS = decision(
    "NOISE_LEVEL_BINS", 16, "intensity bins over full scale",
    "Significance and panels use the noise at the pixel's level, from the frame's noise level function: sRGB "
    "amplifies the dark's (read noise 2 % of full scale: 9 levels over a dark 8-bit frame, 3 at a lobe's 175 "
    "background). Bins of 1/16 hold the sRGB slope within 30 % above 40 levels; a bin takes the largest of "
    "itself and its two neighbours, so that a drawn panel of one level (its own bins' noise near 0) cannot lower "
    "the bar that finds it.", basis="physics", stage=_V)
NOISE_LEVEL_MIN_SAMPLES = decision(
    "NOISE_LEVEL_MIN_SAMPLES", 500, "pixels",
    "A bin's noise from at least this many pixels (the MAD's standard error about 5 %).", basis="physics", stage=_V)
CONFIDENCE_COEFFICIENTS = decision(
    "CONFIDENCE_COEFFICIENTS", np.array([-9.148, 1.264, 0.555, 1.293, 0.270, 0.000]),
    "logistic intercept, then weights of white share, significance, white surround, residual "
    "ratio, panel share",
    "The confidence's logistic model, fitted by simtest.evaluate.calibration.fit_logistic (L2 "
    "penalty chosen by frame-wise cross-validation) to the labels of the fits that pass the checks, each "
    "fit on the structure whose labelled pixels hold its BP; tests/test_verify.py refits them.",
    basis="tuned", stage=_V,
    chosen_on=("banner-labelled",), n="118 fits that pass the checks on the 24 banner frames, 52 isolated")

DEFAULT_MIN_CONFIDENCE = decision(
    "DEFAULT_MIN_CONFIDENCE", 0.15, "confidence in [0, 1]",
    "The default operating point of a colour frame without a rig of separate lights (no camera "
    "file, or one light), the kind of frame the confidence's model was fitted on: a fit that "
    "passes the checks but ranks below it is low_confidence. Of the thresholds (0 to 0.5 by "
    "0.05) whose F1 over the 98 labelled isolated highlights, from the fits' leave-one-frame-out "
    "confidences, is within 0.01 of the largest (0.511 at 0.3, here; the F1's standard error is about 0.04), "
    "the lowest: recall first.",
    basis="tuned", stage=_V, chosen_on=("banner-labelled",),
    n="118 fits that pass the checks on the 24 banner frames, 52 isolated, leave one frame out")
MIN_CONFIDENCE_UNMODELLED = decision(
    "MIN_CONFIDENCE_UNMODELLED", 0.0, "confidence in [0, 1]",
    "The default operating point where the confidence's model does not describe the frame: every "
    "fit that passes the checks. Under a rig of separate lights (a camera file's guides) each guide "
    "lights its own lobe, so a highlight's partner lies in its surround and two fused lobes make one "
    "candidate whose isophotes are no ellipse, which the model (fitted on frames of one light) reads "
    "as a cluster; the rig's own checks (pairing, joint fits) judge those. On a grey frame the "
    "model's colour feature is not measured (the frames it was fitted on are colour, where it "
    "weighs most), and its surround counts light of any colour: clear highlights of grey renders "
    "get 0.02 to 0.7.", basis="physics", stage=_V)

PAIR_DEPTH_MIN_MM = decision(
    "PAIR_DEPTH_MIN_MM", 2.0, "mm along the BP's ray",
    "Nearest tissue depth over which another guide's specular point is predicted: white-light "
    "colonoscopes and gastroscopes focus from about 2 to 3 mm (their data sheets' near focus); "
    "nearer, nothing is sharp.", basis="physics", stage=_V)
PAIR_DEPTH_MAX_MM = decision(
    "PAIR_DEPTH_MAX_MM", 100.0, "mm along the BP's ray",
    "Farthest depth (the data sheets' far end of the depth of field; beyond it the other guide's "
    "highlight lies within the candidate's own lobe). Under separate guides an ok plane fit whose distance "
    "lies beyond it is not_converged: their lobes coincide there, so no parallax holds its depth.",
    basis="physics", stage=_V)
PAIR_TOL_PX = decision(
    "PAIR_TOL_PX", 2.0, "px",
    "Largest distance between a peak's region and the rig's predicted curve for it to be another "
    "guide's highlight: half a pixel of BP rounding per axis and about a pixel of the detection's "
    "blur (as OWN_RADIUS_PX).", basis="physics", stage=_V)
LOBE_TWIN_EXTENT_RATIO = decision(
    "LOBE_TWIN_EXTENT_RATIO", 1.5, "largest ratio of two lobes' isophote extents in one direction",
    "Two guides' lobes of one smooth patch image its one shape: their isophotes differ in extent only by the "
    "change of curvature between the specular points (an extent goes as curvature^-1/2; lightaware-curved's "
    "patches change by up to 37 %, a ratio of 1.2) and the other lobe's tail. Beyond it no curved-patch fit "
    "is tried (reconstruct.curved_lobes). Measured, not tuned: liver pairs 1.04 to 1.08, a colonoscope "
    "glint pair 1.91.", basis="physics", stage=_L)
LIGHT_AWARE_ROI_SCALE = decision(
    "LIGHT_AWARE_ROI_SCALE", 2.5, "times the detection's ROI half-size, about the BP",
    "The window the photometric fit reads (the lobe's tails down to the background, which the detection's ROI, "
    "cut near the isophote, leaves out), and so the reach within which another candidate's ROI may hold another "
    "guide's lobe of the same curved patch; the fits' default since they began, not re-chosen.",
    basis="convention", stage=_L)
GUIDE_SEEN_REL = decision(
    "GUIDE_SEEN_REL", 0.5, "share of a guide's predicted lobe height",
    "A plane fit predicts every guide's specular point and how high its lobe rises there relative to "
    "the fitted highlight's (the rig's falloff and profile, the plane's geometry). Where another "
    "guide's lobe is predicted in the frame at least this share as high "
    "as the fitted one (at their specular points), or less high where this share of its predicted rise "
    "stands SIGNIFICANCE_MIN noise sigmas above the noise about its point, the image must rise there at "
    "least this share of its predicted rise, both measured alike (the peak within PAIR_TOL_PX of the point above "
    "the median of a ring at the highlight's half-size); else the fit gave the lobe to the wrong guide (one lobe "
    "alone hardly tells which guide lit it). The share leaves room for the albedo, shading and "
    "Fresnel differences between the two points, which the plane model leaves out.",
    basis="physics", stage=_L)
TOP_CORE_SHARE = decision(
    "TOP_CORE_SHARE", 0.5, "share of a clipped top's largest distance from its edge",
    "A guide's specular point is where its lobe peaks, so it lies inside its clipped top, and away from the "
    "top's edge: the top is the lobe's level set above the clip, centred on the peak up to the shift of "
    "the light's falloff and the perspective, which grows with the top (15 px on a top of 106 px inner "
    "radius). A joint fit whose points lie at least this deep in each of a pair's tops places the pair; "
    "a plane three times too far puts them at the tops' inner edges, near 0.", basis="convention", stage=_V)
FUSED_LOBE_LEVEL = decision(
    "FUSED_LOBE_LEVEL", 0.5, "share of the BP's height above the ROI border's median",
    "A guide's specular point belongs to a candidate's highlight when it lies in the connected "
    "region above this share of the BP's height over the diffuse shading: two guides' lobes on one patch peak within a "
    "factor of about two of each other (equal guides, inverse-square falloff over the few mm "
    "between their specular points, both clipped where they fuse), so a fused lobe's peak stays "
    "above half; a valley below half leaves two candidates, each with its own row.",
    basis="physics", stage=_L)
FUSED_TOPS_STRETCH = decision(
    "FUSED_TOPS_STRETCH", 1.5, "length along the rig's curve over width across it",
    "Clipped tops this much longer along the rig's curve than wide hold two guides' lobes: one top is 2 r each "
    "way, two tops s apart are s + 2 r long, longer by half from s = r, where they begin to fuse. Two guides "
    "only: three or more make a polygon of tops, as wide as long.", basis="physics", stage=_L)
FUSED_TOPS_WAIST_PX = decision(
    "FUSED_TOPS_WAIST_PX", 1.0, "px of the tops' distance transform",
    "Two guides' clipped tops fused into one show a waist: between their specular points the top is "
    "narrower than at either (two discs of radius r, s apart: sqrt(r^2 - s^2 / 4) at the middle); one "
    "lobe's top is convex (a plane's isophotes are ellipses), so its distance to the edge along a segment "
    "never drops below the ends'. A waist counts where it is this much shallower than the shallower end: "
    "the transform's step on an edge that noise makes ragged by a pixel.", basis="physics", stage=_L)
PEAK_SMOOTH_SIGMA_PX = decision(
    "PEAK_SMOOTH_SIGMA_PX", 1.0, "px (Gaussian sigma)",
    "Two guides' unclipped lobes fused into one region are told apart on the luma smoothed over a "
    "pixel: it parts a sensor's white noise by sqrt(4 pi) (a dip between two smoothed pixels by "
    "sqrt(2 pi)), and moves a lobe's peak by under 0.1 px for lobes of 3 px sigma or more.",
    basis="physics", stage=_L)
PEAK_SMOOTH_GAP_SHARE = decision(
    "PEAK_SMOOTH_GAP_SHARE", 1.0 / 6.0, "share of the two specular points' gap D (Gaussian sigma)",
    "A fused region that neither its colour nor its tops' stretch vouch for (pale or weak; a dimmer lobe's top "
    "below the brighter's margin) is two guides' lobes only where its luma dips between their points; smoothed "
    "over D / 6, two equal lobes of sigma s keep their dip while sqrt(s^2 + (D / 6)^2) < D / 2, i.e. s < 0.47 D "
    "(two Gaussians dip only for D > 2 s), and white noise falls by sqrt(4 pi) D / 6: a dip of a few levels.",
    basis="physics", stage=_L)
PEAK_TOP_SHARE = decision(
    "PEAK_TOP_SHARE", 0.5, "share of the dip between two peaks, above the valley",
    "Each of two fused unclipped lobes' tops is the region above this share of the dip between "
    "their peaks: halfway, as far from the valley's saddle, where the tops join, as from the "
    "peaks' noise; the tops' centroids place the lobes.", basis="convention", stage=_L)

# --- JPEG noise model (verification) -----------------------------------------------------------------

JPEG_MIN_COEFFICIENTS = decision(
    "JPEG_MIN_COEFFICIENTS", 40, "DCT coefficients outside the zero bin",
    "A quantiser step is estimated from at least this many coefficients (the binomial scatter of "
    "a 0.8 share over 40 draws is 0.06).", basis="physics", stage=_V)
JPEG_PERIODICITY_MIN = decision(
    "JPEG_PERIODICITY_MIN", 0.8, "share of coefficients within 1 of a multiple of the step",
    "The decoder's integer IDCT and 8-bit rounding move each coefficient by up to about 1.5: "
    "84 % stay within +-1 of a multiple at quality 50.", basis="tuned", stage=_V,
    chosen_on=("libjpeg-encodes",), n="OpenCV's libjpeg at quality 50")
JPEG_CHANCE_SD = decision(
    "JPEG_CHANCE_SD", 4.0, "binomial standard deviations",
    "... and this far above the share 3 / q that chance gives (a false step at 1 in 30 000).",
    basis="physics", stage=_V)
JPEG_MIN_STEP = decision(
    "JPEG_MIN_STEP", 4, "grey levels",
    "Smallest identifiable step: the +-1 window of steps 2 and 3 covers every value.",
    basis="physics", stage=_V)
JPEG_UNIMODAL_SHARE = decision(
    "JPEG_UNIMODAL_SHARE", 0.5, "first multiple's count over the later multiples'",
    "A true step's counts fall off from its first multiple; a divisor's first multiple lies "
    "between the step's and holds next to none; a half leaves room for binomial scatter.",
    basis="physics", stage=_V)
JPEG_MIN_QUANTISED = decision(
    "JPEG_MIN_QUANTISED", 4, "frequencies of 64",
    "A frame carries a JPEG grid when at least this many frequencies show a step (one or two can "
    "be texture's periodicity).", basis="convention", stage=_V)
JPEG_BLOCKINESS_CLEAR = decision(
    "JPEG_BLOCKINESS_CLEAR", 1.3, "blockiness (1 on average)",
    "A phase this blocky on both axes is the grid without a search: JPEG at quality 75 or below "
    "makes 1.3 to 2.8; noise and content leave every phase within 0.1 of 1.", basis="tuned",
    stage=_V, chosen_on=("libjpeg-encodes", "suite-endoscope"), n="qualities 25 to 95")

# --- Light-aware fits --------------------------------------------------------------------------------

ISOPHOTE_NOISE_PX = decision(
    "ISOPHOTE_NOISE_PX", 0.05, "px",
    "Floor of a contour point's localisation noise, used only to judge whether a fit observes "
    "the depth: marching squares' interpolation on a smooth 8-bit lobe (1/255 over a slope of "
    "0.1 per px) errs by about 0.04 px.", basis="physics", stage=_L)
PHOTOMETRIC_NOISE_REL = decision(
    "PHOTOMETRIC_NOISE_REL", 0.002, "fraction of the ROI's maximum",
    "Floor of the photometric fit's per-pixel noise for the same judgement: 8-bit quantisation's "
    "RMS (1 / (255 sqrt 12) = 0.0011) doubled for render noise.", basis="physics", stage=_L)
DEPTH_OBSERVABLE_REL_SIGMA = decision(
    "DEPTH_OBSERVABLE_REL_SIGMA", 0.5, "relative 1-sigma of the depth at the noise floors",
    "A light-aware fit reports a depth only when the image depends on it: beyond 0.5 (a factor "
    "of about 1.5) epsilon/d is too small and a depth would be a guess.", basis="physics",
    stage=_L)
PLANE_MISFIT_RHO = decision(
    "PLANE_MISFIT_RHO", 0.3, "correlation of neighbouring residuals",
    "Pixel noise is independent, so a plane model that fits leaves uncorrelated neighbours; "
    "rendered planes measured 0.07 to 0.13 (the pixel's box filter), curved patches 0.47 to 0.98.",
    basis="tuned", stage=_L, chosen_on=("suite-lightaware", "suite-lightaware-curved"),
    n="rendered planes, spheres, cylinders, liver and colon at seed 0")
PLANE_MISFIT_REL = decision(
    "PLANE_MISFIT_REL", 2e-4, "fraction of the ROI's maximum",
    "Smallest systematic residual for the same judgement: a fifth of 8-bit quantisation's RMS; "
    "below it the residual is rounding, whatever its correlation.", basis="physics", stage=_L)
PATCH_MISFIT_RMS_REL = decision(
    "PATCH_MISFIT_RMS_REL", 0.01, "fraction of the ROI's maximum",
    "The quadric patch does not fit above this residual RMS, five times the photometric noise "
    "floor; fits within range left 4e-4 to 1.7e-3, the colon's fold streaks 0.018 to 0.06.",
    basis="tuned", stage=_L, chosen_on=("suite-lightaware-curved",), n="6 realisations per case")
SMOOTHEST_FILM_ALPHA = decision(
    "SMOOTHEST_FILM_ALPHA", 0.015, "GGX alpha",
    "The smoothest wet film the fits take for real (Phong n 8887): half the renderer's smoothest "
    "mucosa film (alpha 0.03), whose fit a bound at n 2000 refused.", basis="physics", stage=_L)
ROUGHEST_FILM_ALPHA = decision(
    "ROUGHEST_FILM_ALPHA", 0.5, "GGX alpha",
    "The roughest lobe the model tells from the rig's diffuse shading (Phong n 6): broader, the "
    "lobe's column and the shading's are nearly collinear over the ROI; two colon-wall fits "
    "below n 6 ended 84 % short in depth.", basis="tuned", stage=_L,
    chosen_on=("suite-endoscope",), n="the colon wall family at seed 0")
DISTANCE_FACTOR_MAX = decision(
    "DISTANCE_FACTOR_MAX", 20.0, "factor of the start's distance",
    "A plane fit whose distance left this factor of its start explains something else (a curved "
    "patch fitted with a large n and h -> 0): not converged.", basis="convention", stage=_L)
RUN_OFF_FACTOR = decision(
    "RUN_OFF_FACTOR", 100.0, "factor beyond the plausible range",
    "A plane fit's Levenberg-Marquardt iterate whose distance or roughness has left the plausible "
    "range (DISTANCE_FACTOR_MAX of the start's distance; the film's roughness range) by this factor "
    "more is stopped there, not converged: a patch that is not the plane (a crest glint, "
    "micro-relief) drives the model to h -> 0 or n -> infinity, where the image hardly depends on "
    "the parameter, and spent the rest of its evaluations there. Of 10 and 100, 100: at 10 a "
    "generated plane lost a light-aware row 0.12 deg off; at 100 no row of the 22 generated "
    "planes changed, and the light-aware step of the colon renders took half the time. The quadric "
    "patch's iterates (apex depth and n) stop so too: no result of lightaware-curved's tuning seed moved.",
    basis="tuned", stage=_L, chosen_on=("bundled-renders", "sensor-like-generated", "suite-lightaware-curved"),
    n="11 renders of 7 bundled scenes; 22 plane frames (ggx_plane seeds 40-41, sensor_plane 100-109); "
      "lightaware-curved seed 0 (132 realisations)")
VALLEY_SCAN_AFTER = decision(
    "VALLEY_SCAN_AFTER", 50, "Levenberg-Marquardt evaluations",
    "A plane fit not converged after this many evaluations crawls along the BP's valley: with large "
    "residuals (the other guide's lobe misplaced) Gauss-Newton's curvature along the depth is far "
    "above the cost's and LM's steps stay small. There each light's valley is scanned about LM's "
    "depth (VALLEY_SCAN_SPAN) and LM resumed from the least cost. On the colonoscope render 202 of "
    "216 solves converge within 50; on a sensor-like plane 8 of 105 solves ended at the cap of 200, "
    "not converged (half its fit time), none with the scan.",
    basis="tuned", stage=_L, chosen_on=("bundled-renders", "sensor-like-generated"),
    n="the colonoscope render at seed 0 (216 solves); test_pair_swap's two poses (sensor_plane "
      "seeds 482 and 423: 53 and 105 solves)")
VALLEY_SCAN_SPAN = decision(
    "VALLEY_SCAN_SPAN", (4.0, 9), "factor of the depth either side; depths scanned per light",
    "The depths a crawling plane fit scans along each light's valley: a factor 4 either side of "
    "LM's, 9 depths a factor sqrt(2) apart. The guides' lobes lie about epsilon / d apart in the "
    "image, so neighbouring depths move them by 30 % of their separation; the span (16-fold) stays "
    "within DISTANCE_FACTOR_MAX of the start.",
    basis="convention", stage=_L)
CLIP_MARGIN = decision(
    "CLIP_MARGIN", 2.0, "noise standard deviations below the clip level",
    "Pixels within 2 sigma below the clip are censored (the curved patches leave them out): nearer, "
    "noise clips a pixel often and its unclipped values are the low draws (mean -0.29 sigma at 1 "
    "sigma below, -0.055 at 2), pulling the lobe down (a fused clipped plateau's depth 30 % short at 1 "
    "% noise, exact without). Of 1, 2, 3: at 1 a row was lost; at 3 a bright red tissue lost 0.7 deg.",
    basis="tuned", stage=_L, chosen_on=("sensor-like-generated",),
    n="tests' sensor_plane seeds 700-729 (60 highlights) and two pinned frames")
CLIP_NOISE_FROM_REL = decision(
    "CLIP_NOISE_FROM_REL", 0.5, "fraction of the clip level",
    "CLIP_MARGIN's sigma is the larger of the ROI's noise and that of its unclipped pixels above "
    "half the clip: noise that grows with the level (shot noise; noise added after a tone curve, "
    "which the linearisation stretches most near the top) is the top's, where the pooled noise of "
    "a darker ROI understates it.", basis="physics", stage=_L)
FLOOR_MARGIN = decision(
    "FLOOR_MARGIN", 3.0, "noise standard deviations above the floor",
    "Pixels within 3 sigma of the floor are left out of the fit: a Gaussian clipped there is "
    "clipped in 0.13 % of draws.", basis="physics", stage=_L)
TWO_CHANNEL_Z = decision(
    "TWO_CHANNEL_Z", 2.0, "standard deviations of a fit difference",
    "The fit with pixels valued from two channels is kept while it agrees with the one without "
    "within 2 sigma (about 95 %); beyond, one of them misreads the lobe and the darkest channel's "
    "fit referees: the more precise of the two that agrees with it as closely, else it stands in.",
    basis="physics", stage=_L)
ON_PLANE_MM = decision(
    "ON_PLANE_MM", 0.1, "mm",
    "A light within this distance of the fitted tangent plane is on it: the specular point lies "
    "within a few px of the BP, below 0.1 mm at 5 to 50 mm and f 300 to 1000 px.",
    basis="physics", stage=_L)
ONE_LIGHT_DEPTH_FACTOR = decision(
    "ONE_LIGHT_DEPTH_FACTOR", 2.5, "factor either way of the fitted depth",
    "Under one light the quadric's data exclude no depth within this factor: the cost changed by "
    "1.3 % between half and twice the truth, and the fitted depth was 0.4 to 0.43 of it.",
    basis="tuned", stage=_L, chosen_on=("suite-lightaware-curved",),
    n="the one-light liver at epsilon/d 0.1")
BODY_PROJECTION_MAX_GAIN = decision(
    "BODY_PROJECTION_MAX_GAIN", 10.0, "noise gain |w| of the body-colour projection",
    "Beyond it the specular white lies too near the tissue's body colours: a 1 % read noise "
    "becomes 10 %, the albedo texture the projection removes.", basis="physics", stage=_L)
BODY_SECOND_SNR = decision(
    "BODY_SECOND_SNR", 1.5, "second singular value of the border over the third",
    "A second body colour is believed above this ratio: noise alone gives 1 + 1.25 / sqrt(M) over "
    "M pixels (thousands: under 1.03) where it is the same in every direction, as it is in units of "
    "each channel's noise (the ratio is read there); JPEG mucosa measured 1.9 to 2.1, noisy mucosa "
    "1.03 to 1.08.",
    basis="tuned", stage=_L, chosen_on=("suite-endoscope",), n="flat mucosa, JPEG 95 and 75")
GGX_FILM_IOR = decision(
    "GGX_FILM_IOR", 1.38, "refractive index",
    "Mucus and water lie between 1.33 and 1.45, where Fresnel's reflectance changes by under 2 % "
    "across a lobe; the lobe's gain absorbs the rest.", basis="physics", stage=_L)
BROAD_LOBE_PHONG_N = decision(
    "BROAD_LOBE_PHONG_N", 100.0, "Phong n (GGX alpha sqrt(2 / (n + 2)) = 0.14)",
    "A one-channel Phong fit this broad is refitted with GGX, the better kept: a broad lobe's tails lie above "
    "the noise, where cos^n falls faster than a microfacet lobe, so a Phong fit that passes still trades its "
    "normal for them (the 0.1 film fitted n 47 to 77, true 198).", basis="tuned", stage=_L,
    chosen_on=("suite-endoscope",), n="endoscope-flat seed 0: film roughness 0.1, 0.2, JPEG 25; 8 realisations each")
LOBE_EDGE_REL = decision(
    "LOBE_EDGE_REL", 0.001, "of the fitted lobe's peak", "The lobe's radius r, where the fit's lobe falls to "
    "this: a ring of a few hundred pixels there still sums above an 8-bit lobe's noise.", basis="physics", stage=_L)
LOBE_ROI_MISMATCH = decision(
    "LOBE_ROI_MISMATCH", 1.5, "lobe radii r", "A ROI narrower than r over this cuts the lobe's tails (a faint "
    "broad lobe's detected region is its noisy top): refit on r. Not the other way: a ROI wider than the lobe "
    "gives the body colours' border room (the 0.1 film's fits on 2 r erred more than on 2.9 r).",
    basis="physics", stage=_L)
SIGMA_CLUSTER_PX = decision(
    "SIGMA_CLUSTER_PX", (8, 16, 32, 64), "px (block sides of the jackknife)",
    "Residuals are correlated over the texture's scale; with blocks of 8 and 16 px alone the "
    "JPEG frames' errors were 1.4 to 2 times the stated sigma, with 32 and 64 px added within "
    "twice it on 29 of 30.", basis="tuned", stage=_L, chosen_on=("suite-endoscope",),
    n="JPEG quality 75 and 25, 15 seeds each")
SIGMA_MIN_CLUSTERS = decision(
    "SIGMA_MIN_CLUSTERS", 16, "blocks",
    "A block side counts where the ROI holds at least this many blocks: the jackknife's relative "
    "standard error is sqrt(2 / 15) = 0.37 there.", basis="physics", stage=_L)

ALBEDO_LINE_PX = decision(
    "ALBEDO_LINE_PX", 7, "px (diameter of the closing's disc)",
    "The albedo's thin dark lines (vessels) that a fit on one channel leaves out are narrower than "
    "this disc: the mucosal vessels are under 0.2 mm wide, a few px at endoscopic distances; a "
    "highlight's lobe is wider.", basis="physics", stage=_L)
ALBEDO_LINE_STEPS = decision(
    "ALBEDO_LINE_STEPS", 2.0, "quantisation steps (or three noise sigmas, the larger)",
    "... and darker than its closing by at least this much: rounding alone moves a pixel by at "
    "most one step.", basis="physics", stage=_L)

# --- Recommendation ----------------------------------------------------------------------------------

ISOCURVE_ISOVALUES = decision(
    "ISOCURVE_ISOVALUES", (0.3, 0.5, 0.7), "isovalue t relative to the BP's height above the border",
    "The isocurve fit's own isophotes, whatever the command line's: near the peak (0.7, 0.85) "
    "the lobe is nearly its quadratic approximation and says little about the distance; the fit "
    "ran off on 9 of 16 planes there and was ok on all 16 at (0.3, 0.5, 0.7), median 0.1 deg.",
    basis="tuned", stage=_R, chosen_on=("exact-planes",),
    n="16 off-axis planes, epsilon/d 0.07 to 0.27")
SIGMA_MARGIN = decision(
    "SIGMA_MARGIN", 2.0, "sigmas",
    "A light-aware normal (with its depth or without) is recommended when this many of its stated sigmas are "
    "below the BP ray's expected error (for a Gaussian error, 98 % one-sided that it is the better).",
    basis="physics", stage=_R)
FUSED_SEPARATION_MAX = decision(
    "FUSED_SEPARATION_MAX", 2.0, "lobe sigmas (the lobe's Gaussian sigma, px)",
    "A rig's lobes whose specular points lie at most this far apart are one lobe with one maximum "
    "(rule 5): two equal Gaussian lobes have one up to 2 sigma apart.", basis="physics", stage=_R)
BP_PLACE_SIGMA_PX = decision(
    "BP_PLACE_SIGMA_PX", 0.29, "px per image axis (1-sigma)",
    "The BP's own error where rule 5 states a sigma: a BP on the pixel grid errs uniformly within "
    "+-0.5 px per axis, an RMS of 1 / sqrt(12); a plateau's centroid does better.",
    basis="physics", stage=_R)
TOP_CORE_PX = decision(
    "TOP_CORE_PX", 3, "px (side of a square)",
    "A clipped top pairs with another guide's (rig_pair) only where it holds a square of this side, the smallest "
    "with an interior pixel: a lobe's top is its level set above the clip, a disc once it holds a few pixels; a "
    "noise that lifts a lobe's flank over the level (added after the clip, JPEG's ringing) leaves specks one or "
    "two pixels across. Such a speck paired with a whole top put rig_pair's points 52 and 72 px off the specular "
    "points (CODED_NOISE root 9 frame 39, tuning: 9.5 deg off at a stated 0.165 deg).", basis="physics", stage=_R)
TOPS_PLACE_SIGMA_PX = decision(
    "TOPS_PLACE_SIGMA_PX", 1.0, "px per image axis (1-sigma)",
    "How far a clipped top's centroid may lie from its guide's specular point where two guides' "
    "lobes fuse (rig_pair's stated sigma): the other lobe's tail lifts the top's inner edge, "
    "moving its centroid inward by up to about a pixel (the two lobes' sum, each symmetric about "
    "its own specular point).", basis="physics", stage=_R)
DEPTH_RELEASE_REL_SIGMA = decision(
    "DEPTH_RELEASE_REL_SIGMA", 0.2, "relative 1-sigma of the depth",
    "A depth is released only within it: the fits estimate log h, and at 0.2 exp(+-0.4) is "
    "already -33 % / +49 %; a 1-sigma of 0.5 spans a factor 2.7 at 2 sigma, no measurement of "
    "scale.", basis="physics", stage=_R)
