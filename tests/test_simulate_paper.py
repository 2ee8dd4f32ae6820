"""The paper's synthetic protocol (simtest.simulate.paper): geometry, BP, randomness, exact cases."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from simtest.constants import gaussian_radius_px
from simtest.geometry.angles import angle_between_deg
from simtest.simulate.paper import PaperParams, PaperSimulator, mirror_point, paper_homography
from simtest.specular import phong_intensity


@settings(max_examples=30, deadline=None)
@given(theta=st.floats(0.0, 85.0), x0=st.floats(-300, 300), y0=st.floats(-300, 300),
       px=st.floats(-150, 150), py=st.floats(-150, 150))
def test_homography_is_the_slanted_camera(theta, x0, y0, px, py):
    """H applied to a texture pixel equals the camera projection of its plane point."""
    p = PaperParams(theta_deg=theta)
    H, K, R, C = paper_homography(p, (x0, y0))
    T = p.texture
    u, v = px + T / 2.0, py + T / 2.0  # texture pixel
    P = np.array([x0 + u - T / 2.0, y0 - (v - T / 2.0), 0.0])  # its plane point (module doc)
    h = H @ [u, v, 1.0]
    X = K @ (R @ (P - C))
    # Both are ratios of O(1e3) numbers computed in float64: 1e-7 px is 1e5 ulps of headroom.
    np.testing.assert_allclose(h[:2] / h[2], X[:2] / X[2], atol=1e-7)
    # The window centre is the principal point (BP at the image centre).
    c = H @ [T / 2.0, T / 2.0, 1.0]
    np.testing.assert_allclose(c[:2] / c[2], [p.image_px / 2.0] * 2, atol=1e-9)


@pytest.mark.parametrize("theta", [0.0, 30.0, 58.0, 85.0])
def test_truth_normal_is_theta_off_the_bp_ray(theta):
    sim = PaperSimulator(PaperParams(theta_deg=theta, sigma=0.0))
    s = sim.sample(np.random.default_rng(0))
    np.testing.assert_allclose(s.bp_px, [203.0, 203.0], atol=1e-9)  # pixel centres: cx = M/2
    ray = np.linalg.solve(s.K, [s.bp_px[0], s.bp_px[1], 1.0])
    assert np.dot(s.normal, ray) < 0  # faces the camera
    # Exact geometry: the BP ray is the optical axis, the normal is theta from it. 1e-9 deg is
    # float64 rounding of a 3-vector built from sin/cos.
    assert abs(angle_between_deg(s.normal, -ray) - theta) < 1e-9


@settings(max_examples=40, deadline=None)
@given(eps=st.floats(1.0, 800.0), a=st.floats(0.0, 2 * math.pi), b=st.floats(-0.5, 0.5))
def test_mirror_point_is_the_phong_maximum(eps, a, b):
    V = np.array([0.0, 0.0, 1000.0])
    L = V + eps * np.array([math.cos(a), math.sin(a), b])
    P = mirror_point(V, L)
    # beta = 0 there: I = c exactly up to rounding of a cosine (1e-12).
    assert phong_intensity(P, V, L, 100.0) == pytest.approx(1.0, abs=1e-12)
    # and every neighbour 1 px away is dimmer.
    for d in ([1, 0], [-1, 0], [0, 1], [0, -1]):
        assert phong_intensity(P + d, V, L, 100.0) < 1.0


def test_image_normalised_at_bp_and_reproducible():
    p = PaperParams(epsilon_px=300.0, n=100.0)
    s1 = PaperSimulator(p).sample(np.random.default_rng(7))
    s2 = PaperSimulator(p).sample(np.random.default_rng(7))
    np.testing.assert_array_equal(s1.image, s2.image)
    np.testing.assert_array_equal(s1.light_px, s2.light_px)
    # Normalised so that the smoothed image is 1 at the BP (float32 division: 1 ulp).
    r, c = int(round(s1.bp_px[1])), int(round(s1.bp_px[0]))
    assert s1.image[r, c] == pytest.approx(1.0, abs=1e-6)
    # The light offset has the paper's norm bounds: |L - V| in [eps, eps sqrt(1.25)].
    d = np.linalg.norm(s1.light_px - np.array([0.0, 0.0, 1000.0]))
    assert 300.0 - 1e-9 <= d <= 300.0 * math.sqrt(1.25) + 1e-9
    s3 = PaperSimulator(p).sample(np.random.default_rng(8))
    assert not np.array_equal(s1.image, s3.image)


def test_noise_has_the_requested_sigma():
    p = PaperParams(sigma=0.05, smoothing_px=0.0, theta_deg=0.0)
    sim = PaperSimulator(p)
    s = sim.sample(np.random.default_rng(1))
    resid = s.image * s.bp_value - sim._clean  # undo normalisation, remove the clean image
    # 165 k samples: the std estimate has relative error about 1/sqrt(2 * 165e3) = 0.2 %; 2 %
    # is 10 standard errors.
    assert np.std(resid) == pytest.approx(0.05, rel=0.02)


def test_the_image_is_the_papers_formula_in_float32_bit_for_bit():
    # sample() forms the image in place; it must be the written formula, (clean + sigma * noise)
    # smoothed, over its value at the BP, each step in float32, from the same random stream
    import cv2

    from simtest.simulate.paper import _bilinear

    p = PaperParams(sigma=0.05, smoothing_px=2.0, epsilon_px=100.0)
    sim = PaperSimulator(p)
    s = sim.sample(np.random.default_rng(11))
    rng = np.random.default_rng(11)
    sim.light(rng)  # the light draw comes first
    clean = sim._render_clean(s.light_px)[0]
    assert clean.dtype == np.float32
    want = clean + np.float32(p.sigma) * rng.standard_normal(clean.shape, dtype=np.float32)
    want = cv2.GaussianBlur(want, (0, 0), sigmaX=2.0, sigmaY=2.0, borderType=cv2.BORDER_REFLECT)
    want = want / np.float32(_bilinear(want, s.bp_px))
    assert want.dtype == s.image.dtype and want.tobytes() == s.image.tobytes()


def test_fronto_noiseless_gives_zero_error():
    """theta = 0, sigma = 0: the camera is the viewer (co-located), the isophote is a circle
    centred at the BP, and the image is symmetric under the pixel grid's quarter turns about
    the BP pixel, so the fitted conic is a circle centred there."""
    from simtest.harness.protocols import PaperRunner
    from simtest.harness.suite import realisation_seed, suite_from_dict

    suite = suite_from_dict({"sweep": [{"name": "z", "parameter": "theta_deg", "values": [0.0],
                                        "set": {"sigma": 0.0}}]})
    case = suite.cases[0]
    runner = PaperRunner(case, suite.estimators)
    row = runner.run(realisation_seed(0, case.key, 0))[0]
    assert all(c is None for c in row.causes.values()), row.causes
    e = row.errors
    # BP ray: the BP is the principal point and the normal is the optical axis: exact.
    assert e["bp_ray"] < 1e-9
    # Cone axis: a conic centre offset delta tilts the axis by about delta / f rad; OpenCV warps
    # with 1/32 px fixed-point coordinates, so delta <= 1/64 px and the tilt <= 2.2e-3 deg.
    assert e["cone_axis"] < 2.2e-3
    assert e["joint_cone_axis"] < 2.2e-3
    # Circle pose: N+- leave the cone axis by asin(sqrt(gap)) (square-root sensitivity). What is
    # left of the gap is float32 rounding of the image (relative 6e-8) through the fit; gap < 1e-6
    # allows a factor 16, and bounds the oracle error by asin(1e-3) = 0.057 deg.
    gap = row.extras["eigenvalue_gap"]
    assert gap < 1e-6
    assert e["paper_oracle"] <= math.degrees(math.asin(math.sqrt(gap))) + e["cone_axis"] + 1e-6
    assert e["paper_oracle"] < 0.058


@pytest.mark.parametrize("field,value", [("sigma", -0.1), ("theta_deg", 90.0), ("n", 0.0),
                                         ("image_px", 4), ("window_at_bp", 1)])
def test_bad_params_name_the_field(field, value):
    with pytest.raises(ValueError) as e:  # pydantic's ValidationError, located at the field
        PaperParams(**{field: value})
    assert e.value.errors()[0]["loc"] == (field,)


def test_a_batch_of_realisations_scores_as_each_one_alone():
    """The harness runs a chunk of paper realisations with their reconstructions batched
    (PaperRunner.run_many); every row must be, to the last bit, that of the realisation run alone,
    so a report does not depend on how realisations are chunked."""
    from simtest.harness.protocols import PaperRunner
    from simtest.harness.suite import realisation_seed, suite_from_dict

    suite = suite_from_dict({"sweep": [{"name": "t", "parameter": "theta_deg", "values": [35.0],
                                        "set": {"sigma": 0.05}}]})
    case = suite.cases[0]
    runner = PaperRunner(case, suite.estimators)
    seeds = [realisation_seed(3, case.key, i) for i in range(12)]
    batch = runner.run_many(seeds)
    for s, rows in zip(seeds, batch, strict=True):
        (a,), (b,) = rows, runner.run(s)
        assert a.causes == b.causes
        for k in a.errors:
            assert np.array_equal(a.errors[k], b.errors[k], equal_nan=True), k
        assert a.extras.keys() == b.extras.keys()
        for k in a.extras:
            assert np.array_equal(a.extras[k], b.extras[k], equal_nan=True), k
    assert sum(all(c is None for c in r[0].causes.values()) for r in batch) >= 6


@settings(max_examples=150, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), sigma=st.sampled_from([0.0, 0.05]),
       smoothing=st.sampled_from([0.0, 0.7, 2.0, 3.3]), theta=st.floats(0.0, 80.0),
       eps=st.sampled_from([0.0, 150.0]), corners=st.lists(st.integers(-20, 140), min_size=4, max_size=4))
def test_a_sample_asked_for_a_region_is_the_whole_images_bits_there(seed, sigma, smoothing, theta, eps,
                                                                      corners):
    # the harness asks for the reconstruction's ROI only: there (and at the BP's 2 x 2 pixels,
    # which the normalisation reads) the values must be those of the whole image to the bit,
    # regions at the image's sides and regions that leave the BP out included; the random
    # stream is the whole image's, consumed through the last row the box reads
    # 120 px: wide enough for SIMD blocks and the scalar last columns of OpenCV's rows, small
    # enough for 150 examples
    p = PaperParams(image_px=120, sigma=sigma, smoothing_px=smoothing, theta_deg=theta,
                    epsilon_px=eps, n=60.0)
    sim = PaperSimulator(p)
    r0, r1 = sorted(corners[:2])
    c0, c1 = sorted(corners[2:])
    asked = (r0, r1 + 1, c0, c1 + 1)
    rng_a, rng_b = np.random.default_rng(seed), np.random.default_rng(seed)
    try:
        whole = sim.sample(rng_a)
    except FloatingPointError:
        with pytest.raises(FloatingPointError):
            sim.sample(rng_b, region=lambda clean, bp: asked)
        return
    part = sim.sample(rng_b, region=lambda clean, bp: asked)
    assert part.region == asked and whole.region is None
    assert part.bp_value == whole.bp_value
    # the box computed: the smallest holding the region and the BP's 2 x 2 pixels, in the image
    u, v = (int(math.floor(min(max(float(x), 0.0), 119.0))) for x in whole.bp_px)
    inside = np.zeros((120, 120), bool)
    inside[max(0, min(r0, v)) : max(r1 + 1, v + 2), max(0, min(c0, u)) : max(c1 + 1, u + 2)] = True
    # the generator is left after the noise of the box's last row grown by the smoothing radius
    # (the light's two draws, then the rows in raster order)
    last = min(120, max(r1 + 1, v + 2) + (gaussian_radius_px(smoothing) + 1 if smoothing > 0 else 0))
    rng_c = np.random.default_rng(seed)
    sim.light(rng_c)
    if sigma > 0:
        rng_c.standard_normal((last, 120), dtype=np.float32)
    assert rng_b.random() == rng_c.random()
    assert np.array_equal(part.image[inside], whole.image[inside])
    assert not part.image[~inside].any()


@pytest.mark.parametrize("eps", [0.0, 200.0])
def test_the_harness_rows_are_those_of_the_whole_images(eps):
    # PaperRunner computes each image in the reconstruction's ROI only; its rows must be those of
    # the whole smoothed image reconstructed in that ROI, so the reports do not change
    from simtest.harness.protocols import PaperRunner
    from simtest.harness.suite import realisation_seed, suite_from_dict
    from simtest.reconstruct import reconstruct_roi

    suite = suite_from_dict({"sweep": [{"name": "e", "parameter": "epsilon_px", "values": [eps],
                                        "set": {"n": 100.0}}]})
    case = suite.cases[0]
    runner = PaperRunner(case, suite.estimators)
    seeds = [realisation_seed(5, case.key, i) for i in range(6)]
    for seedseq, (row,) in zip(seeds, runner.run_many(seeds), strict=True):
        s = runner.sim.sample(np.random.Generator(np.random.PCG64(seedseq)))
        est = reconstruct_roi(s.image, s.K, bp_uv=s.bp_px, roi=runner.roi(s.clean, s.bp_px),
                              settings=runner.settings)
        want = runner._score(s.normal, s.bp_px, est)
        assert row.causes == want.causes
        for k in want.errors:
            assert np.array_equal(row.errors[k], want.errors[k], equal_nan=True), k
        for k in want.extras:
            assert np.array_equal(row.extras[k], want.extras[k], equal_nan=True), k
