"""Issue 39's defects of the light-aware step, on exact analytic planes: the isocurve fit's own
isophotes, the ceiling on the depth's relative uncertainty, the light-aware normal kept where its
sigma beats the BP ray's expected error, and every light-aware normal in ``normals``."""

from __future__ import annotations

import dataclasses
import json
from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from simtest.geometry import angle_between_deg
from simtest.geometry.angles import unit
from simtest.geometry.lights import Light, LightRig
from simtest.reconstruct import read_estimates, write_estimates
from simtest.reconstruct.io import dumps, estimate_to_dict
from simtest.reconstruct.pipeline import reconstruct
from simtest.reconstruct.lightaware import LightAwareEstimate
from simtest.reconstruct.recommend import (DEPTH_REL_SIGMA_CEILING, SIGMA_MARGIN, bp_ray_error_deg, depth_within_ceiling,
                                           guide_spread_deg, recommend, with_guide_spread, without_guide_spread)
from simtest.reconstruct.light_fits import light_aware_estimates, with_light_aware
from simtest.reconstruct.settings import ReconSettings
from simtest.simulate.offset import specular_point
from test_lightaware import one_light, plane_case, tilted_normal

#: The command line's settings: isovalues (0.7, 0.85), local normalisation.
CLI = ReconSettings.for_frames()


def _plane8(h, tilt, x_mm, az=30.0, noise=0.0, seed=0):
    """An exact plane lit by one inverse-square light x_mm beside the lens, as an 8-bit image
    (peak 230; optional Gaussian read noise, a fraction of full scale)."""
    rig = one_light(x_mm, "inverse_square")
    img, K, N, depth, _ = plane_case(h, tilt, rig, az=az)
    f = img / img.max() * 230.0
    if noise:
        f = f + np.random.default_rng(seed).normal(0.0, noise * 255.0, f.shape)
    return np.clip(np.rint(f), 0, 255).astype(np.uint8), K, N, depth, rig


def _highlight(img, K):
    ests = [e for e in reconstruct(img, K, settings=CLI) if e.ok]
    assert len(ests) == 1, ests
    return ests[0]


# --- item: isovalues that suit isocurve_fit, chosen by it ---------------------------------------------


def test_isocurve_fit_succeeds_with_the_command_lines_default_isovalues(monkeypatch):
    # On the contours at the command line's 0.7 and 0.85 the fit ran off or lost the depth on 11
    # of 12 exact 8-bit planes (0 of 160 in issue 39's count); on its own isophotes (0.3, 0.5,
    # 0.7) it is ok on all 8 planes here (16 of 16 over tilts 15 and 35 deg, epsilon/d 0.07 to
    # 0.27, measured), median error 0.1 deg. Bounds: at least 7 of 8 ok, median within 0.5 deg
    # (8-bit quantisation of the contours; the largest single error measured was 1.3 deg).
    # Only isocurve_fit's result is read: the photometric fit (fitted after it, from its normal,
    # 98 % of the CPU here) is stood in for; isocurve_fit's estimates are the same to the bit
    # with it (checked on these 8 planes when it was stood in).
    from simtest.reconstruct import light_fits
    from simtest.reconstruct.lightaware import LightAwareEstimate

    monkeypatch.setattr(light_fits, "_photometric",
                        lambda *a: LightAwareEstimate("photometric_fit", "not_converged", "stood in"))
    errs, ok = [], 0
    for h in (15.0, 30.0):
        for tilt in (15.0, 35.0):
            for az in (30.0, 200.0):
                img, K, N, _, rig = _plane8(h, tilt, 3.0, az)
                est = _highlight(img, K)
                assert [i.isovalue for i in est.isophotes] == [0.7, 0.85]
                r = light_aware_estimates(img, est, K, rig, quadric=False)["isocurve_fit"]
                ok += r.ok
                if r.ok:
                    errs.append(angle_between_deg(r.normal, N))
    assert ok >= 7, ok
    assert np.median(errs) < 0.5, errs


# --- item: a ceiling on the depth's relative uncertainty ---------------------------------------------


