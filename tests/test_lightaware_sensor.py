"""The image model of a sensor frame: the response undone, the diffuse shading, clipped pixels censored."""

from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from simtest.geometry import angle_between_deg
from simtest.geometry.angles import unit
from simtest.geometry.camera_file import CameraFileError, load_camera, save_camera
from simtest.geometry.cameras import PinholeCamera
from simtest.geometry.lights import Light, LightRig
from simtest.geometry.response import ResponseError, SensorResponse
from simtest.reconstruct import lightaware as la
from simtest.reconstruct.lightaware import model as lam
from test_lightaware import plane_case

RIG = LightRig((Light((-4.0, 0, 0), 1.0, "inverse_square", 1.0), Light((4.0, 0, 0), 1.0, "inverse_square", 1.0)))


def _srgb(s):
    return np.where(s <= 0.0031308, 12.92 * s, 1.055 * np.power(np.maximum(s, 0.0031308), 1 / 2.4) - 0.055)


@settings(max_examples=30, deadline=None)
@given(curve=st.sampled_from(["linear", "srgb", "gamma"]), g=st.floats(1.2, 3.0),
       wb=st.tuples(*[st.floats(0.5, 2.0)] * 3), exposure=st.floats(0.2, 5.0))
def test_linearize_inverts_the_forward_response(curve, g, wb, exposure):
    # pixel = clip(curve(exposure * wb * radiance)) at 16 bits: linearize gives the radiance back
    # to the quantisation step (1 / 65535 of full scale, through the curve's slope)
    rng = np.random.default_rng(0)
    rad = rng.uniform(0, 0.9, (8, 9, 3)) / (exposure * np.array(wb))
    s = np.clip(exposure * np.array(wb) * rad, 0, 1)
    enc = {"linear": s, "srgb": _srgb(s), "gamma": s ** (1 / g)}[curve]
    pix = np.rint(enc * 65535).astype(np.uint16)
    resp = SensorResponse(curve, g if curve == "gamma" else 1.0, wb, exposure)
    for c in range(3):
        lin, clip, ch = resp.linearize(pix, channel=c)
        assert ch == c
        np.testing.assert_allclose(lin, rad[..., c], atol=5e-3 / (exposure * wb[c]))
        assert clip == pytest.approx(1.0 / (exposure * wb[c]))


@settings(max_examples=40, deadline=None)
@given(clip_code=st.integers(1, 255), bright=st.floats(0.0, 1.0), seed=st.integers(0, 2**16))
def test_a_frame_the_forward_model_wrote_passes_the_clip_check(clip_code, bright, seed):
    # pixel = clip(curve(...)): every value at or below the clip level, whatever its share of
    # clipped pixels (bright: up to all of them), so the frame is the sensor's
    rng = np.random.default_rng(seed)
    rad = rng.uniform(0.0, 1.0 + 3.0 * bright, (16, 12, 3))
    pix = np.minimum(np.rint(_srgb(np.clip(rad, 0, 1)) * clip_code), clip_code).astype(np.uint8)
    SensorResponse("srgb", clip=float(clip_code)).check_frame(pix)
    SensorResponse("srgb").check_frame(pix)  # no clip: the dtype's maximum


def test_a_clip_in_the_wrong_units_is_one_line_naming_the_key():
    tissue = np.full((40, 40, 3), (180, 90, 60), np.uint8)
    with pytest.raises(ResponseError, match=r"response\.clip: 1 is below 100% of the frame's pixel values "
                                            r"\(largest 180\).*255 for an 8-bit frame"):
        SensorResponse("srgb", clip=1.0).linearize(tissue)
    with pytest.raises(ResponseError, match=r"response\.clip: 4095 is above the largest value a uint8 frame"):
        SensorResponse("srgb", clip=4095.0).check_frame(tissue)
    # a float frame in 8-bit units without a clip: the default (1) is named as such
    with pytest.raises(ResponseError, match=r"1 \(not given: the dtype's maximum, 1 for floats\)"):
        SensorResponse("linear").check_frame(tissue.astype(np.float32))
    # a decoder's overshoot above a clip below the dtype's maximum (a quarter of the frame at
    # most) passes: video range, white at 235, a clipped highlight decoded up to 250
    video = tissue.copy()
    video[:15, :15] = 250  # 14 % of the pixels
    SensorResponse("srgb", clip=235.0).check_frame(video)


