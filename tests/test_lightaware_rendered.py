"""Light-aware reconstruction on Mitsuba renders (8-bit, 16 spp, 200 x 200 px) lit off the camera."""

from __future__ import annotations

import functools

import numpy as np
import pytest

from simtest.geometry import angle_between_deg
from simtest.geometry.lights import Light, LightRig
from simtest.harness import protocols
from simtest.harness.protocols import RenderedRunner, reconstruct_image, render_rig
from simtest.harness.suite import harness_recon_settings, load_suite, realisation_seed
from simtest.reconstruct.recommend import recommend
from simtest.reconstruct.light_fits import with_light_aware
from simtest.render import render_scene
from simtest.scene import load_scene, with_overrides

ISOVALUES = (0.3, 0.5, 0.7)
#: The settings of a rendered harness case with those isovalues.
SETTINGS = harness_recon_settings("rendered", ISOVALUES[0], ISOVALUES[1:])
#: The issue's must-holds on rendered planes: mean normal error and depth error (eps/d >= 0.1).
MEAN_NORMAL_DEG = 0.3
DEPTH_REL = 0.03

PLANE = {"camera.width_px": 200, "camera.height_px": 200, "camera.fov_deg": 70.0,
         "geometry.tilt_deg": 20.0, "geometry.distance_mm": 20.0, "light.falloff": "keep",
         "light.intensity": 400.0, "material.n": 60.0, "sensor.exposure": 0.9,
         "light.alpha_deg": 30.0, "light.b": 0.0}


def _render(overrides, seed=1):
    spec = with_overrides(load_scene("plane_58deg"), {**PLANE, **overrides})
    return render_scene(spec, seed=seed)


def _matched(ests, bp):
    return min(ests, key=lambda e: float(np.linalg.norm(np.asarray(e.bp_px) - bp)))


@pytest.fixture(scope="module")
def plane_results():
    out = []
    for eps in (1.0, 2.0, 6.0, 10.0):  # epsilon/d = 0.05, 0.1, 0.3, 0.5 at 20 mm
        res = _render({"light.epsilon_mm": eps})
        rig = render_rig(res)
        ests = with_light_aware(res.sensor, reconstruct_image(res.sensor, res.K, SETTINGS), res.K, rig)
        h = res.highlights[0]
        est = _matched(ests, h.bp_px)
        out.append((eps / 20.0, est, h))
    return out


def test_rendered_planes_normal_and_depth(plane_results):
    errs, bp_errs = [], []
    for eps_d, est, h in plane_results:
        rec = recommend(est)
        assert rec.normal_from == "photometric_fit"
        errs.append(angle_between_deg(rec.normal, h.normal))
        bp_errs.append(angle_between_deg(est.bp_ray, h.normal))
        if eps_d >= 0.1:
            assert abs(rec.depth_mm / np.linalg.norm(h.bp_mm) - 1) <= DEPTH_REL, (eps_d, rec)
    assert float(np.mean(errs)) <= MEAN_NORMAL_DEG, errs
    # the baseline it replaces: the BP ray errs by about 24 deg per unit epsilon/d
    assert float(np.mean(bp_errs)) > 10 * MEAN_NORMAL_DEG


def test_two_light_merged_highlight_on_renders():
    # Two light guides 2 mm either side of the lens: the image of the pair is the sum of the two
    # lights' renders (direct lighting only), quantised to 8 bits like the sensor does.
    renders = [_render({"light.epsilon_mm": 2.0, "light.alpha_deg": a, "light.b": 0.0})
               for a in (0.0, 180.0)]
    linear = sum(np.asarray(r.linear, dtype=np.float64) for r in renders)
    sensor = np.rint(np.clip(0.5 * 0.9 * linear, 0.0, 1.0) * 255).astype(np.uint8)
    rig = LightRig(tuple(Light(tuple(float(x) for x in r.light_pos), 0.5, "inverse_square")
                         for r in renders))
    ests = reconstruct_image(sensor, renders[0].K, SETTINGS)
    assert len(ests) == 1, "the two highlights merge into one blob"
    est = with_light_aware(sensor, ests, renders[0].K, rig)[0]
    pho = est.light_aware["photometric_fit"]
    truth = renders[0].highlights[0].normal  # a plane: one normal
    assert pho.has_normal and angle_between_deg(pho.normal, truth) <= MEAN_NORMAL_DEG
    assert recommend(est).normal_from == "photometric_fit"
    assert "isocurve_fit" in est.light_aware and est.light_aware["isocurve_fit"].status == "multi_light_rig"