def test_depth_ceiling_withdraws_a_depth_known_to_50_percent():
    img, K, N, depth, rig = _plane8(30.0, 20.0, 2.0)
    est = _highlight(img, K)
    pho = light_aware_estimates(img, est, K, rig, quadric=False)["photometric_fit"]
    assert pho.ok and pho.depth_mm is not None
    assert depth_within_ceiling(pho) is pho  # exact: its sigma is far below the ceiling
    loose = dataclasses.replace(pho, depth_sigma_mm=0.5 * pho.depth_mm)
    out = depth_within_ceiling(loose)
    assert out.status == "depth_not_observable" and out.depth_mm is None
    assert out.depth_sigma_mm is None and out.distance_mm is None
    assert f"> ceiling {DEPTH_REL_SIGMA_CEILING}" in out.detail
    np.testing.assert_array_equal(out.normal, pho.normal)  # the normal is kept
    # the patch fits' noise-floored relative sigma counts too, the larger of the two
    floored = dataclasses.replace(pho, depth_rel_sigma=0.3)
    assert depth_within_ceiling(floored).depth_mm is None
    within = dataclasses.replace(pho, depth_sigma_mm=0.19 * pho.depth_mm, depth_rel_sigma=0.1)
    assert depth_within_ceiling(within) is within
    # a depth without a sigma is not released either
    assert depth_within_ceiling(dataclasses.replace(pho, depth_sigma_mm=None)).depth_mm is None


def test_a_noisy_plane_whose_depth_is_known_to_25_percent_gives_no_depth():
    # 1 % read noise, epsilon/d 0.03: the photometric fit's relative depth sigma is 0.28 (measured;
    # it passed as ok before, with the depth 65 % short). Its depth is withdrawn; its normal is
    # recommended where twice its sigma is below the BP ray's expected error (rule 3), else the BP
    # ray. Measured: the fit 1.61 deg off with a sigma of 0.68 (0.62 before the sigma counted the
    # residual's correlation), the BP ray's expected error 1.36 and its error 1.05: the BP ray.
    img, K, N, depth, rig = _plane8(30.0, 20.0, 1.0, noise=0.01)
    est = with_light_aware(img, [_highlight(img, K)], K, rig, quadric=False)[0]
    pho = est.light_aware["photometric_fit"]
    assert pho.status == "depth_not_observable" and pho.depth_mm is None
    assert "ceiling" in pho.detail
    rec = recommend(est)
    assert rec.depth_mm is None
    kept = SIGMA_MARGIN * pho.normal_sigma_deg < pho.bp_ray_error_deg
    assert rec.normal_from == ("photometric_fit" if kept else "bp_ray")


# --- item: the light-aware normal is kept where its sigma beats the BP ray ---------------------------


@settings(max_examples=50, deadline=None)
@given(tilt=st.floats(0, 60), az=st.floats(0, 360), h=st.floats(5, 80),
       lx=st.floats(-6, 6), ly=st.floats(-6, 6), lz=st.floats(-2, 2))
def test_bp_ray_error_is_the_half_angle_at_the_specular_point(tilt, az, h, lx, ly, lz):
    # on a plane the BP ray's error is exactly half the angle the light subtends from the camera
    # at the specular point (the normal bisects the two directions there); 1e-6 deg: rounding
    N = tilted_normal(tilt, az)
    # a scope's light is on the camera's side of the tissue (a light behind the plane lights
    # nothing the camera sees): at least 1 mm above the plane n . X = -h
    assume(h + float(np.dot(N, (lx, ly, lz))) >= 1.0)
    rig = one_light(0.0)
    rig = type(rig)((dataclasses.replace(rig.lights[0], position_mm=(lx, ly, lz)),))
    X, depth = specular_point(N, h, rig.lights[0].position)
    ray = X / np.linalg.norm(X)
    assert bp_ray_error_deg(ray, depth, rig) == pytest.approx(angle_between_deg(-ray, N), abs=1e-6)


