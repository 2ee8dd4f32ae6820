"""Light-aware estimators on exact images of planes lit off the camera centre."""

from __future__ import annotations

import functools

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from simtest.geometry import angle_between_deg, project_points
from simtest.geometry.angles import unit
from simtest.geometry.conics import plane_basis
from simtest.geometry.lights import Light, LightRig
from simtest.reconstruct import reconstruct_roi
from simtest.reconstruct import lightaware as la
from simtest.reconstruct.isophote import extract_isophote
from simtest.reconstruct.pipeline import reconstruct
from simtest.reconstruct.recommend import recommend
from simtest.reconstruct.light_fits import with_light_aware
from simtest.reconstruct.settings import ReconSettings
from _quadrics import phong_sphere_image
from simtest.simulate.analytic import phong_plane_image
from simtest.simulate.offset import rig_plane_image, specular_point
from simtest.tolerances import TOL
from exact_tolerances import EXACT

ISOVALUES = (0.3, 0.6)
ROUGHNESS = 60.0


def tilted_normal(tilt_deg: float, az_deg: float = 30.0) -> np.ndarray:
    t, a = np.radians(tilt_deg), np.radians(az_deg)
    return np.array([np.sin(t) * np.cos(a), np.sin(t) * np.sin(a), -np.cos(t)])


def plane_case(h, tilt, rig, f=300.0, size=240, az=30.0):
    """Exact image of a plane whose (first light's) specular point projects near the image centre."""
    N = tilted_normal(tilt, az)
    L = np.asarray(rig.lights[0].position_mm)
    X, depth = specular_point(N, h, L)
    K = np.array([[f, 0, 0], [0, f, 0], [0, 0, 1.0]])
    x = project_points(X, K)
    # the specular point lands between pixel centres, not on one
    K[0, 2], K[1, 2] = (size - 1) / 2 - x[0] + 0.3, (size - 1) / 2 - x[1] - 0.2
    img = rig_plane_image(K, (size, size), N, h, rig, ROUGHNESS)
    return img, K, N, depth, project_points(X, K)


def isophote_points(img, bp, isovalues=ISOVALUES):
    peak = img.max()
    out = []
    for t in isovalues:
        iso = extract_isophote(img, t * peak, bp)
        assert iso, iso
        out.append(la.refine_isophote_points(img, t * peak, iso.points_uv))
    return out


def roi_around(img, bp, half):
    r0, c0 = int(max(bp[1] - half, 0)), int(max(bp[0] - half, 0))
    r1, c1 = int(min(bp[1] + half + 1, img.shape[0])), int(min(bp[0] + half + 1, img.shape[1]))
    return img[r0:r1, c0:c1], (c0, r0)


def one_light(x_mm=3.0, falloff="none"):
    return LightRig((Light((x_mm, 0.0, 0.0), 1.0, falloff),))


# --- the simulator ---------------------------------------------------------------------------------


@pytest.mark.parametrize("falloff", ["none", "inverse_square"])
def test_rig_image_equals_one_light_closed_form(falloff):
    rig = one_light(4.0, falloff)
    K = np.array([[200.0, 0, 60.5], [0, 200.0, 50.5], [0, 0, 1]])
    N = tilted_normal(35.0)
    a = rig_plane_image(K, (100, 120), N, 30.0, rig, 40.0)
    b = phong_plane_image(K, (100, 120), N, 30.0, 40.0, light_mm=(4.0, 0, 0), falloff=falloff != "none")
    np.testing.assert_allclose(a, b, rtol=1e-10, atol=1e-14)


def test_rig_image_sums_its_lights_with_profile():
    K = np.array([[200.0, 0, 60.5], [0, 200.0, 50.5], [0, 0, 1]])
    N = tilted_normal(20.0)
    l1 = Light((2.0, 0.0, 0.0), 1.0, "inverse_square", 2.0)
    l2 = Light((-2.0, 1.0, 0.5), 0.5, "none", 0.0)
    both = rig_plane_image(K, (100, 120), N, 25.0, LightRig((l1, l2)), 50.0)
    one = rig_plane_image(K, (100, 120), N, 25.0, LightRig((l1,)), 50.0)
    two = rig_plane_image(K, (100, 120), N, 25.0, LightRig((l2,)), 50.0)
    np.testing.assert_allclose(both, one + two, rtol=1e-12)
    # the estimators' own model (an independent derivation) gives the same image
    rays = la.model._rays(K, np.stack(np.meshgrid(np.arange(120.0), np.arange(100.0)), -1).reshape(-1, 2))
    model = la.plane_rig_intensity(rays, N, 25.0, LightRig((l1, l2)), 50.0).reshape(100, 120)
    np.testing.assert_allclose(model, both, rtol=1e-9, atol=1e-14)


def test_specular_point_is_the_peak_without_falloff():
    img, K, N, depth, bp = plane_case(20.0, 30.0, one_light())
    assert np.isclose(img.max(), 1.0, atol=1e-3)
    peak = np.array(np.unravel_index(np.argmax(img), img.shape)[::-1])
    assert np.all(np.abs(peak - bp) <= 0.5 + 1e-9)


# --- the model's derivatives -------------------------------------------------------------------------


@settings(max_examples=25, deadline=None)
@given(tilt=st.floats(0, 60), az=st.floats(0, 360), h=st.floats(5, 80),
       lx=st.floats(-5, 5), ly=st.floats(-5, 5), rough=st.floats(5, 120), m=st.floats(0, 3))