#: The issue's must-hold on rendered curved surfaces: median normal error at epsilon/d 0.1 and 0.3.
CURVED_MEDIAN_DEG = 1.0


def test_rendered_sphere_under_one_light_is_recommended_the_bp_ray():
    # The lightaware-curved suite's sphere (radius 20 mm, 50 mm away, Phong n = 30, falloff
    # kept), lit 5 and 15 mm off the camera (epsilon/d 0.1 and 0.3), two seeds each: the plane
    # fit reports its misfit and the quadric patch is run. Its normal is good here (a sphere has
    # no third-order shape: suite medians 0.31 and 0.79 deg), but under one light its depth
    # trades with the third-order shape the data cannot exclude (on the liver the same fit erred
    # 3.8 deg, its depth 57 % short, where the BP ray erred 2.9): no depth is released, its sigma
    # spans the depths within a factor 2.5, and the BP ray is recommended (issue 39: the
    # one-light curved target is withdrawn).
    errs = []
    for eps in (5.0, 15.0):
        for seed in (1, 2):
            spec = with_overrides(load_scene("sphere"), {"camera.width_px": 200,
                                                         "camera.height_px": 200,
                                                         "light.epsilon_mm": eps})
            res = render_scene(spec, seed=seed)
            rig = render_rig(res)
            ests = with_light_aware(res.sensor, reconstruct_image(res.sensor, res.K, SETTINGS),
                                    res.K, rig)
            h = res.highlights[0]
            est = _matched(ests, h.bp_px)
            assert est.light_aware["photometric_fit"].status == "plane_misfit"
            q = est.light_aware["quadric_fit"]
            assert q.status != "ok" and q.depth_mm is None, q
            rec = recommend(est)
            assert rec.normal_from == "bp_ray", q
            if q.has_normal:
                errs.append(angle_between_deg(q.normal, h.normal))
    assert len(errs) >= 3 and float(np.median(errs)) <= CURVED_MEDIAN_DEG, errs


@pytest.fixture(scope="module", autouse=True)
def _scored_fits_only(without_end_to_end):
    """The suite runs here are asserted on their scored rows (the harness's fits of the matched
    detections); the frames' end-to-end records (every candidate fitted again) are tested
    elsewhere (conftest's ``without_end_to_end``)."""
    yield


@pytest.fixture(scope="module", autouse=True)
def _renders_once(shared_renders):
    """The suite's renders made once in this module (conftest's shared_renders): the liver tests
    profile the very frames that the liver_two_lights sweep scores (:func:`_liver_case`)."""
    yield


def _curved_suite_errors(sweep, realisations=(0, 1), values=None):
    """Errors (deg) of the recommended normal and of the BP ray on a ``lightaware-curved`` sweep (``values``:
    its cases at those sweep values only), run as the harness runs it (the suite's scene settings and
    realisation seeds): a list of ``(epsilon/d, recommended, bp_ray, within 2 sigma)``, one per scored
    highlight (the last 1.0 where the recommended normal's error is at most twice its stated sigma, 0.0
    where not, NaN where it states none)."""
    suite = load_suite("lightaware-curved")
    out = []
    for case in (c for c in suite.cases if c.sweep == sweep and (values is None or c.x in values)):
        runner = RenderedRunner(case, ("recommended", "bp_ray"))
        for i in realisations:
            for row in runner.run(realisation_seed(suite.seed, case.key, i)):
                out.append((row.extras["eps_over_d"], row.errors["recommended"],
                            row.errors["bp_ray"], row.extras["recommended_within_2sigma"]))
    return out