@pytest.mark.parametrize(("h", "tilt", "x_mm"), [(60.0, 20.0, 0.5), (60.0, 40.0, 0.25)])
def test_an_unobservable_depth_keeps_the_better_light_aware_normal(h, tilt, x_mm):
    # epsilon/d 0.004 to 0.008: the photometric fit's depth is not observable, its normal is good
    # (0.01 and 0.07 deg, sigma 0.07 and 0.05, measured) where the BP ray errs by 0.26 and 0.10;
    # the BP ray's expected error at the nominal 20 mm is 0.68 and 0.30 deg. The fit's normal is
    # recommended (it was discarded for the BP ray before), without a depth.
    img, K, N, depth, rig = _plane8(h, tilt, x_mm)
    est = with_light_aware(img, [_highlight(img, K)], K, rig)[0]
    pho = est.light_aware["photometric_fit"]
    assert pho.status == "depth_not_observable"
    rec = recommend(est)
    assert rec.normal_from == "photometric_fit" and rec.depth_mm is None
    assert rec.normal_sigma_deg == pho.normal_sigma_deg
    assert SIGMA_MARGIN * rec.normal_sigma_deg < pho.bp_ray_error_deg
    assert angle_between_deg(rec.normal, N) < angle_between_deg(est.bp_ray, N)
    # twice the sigma no better than the BP ray's expected error: the BP ray
    worse = {"photometric_fit": dataclasses.replace(
        pho, normal_sigma_deg=pho.bp_ray_error_deg / SIGMA_MARGIN)}
    assert recommend(dataclasses.replace(est, light_aware=worse)).normal_from == "bp_ray"
    # a plane misfit is never kept (its sigma, even the sandwich's, does not cover a wrong local
    # minimum), nor the isocurve fit beside it (the same plane model)
    misfit = {"photometric_fit": dataclasses.replace(pho, status="plane_misfit"),
              "isocurve_fit": dataclasses.replace(pho, estimator="isocurve_fit")}
    assert recommend(dataclasses.replace(est, light_aware=misfit)).normal_from == "bp_ray"


def test_a_fit_far_from_the_bp_ray_by_its_own_sigmas_is_kept():
    # the BP ray's expected error from the rig's geometry is small (0.3 deg), but the detected BP
    # may sit off the specular point (diffuse shading pulls it: 3 px, 2 deg on the endoscope
    # suite's mucosa): a fit whose normal is more than 2 x SIGMA_MARGIN of its sigmas from the BP
    # ray says by its own sigma that the BP ray is the worse
    img, K, N, depth, rig = _plane8(60.0, 40.0, 0.25)
    est = with_light_aware(img, [_highlight(img, K)], K, rig)[0]
    pho = est.light_aware["photometric_fit"]
    off = float(np.radians(2.0))
    bp = np.asarray(est.bp_ray)
    normal = unit(bp * np.cos(off) + unit(np.cross(bp, [0.0, 1.0, 0.0])) * np.sin(off))
    for sigma, kept in [(0.45, True), (0.55, False)]:  # 2 deg against 4 sigma: 1.8 and 2.2 deg
        r = dataclasses.replace(pho, status="depth_not_observable", normal=normal, normal_sigma_deg=sigma,
                                bp_ray_error_deg=0.3)
        got = recommend(dataclasses.replace(est, light_aware={"photometric_fit": r})).normal_from
        assert got == ("photometric_fit" if kept else "bp_ray"), sigma


def test_bp_ray_error_of_guides_either_side_of_the_lens():
    # the mean light of a symmetric rig is at the lens, where the BP ray would err by nothing: the
    # expected error is each guide's half angle (5.7 deg at 20 mm on the axis with guides at 4 mm)
    rig = LightRig((Light((-4.0, 0, 0)), Light((4.0, 0, 0))))
    assert bp_ray_error_deg(np.array([0.0, 0.0, 1.0]), 20.0, rig) == pytest.approx(
        0.5 * np.degrees(np.arctan(4.0 / 20.0)), abs=1e-9)


#: Twice acos's resolution near 0 (deg): acos(1 - eps) = sqrt(2 eps) rad = 1.2e-6 deg, so two unit
#: vectors equal to the last bit read as up to that far apart (hypothesis found 1.21e-6 deg).
ACOS_FLOOR_DEG = 2.0 * float(np.degrees(np.sqrt(2.0 * np.finfo(float).eps)))


@settings(max_examples=60, deadline=None)
@given(tilt=st.floats(0, 45), az=st.floats(0, 360), h=st.floats(8, 60), baseline=st.floats(1.0, 8.0),
       along=st.floats(0, 180), which=st.integers(0, 1))