def test_analytic_jacobian_matches_finite_differences(tilt, az, h, lx, ly, rough, m):
    rig = LightRig((Light((lx, ly, 0.5), 1.0, "inverse_square", m), Light((-ly, lx, 0.0), 0.7, "none")))
    arr = la.model._rig_arrays(rig)
    n0 = tilted_normal(tilt, az)
    e1, e2 = plane_basis(n0)
    rng = np.random.default_rng(0)
    rays = np.column_stack([rng.uniform(-0.3, 0.3, (40, 2)), np.ones(40)]) - 0.2 * n0
    rays /= np.linalg.norm(rays, axis=1, keepdims=True)
    p = np.array([0.01, -0.02, np.log(h), np.log(rough)])

    def S(q):
        n, dns = la.model._normal_derivs(q, n0, e1, e2)
        return la.model._rig_image(rays, n, dns, np.exp(q[2]), arr, np.exp(q[3]))

    s0, dS = S(p)
    for k in range(4):
        dp = np.zeros(4)
        dp[k] = 1e-6
        fd = (S(p + dp)[0] - S(p - dp)[0]) / 2e-6
        np.testing.assert_allclose(dS[:, k], fd, rtol=1e-4, atol=1e-7 * max(1.0, np.abs(s0).max()))


# --- bisector ----------------------------------------------------------------------------------------


@settings(max_examples=40, deadline=None)
@given(tilt=st.floats(0, 60), az=st.floats(0, 360), h=st.floats(5, 80),
       lx=st.floats(-6, 6), ly=st.floats(-6, 6), lz=st.floats(-2, 2))
def test_bisector_is_exact_with_the_true_depth(tilt, az, h, lx, ly, lz):
    N = tilted_normal(tilt, az)
    rig = LightRig((Light((lx, ly, lz)),))
    if N @ np.array([lx, ly, lz]) + h <= 0.5:
        return
    X, depth = specular_point(N, h, (lx, ly, lz))
    if X[2] <= 0.0:  # a light behind the lens' plane can put the specular point behind it: not imaged
        return
    K = np.array([[300.0, 0, 200], [0, 300.0, 150], [0, 0, 1]])
    est = la.bisector(project_points(X, K), K, rig, depth)
    assert angle_between_deg(est.normal, N) < 1e-6
    # the start's closed form: the plane distance putting the specular point on the BP ray
    # (determined when the light is off the camera and the normal off the BP ray)
    b = unit(X)
    if np.linalg.norm([lx, ly, lz]) > 0.5 and np.linalg.norm(np.cross(b, N)) > 0.05:
        assert np.isclose(la.model._distance_for_bp(b, N, np.array([lx, ly, lz])), h, rtol=1e-6)


def test_bisector_colocated_is_the_bp_ray_at_any_depth():
    K = np.array([[300.0, 0, 200], [0, 300.0, 150], [0, 0, 1]])
    ray = la.model._rays(K, [[250.0, 100.0]])[0]
    for depth in (1.0, 20.0, 300.0):
        est = la.bisector([250.0, 100.0], K, LightRig.colocated(), depth)
        assert angle_between_deg(est.normal, -ray) < 1e-9


def test_bisector_reads_a_depth_map_and_names_bad_input():
    K = np.array([[300.0, 0, 20], [0, 300.0, 15], [0, 0, 1]])
    depth_map = np.full((30, 40), 25.0)
    a = la.bisector([10.0, 12.0], K, one_light(), depth_map)
    b = la.bisector([10.0, 12.0], K, one_light(), 25.0)
    assert np.allclose(a.normal, b.normal) and a.depth_mm == 25.0
    with pytest.raises(ValueError, match="outside the depth map"):
        la.bisector([100.0, 12.0], K, one_light(), depth_map)
    with pytest.raises(ValueError, match="depth_mm"):
        la.bisector([10.0, 12.0], K, one_light(), -1.0)


# --- must hold: exact images, 10 to 60 mm, tilts 0 to 50 deg, one light 3 mm off -----------------

GRID = [(10.0, 0.0), (10.0, 50.0), (25.0, 25.0), (60.0, 0.0), (60.0, 50.0), (40.0, 35.0)]


@pytest.mark.parametrize("h,tilt", GRID)
def test_isocurve_fit_exact_plane(h, tilt):
    rig = one_light(3.0, "none")  # without falloff eq. 2 is exact
    img, K, N, depth, bp = plane_case(h, tilt, rig)
    est = la.isocurve_fit(isophote_points(img, bp), ISOVALUES, bp, K, rig)
    assert est.ok, (est.status, est.detail)
    assert angle_between_deg(est.normal, N) < EXACT.exact_image_normal_deg
    assert abs(est.depth_mm / depth - 1) < EXACT.exact_image_depth_rel
    assert np.isclose(est.roughness, ROUGHNESS, rtol=1e-3)


@pytest.mark.parametrize("h,tilt", GRID)
def test_photometric_fit_exact_plane_with_falloff(h, tilt):
    rig = one_light(3.0, "inverse_square")
    img, K, N, depth, bp = plane_case(h, tilt, rig)
    roi, origin = roi_around(img, bp, 60)
    est = la.photometric_fit(roi, origin, bp, K, rig)
    assert est.ok, (est.status, est.detail)
    assert angle_between_deg(est.normal, N) < EXACT.exact_image_normal_deg
    assert abs(est.depth_mm / depth - 1) < EXACT.exact_image_depth_rel
    assert np.isclose(est.roughness, ROUGHNESS, rtol=1e-6)