def test_reconstruct_refuses_a_clip_in_the_wrong_units(tmp_path):
    from typer.testing import CliRunner

    from simtest.cli import app

    model = PinholeCamera(np.array([[300.0, 0, 20], [0, 300, 20], [0, 0, 1]]), image_size=(40, 40))
    cam = save_camera(tmp_path / "cam.json", model, RIG, SensorResponse("srgb", clip=1.0))
    frame = tmp_path / "frame.npy"
    np.save(frame, np.full((40, 40, 3), (180, 90, 60), np.uint8))
    res = CliRunner().invoke(app, ["reconstruct", str(frame), "--intrinsics", str(cam), "-o", str(tmp_path / "o")])
    assert res.exit_code == 2, res.output
    lines = [ln for ln in res.output.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith(f"error: {cam}: response.clip: 1 is below"), res.output
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("lights", [RIG, None])
def test_a_folder_refuses_a_clip_in_the_wrong_units_as_one_image_does(tmp_path, lights):
    # A folder checked its frames against the response only where the light-aware fits ran (a rig
    # off the camera): with no lights in the camera file, one image was refused and a folder of
    # it was not. Every frame is now checked before its reconstruction, lights or none.
    import cv2
    from typer.testing import CliRunner

    from simtest.cli import app

    model = PinholeCamera(np.array([[300.0, 0, 20], [0, 300, 20], [0, 0, 1]]), image_size=(40, 40))
    cam = save_camera(tmp_path / "cam.json", model, lights, SensorResponse("srgb", clip=1.0))
    folder = tmp_path / "frames"
    folder.mkdir()
    for i in range(2):
        cv2.imwrite(str(folder / f"f{i}.png"), np.full((40, 40, 3), (60, 90, 180), np.uint8))
    res = CliRunner().invoke(app, ["reconstruct", str(folder), "--intrinsics", str(cam), "-o", str(tmp_path / "o")])
    assert res.exit_code == 2, res.output
    lines = [ln for ln in res.output.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: frame ") and "response.clip: 1 is below" in lines[0], res.output
    assert not (tmp_path / "o" / "estimates.parquet").exists()


def test_linearize_picks_the_darkest_channel():
    img = np.zeros((20, 20, 3), np.uint8)
    img[..., 0], img[..., 1], img[..., 2] = 200, 90, 60
    assert SensorResponse("srgb").linearize(img)[2] == 2
    # a white balance that lifts blue makes green the darkest in linear terms
    assert SensorResponse("srgb", white_balance=(1.0, 1.0, 0.3)).linearize(img)[2] == 1


def test_camera_file_response_round_trip_and_errors(tmp_path):
    model = PinholeCamera(np.array([[300.0, 0, 100], [0, 300, 100], [0, 0, 1]]), image_size=(200, 200))
    resp = SensorResponse("gamma", 2.2, (1.5, 1.0, 1.2), 0.8, 255.0)
    p = save_camera(tmp_path / "cam.json", model, RIG, resp)
    assert load_camera(p).response == resp
    assert load_camera(save_camera(tmp_path / "c2.json", model, RIG)).response is None
    base = json.loads(p.read_text())
    for bad, key in [({"curve": "log"}, "curve"), ({"curve": "srgb", "gamma": 2.2}, "gamma"),
                     ({"curve": "gamma"}, "gamma"), ({"curve": "srgb", "exposure": 0}, "exposure"),
                     ({"curve": "srgb", "white_balance": [1, True, 1]}, "white_balance"),
                     ({"curve": "srgb", "clip": float("inf")}, "clip"), ({"curve": "srgb", "gain": 1}, "gain"),
                     (None, "response")]:
        base["response"] = bad
        (tmp_path / "bad.json").write_text(json.dumps(base))
        with pytest.raises(CameraFileError, match=key) as exc:
            load_camera(tmp_path / "bad.json")
        assert "\n" not in str(exc.value) and "bad.json" in str(exc.value)
    with pytest.raises(ResponseError):
        SensorResponse.from_json([1, 2])


def rig_diffuse_shading(K, shape, normal, depth_mm, rig):
    """The rig's Lambertian shading (unit albedo) of the plane with ``normal`` at ``depth_mm``
    along the optical axis, on an image of ``shape`` (H, W) through ``K``: the diffuse column of
    the light-aware image model, per pixel."""
    H, W = shape[:2]
    vv, uu = np.mgrid[0:H, 0:W]
    dT = np.ascontiguousarray(lam._rays(K, np.column_stack([uu.ravel(), vv.ravel()]).astype(float)).T)
    arr = lam._rig_arrays(rig)
    return lam._rig_diffuse(dT, lam._ray_light(arr[0], dT), normal, depth_mm, arr).reshape(H, W)


@pytest.mark.parametrize("albedo", [0.3, 1.0])
@pytest.mark.parametrize("clip", [None, 0.6])
def test_diffuse_column_and_censored_pixels(albedo, clip):
    # An exact plane under the two-guide rig with the rig's Lambertian shading added (albedo times
    # the lobe's peak) and a constant: without the diffuse column the plane model trades the
    # shading for roughness and misfits (0.02 to 0.2 deg off); with it the fit is exact again,
    # and so with the top 40 % clipped, left out or censored.
    img, K, N, depth, bp = plane_case(20.0, 30.0, RIG, size=160)
    D = rig_diffuse_shading(K, img.shape, N, 20.0, RIG)
    y = img + albedo * D / D.max() * img.max() + 0.01 * img.max()
    level = None if clip is None else clip * y.max()
    if level is not None:
        y = np.minimum(y, level)
    plain = la.photometric_fit(y, (0, 0), bp, K, RIG, clip_level=level)
    assert plain.status != "ok" or angle_between_deg(plain.normal, N) > 0.01
    for censor in (False, True):
        r = la.photometric_fit(y, (0, 0), bp, K, RIG, clip_level=level, diffuse=True, censor=censor)
        assert r.ok, r
        # exact image: the error is the solver's tolerance (1e-8 relative cost), far below 1e-3 deg
        assert angle_between_deg(r.normal, N) < 1e-3
        assert r.roughness == pytest.approx(60.0, rel=1e-4)


def test_a_clipped_top_read_low_is_the_clips_not_the_lobes():
    # A clipped top whose pixels read below the clip (noise after the sensor saturates, JPEG's
    # ringing: here 30 % of them at 0.97 of it) holds no information on the lobe beyond "at least
    # the clip". Fitted as the lobe's values they pulled it broad: 0.23 deg off, roughness 38.6
    # for 60, distance 3.3 % short. The sensor model min(lobe, clip) reads them as the clip's:
    # 0.002 deg, 59.5, 0.04 % (some lie where the model is just below the clip: not exact).
    img, K, N, depth, bp = plane_case(20.0, 30.0, RIG, size=160)
    level = 0.4 * img.max()
    low = (img >= level) & (np.random.default_rng(0).random(img.shape) < 0.3)
    y = np.where(low, 0.97 * level, np.minimum(img, level))
    r = la.photometric_fit(y, (0, 0), bp, K, RIG, clip_level=level, censor=True)
    assert r.ok, r
    assert angle_between_deg(r.normal, N) < 0.02  # ten times the 0.002 deg left, a tenth of the bias
    assert r.roughness == pytest.approx(60.0, rel=0.02)
    assert r.distance_mm == pytest.approx(20.0, rel=0.005)


@pytest.mark.parametrize("rig", [RIG, LightRig((Light((3.0, 0.0, 0.0), 1.0, "inverse_square", 2.0),
                                                  Light((-3.0, 1.0, 0.5), 0.7, "none")))])
def test_diffuse_gradient_is_the_central_differences_of_the_shading(rig):
    # the analytic derivatives of the rig's Lambertian shading in (a, b, log h) against central
    # differences (step 1e-6: their own error is about 1e-9 of the derivative)
    from simtest.geometry.conics import plane_basis

    K = np.array([[200.0, 0, 50], [0, 200.0, 40], [0, 0, 1]])
    vv, uu = np.mgrid[0:80, 0:100]
    dT = np.ascontiguousarray(lam._rays(K, np.column_stack([uu.ravel(), vv.ravel()]).astype(float)).T)
    arr = lam._rig_arrays(rig)
    rl = lam._ray_light(arr[0], dT)
    nb = unit(np.array([0.2, -0.1, -1.0]))
    e1, e2 = plane_basis(nb)
    p = np.array([0.03, -0.02, np.log(20.0)])
    G = lam._rig_diffuse_grad(dT, rl, p, nb, e1, e2, arr)
    F = np.empty_like(G)
    for k in range(3):
        vals = []
        for sg in (1.0, -1.0):
            q = p.copy()
            q[k] += sg * 1e-6
            mv = nb + q[0] * e1 + q[1] * e2
            vals.append(lam._rig_diffuse(dT, rl, mv / np.linalg.norm(mv), float(np.exp(q[2])), arr))
        F[k] = (vals[0] - vals[1]) / 2e-6
    np.testing.assert_allclose(G, F, rtol=0, atol=1e-7 * np.abs(F).max())


def test_sandwich_sigma_covers_correlated_residuals():
    # An exact two-guide plane with spatially correlated noise (white noise smoothed over 2 px,
    # 2 % of the peak): the residuals correlate, the fit reports plane_misfit, and its sigma is
    # the sandwich's, which counts them. The plain s^2 (J^T J)^-1 takes each pixel as
    # independent evidence: 0.004 to 0.006 deg here, where the errors are 0.001 to 0.08. The
    # errors fall within 2 sigma on at least 9 of 10 realisations (the must-hold's 90 %). (On a
    # 100 px ROI the same plane's fit ends in a local minimum 4.4 deg off, noise-free, with a
    # sandwich sigma of 0.19: a bias no sigma of the fit covers; the recommendation keeps no
    # plane misfit.)
    from scipy.ndimage import gaussian_filter

    img, K, N, depth, bp = plane_case(20.0, 30.0, RIG, size=120)
    within = 0
    for seed in range(10):
        rng = np.random.default_rng(seed)
        noise = gaussian_filter(rng.normal(size=img.shape), 2.0)
        r = la.photometric_fit(img + noise * (0.02 * img.max() / noise.std()), (0, 0), bp, K, RIG)
        assert r.status == "plane_misfit"
        within += angle_between_deg(r.normal, N) < 2 * r.normal_sigma_deg
    assert within >= 9


def _textured_plane(seed, size=120):
    """An exact plane under the two-guide rig whose diffuse shading carries a textured albedo
    (white noise smoothed over 3 px, 20 % of the shading: vessels, a mucosal pattern), in 8 bits
    with 0.4 % read noise, its normal and depth."""
    from scipy.ndimage import gaussian_filter

    img, K, N, depth, bp = plane_case(20.0, 30.0, RIG, size=size)
    D = rig_diffuse_shading(K, img.shape, N, 20.0, RIG)
    rng = np.random.default_rng(seed)
    tex = gaussian_filter(rng.normal(size=img.shape), 3.0)
    y = (img / img.max() * 0.5 + (1 + 0.2 * tex / tex.std()) * D / D.max() * 0.4 + 0.02
         + rng.normal(0.0, 0.004, img.shape))
    return np.round(np.clip(y, 0, 1) * 255) / 255, K, N, depth, bp


@pytest.mark.parametrize("seed", [0, 1, 3, 4])
def test_a_textured_plane_on_the_sensor_path_passes_with_a_sigma_that_covers_it(seed):
    # The albedo texture under the diffuse light leaves residuals whose neighbours correlate
    # (rho 0.97): the neighbour test called every such plane plane_misfit, though the normal is
    # 0.16 to 0.45 deg off, and its sandwich sigma (0.32 to 0.47) did not cover it on seed 3. The
    # curvature's score test against the residual's own correlated noise passes it, and the sigma
    # counting the residual's correlation area covers the error at 2 sigma.
    y, K, N, depth, bp = _textured_plane(seed)
    r = la.photometric_fit(y, (0, 0), bp, K, RIG, diffuse=True, floor_level=0.0)
    assert r.status == "ok", r
    assert angle_between_deg(r.normal, N) < 2.0 * r.normal_sigma_deg
    # the depth of the highlight's light (the first): within 4 % on these seeds; its stated
    # sigma (relative, as the harness reads it) covers it at 2 sigma
    d0 = r.light_depths_mm[0]
    assert abs(d0 - depth) < 2.0 * r.depth_sigma_mm * d0 / r.depth_mm


def test_a_textured_plane_fit_far_off_still_misfits():
    # seed 2's fit from the mean light's bisector (here the BP ray) ends 3.5 deg off, a local
    # minimum: the score test sees the pattern it leaves. From the start of the light that fits
    # best (the fit's own, for a rig of several lights) it ends within twice its sigma
    y, K, N, depth, bp = _textured_plane(2)
    ray = unit(np.linalg.solve(K, [bp[0], bp[1], 1.0]))
    r = la.photometric_fit(y, (0, 0), bp, K, RIG, diffuse=True, floor_level=0.0, start_normal=-ray)
    assert r.status == "plane_misfit" and "curved patch" in r.detail, r
    r = la.photometric_fit(y, (0, 0), bp, K, RIG, diffuse=True, floor_level=0.0)
    assert r.ok and angle_between_deg(r.normal, N) < 2.0 * r.normal_sigma_deg, r


@pytest.mark.parametrize("seed", [0, 4])
def test_a_noisy_sphere_misfits_on_the_sensor_path(seed):
    # An exact sphere at 1 % noise in 8 bits, fitted with the diffuse column: its residuals do not
    # correlate enough for the neighbour test, and the sensor path, which had no other test, passed
    # it as ok 7.0 and 5.4 deg off (sigma 2.0 and 1.6); the curvature's score test sees it.
    from test_lightaware_coverage import _sphere
    from simtest.reconstruct.pipeline import reconstruct
    from simtest.reconstruct.settings import ReconSettings

    img, K, n, rig, dist = _sphere(seed, 0.01)
    img = np.round(np.clip(img, 0, 1) * 255) / 255
    ests = [e for e in reconstruct(img, K, settings=ReconSettings(isovalues=(0.3, 0.5, 0.7))) if e.ok]
    assert len(ests) == 1
    r = la.photometric_fit(img, (0, 0), ests[0].bp_px, K, rig, nominal_depth_mm=dist, diffuse=True)
    assert r.status == "plane_misfit" and "curved patch" in r.detail, r


@pytest.mark.parametrize("s", [0.0, 1.0, 2.0])
def test_correlation_area_of_smoothed_white_noise(s):
    # White noise smoothed by a Gaussian of s px has a Gaussian autocorrelation of s sqrt(2) px,
    # whose integral is 4 pi s^2 px (white: 1). The estimate from one 120 x 120 field scatters by
    # up to 70 % at s = 2 (about 300 independent patches, and the window's cut at the first zero
    # of a noisy radial profile); the median of five is within a factor 1.6.
    from scipy.ndimage import gaussian_filter
    from simtest.reconstruct.lightaware.solve import _correlation_area

    shape = (120, 120)
    areas = []
    for seed in range(5):
        z = np.random.default_rng(seed).normal(size=shape)
        z = gaussian_filter(z, s) if s else z
        areas.append(_correlation_area(z.ravel(), np.arange(z.size), shape, 1))
    expected = max(4 * np.pi * s * s, 1.0)
    assert expected / 1.6 < np.median(areas) < 1.6 * expected


def _correlation_area_by_lags(r, sel, shape, step):
    """_correlation_area's definition summed lag by lag (no FFT): the reference of the test below."""
    Hs, Ws = -(-shape[0] // step), -(-shape[1] // step)
    rows, cols = np.divmod(np.asarray(sel), shape[1])
    R, M = np.zeros((Hs, Ws)), np.zeros((Hs, Ws))
    R[rows // step, cols // step] = r - np.mean(r)
    M[rows // step, cols // step] = 1.0
    lags, pairs, prods = [], [], []
    for dy in range(-Hs + 1, Hs):
        for dx in range(-Ws + 1, Ws):
            a = (slice(max(0, -dy), Hs - max(0, dy)), slice(max(0, -dx), Ws - max(0, dx)))
            b = (slice(max(0, dy), Hs - max(0, -dy)), slice(max(0, dx), Ws - max(0, -dx)))
            lags.append(np.hypot(dy, dx))
            pairs.append(float((M[a] * M[b]).sum()))
            prods.append(float((R[a] * R[b]).sum()))
    lags, pairs, prods = np.rint(lags).astype(int), np.array(pairs), np.array(prods)
    n0 = pairs[np.flatnonzero(lags == 0)[0]]
    var = prods[np.flatnonzero(lags == 0)[0]] / max(n0, 1.0)
    if not var > 0:
        return 1.0
    use = pairs > n0 / 8.0
    acf = np.where(use, prods / np.maximum(pairs, 1.0), 0.0) / var
    cut = min(Hs, Ws) // 2 + 1
    for k in range(1, min(Hs, Ws) // 2 + 1):  # the radial mean's first zero (or empty ring)
        ring = use & (lags == k)
        if not ring.any() or acf[ring].mean() <= 0:
            cut = k
            break
    return max(float(acf[use & (lags < cut)].sum()), 1.0)


@settings(max_examples=60, deadline=None)
@given(h=st.integers(2, 24), w=st.integers(2, 24), step=st.integers(1, 3), keep=st.floats(0.2, 1.0),
       blur=st.floats(0.0, 3.0), seed=st.integers(0, 2**31 - 1))
def test_correlation_area_is_its_lag_by_lag_definition(h, w, step, keep, blur, seed):
    # the FFT's zero padding is long enough that no lag wraps round, and the pair counts are exact:
    # the same area as the lags summed one by one, to rounding (1e-9 relative: sums of at most
    # 24 x 24 products of unit-variance residuals)
    from scipy.ndimage import gaussian_filter
    from simtest.reconstruct.lightaware.solve import _correlation_area

    rng = np.random.default_rng(seed)
    shape = (h * step, w * step)
    z = rng.normal(size=(h, w))
    z = gaussian_filter(z, blur) if blur else z
    on = rng.random((h, w)) < keep
    on.flat[rng.integers(on.size)] = True
    rr, cc = np.nonzero(on)
    sel = (rr * step) * shape[1] + cc * step
    r = z[rr, cc]
    assert _correlation_area(r, sel, shape, step) == pytest.approx(
        _correlation_area_by_lags(r, sel, shape, step), rel=1e-9)


@settings(max_examples=80, deadline=None)
@given(sx=st.floats(2.0, 40.0), sy=st.floats(2.0, 40.0), peak=st.floats(20.0, 255.0),
       cx=st.floats(0.0, 64.0), cy=st.floats(0.0, 64.0), theta=st.floats(0.0, 3.2))
def test_a_lone_lobe_holds_no_albedo_line(sx, sy, peak, cx, cy, theta):
    # an elliptical lobe's level sets are ellipses, closed under the disc's closing: nothing of
    # it is left out, whatever its width, peak, place (the ROI's border cutting it included) or
    # orientation, rounded to 8 bits (the threshold, two steps, is above the rounding's one)
    from simtest.reconstruct.lightaware.model import albedo_lines

    yy, xx = np.mgrid[0:64, 0:64].astype(float)
    u, v = xx - cx, yy - cy
    a, b = u * np.cos(theta) + v * np.sin(theta), -u * np.sin(theta) + v * np.cos(theta)
    lobe = np.rint(10.0 + peak * np.exp(-0.5 * ((a / sx) ** 2 + (b / sy) ** 2)))
    assert not albedo_lines(lobe).any()


def test_albedo_lines_are_the_thin_dark_lines_over_a_lobe():
    # a lobe over a shading gradient, crossed by two lines 1 and 3 px wide, 6 levels dark: away
    # from the lobe (beyond twice its sigma) every line pixel is found, on its flanks fewer (the
    # closing sees the flank's slope: a miss, never a false line); nothing but the lines grown by
    # a pixel is found; and on flat shading a dark band wider than the disc is not a line (on a
    # slope, the band's side next to its higher wall is: its bottom is narrow at low levels)
    from simtest.reconstruct.lightaware.model import ALBEDO_LINE_PX, albedo_lines

    yy, xx = np.mgrid[0:80, 0:80].astype(float)
    img = 40.0 + 0.5 * xx + 150.0 * np.exp(-((xx - 40) ** 2 + (yy - 40) ** 2) / (2 * 12.0 ** 2))
    truth = np.zeros(img.shape, bool)
    truth[20, :], truth[50:53, :] = True, True
    got = albedo_lines(np.rint(img - 6.0 * truth))
    grown = truth | np.roll(truth, 1, axis=0) | np.roll(truth, -1, axis=0)
    away = (slice(None), slice(4, 15))
    assert got[away][truth[away]].all()
    assert not (got & ~grown).any()
    band = np.zeros(img.shape, bool)
    band[:, 30:30 + 2 * ALBEDO_LINE_PX] = True
    assert not albedo_lines(np.rint(40.0 - 6.0 * band)).any()


def test_the_darkest_channels_fit_leaves_the_vessels_out():
    # photometric_fit's exclude: the pixels given are left out as clipped pixels are (a fit on the
    # ROI with its lines left out equals one on the ROI whose lines are set to anything else)
    img, K, N, _, bp = plane_case(20.0, 25.0, RIG, size=60)
    lines = np.zeros(img.shape, bool)
    lines[::7, :] = True
    a = la.photometric_fit(img, (0, 0), bp, K, RIG, exclude=lines)
    b = la.photometric_fit(np.where(lines, 0.0, img), (0, 0), bp, K, RIG, exclude=lines)
    assert a.status == b.status and np.allclose(a.normal, b.normal, atol=1e-12)
    with pytest.raises(ValueError, match="exclude"):
        la.photometric_fit(img, (0, 0), bp, K, RIG, exclude=lines[1:])


@settings(max_examples=50, deadline=None)
@given(st.integers(0, 2**32 - 1))
def test_curvature_shift_is_the_linearised_patchs_step_in_the_plane(seed):
    # A residual that the plane's columns and the curvature columns explain exactly, r = -A beta:
    # the shift is beta's tilt (a, b: radians in the normal's tangent plane) in degrees and its
    # log-distance step, whatever the linear columns after the first four and the curvatures
    from simtest.reconstruct.lightaware.solve import _curvature_shift

    rng = np.random.default_rng(seed)
    m, k = 200, 4 + int(rng.integers(1, 4))
    span, cols = rng.normal(size=(m, k)), rng.normal(size=(m, 3))
    beta = rng.normal(scale=0.1, size=k + 3)
    dn, dlh = _curvature_shift(cols, span, -np.column_stack([span, cols]) @ beta)
    assert dn == pytest.approx(np.degrees(np.hypot(beta[0], beta[1])), rel=1e-9, abs=1e-12)
    assert dlh == pytest.approx(abs(beta[2]), rel=1e-9, abs=1e-12)
    # degenerate columns give no shift
    assert _curvature_shift(np.column_stack([span[:, :1]] * 3), span, span @ beta[:k]) is None


def test_curved_patch_fits_read_a_noisy_clipped_top_as_the_plane_fit_does():
    # The two-light test sphere with its top clipped at 0.6 of the peak and read noise (0.3 % of
    # the peak) added after the sensor saturates, then clipped again: the top's pixels read up to
    # a few sigma below the clip. Fitted as the lobe's values they pulled both curved patches to a
    # broad lobe (roughness about 2 for 40, depth about 55 % short), or to a misfit. With the plane
    # fit's margin below the clip they are read as clipped: an ok patch's depth lies within twice
    # its stated sigma, and the rest say their depth is not observable or misfit (never ok off).
    from test_lightaware import SPHERE_C, SPHERE_K, SPHERE_R, sphere_rig_case

    from simtest.reconstruct import ReconSettings, reconstruct
    from simtest.reconstruct.light_fits import with_light_aware

    img, rig, _ = sphere_rig_case([(-5.0, 0.0, 0.0), (5.0, 0.0, 0.0)])
    truth_mm = float(np.linalg.norm(SPHERE_C) - SPHERE_R)  # the apex: the symmetric rig's mean light
    clip = 0.6 * img.max()
    oks = 0
    for seed in (9012, 9013, 9014):
        noise = np.random.default_rng(seed).normal(0.0, 0.003 * img.max(), img.shape)
        y = np.minimum(np.minimum(img, clip) + noise, clip)
        ests = reconstruct(y, SPHERE_K, settings=ReconSettings(isovalues=(0.3, 0.5, 0.7)))
        ests = with_light_aware(y, ests, SPHERE_K, rig, nominal_depth_mm=20.0, saturation_level=clip,
                                quadric=True, cubic=True, fit_rejected=True)
        for name in ("quadric_fit", "cubic_patch_fit"):
            f = ests[0].light_aware[name]
            if f.ok:
                oks += 1
                assert abs(f.depth_mm - truth_mm) <= 2.0 * f.depth_sigma_mm, (seed, f)
                assert angle_between_deg(f.normal, unit(-SPHERE_C)) < 0.1, (seed, f)  # 0.4 px at f 250
    assert oks >= 2  # not vacuous: the fits that read the top as the clip's come out ok