def test_the_guides_spread_is_the_angle_to_the_other_guides_plane(tilt, az, h, baseline, along, which):
    # A plane lit at its specular point by guide `which` alone has the bisector of the directions to the
    # camera and to that guide as its normal; the other guide's hypothesis, at the same point, the other
    # bisector. The spread at the true normal is exactly the angle between the two bisectors, and under
    # one light (the same guide alone) 0; to ACOS_FLOOR_DEG, the rounding of an angle read by acos.
    N = tilted_normal(tilt, az)
    a = np.radians(along)
    half = 0.5 * baseline * np.array([np.cos(a), np.sin(a), 0.0])
    guides = (Light(tuple(-half)), Light(tuple(half)))
    assume(all(h + float(np.dot(N, g.position)) >= 1.0 for g in guides))
    X, depth = specular_point(N, h, guides[which].position)
    ray = X / np.linalg.norm(X)
    other = unit(-ray + unit(guides[1 - which].position - X))
    assert guide_spread_deg(ray, N, depth, LightRig(guides)) == pytest.approx(angle_between_deg(N, other),
                                                                             abs=ACOS_FLOOR_DEG)
    assert guide_spread_deg(ray, N, depth, LightRig((guides[which],))) == pytest.approx(0.0, abs=ACOS_FLOOR_DEG)


def test_a_depthless_fit_under_two_guides_counts_their_spread_and_keeps_the_bp_ray():
    # A fit that cannot pin the depth under two guides cannot tell which lit its lobe: its sigma counts the
    # spread of the guides' normals (here 5.7 deg: guides 4 mm either side of the lens at 20 mm on the
    # axis), so rule 3 gives the BP ray, whose error (2.9 deg) it no longer beats; where the image resolves
    # the guides the spread comes off again, and the fit is kept. Under one light nothing changes.
    ray, depth = np.array([0.0, 0.0, 1.0]), 20.0
    rig = LightRig((Light((-4.0, 0, 0)), Light((4.0, 0, 0))))
    normal = unit(-ray + unit(rig.positions[0] - depth * ray))  # guide 1's plane
    fit = LightAwareEstimate("photometric_fit", "depth_not_observable", "", normal, normal_sigma_deg=0.3)
    spread = guide_spread_deg(ray, normal, depth, rig)
    assert spread == pytest.approx(np.degrees(np.arctan(4.0 / 20.0)), abs=1e-9)
    counted = with_guide_spread(fit, ray, depth, rig)
    assert counted.normal_sigma_deg == pytest.approx(np.hypot(0.3, spread)) and counted.guide_spread_deg == spread
    assert with_guide_spread(counted, ray, depth, rig) is counted  # counted once
    beside = bp_ray_error_deg(ray, depth, rig)
    for r, name in [(counted, "bp_ray"), (without_guide_spread(counted, "resolved"), "photometric_fit")]:
        r = dataclasses.replace(r, bp_ray_error_deg=beside)
        assert recommend(SimpleNamespace(bp_ray=-ray, light_aware={"photometric_fit": r})).normal_from == name
    back = without_guide_spread(counted, "resolved")
    assert back.normal_sigma_deg == pytest.approx(0.3) and back.guide_spread_deg is None
    assert "resolved" in back.detail and "not resolved" not in back.detail
    one = LightRig((Light((-4.0, 0, 0)),))
    assert with_guide_spread(fit, ray, depth, one) is fit
    assert with_guide_spread(dataclasses.replace(fit, status="ok"), ray, depth, rig).guide_spread_deg is None


# --- item: every light-aware normal in ``normals`` ---------------------------------------------------