def test_photometric_fit_leaves_out_clipped_pixels():
    rig = one_light(3.0, "inverse_square")
    img, K, N, depth, bp = plane_case(25.0, 25.0, rig)
    clipped = np.minimum(img * 1.6, 1.0)  # a saturated plateau at the top of the lobe
    roi, origin = roi_around(clipped, bp, 60)
    est = la.photometric_fit(roi, origin, bp, K, rig, clip_level=1.0)
    assert est.ok and angle_between_deg(est.normal, N) < EXACT.exact_image_normal_deg
    assert abs(est.depth_mm / depth - 1) < EXACT.exact_image_depth_rel


def test_two_light_merged_highlight_photometric_fit():
    # two light guides 2.5 mm either side of the lens: at 30 mm their lobes merge into one blob
    rig = LightRig((Light((2.5, 0.0, 0.0)), Light((-2.5, 0.0, 0.0))))
    img, K, N, depth, bp = plane_case(30.0, 20.0, rig)
    roi, origin = roi_around(img, bp, 70)
    # one merged blob: the isophote at half the peak is a single closed contour
    assert extract_isophote(img, 0.5 * img.max(), project_points(unit(-N), K))
    bp_img = np.array(np.unravel_index(np.argmax(img), img.shape)[::-1], dtype=float)
    est = la.photometric_fit(roi, origin, bp_img, K, rig)
    assert est.has_normal and angle_between_deg(est.normal, N) < EXACT.exact_image_normal_deg
    # the depth reported is that of the rig's mean light (here the camera centre): not observable
    # from the mean alone, but the two lights' spread fixes the scale
    Xm, dm = specular_point(N, 30.0, (0.0, 0.0, 0.0))
    assert est.depth_mm is not None and abs(est.depth_mm / dm - 1) < EXACT.exact_image_depth_rel
    # and each light's specular point, which is what a highlight of that light is scored against
    for L, d in zip(rig.lights, est.light_depths_mm, strict=True):
        assert abs(d / specular_point(N, 30.0, L.position_mm)[1] - 1) < EXACT.exact_image_depth_rel


@pytest.mark.parametrize("half", [25, 40, 60])
@pytest.mark.parametrize("tilt", [0.0, 15.0, 30.0])
@pytest.mark.parametrize("offset", [3.0, 5.0, 8.0])
def test_photometric_fit_gives_each_lights_depth_at_large_offsets(offset, tilt, half):
    # separate highlights of two guides +-offset mm beside the lens, plane at 20 mm: each light's
    # specular point lies 0.2 to 2 % farther than the mean light's (on the plane's foot here), a
    # difference the exact-image tolerance (0.1 %) sees. At 8 mm the mean light's start (the BP
    # ray, 11 deg off) ran off to h -> 0; the fit starts from the light whose start fits best.
    # Where the other light's lobe enters the ROI the start roughness ran to n ~ 1 and the fit to
    # h 50 to 67 mm (11 of these 27 failed); the grid's start roughness, where it halves the
    # start's cost, mends them
    rig = LightRig((Light((offset, 0.0, 0.0)), Light((-offset, 0.0, 0.0))))
    img, K, N, depth, bp = plane_case(20.0, tilt, rig, size=320)
    roi, origin = roi_around(img, bp, half)
    est = la.photometric_fit(roi, origin, bp, K, rig)
    assert est.ok, (est.status, est.detail)
    assert angle_between_deg(est.normal, N) < EXACT.exact_image_normal_deg
    assert abs(est.light_depths_mm[0] / depth - 1) < EXACT.exact_image_depth_rel
    assert abs(est.light_depths_mm[1] / specular_point(N, 20.0, rig.lights[1].position_mm)[1] - 1) \
        < EXACT.exact_image_depth_rel
    assert abs(est.depth_mm / specular_point(N, 20.0, (0.0, 0.0, 0.0))[1] - 1) < EXACT.exact_image_depth_rel
    # a withdrawn depth withdraws every light's
    gone = est.without_depth("plane_misfit", "test")
    assert gone.depth_mm is None and gone.light_depths_mm is None and gone.distance_mm is None
    assert gone.normal is est.normal and gone.status == "plane_misfit"


def test_photometric_fit_under_one_light_has_no_per_light_depths():
    img, K, N, depth, bp = plane_case(25.0, 20.0, one_light(3.0))
    est = la.photometric_fit(*roi_around(img, bp, 60), bp, K, one_light(3.0))
    assert est.ok and est.light_depths_mm is None


# --- epsilon = 0 -----------------------------------------------------------------------------------


@pytest.mark.parametrize("tilt", [0.0, 30.0])
def test_colocated_depth_is_null_and_normal_as_good_as_cone_axis(tilt):
    rig = LightRig((Light(falloff="none"),))
    img, K, N, depth, bp = plane_case(20.0, tilt, rig)
    cone = reconstruct_roi(img, K, ISOVALUES, bp_uv=bp)
    cone_err = angle_between_deg(cone.cone_axis, N)
    for est in (la.isocurve_fit(isophote_points(img, bp), ISOVALUES, bp, K, rig),
                la.photometric_fit(*roi_around(img, bp, 60), bp, K, rig)):
        assert est.status == "depth_not_observable", est
        assert est.depth_mm is None and est.distance_mm is None
        assert angle_between_deg(est.normal, N) <= cone_err + EXACT.exact_image_normal_deg