@pytest.mark.parametrize("sweep", ["cylinder_offset", "saddle_offset"])
def test_rendered_cylinder_and_saddle_under_one_light_keep_the_bp_ray_or_beat_it(sweep):
    # The suite's cylinder (radius 15 mm, 55 mm away) and saddle (r1 = 80 mm, r2 = 150 mm, 60 mm
    # away) at epsilon/d 0.1 and 0.3, two realisations each: under one light the quadric's depth
    # is not observable (its third-order shape trades with it), and the BP ray is kept unless a
    # misfitting plane's normal is confirmed by the quadric's (recommend's rule 4); such a normal
    # is better than the BP ray and within twice its stated sigma (the cylinder at 0.3,
    # realisation 0: 2.6 deg against 8.2).
    rows = _curved_suite_errors(sweep)
    eps_d = sorted(r[0] for r in rows)
    assert eps_d[0] == pytest.approx(0.1, abs=0.01) and eps_d[-1] == pytest.approx(0.31, abs=0.02)
    for eps_d, rec, bp, within in rows:
        assert rec == bp or (rec < bp and within == 1.0), (eps_d, rec, bp, within)


def test_rendered_colon_recommended_normal_is_never_worse_than_the_bp_ray():
    # The colon's fold streaks are no quadric patch's lobe: the curved fit misfits (correlated
    # or large residuals) or runs off, and the recommendation is the BP ray. epsilon/d 0.1 and
    # 0.3 at the highlight, as the suite sets them (the must-hold's median <= 1 deg is not met
    # there). Without the residual-RMS test the fit of realisation 0 at 0.3 ends "ok" on a
    # streak, its depth at half the truth.
    rows = _curved_suite_errors("colon_offset")
    assert len(rows) >= 3
    assert {round(r[0], 1) for r in rows} == {0.1, 0.3}
    for eps_d, rec, bp, _ in rows:
        assert rec == bp, (eps_d, rec, bp)


def test_rendered_liver_under_two_lights_is_recommended_a_normal_within_the_median():
    # The suite's liver pose lit by two guides either side of the lens (epsilon/d 0.1 and 0.3 for
    # each light), realisation 0: the third-order patch fitted to both lobes is recommended and
    # each light's highlight is scored with the normal at its specular point. Under one light
    # (test above, the liver_offset sweep) the recommendation is the BP ray, 2.9 deg off at 0.1.
    rows = _curved_suite_errors("liver_two_lights", realisations=(0,), values=(6.4, 19.1))
    assert {round(r[0], 1) for r in rows} == {0.1, 0.3}
    rec = [r[1] for r in rows]
    bp = [r[2] for r in rows]
    assert float(np.median(rec)) <= CURVED_MEDIAN_DEG, rows
    assert all(a < b for a, b in zip(rec, bp)), rows


@functools.lru_cache(maxsize=None)
def _liver_case(sweep, eps_mm):
    """The suite's liver render (realisation 0) of one case, its rig and its matched estimate;
    rendered once per module (two tests profile the same case)."""
    from simtest.constants import MAX_SEED

    suite = load_suite("lightaware-curved")
    case = next(c for c in suite.cases if c.sweep == sweep and c.x == eps_mm)
    runner = RenderedRunner(case, ("bp_ray",))
    seed = int(realisation_seed(suite.seed, case.key, 0).generate_state(1, np.uint32)[0]) & MAX_SEED
    # through the harness's render_scene, as the runner renders it: one render per module
    res = protocols.render_scene(with_overrides(runner.spec, {"render.seed": seed}), seed=seed)
    img, rig = np.asarray(res.sensor), render_rig(res)
    h = res.highlights[0]
    est = _matched(reconstruct_image(img, res.K, runner.settings), h.bp_px)
    return res, img, rig, est