def test_normals_carry_the_quadric_and_cubic_patch_normals(tmp_path):
    img, K, N, depth, rig = _plane8(25.0, 25.0, 3.0)
    est = with_light_aware(img, [_highlight(img, K)], K, rig, quadric=True)[0]
    la_ = dict(est.light_aware)
    assert la_["quadric_fit"].normal is not None
    # a stand-in for a cubic patch fit (its own fit takes seconds): a normal of its own
    la_["cubic_patch_fit"] = dataclasses.replace(la_["quadric_fit"], estimator="cubic_patch_fit",
                                                 normal=tilted_normal(10.0, 70.0))
    est = dataclasses.replace(est, light_aware=la_)
    normals = estimate_to_dict(est)["normals"]
    for name in ("isocurve_fit", "photometric_fit", "quadric_fit", "cubic_patch_fit"):
        np.testing.assert_allclose(normals[name], la_[name].normal, atol=1e-12)
    path = write_estimates(tmp_path / "estimates.json", [est], K=K, isovalues=CLI.isovalues, lights=rig)
    back = read_estimates(path)["specularities"][0]["normals"]
    np.testing.assert_allclose(back["cubic_patch_fit"], tilted_normal(10.0, 70.0), atol=1e-12)
    # a schema-2 file written before these keys is still read
    doc = json.loads(path.read_text())
    for s in doc["specularities"]:
        s["normals"].pop("quadric_fit")
        s["normals"].pop("cubic_patch_fit")
    (tmp_path / "older.json").write_text(json.dumps(doc))
    assert "quadric_fit" not in read_estimates(tmp_path / "older.json")["specularities"][0]["normals"]


# --- rule 4: a misfitting plane whose normal the quadric confirms -----------------------------------

def _tilted(v, deg, axis=(0.0, 1.0, 0.0)):
    """``v`` turned by ``deg`` about the direction of ``v x axis``."""
    v = unit(np.asarray(v, dtype=np.float64))
    k = unit(np.cross(v, axis))
    t = np.radians(deg)
    return unit(v * np.cos(t) + np.cross(k, v) * np.sin(t))


_RULE4_BASE = {}


def _rule4_base():
    """A highlight of an exact 8-bit plane lit 3 mm off the lens, and its photometric fit (ok)."""
    if not _RULE4_BASE:
        img, K, N, depth, rig = _plane8(25.0, 25.0, 3.0)
        est = with_light_aware(img, [_highlight(img, K)], K, rig)[0]
        _RULE4_BASE.update(est=est, pho=est.light_aware["photometric_fit"])
    return _RULE4_BASE["est"], _RULE4_BASE["pho"]


@settings(max_examples=60, deadline=None)
@given(gap=st.floats(0.0, 6.0), s_q=st.floats(0.05, 8.0), bp_err=st.floats(0.5, 30.0),
       off=st.floats(0.0, 2.0))
def test_a_misfitting_plane_is_kept_where_the_quadric_confirms_it(gap, s_q, bp_err, off):
    # Rule 4: the misfitting plane's normal is recommended, depth withheld, with the stated sigma
    # g + s_q, exactly where it lies within the quadric's sigma of the quadric's normal (g <= s_q)
    # and twice that sigma beats the BP ray's expected error; else the BP ray. The plane's normal is
    # put `off` deg from the BP ray (well below 2 x SIGMA_MARGIN x sigma: that term does not decide)
    est, pho = _rule4_base()
    # (away from the two boundaries by more than the angles' rounding: acos near 1 resolves
    # about 1e-8 rad, 1e-6 deg)
    assume(abs(gap - s_q) > 1e-5 and abs(SIGMA_MARGIN * (gap + s_q) - bp_err) > 1e-5)
    assume(off < SIGMA_MARGIN * (gap + s_q) and 0.5 * off < bp_err)
    n_p = _tilted(est.bp_ray, off)
    n_q = _tilted(n_p, gap, axis=(1.0, 0.0, 0.0))
    plane = dataclasses.replace(pho, status="plane_misfit", normal=n_p, depth_mm=None, depth_sigma_mm=None,
                                distance_mm=None, bp_ray_error_deg=bp_err)
    quad = dataclasses.replace(pho, estimator="quadric_fit", status="patch_misfit", normal=n_q,
                               normal_sigma_deg=s_q, depth_mm=None, bp_ray_error_deg=bp_err)
    rec = recommend(dataclasses.replace(est, light_aware={"photometric_fit": plane, "quadric_fit": quad}))
    g = angle_between_deg(n_p, n_q)
    if g <= s_q and SIGMA_MARGIN * (g + s_q) < bp_err:
        assert rec.normal_from == "photometric_fit" and rec.depth_mm is None
        assert np.allclose(rec.normal, n_p)
        assert rec.normal_sigma_deg == pytest.approx(g + s_q, abs=1e-6)
    else:
        assert rec.normal_from == "bp_ray"