def test_isocurve_fit_refuses_a_two_light_rig_and_names_bad_input():
    rig = LightRig((Light((2.0, 0, 0)), Light((-2.0, 0, 0))))
    K = np.eye(3)
    est = la.isocurve_fit([np.zeros((10, 2))], [0.5], [0.0, 0.0], K, rig)
    assert est.status == "multi_light_rig" and not est.has_normal
    with pytest.raises(ValueError, match="isovalues"):
        la.isocurve_fit([np.zeros((10, 2))], [1.5], [0.0, 0.0], K, one_light())
    with pytest.raises(ValueError, match="one point set per isovalue"):
        la.isocurve_fit([np.zeros((10, 2))], [0.2, 0.5], [0.0, 0.0], K, one_light())


# --- the fits' own machinery -----------------------------------------------------------------------


@settings(max_examples=25, deadline=None)
@given(tilt=st.floats(0, 60), az=st.floats(0, 360), h=st.floats(5, 80),
       lx=st.floats(-5, 5), ly=st.floats(-5, 5), lz=st.floats(-2, 2))
def test_log_depth_gradient_matches_finite_differences(tilt, az, h, lx, ly, lz):
    n, L = tilted_normal(tilt, az), np.array([lx, ly, lz])
    e1, e2 = plane_basis(n)

    def log_depth(q):
        return np.log(la.specular_point_depth(unit(n + q[0] * e1 + q[1] * e2), h * np.exp(q[2]), L))

    fd = np.array([(log_depth(dq) - log_depth(-dq)) / 2e-6 for dq in 1e-6 * np.eye(3)])
    # central differences at 1e-6: truncation ~1e-12 times the third derivative, rounding
    # ~1e-16 / 1e-6 of a log depth of a few units
    np.testing.assert_allclose(la.model._log_depth_gradient(n, h, L), fd, rtol=1e-6, atol=1e-8)


def test_photometric_fit_ends_where_the_full_least_squares_is_stationary():
    # The fit eliminates the gain and background (variable projection): at its solution the
    # gradient of the full eight-parameter cost, linear parameters at their optimum, vanishes.
    rig = one_light(3.0, "inverse_square")
    img, K, N, depth, bp = plane_case(20.0, 30.0, rig, f=200.0, size=120)
    rng = np.random.default_rng(np.random.SeedSequence(7))
    roi, origin = roi_around(img + 0.1 + rng.normal(0.0, 0.01, img.shape), bp, 30)
    est = la.photometric_fit(roi, origin, bp, K, rig)
    assert est.ok, est
    H, W = roi.shape
    vv, uu = np.mgrid[0:H, 0:W]
    uv = np.column_stack([uu.ravel() + origin[0], vv.ravel() + origin[1]]).astype(float)
    e1, e2 = plane_basis(est.normal)
    n, dns = la.model._normal_derivs(np.zeros(2), est.normal, e1, e2)
    S, dS = la.model._rig_image(la.model._rays(K, uv), n, dns, est.distance_mm, la.model._rig_arrays(rig),
                          est.roughness)
    du, dv = (uv - bp).T / max(H, W)
    A = np.column_stack([S, np.ones_like(S), du, dv])
    y = roi.ravel() / np.abs(roi).max()
    lin = np.linalg.lstsq(A, y, rcond=None)[0]
    r = A @ lin - y
    J = np.column_stack([lin[0] * dS, A])
    # the cosine between r and each column of J: 0 at a stationary point (LM stops at 1e-8 of
    # the cost; a wrong Jacobian of the projected problem would stop it elsewhere)
    cos = np.abs(J.T @ r) / (np.linalg.norm(J, axis=0) * np.linalg.norm(r))
    assert cos.max() < 1e-5, cos


def test_photometric_fit_robust_loss_discounts_hot_pixels():
    # hot pixels off the lobe: a robust loss reweights them away (the linear part is solved
    # with the weights too), the Gaussian one is pulled by them
    rig = one_light(3.0, "inverse_square")
    img, K, N, depth, bp = plane_case(25.0, 25.0, rig)
    roi, origin = roi_around(img, bp, 60)
    rng = np.random.default_rng(np.random.SeedSequence(3))
    hot = roi.copy()
    rr, cc = rng.integers(0, roi.shape[0], 40), rng.integers(0, roi.shape[1], 40)
    hot[rr, cc] += 0.5 * roi.max()
    plain = la.photometric_fit(hot, origin, bp, K, rig)
    robust = la.photometric_fit(hot, origin, bp, K, rig, loss="cauchy", f_scale=0.02)
    assert robust.has_normal and plain.has_normal
    assert angle_between_deg(robust.normal, N) < 0.5 * angle_between_deg(plain.normal, N)


def test_photometric_fit_supersampled_model_matches_a_box_filtered_image():
    # a renderer's box filter: 3 x 3 samples per pixel averaged; the fit with the same samples
    # is exact (at f = 120 px the lobe is a few pixels wide and the filter matters)
    rig = one_light(3.0, "inverse_square")
    N = tilted_normal(30.0)
    X, depth = specular_point(N, 20.0, rig.lights[0].position_mm)
    K = np.array([[120.0, 0, 0], [0, 120.0, 0], [0, 0, 1.0]])
    x = project_points(X, K)
    K[0, 2], K[1, 2] = 31.5 - x[0] + 0.3, 31.5 - x[1] - 0.2
    img = phong_plane_image(K, (64, 64), N, 20.0, ROUGHNESS, light_mm=(3.0, 0, 0), falloff=True,
                            supersample=3)
    bp = project_points(X, K)
    est = la.photometric_fit(img, (0, 0), bp, K, rig, supersample=3)
    assert est.ok, est
    assert angle_between_deg(est.normal, N) < EXACT.exact_image_normal_deg
    assert abs(est.depth_mm / depth - 1) < EXACT.exact_image_depth_rel
    # the point-sampled model on the same image is not exact
    point = la.photometric_fit(img, (0, 0), bp, K, rig)
    assert angle_between_deg(point.normal, N) > 10 * angle_between_deg(est.normal, N)


