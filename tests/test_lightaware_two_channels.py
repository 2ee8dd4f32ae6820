"""Pixels clipped in one channel only (red, by the tissue's own reflection beside the lobe) are
valued from their two other channels (``colour._from_two_channels``), and the photometric fit
with them is kept where the fit without them is ok and agrees with it within the sigma of their
difference (``plane._two_channel_choice``, a Hausman test)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from simtest.geometry import angle_between_deg
from simtest.geometry.angles import unit
from simtest.geometry.response import SensorResponse
from simtest.reconstruct import lightaware as la
from simtest.reconstruct.lightaware import colour as lam
from simtest.reconstruct.lightaware import plane as lap
from simtest.reconstruct.lightaware.estimate import LightAwareEstimate
from test_lightaware_colour import RIG, _colour_plane


def test_clipped_channels_are_censored_taken_from_two_channels_or_left_out():
    # clipping the brightest 2 % of each channel: a pixel whose one clipped channel has a negative
    # weight takes its value from its two unclipped channels; one with several clipped channels,
    # a weight among them negative, bounds nothing (left out); one whose clipped channels' weights
    # are all >= 0 bounds the value from below (censored)
    rgb, s, K, N, depth, bp = _colour_plane(0)
    clip = np.percentile(rgb.reshape(-1, 3), 98, axis=0)
    y = np.minimum(rgb, clip)
    values, lower, missing, w = lam.specular_image(y, clip)
    clipped = y >= clip
    neg = (clipped & (w < 0)).any(axis=2)
    two = neg & (np.count_nonzero(clipped, axis=2) == 1)
    assert np.array_equal(missing, neg & ~two)
    assert np.array_equal(lower, clipped.any(axis=2) & ~neg)
    assert lower.any() and missing.any() and two.any()
    assert np.all(values[lower] <= s[lower] + 1e-4 * s.max())
    free = ~lower & ~missing & ~two
    np.testing.assert_allclose(values[free], s[free], atol=1e-4 * s.max())
    # the two channels' values: at most w . I as measured (an upper bound of the specular image
    # there, the clipped channel's weight negative), and the specular image to the second body
    # colour's texture, which two channels cannot remove with the first (the vessels absorb the
    # three channels by 0.25, 0.55 and 0.45: up to 5 % of the peak here)
    assert np.all(values[two] <= (y @ w)[two]) and np.all(s[two] <= (y @ w)[two] + 1e-4 * s.max())
    np.testing.assert_allclose(values[two], s[two], atol=0.06 * s.max())
    # without them (two_channels=False) those pixels are left out, as the others with a negative
    # weight clipped
    _, lower0, missing0, _ = lam.specular_image(y, clip, two_channels=False)
    assert np.array_equal(missing0, neg) and np.array_equal(lower0, lower)


@settings(max_examples=100, deadline=None)
@given(spec=st.floats(0.05, 2.0), body=st.floats(0.05, 1.0), channel=st.integers(0, 2),
       colour=st.tuples(st.floats(0.1, 1.0), st.floats(0.05, 1.0), st.floats(0.05, 1.0)))
def test_one_clipped_channel_gives_the_specular_value_under_one_body_colour(spec, body, channel, colour):
    # a border of one body colour b1 (its shading varying) and a pixel S (1, 1, 1) + alpha b1 whose
    # channel `channel` is clipped: the two others give S exactly (b1 removed), never above the
    # three channels' projection as measured; a pair too near white's direction is left out
    b1 = np.asarray(colour, dtype=np.float64)
    w = np.ones(3)  # any weights with w . 1 = 1 and the clipped channel's negative
    w[channel] = -1.0
    pix = spec + body * b1
    clip = np.full(3, np.inf)
    clip[channel] = 0.5 * pix[channel]
    v = np.minimum(pix, clip)[None, None, :]
    clipped = v >= clip
    neg = (clipped & (w < 0)).any(axis=2)
    anyc = clipped.any(axis=2)
    values = v @ w
    ring = np.outer(np.linspace(0.2, 1.0, 12), b1)  # the border: b1 under a varying shading
    o0, o1 = [k for k in range(3) if k != channel]
    gain = np.hypot(b1[o1], b1[o0]) / abs(b1[o0] - b1[o1]) if b1[o0] != b1[o1] else np.inf
    lam._from_two_channels(v, clipped, neg, anyc, values, ring)
    if gain > lam.BODY_PROJECTION_MAX_GAIN:
        assert neg[0, 0] and anyc[0, 0]
        return
    assert not neg[0, 0] and not anyc[0, 0]
    assert values[0, 0] <= float(v[0, 0] @ w) + 1e-12
    assert values[0, 0] == pytest.approx(min(spec, float(v[0, 0] @ w)), rel=1e-9, abs=1e-12)


def _est(status, normal, sigma, depth, depth_sigma, projection="body_colours"):
    return LightAwareEstimate("photometric_fit", status, "", normal=np.asarray(normal, dtype=np.float64),
                              distance_mm=depth, normal_sigma_deg=sigma, depth_mm=depth,
                              depth_sigma_mm=depth_sigma, projection=projection)


def _tilted(deg):
    return np.array([np.sin(np.radians(deg)), 0.0, -np.cos(np.radians(deg))])


@settings(max_examples=300, deadline=None)
@given(plain_status=st.sampled_from(["ok", "depth_not_observable", "plane_misfit"]),
       both_status=st.sampled_from(["ok", "depth_not_observable"]),
       sp=st.floats(0.01, 5.0), sb=st.floats(0.01, 5.0), gap=st.floats(0.0, 10.0),
       dp=st.floats(0.01, 5.0), db=st.floats(0.01, 5.0), dgap=st.floats(0.0, 10.0),
       chan_fit=st.tuples(st.floats(-10.0, 10.0), st.floats(0.01, 5.0), st.floats(-10.0, 10.0), st.floats(0.01, 5.0)))
def test_the_two_channel_fit_is_kept_only_where_the_plain_one_is_ok_and_agrees(
        plain_status, both_status, sp, sb, gap, dp, db, dgap, chan_fit):
    plain = _est(plain_status, _tilted(0.0), sp, 20.0 if plain_status == "ok" else None,
                 dp if plain_status == "ok" else None)
    both = _est(both_status, _tilted(gap), sb, 20.0 + dgap if both_status == "ok" else None,
                db if both_status == "ok" else None)
    got = lap._two_channel_choice(both, plain)
    margin = 1e-9  # away from the bounds by more than the arithmetic's rounding

    def agree(eff, other):  # the Hausman test, eff the more precise: -1 apart, 1 agree, 0 at a bound
        room = lap.TWO_CHANNEL_Z * np.sqrt(max(other.normal_sigma_deg ** 2 - eff.normal_sigma_deg ** 2, 0.0))
        droom = lap.TWO_CHANNEL_Z * np.sqrt(max(other.depth_sigma_mm ** 2 - eff.depth_sigma_mm ** 2, 0.0))
        g, d = angle_between_deg(eff.normal, other.normal), abs(eff.depth_mm - other.depth_mm)
        return 1 if g <= room - margin and d <= droom - margin else -1 if g > room + margin or d > droom + margin else 0

    ok_both = plain_status == both_status == "ok" and sb < sp
    kept = ok_both and agree(both, plain) == 1
    if kept:
        assert got.normal is both.normal and "valued from the other two" in got.detail
    if not ok_both or agree(both, plain) == -1:
        assert got is plain  # unchanged: the fit without those pixels, as before they were valued
    # where both are ok and more precise but disagree, the darkest channel's fit referees where it
    # is ok (one of the two misread the lobe): the more precise of the two that agrees with it by
    # the same test, else it stands in; not ok, the plain one; elsewhere it is never fitted
    disagree = ok_both and agree(both, plain) == -1
    calls = []
    cgap, sc, cdep, dc = chan_fit
    for chan_status in ("ok", "plane_misfit"):
        chan = _est(chan_status, _tilted(cgap), sc, 20.0 + cdep, dc, projection="darkest_channel")
        got = lap._two_channel_choice(both, plain, lambda c=chan: calls.append(c) or c)
        if disagree and chan_status != "ok":
            assert got is plain
        if disagree and chan_status == "ok":
            assert "disagree" in got.detail
            if agree(both, chan) == 1:
                assert got.normal is both.normal and "agrees with the one with them" in got.detail
            elif agree(both, chan) == -1 and agree(plain, chan) == 1:
                assert got.normal is plain.normal and "agrees with the one without them" in got.detail
            elif agree(both, chan) == -1 and agree(plain, chan) == -1:
                assert got.normal is chan.normal
        if kept:
            assert got.normal is both.normal and not calls
        if not ok_both:
            assert got is plain and not calls
    # on one channel (no projection) no pixel was valued from two: the plain fit, whatever else
    one = _est("ok", _tilted(0.0), 0.1 * sp, 20.0, 0.1 * dp, projection="darkest_channel")
    assert lap._two_channel_choice(one, plain) is plain


def _red_clipped_frame():
    """An 8-bit sRGB frame of a plane whose vessels absorb every channel nearly alike, its red
    channel clipped by the body reflection alone on 148 pixels beside the lobes (the frame of
    test_lightaware_colour's least-fluctuation test): linear RGB, K, N, BP, the BP ray."""
    rgb, s, K, N, depth, bp = _colour_plane(1, absorb=np.array([0.3, 0.4, 0.38]))
    response = SensorResponse("srgb", 1.0, (1.0, 1.0, 1.0), 1.0, 255.0)
    x = np.clip(rgb, 0.0, 1.0)
    encoded = np.round(255.0 * np.where(x <= 0.0031308, 12.92 * x, 1.055 * x ** (1 / 2.4) - 0.055))
    lin = np.stack([response.linear(encoded[..., c], c, 255.0) for c in range(3)], axis=-1)
    ray = unit(np.linalg.solve(K, [bp[0], bp[1], 1.0]))
    return lin, K, N, bp, ray


def test_red_clipped_pixels_valued_from_green_and_blue_take_the_fit_out_of_its_local_minimum():
    # left out, the 148 red-clipped pixels beside the lobes leave the body colours' fit from the
    # BP ray in a local minimum 5.4 deg off, its depth not observable; valued from green and blue
    # it finds the plane within 0.01 deg and 0.1 % (the 8-bit rounding's share)
    lin, K, N, bp, ray = _red_clipped_frame()
    clipped = lin >= 1.0
    assert np.count_nonzero(np.count_nonzero(clipped, axis=2) == 1) > 100
    assert lap._one_channel_clipped(lin, 1.0)
    kw = dict(diffuse=True, lobe="phong", clip_level=[1.0] * 3, censor=True, start_normal=-ray,
              projection="border")
    without = la.photometric_fit(lin, (0, 0), bp, K, RIG, two_channels=False, **kw)
    # (or, its starts stopped where they ran off past RUN_OFF_FACTOR, not converged: not ok either way)
    assert without.status in ("depth_not_observable", "not_converged")
    assert not without.has_normal or angle_between_deg(without.normal, N) > 1.0
    with_ = la.photometric_fit(lin, (0, 0), bp, K, RIG, two_channels=True, **kw)
    assert with_.ok and with_.projection == "body_colours", with_
    assert angle_between_deg(with_.normal, N) < 0.01
    assert with_.distance_mm == pytest.approx(20.0, rel=1e-3)
    # the default keeps the fit without them there: it is not ok, so nothing vouches for the
    # other (a curved patch's plane can pass with those pixels, _two_channel_choice)
    auto = la.photometric_fit(lin, (0, 0), bp, K, RIG, **kw)
    assert auto.status == without.status and auto.detail == without.detail