@settings(max_examples=60, deadline=None)
@given(sigma=st.floats(0.01, 40.0), bp_err=st.floats(0.5, 30.0), off=st.floats(0.0, 2.0))
def test_an_ok_fit_is_recommended_only_where_its_sigma_beats_the_bp_ray(sigma, bp_err, off):
    # Rule 1: an ok fit is recommended with its depth where SIGMA_MARGIN of its stated sigmas lie below the BP
    # ray's expected error, else the BP ray (a plane fit whose normal misses the law of reflection at the BP by
    # degrees states that miss in its sigma: the independent sensor-like probe's fit 18 deg off, sigma 20, against
    # a BP ray 12 deg off). The normal is put `off` deg from the BP ray, below 2 x bp_err (half the angle is the
    # least BP ray error the rule assumes, _bp_ray_error_beside): that term does not decide
    est, pho = _rule4_base()
    assume(abs(SIGMA_MARGIN * sigma - bp_err) > 1e-5 and 0.5 * off < bp_err - 1e-5)
    ok = dataclasses.replace(pho, normal=_tilted(est.bp_ray, off), normal_sigma_deg=sigma, bp_ray_error_deg=bp_err)
    rec = recommend(dataclasses.replace(est, light_aware={"photometric_fit": ok}))
    if SIGMA_MARGIN * sigma < bp_err:
        assert rec.normal_from == "photometric_fit" and rec.depth_mm == ok.depth_mm
    else:
        assert rec.normal_from == "bp_ray" and rec.depth_mm is None
    # a fit that states no sigma (or no BP ray error) is recommended as before
    for loose in (dataclasses.replace(ok, normal_sigma_deg=None), dataclasses.replace(ok, bp_ray_error_deg=None)):
        assert recommend(dataclasses.replace(est, light_aware={"photometric_fit": loose})).normal_from \
            == "photometric_fit"


def test_a_quadric_without_a_stated_sigma_confirms_nothing():
    # the patch fits state 180 deg where their covariance is singular: no confirmation
    est, pho = _rule4_base()
    plane = dataclasses.replace(pho, status="plane_misfit", depth_mm=None, bp_ray_error_deg=20.0)
    for sigma in (180.0, None):
        quad = dataclasses.replace(pho, estimator="quadric_fit", status="patch_misfit", normal_sigma_deg=sigma)
        rec = recommend(dataclasses.replace(est, light_aware={"photometric_fit": plane, "quadric_fit": quad}))
        assert rec.normal_from == "bp_ray", sigma
    # and without a quadric, the misfit alone is never recommended
    rec = recommend(dataclasses.replace(est, light_aware={"photometric_fit": plane}))
    assert rec.normal_from == "bp_ray"


# --- item: the slow patch fits run only where the plane fit misfits ----------------------------------


@pytest.mark.parametrize("status", ["ok", "depth_not_observable", "too_few_points", "light_behind_plane",
                                    "plane_misfit", "not_converged"])
def test_the_patch_fits_run_only_where_the_plane_is_not_the_surface(monkeypatch, status):
    # the photometric fit's status stands in for what each outcome of a real fit says; the
    # quadric (and, with two lights apart, the cubic patch) run after a misfit or a fit that ran
    # off, never after a fit whose plane fits (a patch has more parameters to trade with the
    # depth) or one with too few pixels for the plane's parameters (fewer than a patch's). After
    # a fit that ran off the quadric runs only beside fewer other candidates than the rig has
    # light places (alone here: the guides' lobes fused in one), not in a glint field
    import simtest.reconstruct.light_fits as rec

    img, K, N, _, _ = _plane8(30.0, 20.0, 2.0)
    rig = LightRig((Light((-2.0, 0.0, 0.0), 1.0, "inverse_square", 0.0),
                    Light((2.0, 0.0, 0.0), 1.0, "inverse_square", 0.0)))
    est = _highlight(img, K)
    real = rec.photometric_fit

    def fit(*a, **k):
        return dataclasses.replace(real(*a, **k), status=status)

    ran = []
    monkeypatch.setattr(rec, "photometric_fit", fit)
    for name in ("quadric_fit", "cubic_patch_fit"):
        monkeypatch.setattr(rec, name, lambda *a, _n=name, **k: ran.append(_n) or
                            rec.LightAwareEstimate(_n, "not_converged", "not run here"))
    out = light_aware_estimates(img, est, K, rig, cubic=None)
    expected = ((["quadric_fit"] if status in rec.QUADRIC_AFTER or status == "not_converged" else [])
                + (["cubic_patch_fit"] if status in rec.CURVED_FIT_AFTER else []))
    assert ran == expected and [k for k in out if k in ran] == expected
    # two other peaks beside it (as many as the rig has light places): no quadric's image
    ran.clear()
    u, v = est.bp_px
    light_aware_estimates(img, est, K, rig, cubic=None, lobe_partners=((u + 3.0, v), (u - 3.0, v)))
    assert "quadric_fit" not in ran
    # asked for, they run whatever the plane's status
    ran.clear()
    light_aware_estimates(img, est, K, rig, quadric=True, cubic=True)
    assert ran == ["quadric_fit", "cubic_patch_fit"]