# --- curved surfaces: the quadric patch ---------------------------------------------------------


def test_quadric_fit_is_exact_on_a_sphere_where_the_plane_model_misfits():
    # Sphere of radius 25 mm, 60 mm away, light 6 mm off (epsilon/d = 0.17), no falloff: the
    # specular point by fixed-point iteration of the bisector condition on the sphere.
    S, R, L = np.array([4.0, -3.0, 60.0]), 25.0, np.array([6.0, 0.0, 0.0])
    n = unit(-S)
    for _ in range(200):
        X = S + R * n
        n = unit(unit(-X) + unit(L - X))
    X = S + R * n
    K = np.array([[300.0, 0, 0], [0, 300.0, 0], [0, 0, 1.0]])
    x = project_points(X, K)
    K[0, 2], K[1, 2] = 49.5 - x[0], 49.5 - x[1]
    img = phong_sphere_image(K, (100, 100), S, R, 30.0, light_mm=L)
    rig = LightRig((Light(tuple(L), 1.0, "none"),))
    bp = project_points(X, K)
    quad = la.quadric_fit(img, (0, 0), bp, K, rig, nominal_depth_mm=35.0)
    plane = la.photometric_fit(img, (0, 0), bp, K, rig, nominal_depth_mm=35.0)
    # one light: the fitted depth is not released (it trades with the third-order shape the
    # data cannot exclude, a sphere's zero included), the band about it holds the truth
    assert quad.status == "depth_not_observable" and quad.depth_mm is None, quad
    near, far = quad.depth_range_mm
    assert near < np.linalg.norm(X) < far
    # the plane's residuals on the sphere are a smooth pattern: reported as a misfit
    assert plane.status == "plane_misfit", plane
    assert plane.depth_mm is None
    # the plane model explains the curvature's compression of the lobe by roughness and distance
    # and misses the normal by degrees; the patch (with its mean-curvature z^2 term) is exact on
    # a sphere, so an exact image gives the normal, the depth (the band's geometric centre),
    # the curvature and the roughness
    assert angle_between_deg(quad.normal, n) < EXACT.exact_image_normal_deg
    assert abs(np.sqrt(near * far) / np.linalg.norm(X) - 1) < EXACT.exact_image_depth_rel
    assert abs(quad.roughness / 30.0 - 1) < EXACT.exact_image_depth_rel
    assert angle_between_deg(plane.normal, n) > 1.0


def test_a_curved_highlight_under_one_light_is_recommended_the_bp_ray():
    # the whole chain on an exact sphere image: detection, the plane fit's misfit, the quadric
    # patch run because of it; under one light its depth is not observable (the data cannot
    # tell a sphere from a patch with third-order shape, where the same fit errs by degrees),
    # its sigma spans the depths within a factor 2.5, and the BP ray is kept
    S, R, L = np.array([2.0, -1.0, 50.0]), 20.0, np.array([5.0, 0.0, 0.0])
    n = unit(-S)
    for _ in range(200):
        X = S + R * n
        n = unit(unit(-X) + unit(L - X))
    K = np.array([[250.0, 0, 59.5], [0, 250.0, 59.5], [0, 0, 1.0]])
    img = phong_sphere_image(K, (120, 120), S, R, 40.0, light_mm=L)
    rig = LightRig((Light(tuple(L), 1.0, "none"),))
    ests = reconstruct(img, K, settings=ReconSettings(isovalues=(0.3, 0.5, 0.7)))
    ests = with_light_aware(img, ests, K, rig, nominal_depth_mm=40.0)
    assert len(ests) == 1
    la_ = ests[0].light_aware
    assert la_["photometric_fit"].status == "plane_misfit"
    rec = recommend(ests[0])
    q = la_["quadric_fit"]
    assert rec.normal_from == "bp_ray", q
    assert q.status == "depth_not_observable" and q.depth_range_mm is not None
    # the quadric's own normal is still exact here: the BP is localised to a fraction of a
    # pixel (1 px = 0.23 deg at f = 250 px), the rest is exact: a tenth of a degree, against
    # several degrees for the BP ray
    assert angle_between_deg(q.normal, n) < 0.1
    assert angle_between_deg(ests[0].bp_ray, n) > 2.0


# --- curved surfaces under two lights: the third-order patch ------------------------------------

#: Sphere of radius 20 mm whose nearest point is 50.4 mm away, Phong n = 40, lights without
#: falloff; f = 250 px, 120 x 120 px.
SPHERE_C, SPHERE_R = np.array([3.0, -2.0, 70.0]), 20.0
SPHERE_K = np.array([[250.0, 0, 59.5], [0, 250.0, 59.5], [0, 0, 1.0]])


def sphere_specular_point(L):
    """The specular point of light L on the test sphere, and its normal, by fixed-point
    iteration of the bisector condition (independent of the estimators' patch model)."""
    n = unit(-SPHERE_C)
    for _ in range(300):
        X = SPHERE_C + SPHERE_R * n
        n = unit(unit(-X) + unit(np.asarray(L, float) - X))
    return SPHERE_C + SPHERE_R * n, n


