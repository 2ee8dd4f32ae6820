"""The sensor path's colour: the tissue's body colours projected out of a linear RGB ROI, so that
the albedo's texture leaves the photometric fit (dichromatic reflection; issue 39's flat mucosa,
whose darkest-channel fit was 9 % short in depth on every frame of one texture)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.ndimage import gaussian_filter

from simtest.geometry import angle_between_deg
from simtest.geometry.angles import unit
from simtest.geometry.response import SensorResponse
from simtest.reconstruct import lightaware as la
from simtest.reconstruct.lightaware import colour as lam
from simtest.simulate.offset import rig_plane_image
from test_lightaware import plane_case
from test_lightaware_sensor import RIG, rig_diffuse_shading

#: Mucosa's base colour and its vessels' absorption per channel (as the renderer's tissue).
BASE = np.array([0.75, 0.26, 0.20])
ABSORB = np.array([0.25, 0.55, 0.45])
#: Phong n of the test's film (the GGX alpha 0.1 of the same peak curvature): on the 240 px
#: image both lights' lobes lie inside, their tails on the border 2e-4 of the peak.
SHARP = 200.0


def _colour_plane(seed, size=240, base=BASE, absorb=ABSORB):
    """An exact plane under the two-guide rig (Phong lobes, white) over the rig's Lambertian
    shading of a textured albedo: a smooth colour variation (12 % RMS) and vessel-like lines
    (the zero set of a smooth field) that absorb each channel differently. Linear RGB (H, W, 3),
    the specular image alone (H, W), K, normal, depth, BP."""
    _, K, N, depth, bp = plane_case(20.0, 30.0, RIG, size=size)
    spec = rig_plane_image(K, (size, size), N, 20.0, RIG, SHARP)
    H, W = spec.shape
    D = rig_diffuse_shading(K, spec.shape, N, 20.0, RIG)
    rng = np.random.default_rng(seed)
    var = gaussian_filter(rng.normal(size=(H, W)), 8.0)
    g = gaussian_filter(rng.normal(size=(H, W)), 4.0)
    vessel = np.exp(-(g / (0.5 * g.std())) ** 2)
    alb = base * ((1 + 0.12 * var / var.std()) [..., None]) * (1 - absorb * vessel[..., None])
    s = spec / spec.max() * 0.5
    rgb = s[..., None] + alb * (D / D.max() * 0.8)[..., None]
    return rgb, s, K, N, depth, bp


def test_the_projection_gives_the_specular_image_back():
    # two body colours (the base and the vessels'): w . I is the white lobe at every pixel, the
    # texture gone but for the white of the lobes' tails on the border where the body colours
    # are measured (2e-4 of the peak there, 1.4e-5 leaked)
    rgb, s, *_ = _colour_plane(0)
    values, lower, missing, w = lam.specular_image(rgb)
    assert w.sum() == pytest.approx(1.0, abs=1e-12)
    np.testing.assert_allclose(values, s, atol=1e-4 * s.max())
    # the border band's white left out entirely (its lobe tails zeroed): exact to round-off
    ring = lam._border_band(s.shape)
    clean = rgb - np.where(ring, s, 0.0)[..., None]
    np.testing.assert_allclose(lam.specular_image(clean)[0], np.where(ring, 0.0, s), atol=1e-12 * s.max())
    assert not lower.any() and not missing.any()


@pytest.mark.parametrize("seed", [0, 1])
def test_a_textured_colour_plane_fits_exactly(seed):
    # The darkest channel's fit takes the texture into its lobe (0.08 deg off here; the
    # renderer's mucosa: 9 % short in depth); on the three channels the texture is projected
    # out and the fit is exact again (the leak of the border's lobe tails, 1.4e-5 of the peak,
    # and the solver's tolerance: far below 1e-3 deg and 1e-3 of the distance)
    rgb, s, K, N, depth, bp = _colour_plane(seed)
    dark = la.photometric_fit(rgb[..., 2], (0, 0), bp, K, RIG, diffuse=True, lobe="phong")
    assert not dark.ok or angle_between_deg(dark.normal, N) > 0.03, dark
    r = la.photometric_fit(rgb, (0, 0), bp, K, RIG, diffuse=True, lobe="phong")
    assert r.ok, r
    assert "body colours projected out" in r.detail and r.projection == "body_colours"
    assert dark.projection is None  # one channel given: nothing projected
    assert angle_between_deg(r.normal, N) < 1e-3
    assert r.distance_mm == pytest.approx(20.0, rel=1e-3)


def test_clipped_channels_are_censored_or_left_out():
    # clipping the brightest 2 % of each channel: a clipped channel whose weight is negative
    # bounds nothing (left out), one whose weight is >= 0 bounds the value from below (censored)
    rgb, s, K, N, depth, bp = _colour_plane(0)
    clip = np.percentile(rgb.reshape(-1, 3), 98, axis=0)
    y = np.minimum(rgb, clip)
    values, lower, missing, w = lam.specular_image(y, clip, two_channels=False)
    clipped = y >= clip
    assert np.array_equal(missing, (clipped & (w < 0)).any(axis=2))
    assert np.array_equal(lower, clipped.any(axis=2) & ~missing)
    assert lower.any() and missing.any()
    # the censored values are lower bounds of the true ones; the rest are the specular image to
    # the leak of the lobe tails on the border (as unclipped: 1e-4 of the peak)
    assert np.all(values[lower] <= s[lower] + 1e-4 * s.max())
    free = ~lower & ~missing
    np.testing.assert_allclose(values[free], s[free], atol=1e-4 * s.max())
    r = la.photometric_fit(y, (0, 0), bp, K, RIG, clip_level=clip, diffuse=True, censor=True, lobe="phong",
                           two_channels=False)
    assert r.ok, r
    assert angle_between_deg(r.normal, N) < 1e-3
    assert r.distance_mm == pytest.approx(20.0, rel=1e-3)


def test_body_colours_near_white_fall_back_to_the_darkest_channel():
    # body colours near white: the projection's noise gain would be far above its bound; the fit
    # runs on one channel (the one whose median is least) and says so
    rgb, s, K, N, depth, bp = _colour_plane(0, base=np.array([0.5, 0.49, 0.48]), absorb=np.array([0.5, 0.2, 0.6]))
    assert lam.specular_image(rgb) is None
    r = la.photometric_fit(rgb, (0, 0), bp, K, RIG, diffuse=True, lobe="phong")
    assert "channel 2" in r.detail and r.projection == "darkest_channel"


def test_one_body_colour_is_projected_out_by_the_least_fluctuation_weights():
    # vessels that darken every channel alike: the border holds one body colour, and the
    # least-fluctuation weights remove it (the texture lies along it: nothing of it is left), so
    # the fit is exact (to the leak of the lobes' tails into the box means, 1e-4 of the peak)
    rgb, s, K, N, depth, bp = _colour_plane(0, absorb=np.full(3, 0.5))
    values, lower, missing, w = lam.specular_image(rgb)
    assert w.sum() == pytest.approx(1.0, abs=1e-12)
    assert abs(w @ BASE) < 1e-3 * np.linalg.norm(w) * np.linalg.norm(BASE)
    r = la.photometric_fit(rgb, (0, 0), bp, K, RIG, diffuse=True, lobe="phong")
    assert "body colours projected out" in r.detail and r.projection == "least_fluctuation"
    assert r.ok, r
    assert angle_between_deg(r.normal, N) < 0.01
    assert r.distance_mm == pytest.approx(20.0, rel=1e-3)


def test_without_noise_the_least_fluctuation_weights_are_the_exact_projection():
    # texture of two body colours and no noise: the fluctuations lie in the body plane, and the
    # weights that let the least of them through are orthogonal to it (specular_image's exact
    # projection), whatever the shading
    rgb, s, *_ = _colour_plane(1)
    body = rgb - s[..., None]
    w = lam._least_fluctuation_weights(body, np.zeros(body.shape[:2], bool))
    wt = np.cross(BASE, BASE * ABSORB)
    np.testing.assert_allclose(w, wt / wt.sum(), atol=1e-6)


@pytest.mark.parametrize("seed", [0, 1])
@pytest.mark.parametrize("noise", [0.01, 0.02])
def test_in_read_noise_the_texture_is_still_projected_out(seed, noise):
    # Read noise of 1 or 2 % of full scale on the linear channels, clipped at 0 (the sensor's).
    # At 1 % the border band still tells the second body colour (its singular value 2.1 times
    # the third here) and the exact projection is used; at 2 % it is lost in the noise (1.3 to
    # 1.4 times, below the bound of 1.5), where the fit fell back to the darkest channel (the
    # endoscope suite's flat mucosa at 0.5 to 2 % read noise: 0.6 to 0.8 deg off, depth 8 to 9 %
    # short). The least-fluctuation weights then still take the texture out, trading what is
    # left of it against the noise gain. Either way the fit recovers the plane within 0.1 deg and
    # 2 % of its distance (the noise's spread here: its sigma 0.04 to 0.05 deg) and its error is
    # within twice its sigma
    rgb, s, K, N, depth, bp = _colour_plane(seed)
    rng = np.random.default_rng(seed)
    y = np.maximum(rgb + rng.normal(0.0, noise, rgb.shape), 0.0)
    ring = lam._border_band(s.shape)
    told = lam._body_weights(y[ring]) is not None
    assert told == (noise == 0.01)
    assert lam.specular_image(y) is not None
    r = la.photometric_fit(y, (0, 0), bp, K, RIG, diffuse=True, lobe="phong")
    assert r.projection == ("body_colours" if told else "least_fluctuation"), r.detail
    assert r.ok, r
    err = angle_between_deg(r.normal, N)
    assert err < 0.1 and err <= 2 * r.normal_sigma_deg, (err, r.normal_sigma_deg)
    assert r.distance_mm == pytest.approx(20.0, rel=0.02)


@settings(max_examples=25, deadline=None)
@given(st.tuples(*[st.floats(0.05, 1.0)] * 3), st.tuples(*[st.floats(0.0, 0.9)] * 3),
       st.floats(0.0, 2.0))
def test_the_projection_removes_any_two_body_colours(base, absorb, spec_gain):
    # w is orthogonal to both body colours and sums to 1: w . (S 1 + D a) = S for any texture of
    # the two, wherever its noise gain is within the bound
    rng = np.random.default_rng(0)
    b1, b2 = np.array(base), np.array(base) * np.array(absorb)
    c1, c2 = rng.uniform(0.5, 1.0, (30, 30)), rng.uniform(0.0, 0.5, (30, 30))
    S = spec_gain * rng.uniform(0, 1, (30, 30))
    S[0] = S[-1] = S[:, 0] = S[:, -1] = 0.0  # the border: body reflection alone
    rgb = S[..., None] + c1[..., None] * b1 + c2[..., None] * b2
    out = lam.specular_image(rgb)
    if out is None:
        return
    values, _, _, w = out
    assert np.linalg.norm(w) <= lam.BODY_PROJECTION_MAX_GAIN
    assert w.sum() == pytest.approx(1.0, abs=1e-9)
    # where the border tells the two body colours apart (else the least-fluctuation weights
    # stand in: a second colour of 1e-9, as hypothesis found, is no colour of the texture), they
    # are well apart and white well off their plane (the exact projection's gain below 5), the
    # projection is theirs and exact to round-off
    wt = np.cross(b1, b2)
    if (lam.specular_image(rgb, fluctuation=False) is not None
            and np.linalg.norm(np.cross(unit(b1), unit(b2))) > 0.05 and abs(wt.sum()) > 0
            and np.linalg.norm(wt / wt.sum()) < 5):
        np.testing.assert_allclose(w, wt / wt.sum(), atol=1e-6)
        np.testing.assert_allclose(values, S, atol=1e-8)


def test_bad_colour_input():
    with pytest.raises(ValueError, match="rgb"):
        lam.specular_image(np.zeros((4, 4, 2)))
    with pytest.raises(ValueError, match="clip_level"):
        lam.specular_image(np.ones((4, 4, 3)), [1.0, 2.0])


def test_a_fit_without_a_depth_on_the_sensor_path_is_retried_from_further_starts():
    # An exact plane at 10 mm, its cores clipped, started from the nominal 40 mm: from that one
    # start the fit ends in a local minimum 11.2 deg off with its depth not observable (the
    # endoscope suite's flat mucosa at 10 mm: 11.4 deg); on RGB values (the sensor path) it is
    # tried again from RETRY_START_DEPTHS starts along the BP's constraint and the lower residual
    # kept: exact (the solver's tolerance)
    from test_lightaware import plane_case

    spec, K, N, depth, bp = plane_case(10.0, 30.0, RIG, size=200)
    y = np.minimum(spec / spec.max(), 0.3)
    rgb = y[..., None] + 0.3 * BASE
    clip = list(0.3 + 0.3 * BASE)
    kw = dict(nominal_depth_mm=40.0, diffuse=True, censor=True, clip_level=clip, lobe="phong")
    one = la.photometric_fit(rgb, (0, 0), bp, K, RIG, n_start_depths=0, **kw)
    assert one.status == "depth_not_observable" and angle_between_deg(one.normal, N) > 5, one
    r = la.photometric_fit(rgb, (0, 0), bp, K, RIG, **kw)
    assert r.ok, r
    assert angle_between_deg(r.normal, N) < 1e-3
    assert r.distance_mm == pytest.approx(10.0, rel=1e-3)


def test_a_body_colours_fit_without_a_depth_gives_way_to_the_least_fluctuation_weights():
    # An 8-bit sRGB frame of a plane whose vessels absorb every channel nearly alike (their
    # colour 6 deg from the base's): the body colours' fit ends in a local minimum 5.4 deg off
    # with its depth not observable and a sigma of 0.39 deg, a normal the recommendation would
    # take over a BP ray of several degrees (or, its starts stopped where they ran off, not converged). The fit on the least-fluctuation weights (ok,
    # within 0.05 deg and 1 % of the distance: the 8-bit rounding's share) stands in for it
    rgb, s, K, N, depth, bp = _colour_plane(1, absorb=np.array([0.3, 0.4, 0.38]))
    response = SensorResponse("srgb", 1.0, (1.0, 1.0, 1.0), 1.0, 255.0)
    x = np.clip(rgb, 0.0, 1.0)
    encoded = np.round(255.0 * np.where(x <= 0.0031308, 12.92 * x, 1.055 * x ** (1 / 2.4) - 0.055))
    lin = np.stack([response.linear(encoded[..., c], c, 255.0) for c in range(3)], axis=-1)
    clip = [1.0] * 3
    # started from the mean light's bisector (the BP ray under this symmetric rig): from the start
    # of the light that fits best (the default for a rig of several lights) the body colours' fit
    # is ok, within twice its sigma
    ray = unit(np.linalg.solve(K, [bp[0], bp[1], 1.0]))
    kw = dict(diffuse=True, lobe="phong", clip_level=clip, censor=True)
    own = la.photometric_fit(lin, (0, 0), bp, K, RIG, projection="border", **kw)
    assert own.ok and angle_between_deg(own.normal, N) < 2.0 * own.normal_sigma_deg, own
    body = la.photometric_fit(lin, (0, 0), bp, K, RIG, projection="border", start_normal=-ray, **kw)
    # (in the local minimum, its depth not observable; or, where its starts ran off past
    # RUN_OFF_FACTOR before they found it, not converged: a not-ok fit either way)
    assert body.projection == "body_colours" and body.status in ("depth_not_observable", "not_converged"), body
    assert not body.has_normal or angle_between_deg(body.normal, N) > 1.0
    r = la.photometric_fit(lin, (0, 0), bp, K, RIG, start_normal=-ray, **kw)
    assert r.ok and r.projection == "least_fluctuation", r
    assert "the body colours' fit is not ok" in r.detail
    assert angle_between_deg(r.normal, N) < 0.05
    assert r.distance_mm == pytest.approx(20.0, rel=0.01)


@given(st.floats(0.002, 0.03), st.integers(0, 2**16))
@settings(max_examples=20, deadline=None)
def test_the_clip_margin_is_clip_margin_noise_sigmas_of_the_unclipped_pixels(sigma, seed):
    # a smooth ramp clipped over a third of the ROI, white noise of sigma: the margin is
    # CLIP_MARGIN sigma (the MAD's spread over about 2,600 neighbour differences: under 5 % at
    # 3 of its standard deviations); per channel for RGB; 0 without noise
    from simtest.decisions import CLIP_MARGIN
    from simtest.reconstruct.light_fits import _clip_margin

    rng = np.random.default_rng(seed)
    ramp = np.tile(np.linspace(0.3, 1.4, 90), (45, 1))
    assert _clip_margin(np.minimum(ramp, 1.0), 1.0) == 0.0
    noisy = np.minimum(ramp + rng.normal(0.0, sigma, ramp.shape), 1.0)
    assert _clip_margin(noisy, 1.0) == pytest.approx(CLIP_MARGIN * sigma, rel=0.15)
    rgb = np.stack([noisy, np.minimum(ramp + rng.normal(0.0, 2 * sigma, ramp.shape), 1.0), np.minimum(ramp, 1.0)], -1)
    got = _clip_margin(rgb, [1.0, 1.0, 1.0])
    assert got[0] == pytest.approx(CLIP_MARGIN * sigma, rel=0.15)
    assert got[1] == pytest.approx(2 * CLIP_MARGIN * sigma, rel=0.15) and got[2] == 0.0


def test_a_channel_within_the_censor_margin_is_censored_at_its_level():
    # exact: a pixel whose green lies within the margin below the clip is censored (a lower bound:
    # green's weight is positive), its bound the projection of the green at the level, not of its
    # value; a pixel whose red (weight negative) lies there is left out; the body colours are
    # measured on the colours clear of the margin, as with the clip at its lower edge
    rng = np.random.default_rng(0)
    body = np.array([[0.6, 0.3, 0.2], [0.5, 0.35, 0.35]])  # (a plane of RGB without white)
    a = rng.uniform(0.4, 1.0, (30, 30, 2))
    rgb = a @ body
    rgb[15, 15] = [0.6, 0.97, 0.5]
    plain = la.colour.specular_image(rgb, 1.0, two_channels=False)
    got = la.colour.specular_image(rgb, 1.0, censor_margin=[0.05, 0.05, 0.05], two_channels=False)
    np.testing.assert_array_equal(la.colour.specular_image(rgb, 1.0 - 0.05)[3], got[3])
    w = got[3]
    assert w[0] < 0 < w[1]  # (red weighs negatively, green positively: the two cases below)
    assert not plain[1][15, 15] and got[1][15, 15] and not got[2][15, 15]
    assert got[0][15, 15] == pytest.approx(np.array([0.6, 0.95, 0.5]) @ w, rel=1e-12)
    red = rgb[..., 0] >= 0.95
    assert red.any() and np.array_equal(got[2], red) and not (got[1] & red).any()
    np.testing.assert_array_equal(got[1] | got[2], (rgb >= 0.95).any(axis=2))  # (each within the margin)


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), width=st.integers(64, 300), height=st.integers(64, 300),
       brightest=st.floats(1.0, 2.0), sigma=st.floats(0.003, 0.02))
def test_a_channel_clipped_under_noise_makes_no_second_body_colour(seed, width, height, brightest, sigma):
    # one body colour (pink tissue) shaded from 0.6 to `brightest` across the ROI, so that its red
    # clips over part of the border, then sensor noise clipped at full scale again: inside the
    # clipped area noise leaves some red readings below the clip, a colour no tissue has. With the
    # margin of the fits (CLIP_MARGIN = 2 sigma) the border holds one body colour: no projection
    # of two (which would fit the specular image 10 times noisier, the 8-bit frame's fit 9.7 deg off)
    rng = np.random.default_rng(seed)
    shade = np.linspace(0.6, brightest, width)[None, :, None] * np.ones((height, 1, 1))
    rgb = np.clip(shade * np.array([0.8, 0.35, 0.3]), 0.0, 1.0)
    rgb = np.clip(rgb + rng.normal(0.0, sigma, rgb.shape), 0.0, 1.0)
    assert lam.specular_image(rgb, 1.0, fluctuation=False, censor_margin=2.0 * sigma) is None
