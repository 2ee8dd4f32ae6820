"""Issue 39's flat-mucosa must-hold on the endoscope suite's own cases (the colonoscope rig's video
frame of a textured plane, through detection, the light-aware fits and the recommendation): one
realisation each of the settings that failed it (0.5 to 2 % read noise: the fit fell back to the
darkest channel, whose albedo texture took 0.6 to 0.8 deg and 8 to 9 % of the depth) and of the
JPEG setting whose block grid is not seen (quality 95), where the border's body colours must be
told through the encoder's rounding.

Each test holds the frames its defect was found on: the suite's renders with the scene's one
tissue texture (the suite file without its ``texture`` key, :func:`one_texture_endoscope`). With a
texture drawn for each realisation the same realisations gave 0.89 deg (read noise 0.02,
realisation 0) and 0.51 deg (JPEG 95): the must-hold itself is judged on the committed report's
medians over five textures (0.39 and 0.18 deg there)."""

from __future__ import annotations

import numpy as np
import pytest

from simtest.harness.runner import make_runner
from simtest.harness.suite import load_suite, realisation_seed
from test_harness_texture import one_texture_endoscope

@pytest.fixture(scope="module", autouse=True)
def _scored_fits_only(without_end_to_end):
    """These tests assert on the scored rows (the harness's fits of the matched detections); the
    frame's end-to-end records (every candidate fitted again, 90 % of a run's CPU here) are
    tested elsewhere (conftest's ``without_end_to_end``)."""
    yield


#: issue 39's must-hold on the flat mucosa: recommended normal and depth of the specular point
MAX_NORMAL_DEG = 0.5
MAX_DEPTH_PCT = 5.0


def _rows(directory, sweep: str, value: float, realisation: int = 0):
    suite = load_suite(one_texture_endoscope(directory))
    case = next(c for c in suite.cases if c.sweep == sweep and float(c.x) == value)
    runner = make_runner(case, ("recommended", "photometric_fit", "bp_ray"))
    rows = runner.run(realisation_seed(suite.seed, case.key, realisation))
    return [r for r in rows if np.isfinite(r.errors["recommended"])]


#: The frames these tests pin changed with issue 62's branching vessels (two layers of vessel
#: networks in place of one-width loops): the albedo now varies more under the lobe (mean
#: transmission about 0.95 to 0.97 per channel, was about 0.98). Two cases miss their bounds on
#: the new texture: read noise 0.02, depth 5.32 % against 5 % (normal 0.076 deg); micro-relief
#: realisation 4, its plane fit 0.94 deg off (against 0.5) and the BP ray (4.97 deg) recommended
#: on the current code. Kept as strict expected failures, so that the fit that
#: meets them again is seen; the flat-mucosa must-hold is re-judged end to end (issue 63). The
#: read-noise case meets them again since the fits censor within CLIP_MARGIN of the clip (depth
#: 4.45 %, normal 0.036 deg).
VESSELS_62 = pytest.mark.xfail(strict=True, reason="issue 62's vessel texture: the must-hold is missed "
                                                   "on this pinned frame (see VESSELS_62)")


@pytest.mark.parametrize("noise", [0.02])
def test_flat_mucosa_in_read_noise_meets_the_must_hold(noise, tmp_path):
    rows = _rows(tmp_path, "plane_read_noise", noise)
    assert rows
    for r in rows:
        assert r.errors["recommended"] <= MAX_NORMAL_DEG, r
        assert r.extras["recommended_depth_err_pct"] <= MAX_DEPTH_PCT, r
        # its sigma covers the error at 2 sigma, and is no more than the BP ray's error
        assert r.extras["recommended_within_2sigma"] == 1.0, r
        assert r.errors["recommended"] < r.errors["bp_ray"], r