def sphere_rig_case(lights):
    img = sum(phong_sphere_image(SPHERE_K, (120, 120), SPHERE_C, SPHERE_R, 40.0, light_mm=L)
              for L in lights)
    rig = LightRig(tuple(Light(tuple(float(x) for x in L), 1.0, "none") for L in lights))
    bp = np.array(np.unravel_index(np.argmax(img), img.shape)[::-1], dtype=np.float64)
    return img, rig, bp


#: The two-light sphere of the whole-chain tests: lights 15 mm either side of the lens.
TWO_LIGHTS_15 = ((-15.0, 0.0, 0.0), (15.0, 0.0, 0.0))


@functools.lru_cache(maxsize=None)
def two_light_sphere_cubic_fits():
    """``(img, rig, ests)``: the exact sphere under :data:`TWO_LIGHTS_15` reconstructed at
    isovalues 0.3, 0.5, 0.7 and fitted light-aware with ``cubic=None`` (run where the plane fit
    fails and the rig has two lights apart: what `simtest reconstruct --cubic-patch` asks for;
    the default leaves the slow fit out) and ``fit_rejected`` (the two lobes merge, status
    merged: fitted all the same). Made once per process: the recommendation here and the
    estimates.json of tests/test_lightaware_io.py check the same fits (their image read-only)."""
    img, rig, _ = sphere_rig_case(TWO_LIGHTS_15)
    img.setflags(write=False)
    ests = reconstruct(img, SPHERE_K, settings=ReconSettings(isovalues=(0.3, 0.5, 0.7)))
    ests = with_light_aware(img, ests, SPHERE_K, rig, nominal_depth_mm=20.0, cubic=None,
                            fit_rejected=True)
    return img, rig, tuple(ests)


@pytest.mark.parametrize("eps", [5.0, 15.0])  # epsilon/d 0.1 and 0.3 for each light
def test_cubic_patch_fit_is_exact_on_a_sphere_under_two_lights(eps):
    lights = [(-eps, 0.0, 0.0), (eps, 0.0, 0.0)]
    img, rig, bp = sphere_rig_case(lights)
    est = la.cubic_patch_fit(img, (0, 0), bp, SPHERE_K, rig, nominal_depth_mm=20.0)
    assert est.ok, est
    # the apex is the mean light's specular point: with the rig symmetric about the lens, the
    # point whose normal points at the camera, on the line from the camera to the centre
    assert angle_between_deg(est.normal, unit(-SPHERE_C)) < EXACT.exact_image_normal_deg
    assert abs(est.depth_mm / (np.linalg.norm(SPHERE_C) - SPHERE_R) - 1) < EXACT.exact_image_depth_rel
    # each light's specular point on the fitted patch is the sphere's (the patch, with its
    # third-order terms 0 and its z^2 term, is exact on a sphere)
    for j, L in enumerate(lights):
        X, n = sphere_specular_point(L)
        assert angle_between_deg(est.light_normals[j], n) < EXACT.exact_image_normal_deg
        assert abs(est.light_depths_mm[j] / np.linalg.norm(X) - 1) < EXACT.exact_image_depth_rel
    assert est.depth_rel_sigma < TOL.depth_rel_sigma_max


@pytest.mark.parametrize("eps", [5.0, 15.0])  # epsilon/d 0.1 and 0.3
def test_quadric_fit_gives_each_lights_specular_point_on_a_sphere_under_two_lights(eps):
    # The quadric patch (its z^2 term included) is exact on a sphere: each light's specular point
    # on the fitted patch is the sphere's, whose normal differs from the apex's (the mean light's)
    # by degrees; a stated sigma for each. At epsilon/d 0.1 the lobes fuse into one highlight and
    # the flat starts find the patch; at 0.3 (lobes apart) they end in a local minimum
    # (patch_misfit at 98 mm, the truth 50) and the coarse depth profile's start finds it
    lights = [(-eps, 0.0, 0.0), (eps, 0.0, 0.0)]
    img, rig, bp = sphere_rig_case(lights)
    est = la.quadric_fit(img, (0, 0), bp, SPHERE_K, rig, nominal_depth_mm=20.0)
    assert est.ok, est
    assert est.light_normals.shape == (2, 3) and np.all(np.isfinite(est.light_normal_sigmas_deg))
    for j, L in enumerate(lights):
        X, n = sphere_specular_point(L)
        assert angle_between_deg(est.normal, n) > 1.0  # the apex's normal is not this light's
        assert angle_between_deg(est.light_normals[j], n) < EXACT.exact_image_normal_deg
        assert abs(est.light_depths_mm[j] / np.linalg.norm(X) - 1) < EXACT.exact_image_depth_rel
    # under one light the depth is not observable, and with it where a specular point lies
    img1, rig1, bp1 = sphere_rig_case(lights[1:])
    one = la.quadric_fit(img1, (0, 0), bp1, SPHERE_K, rig1, nominal_depth_mm=20.0)
    assert one.status == "depth_not_observable" and one.light_normals is None and one.light_depths_mm is None


@pytest.mark.parametrize("eps", [5.0, 15.0])
def test_cubic_patch_fit_depth_is_not_observable_under_one_light(eps):
    # The same sphere lit by one of the two lights: the third-order terms stand in for the
    # light's offset, so the exact image no longer fixes the depth (measured relative sigma at
    # the noise floor: 61 at epsilon/d 0.1, 12 at 0.3); the normal, the bisector at an
    # undetermined depth, is given for the record only.
    img, rig, bp = sphere_rig_case([(eps, 0.0, 0.0)])
    est = la.cubic_patch_fit(img, (0, 0), bp, SPHERE_K, rig, nominal_depth_mm=20.0)
    assert est.status == "depth_not_observable", est
    assert est.depth_mm is None and est.light_normals is None and est.light_depths_mm is None
    assert est.depth_rel_sigma > TOL.depth_rel_sigma_max