def _liver_profile(sweep, eps_mm, factors, depth_scale=1.0):
    """The cubic patch's depth profile on the suite's liver render (realisation 0) at the depths
    ``factors`` times the true apex depth (times ``depth_scale``), in units of the noise floor's
    variance above its value at the truth (the second factor must be 1)."""
    from simtest.reconstruct._pixels import Roi
    from simtest.reconstruct.detect import luma
    from simtest.reconstruct.lightaware import patch_depth_profile
    from simtest.tolerances import TOL

    res, img, rig, est = _liver_case(sweep, eps_mm)
    roi = Roi(*(int(v) for v in est.roi))
    near = Roi.around(est.bp_px, 1.5 * max(roi.shape) / 2.0, img.shape)  # the recommendation's
    # the apex is the mean light's specular point; for the symmetric pair on this smooth patch
    # its depth is within 0.1 % of the mean of the two lights' (measured 63.58 to 63.72 mm)
    depth = depth_scale * float(np.mean([np.linalg.norm(x.bp_mm) for x in res.highlights]))
    cost = patch_depth_profile(luma(img)[near.slices], (near.col0, near.row0), est.bp_px, res.K,
                               rig, depth * np.asarray(factors), clip_level=255.0)
    return (cost - cost[1]) / TOL.photometric_noise_rel**2


#: Bound on each guide's end-to-end error on the liver under two guides at epsilon/d 0.3: the README's "within 1
#: deg", and half the BP ray's error (the suite's two-guide claim). Measured 0.05 to 0.06 deg, the BP ray 8.2 to 8.6.
LIVER_RIG_E2E_DEG = 1.0


@pytest.mark.slow
def test_rendered_liver_under_two_guides_apart_gets_each_guides_normal_end_to_end():
    # As a user gets it (simtest reconstruct with the render's camera file): at epsilon/d 0.3 each guide's lobe is
    # the other's cluster neighbour, nearer than any plane through its BP puts it, and one patch fit of both makes
    # each guide's row (reconstruct.curved_lobes). Both had the BP ray before.
    from simtest.harness.end_to_end import frame_records

    res = _liver_case("liver_two_lights", 19.1)[0]
    recs = frame_records(res, lambda e, h, r: {"recommended_depth_err_pct": np.nan,
                                               "recommended_depth_within_2sigma": np.nan})
    assert len(recs) == 2, recs
    for r in recs:
        assert r["status"] == "ok" and r["normal_from"] in ("quadric_fit", "cubic_patch_fit"), r
        assert r["error_deg"] < min(LIVER_RIG_E2E_DEG, r["bp_ray_error_deg"] / 2.0), r


@pytest.mark.slow
def test_rendered_liver_depth_is_observable_under_two_lights_and_not_under_one():
    # Where the must-hold breaks under one light, and what a second light changes. The cubic
    # patch refitted with the apex depth fixed at 0.71, 1 and 1.41 times the truth; rises in
    # units of the noise floor's variance (a chi^2 difference: 9 is 3 sigma). One light at
    # epsilon/d 0.3: flat (measured below 0.02): the third-order shape stands in for the offset.
    # Two lights at 0.3: above 9 on both sides (measured 1970 and 1350). At 0.1 the nearer side
    # rises (measured 126); the farther side did not (measured -7): there the depth is bounded
    # from below only, and the fit ends deep (11 % on average over the suite's realisations).
    factors = [0.71, 1.0, 1.41]
    one = _liver_profile("liver_offset", 19.1, factors)
    assert np.all(np.abs(one) < 1.0), one
    two = _liver_profile("liver_two_lights", 19.1, factors)
    assert np.all(np.delete(two, 1) > 9.0), two


def test_rendered_liver_depth_profile_is_the_images_not_the_depths_8th_digit():
    # The profile is the image's, not the 8th digit's of the depths asked for: the cuda_ad_rgb
    # render of this scene (the same 8-bit image) gives a truth 3e-8 deeper, at which the
    # profile's fits from the narrow flat start alone all missed a lobe (costs 1.8 to 8.3, against
    # 0.0014 to 0.0093 here); each fit also starts wide now (_PROFILE_WIDE_START).
    moved = _liver_profile("liver_two_lights", 19.1, [0.71, 1.0, 1.41], depth_scale=1.0 + 3e-8)
    assert np.all(np.delete(moved, 1) > 9.0), moved


def test_rendered_liver_depth_is_bounded_from_below_under_two_lights_at_epsilon_over_d_0_1():
    near = _liver_profile("liver_two_lights", 6.4, [0.71, 1.0, 1.41])
    assert near[0] > 9.0, near