@pytest.mark.parametrize("realisation", [0, 1])
def test_flat_mucosa_in_a_jpeg_frame_at_quality_95_meets_the_must_hold(realisation, tmp_path):
    # JPEG at quality 95: the block grid is not seen and the colour path runs. The encoder's
    # rounding of the chroma brings the border's third singular value to half its second (the
    # vessels' second body colour), which a bound of 3 on their ratio took for no second colour:
    # the least-fluctuation weights' fit misfit (0.3 deg off) and the darkest channel's stood in,
    # 0.6 deg off and 8 % short in depth. The border band's body colours (ratio about 2) fit it
    # within the must-hold, their error within twice their sigma
    rows = _rows(tmp_path, "plane_jpeg_quality", 95, realisation)
    assert rows
    for r in rows:
        assert r.errors["recommended"] <= MAX_NORMAL_DEG, r
        assert r.extras["recommended_depth_err_pct"] <= MAX_DEPTH_PCT, r
        assert r.extras["recommended_within_2sigma"] == 1.0, r


@pytest.mark.parametrize("relief, realisation", [(0.0, 0), (0.002, 1)])
@pytest.mark.slow
def test_on_the_colon_wall_a_projected_fit_without_its_depth_is_not_recommended(relief, realisation, tmp_path):
    # The colon wall (curved) of the suite's micro_relief sweep. A fit on a projection passed its
    # own tests with its depth not observable or above the recommendation's ceiling, and was
    # recommended over the BP ray: on the least-fluctuation weights (relief 0.002, realisation
    # 1: relative depth sigma 0.37, 16 deg off, sigma 2.4, where the BP ray erred 1.5 deg), and
    # on the border band's body colours (relief 0, realisation 0: 17.6 deg off, sigma 3.6, BP ray
    # 2.3 deg). Such a fit gives way to the darkest channel's (issue 39's must-hold on curved
    # meshes: never worse than the BP ray by more than the recommendation's stated sigma). The
    # relief-0 row's JPEG-broken top, once in pieces (merged: its plane fit 16.9 deg off with a
    # sigma of 4.1), is now read whole (CLIP_LUMA_MARGIN_REL); its isophote encloses another BP
    # (merged, not fitted): the BP ray, 2.2 deg. That fit's sigma is not mended, only not reached
    rows = _rows(tmp_path, "micro_relief", relief, realisation=realisation)
    assert rows
    # within 1 deg of the BP ray's error: a recommended fit's own sigma may allow that much (its
    # sigma beats the BP ray's 2 to 5 deg), the 17.5 deg of that fit it does not
    for r in rows:
        assert r.errors["recommended"] <= r.errors["bp_ray"] + 1.0, r


@pytest.mark.parametrize("realisation", [pytest.param(4, marks=VESSELS_62), 7])
@pytest.mark.slow
def test_flat_mucosa_under_a_micro_relief_keeps_the_plane_fit_within_its_sigma(realisation):
    # The suite's flat mucosa under a 0.002 mm RMS micro-relief, its texture drawn for each
    # realisation as `validate` draws it: the relief's random curvatures over the lobe put a
    # curved patch's pattern in the residual, which the score test sees on the frame's 165,000
    # pixels (score 321 to 793 against 21.1), and the plane fit, 0.18 and 0.13 deg off, was
    # plane_misfit: the BP ray (6.3 and 6.8 deg) was recommended. That pattern moves the normal
    # by less than the fit's sigma (solve._curvature_shift: 0.04 to 0.14 deg against 0.14 to
    # 0.26), so the fit is kept, its sigma grown by the shift, and covers its error at 2 sigma
    suite = load_suite("endoscope")
    case = next(c for c in suite.cases if c.sweep == "plane_relief" and float(c.x) == 0.002)
    rows = make_runner(case, ("recommended", "photometric_fit", "bp_ray")).run(
        realisation_seed(suite.seed, case.key, realisation))
    rows = [r for r in rows if np.isfinite(r.errors["recommended"])]
    assert rows
    for r in rows:
        assert r.extras["recommended_bp_ray_share"] == 0.0, r
        assert r.extras["recommended_within_2sigma"] == 1.0, r
        assert r.errors["recommended"] <= MAX_NORMAL_DEG, r