@pytest.mark.parametrize("lights, fixes_depth", [
    ([(-5.0, 0.0, 0.0), (5.0, 0.0, 0.0)], True),  # two lights, the pair closest together
    ([(15.0, 0.0, 0.0)], False),  # one light, the farthest from the camera
])
@pytest.mark.slow
def test_depth_profile_rises_under_two_lights_and_stays_flat_under_one(lights, fixes_depth):
    # The cubic patch refitted with its apex depth fixed at half, once and twice the truth.
    # In units of the noise floor's variance (TOL.photometric_noise_rel^2 per pixel, summed
    # residuals), the rise away from the truth is a chi^2 difference: above 9 (3 sigma) it
    # tells the depth from the shape, below 0.01 it does not (measured on this sphere: two
    # lights 20 to 1400, one light below 0.01). Each claim on its hardest case of epsilon 5 and
    # 15 mm (epsilon/d 0.1 and 0.3): the two lights' rise is least when they are closest, the
    # one light's profile is least flat when it is farthest (the other two cases took a minute).
    var = TOL.photometric_noise_rel**2
    img, rig, bp = sphere_rig_case(lights)
    # the apex: the mean light's specular point (the camera-facing one for the pair)
    mean_light = np.mean(np.asarray(lights, float), axis=0)
    depth = float(np.linalg.norm(sphere_specular_point(mean_light)[0]))
    cost = la.patch_depth_profile(img, (0, 0), bp, SPHERE_K, rig, depth * np.array([0.5, 1.0, 2.0]))
    assert cost[1] < 1e-6 * var  # the truth fits an exact image exactly
    rises = (cost[[0, 2]] - cost[1]) / var
    if fixes_depth:
        assert np.all(rises > 9.0), rises
    else:
        assert np.all(rises < 0.01), rises


def test_patch_depth_profile_names_bad_depths():
    img, rig, bp = sphere_rig_case([(5.0, 0.0, 0.0)])
    with pytest.raises(ValueError, match="depths_mm"):
        la.patch_depth_profile(img, (0, 0), bp, SPHERE_K, rig, [10.0, -1.0])
    with pytest.raises(ValueError, match="values"):
        la.patch_depth_profile(np.full((3, 3), np.nan), (0, 0), bp, SPHERE_K, rig, [10.0])


@pytest.mark.slow
def test_two_light_curved_highlight_is_recommended_the_cubic_patch_and_scored_per_light():
    # The whole chain on the exact two-light sphere: the plane fit misfits, the cubic patch is
    # run because the rig has two lights apart, recommended, and the harness scores each light's
    # highlight with that light's normal. With one light it is not run.
    from simtest.harness.estimators import score

    lights = list(TWO_LIGHTS_15)
    img, rig, ests = two_light_sphere_cubic_fits()
    assert len(ests) >= 1
    for j, L in enumerate(lights):
        X, n = sphere_specular_point(L)
        est = min(ests, key=lambda e: float(np.linalg.norm(np.asarray(e.bp_px)
                                                           - project_points(X, SPHERE_K))))
        assert est.light_aware["photometric_fit"].status != "ok"
        rec = recommend(est)
        assert rec.normal_from == "cubic_patch_fit", est.light_aware["cubic_patch_fit"]
        assert rec.light_normals is not None and rec.light_depths_mm is not None
        errs = score(est, n, ("recommended", "cubic_patch_fit", "bp_ray"), light=j)
        # the BP is localised to a fraction of a pixel (1 px = 0.23 deg at f = 250 px); the
        # rest is exact
        assert errs["recommended"][0] < 0.1 and errs["cubic_patch_fit"][0] < 0.1, errs
        assert errs["bp_ray"][0] > 3.0, errs
    img1, rig1, _ = sphere_rig_case(lights[1:])
    one = with_light_aware(img1, reconstruct(img1, SPHERE_K, settings=ReconSettings(
        isovalues=(0.3, 0.5, 0.7))), SPHERE_K, rig1, nominal_depth_mm=20.0, cubic=None, fit_rejected=True)
    assert all("cubic_patch_fit" not in e.light_aware for e in one)
    # by default the cubic patch is not run at all; the progress callback counts every
    # highlight examined, once, up to the total
    calls = []
    default = with_light_aware(img, reconstruct(img, SPHERE_K, settings=ReconSettings(
        isovalues=(0.3, 0.5, 0.7))), SPHERE_K, rig, nominal_depth_mm=20.0, fit_rejected=True,
        on_highlight=lambda done, total: calls.append((done, total)))
    assert all("cubic_patch_fit" not in e.light_aware for e in default)
    n = sum(e.status != "too_small" for e in default)
    assert calls == [(k, n) for k in range(1, n + 1)]


def test_a_fit_the_solver_refuses_is_a_status_not_an_exception(monkeypatch):
    # scipy's least_squares raises ValueError when the residuals are not finite at the start;
    # one highlight's refusal must become its status, never abort the frame
    from simtest.reconstruct import light_fits as rec_mod

    def refuses(*args, **kwargs):
        raise ValueError("Residuals are not finite in the initial point.")

    monkeypatch.setattr(rec_mod, "photometric_fit", refuses)
    lights = [(-15.0, 0.0, 0.0), (15.0, 0.0, 0.0)]
    img, rig, _ = sphere_rig_case(lights)
    ests = with_light_aware(img, reconstruct(img, SPHERE_K, settings=ReconSettings(
        isovalues=(0.3, 0.5, 0.7))), SPHERE_K, rig, nominal_depth_mm=20.0, fit_rejected=True)
    assert ests and all(e.light_aware["photometric_fit"].status == "not_converged" for e in ests)
    assert all("not finite" in e.light_aware["photometric_fit"].detail for e in ests)
    assert all(recommend(e).normal is not None for e in ests)