@pytest.mark.parametrize("peaks, refitted", [(1, True), (2, False)])
def test_a_glint_field_is_not_refitted_from_the_pair(monkeypatch, peaks, refitted):
    # a plane under k lights shows at most k lobes: where the highlight's ROI holds as many other peaks as
    # the rig has light places (a glint field on wet tissue) no plane's image is there, and its fit is not
    # refitted from the pair's depth nor on the pair's ROI; beside fewer (another guide's lobe) it is
    import simtest.reconstruct.light_fits as rec

    img, K, _, _, _ = _plane8(30.0, 20.0, 2.0)
    rig = LightRig((Light((-2.0, 0.0, 0.0), 1.0, "inverse_square", 0.0),
                    Light((2.0, 0.0, 0.0), 1.0, "inverse_square", 0.0)))
    est = _highlight(img, K)
    real, with_pair = rec.photometric_fit, []

    def fit(*a, **k):  # a depth-less plane fit, which the pair's depth may complete
        with_pair.append(bool(k.get("pair_starts")))
        return dataclasses.replace(real(*a, **k), status="depth_not_observable")

    monkeypatch.setattr(rec, "photometric_fit", fit)
    u, v = est.bp_px
    partners = ((u + 3.0, v), (u - 3.0, v))[:peaks]
    light_aware_estimates(img, est, K, rig, pair_starts=((0, 1, 25.0),), lobe_partners=partners, quadric=False,
                          cubic=False)
    assert any(with_pair) == refitted, with_pair


# --- rule 1 for the candidates the light-aware step does not fit ------------------------------------

def test_a_rejected_candidate_under_an_offset_rig_gets_the_bp_ray():
    # A candidate rejected after its isophotes gave a joint cone axis: with no rig, or a rig at
    # the camera centre, the co-located order recommends that axis; under a light off the lens
    # the co-located estimators' normals are not the surface's (the BP ray errs by the half angle
    # at most, the cone axis by the light's whole offset), and rule 1 gives the BP ray, as it does
    # to a fitted highlight whose fits all fail. The JSON writer's two paths say the same.
    img, K, N, depth, rig = _plane8(25.0, 25.0, 3.0)
    est = _highlight(img, K)
    assert est.joint_cone_axis is not None
    rejected = dataclasses.replace(est, status="not_specular")
    assert rejected.recommended.normal_from == "joint_cone_axis"
    co_located = LightRig((Light((0.0, 0.0, 0.0)),))
    assert with_light_aware(img, [rejected], K, co_located)[0].light_aware is None
    out = with_light_aware(img, [rejected, est], K, rig)
    assert out[0].light_aware == {} and out[1].light_aware
    rec = out[0].recommended
    assert rec.normal_from == "bp_ray" and rec.normal is out[0].bp_ray
    for e in (out[0], dataclasses.replace(out[0], isophotes=())):
        d = estimate_to_dict(e)
        assert d["normal_from"] == "bp_ray" and d["normal"] == list(e.bp_ray)
    assert json.loads(dumps([estimate_to_dict(e) for e in out[:1]]))[0]["normal_from"] == "bp_ray"
    assert json.loads(dumps([estimate_to_dict(out[0])] * 2))[1]["normal"] == list(out[0].bp_ray)