def test_the_plane_fit_on_the_endoscope_renders_specular_image_recovers_the_normal():
    # The endoscope suite's flat mucosa (guides 4 mm off the lens, plane 20 mm away, GGX film):
    # its sensor image holds the textured albedo's diffuse shading and the sRGB tone curve
    # besides the lobes, and the photometric fit there errs by tenths of a degree. On the
    # render's specular radiance alone (the oracle input of ``photometric_fit_on_specular``)
    # the same fit recovers the plane: the model and its geometry are right, the rest of the
    # image formation is what defeats it. Bound: 0.05 deg, ten times the 0.003 deg measured and
    # fifty times below the BP ray's error there (2.5 deg).
    suite = load_suite("endoscope")
    case = next(c for c in suite.cases if c.sweep == "guide_offset" and c.x == 4.0)
    runner = RenderedRunner(case, ("photometric_fit", "photometric_fit_on_specular",
                                   "photometric_fit_on_radiance", "bp_ray"))
    rows = runner.run(realisation_seed(suite.seed, case.key, 0))
    assert len(rows) == 2  # one row per guide's highlight
    # the two guides' lobes, 18 px apart under the peak-protecting exposure, are two detections,
    # one of them the other's cluster neighbour: the rows of the detected ones are scored
    rows = [row for row in rows if np.isfinite(row.errors["bp_ray"])]
    assert rows
    for row in rows:
        oracle, bp = row.errors["photometric_fit_on_specular"], row.errors["bp_ray"]
        assert oracle <= 0.05, row.errors
        assert bp > 1.0, row.errors
        # with the diffuse shading in (or the sensor's steps too) the fit fails (NaN) or does worse
        assert not row.errors["photometric_fit_on_radiance"] <= oracle, row.errors
        assert not row.errors["photometric_fit"] <= oracle, row.errors


def test_the_specular_oracle_is_not_run_without_a_specular_image():
    from simtest.harness.estimators import score
    from simtest.harness.protocols import fit_on_oracle_image
    from simtest.reconstruct.pipeline import SpecularityEstimate

    est = SpecularityEstimate(np.array([10.0, 10.0]), 1.0, False, (0, 20, 0, 20), "ok", "",
                              np.array([0.0, 0.0, -1.0]), ())
    matched = [("h", est, 0.0), ("h2", None, np.inf)]
    rig = LightRig((Light((2.0, 0.0, 0.0)),))
    assert fit_on_oracle_image("photometric_fit_on_specular", None, matched, np.eye(3), rig) is matched
    err, cause = score(est, np.array([0.0, 0.0, -1.0]), ["photometric_fit_on_specular"])[
        "photometric_fit_on_specular"]
    assert np.isnan(err) and cause == "photometric_fit_on_specular_not_run"


def test_the_sigma_covers_the_errors_on_the_lightaware_suites_noise_free_planes():
    # The lightaware suite's noise-free 8-bit planes (Mitsuba, 200 x 200 px, epsilon 4, 6 and 10 mm
    # at 20 mm, five light directions each): the recommended photometric fits erred by 0.002 to
    # 0.35 deg, and the white sigma s^2 (J^T J)^-1 (0.02 to 0.09 deg) covered 7 of 15 at twice:
    # the residual is the 8-bit rounding of a smooth lobe, correlated where the lobe changes by
    # less than a level a pixel. Counted with its correlation area, at least 90 % (measured: 14
    # of 15; the suite's 60 planes, 56).
    from simtest.harness.runner import make_runner

    suite = load_suite("lightaware")
    covered = []
    for value in (4.0, 6.0, 10.0):
        case = next(c for c in suite.cases if c.sweep == "plane_offset" and float(c.x) == value)
        runner = make_runner(case, ("recommended", "bp_ray"))
        for i in range(case.realisations):
            for r in runner.run(realisation_seed(suite.seed, case.key, i)):
                w = r.extras.get("recommended_within_2sigma", np.nan)
                if np.isfinite(w):
                    covered.append(w)
    assert len(covered) == 15
    assert np.mean(covered) >= 0.9, covered