def test_cubic_patch_residual_stays_finite_where_a_fit_runs_off():
    # A fit that runs off to an enormous depth (log s = 800: s^2 overflows a float) must give a
    # finite residual, not raise: on the colon render of lightaware-curved (colon_offset at
    # epsilon/d 0.1, realisations 3 and 4) an OverflowError there failed every estimator.
    img, rig, bp = sphere_rig_case([(5.0, 0.0, 0.0)])
    S = la.cubic._cubic_setup(img, (0, 0), bp, SPHERE_K, rig, None, 800)
    for log_s in (800.0, -800.0):
        p = np.zeros(11)
        p[2], p[6], p[7] = log_s, np.log(40.0), 0.5
        assert np.all(np.isfinite(S["res"](p)))


def test_a_megapixel_roi_is_refined_on_a_bounded_sub_grid():
    # a broad lobe's ROI on a large frame (640 x 640 px, 1.6 times REFINE_MAX_PIXELS): the
    # refinement on every kept pixel takes a regular sub-grid of at most that many (its cost
    # bound), and an exact image's fit stays exact (the tolerances of the exact-plane test)
    from simtest.reconstruct.lightaware.plane_solve import REFINE_MAX_PIXELS

    rig = one_light(3.0, "inverse_square")
    img, K, N, depth, bp = plane_case(20.0, 20.0, rig, f=900.0, size=640)
    assert img.size > REFINE_MAX_PIXELS
    est = la.photometric_fit(img, (0, 0), bp, K, rig)
    assert est.ok, (est.status, est.detail)
    assert est.n_residuals <= REFINE_MAX_PIXELS
    assert est.n_residuals > REFINE_MAX_PIXELS // 4  # the refinement ran (the starts take 16384)
    assert angle_between_deg(est.normal, N) < EXACT.exact_image_normal_deg
    assert abs(est.depth_mm / depth - 1) < EXACT.exact_image_depth_rel


def test_an_iterate_that_runs_off_is_stopped_where_it_left():
    # r(p) = exp(-p): LM drives p to infinity and only the evaluation budget ends it; a stop
    # that says p past 5 is lost ends it at the first point beyond, not converged, its reason
    # the message, with the residual there
    from simtest.reconstruct.lightaware.solve import _solve

    def resjac(p, grad=True):
        r = np.exp(-p[:1])
        return r, (-r[:, None] if grad else None)

    free_run = _solve(resjac, [0.0], (), "linear", 1.0, 200)
    x, nfev, conv, msg, r = _solve(resjac, [0.0], (), "linear", 1.0, 200,
                                   stop=lambda p: "lost" if p[0] > 5.0 else "")
    assert not conv and msg == "lost" and x[0] > 5.0
    assert r[0] == pytest.approx(np.exp(-x[0]), rel=1e-15)
    assert nfev < free_run[1]


@given(st.floats(-8.0, 8.0), st.floats(-8.0, 8.0), st.booleans())
@settings(max_examples=60, deadline=None)
def test_an_iterate_is_past_saving_beyond_the_plausible_range_widened(log_h, log_n, shaded):
    # exact: inside the plausible range (widened by RUN_OFF_FACTOR) an iterate is never stopped;
    # past it, always, and a stopped iterate's solution is implausible
    from simtest.decisions import DISTANCE_FACTOR_MAX, RUN_OFF_FACTOR
    from simtest.reconstruct.lightaware.solve import _ROUGHNESS_RANGE, _ROUGHNESS_RANGE_SHADED, _implausible

    h0, lo_hi = 20.0, _ROUGHNESS_RANGE_SHADED if shaded else _ROUGHNESS_RANGE
    h, n = h0 * np.exp(log_h), float(np.exp(np.log(lo_hi[0] * lo_hi[1]) / 2 + log_n))
    inside = (h0 / (DISTANCE_FACTOR_MAX * RUN_OFF_FACTOR) <= h <= h0 * DISTANCE_FACTOR_MAX * RUN_OFF_FACTOR
              and lo_hi[0] / RUN_OFF_FACTOR <= n <= lo_hi[1] * RUN_OFF_FACTOR)
    assert (_implausible(h, h0, n, shaded, widen=RUN_OFF_FACTOR) == "") == inside
    if not inside:
        assert _implausible(h, h0, n, shaded)


def test_an_iterate_whose_ggx_alpha_overflows_is_stopped_not_an_error():
    # a GGX fit's iterate run off to log alpha = 400: alpha^2 overflows a float, which raised
    # OverflowError in the run-off check (a real tile's fit ended "not_converged: OverflowError");
    # its Phong exponent is -2, outside every range: the iterate is stopped
    from simtest.decisions import RUN_OFF_FACTOR
    from simtest.reconstruct.lightaware.model import phong_of_ggx_alpha
    from simtest.reconstruct.lightaware.solve import _implausible

    n = phong_of_ggx_alpha(float(np.exp(400.0)))
    assert n == -2.0
    assert _implausible(20.0, 20.0, n, widen=RUN_OFF_FACTOR)
    assert phong_of_ggx_alpha(la.model.ggx_alpha_of_phong(60.0)) == pytest.approx(60.0, rel=1e-12)
