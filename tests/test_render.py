"""Mitsuba renders against closed forms: Phong radiance, intrinsics, normals, highlights, files.

Films are small (96 to 200 px) to keep the suite fast on a 2-core CPU.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import trimesh
from scipy import ndimage
from hypothesis import example, given, settings
from hypothesis import strategies as st

from simtest.geometry import angle_between_deg, pixel_to_ray
from simtest.render import RendererUnavailable, choose_variant, render_scene, write_render
from simtest.scene.kinds import plane_normal_cam
from simtest.render.truth import bisector_cos_image
from simtest.simulate.truth import bisector
from simtest.scene import (
    bundled_scene_names,
    load_scene,
    scene_from_dict,
    scene_to_dict,
    with_overrides,
)

pytestmark = pytest.mark.render


def _phong_plane_closed_form(K, size, normal, c, n, sub=16):
    """Pixel means (H, W) of paper eq. 1 on a plane, co-located light, from sub x sub midpoints.

    With the light at the camera centre, cos(beta) = 2 cos(theta_i)^2 - 1 where theta_i is the
    angle between the viewing ray and the normal; the midpoint rule's error (~1/(24 sub^2) of the
    second derivative) is far below the tolerance.
    """
    W, H = size
    o = (np.arange(sub) + 0.5) / sub - 0.5
    u = np.arange(W)[None, :, None, None] + o[None, None, None, :]
    v = np.arange(H)[:, None, None, None] + o[None, None, :, None]
    u, v = np.broadcast_arrays(u, v)
    rays = pixel_to_ray(np.stack([u, v], axis=-1), K)
    cos_i = -(rays @ normal)
    cos_beta = np.where(cos_i > 0, 2.0 * cos_i**2 - 1.0, 0.0)
    return (c * np.maximum(cos_beta, 0.0) ** n).mean(axis=(2, 3))


@pytest.mark.parametrize(("tilt_deg", "fov_deg", "size"), [(0.0, 60.0, 128), (58.0, 150.0, 160)])
def test_exact_phong_plane_matches_eq1(tilt_deg, fov_deg, size):
    spec = scene_from_dict({
        "camera": {"width_px": size, "height_px": size, "fov_deg": fov_deg},
        "light": {"falloff": "cancel", "intensity": 1.0},
        "material": {"model": "phong", "c": 1.0, "n": 50.0},
        "geometry": {"type": "plane", "tilt_deg": tilt_deg, "distance_mm": 50.0},
        # 64 multijitter samples: median pixel error ~1e-4 to 3e-4 measured, 4x under the bound.
        "render": {"spp": 64, "sampler": "multijitter"},
    })
    r = render_scene(spec, seed=1)
    ref = _phong_plane_closed_form(r.K, (size, size), plane_normal_cam(spec.geometry), 1.0, 50.0)
    sel = ref > 0.01 * ref.max()
    assert sel.sum() > 200  # the comparison covers a whole highlight, not a few pixels
    rel = np.abs(r.linear[sel] - ref[sel]) / ref[sel]
    # The bound: median relative error below 1e-3 over pixels above 1 % of the peak.
    assert np.median(rel) < 1e-3
    # Falloff kept: the same image divided by the squared light distance (per sample, so compare
    # on the flat fronto case only, where it varies least within a pixel).
    if tilt_deg == 0.0:
        keep = render_scene(with_overrides(spec, {"light.falloff": "keep"}), seed=1)
        ratio = keep.linear[sel] * r.distance[sel] ** 2 / r.linear[sel]
        # Pixel means of f/d^2 vs (mean f)/(mean d)^2 differ at second order in the pixel
        # footprint (~1e-4 relative here); 1e-3 leaves room for float32.
        assert np.median(np.abs(ratio - 1.0)) < 1e-3


def _sphere_image_centre(K, c, r):
    """Centre (u, v) of the image ellipse of a sphere: the cone X^T (c c^T - (|c|^2 - r^2) I) X = 0."""
    Q = np.outer(c, c) - (c @ c - r * r) * np.eye(3)
    Ki = np.linalg.inv(K)
    C = Ki.T @ Q @ Ki
    return -np.linalg.solve(C[:2, :2], C[:2, 2])


@pytest.mark.parametrize(("centre", "offset"), [((0.0, 0.0, 60.0), (0.0, 0.0)),
                                                ((12.0, -7.0, 60.0), (0.0, 0.0)),
                                                ((-15.0, 10.0, 50.0), (7.0, -4.5))])
def test_intrinsics_project_sphere_to_its_rendered_centroid(centre, offset):
    spec = scene_from_dict({
        "camera": {"width_px": 128, "height_px": 96, "focal_px": 110.0,
                   "principal_offset_px": list(offset)},
        "render": {"spp": 64},
        "geometry": {"type": "sphere", "center_mm": list(centre), "radius_mm": 4.0},
    })
    r = render_scene(spec, seed=0)
    a = r.coverage.astype(np.float64)
    vv, uu = np.mgrid[: a.shape[0], : a.shape[1]]
    centroid = np.array([(a * uu).sum() / a.sum(), (a * vv).sum() / a.sum()])
    # The coverage-weighted centroid of a box-filtered render is the area centroid of the image
    # ellipse; 64 samples per pixel leave ~0.005 px of noise, a half-pixel error in K shows as 0.5.
    expected = _sphere_image_centre(r.K, np.array(centre), 4.0)
    assert np.max(np.abs(centroid - expected)) < 0.05


def test_plane_and_sphere_ground_truth_normals():
    plane = scene_from_dict({"camera": {"width_px": 96, "height_px": 96, "fov_deg": 120.0},
                             "render": {"spp": 4},
                             "geometry": {"type": "plane", "tilt_deg": 40.0, "azimuth_deg": 30.0,
                                          "distance_mm": 30.0}})
    r = render_scene(plane)
    assert r.mask.sum() > 1000
    # float32 AOVs: ~1e-5 deg; the bound is 1e-3 deg.
    assert angle_between_deg(r.normals[r.mask], plane_normal_cam(plane.geometry)).max() < 1e-3
    # depth is z, distance the ray length, position on the plane.
    p = r.position[r.mask].astype(np.float64)
    assert np.allclose(r.depth[r.mask], p[:, 2], rtol=1e-6)
    assert np.allclose(r.distance[r.mask], np.linalg.norm(p, axis=1), rtol=1e-6)
    assert np.allclose(p @ plane_normal_cam(plane.geometry), -30.0, rtol=1e-4)
    assert np.all(np.isnan(r.normals[~r.mask]))

    c, R = np.array([5.0, -3.0, 60.0]), 15.0
    sphere = scene_from_dict({"camera": {"width_px": 96, "height_px": 96, "fov_deg": 50.0},
                              "render": {"spp": 64},
                              "geometry": {"type": "sphere", "center_mm": list(c), "radius_mm": R}})
    s = render_scene(sphere)
    assert s.mask.sum() > 500
    # Pixel means: mean(p) - c = R mean(n), so the directions agree to float32 round-off.
    expected = (s.position[s.mask] - c) / R
    assert angle_between_deg(s.normals[s.mask], expected).max() < 1e-3
    # Independent of the AOVs: ray-sphere intersection of the rays from K (pixel_to_ray),
    # n = (t d - c) / R with t the near root of |t d - c| = R, averaged over a 16 x 16 grid in each
    # pixel like the render's box filter. Interior pixels only (the mask eroded once): their whole
    # footprint and their neighbours' hit the sphere, no silhouette averaging.
    interior = ndimage.binary_erosion(s.mask)
    assert interior.sum() > 1500
    vv, uu = np.nonzero(interior)
    o = (np.arange(16) + 0.5) / 16 - 0.5
    grid = np.stack(np.meshgrid(o, o, indexing="xy"), axis=-1).reshape(-1, 2)  # (256, 2)
    d = pixel_to_ray(np.stack([uu, vv], axis=-1)[:, None, :] + grid[None], s.K)  # (N, 256, 3)
    b = d @ c
    t = b - np.sqrt(b * b - (c @ c - R * R))
    n_exact = ((t[..., None] * d - c) / R).mean(axis=1)
    err = angle_between_deg(s.normals[vv, uu], n_exact)
    # Measured max 0.011 deg, median 0.0014 deg: the mean of 64 multijittered samples is not the
    # pixel's area mean (the normal turns ~2 deg per pixel here, more toward the limb). A wrong
    # AOV is far above: a 0.1 px shift of the principal point measures 0.6 deg max, 0.2 median.
    assert err.max() < 0.05
    assert np.median(err) < 0.005
    # Silhouette pixels (partly covered) are masked out.
    assert np.array_equal(s.mask, s.coverage >= 1.0)
    assert ((s.coverage > 0) & (s.coverage < 1)).sum() > 20


def test_seed_reproducibility_and_noise():
    spec = with_overrides(load_scene("plane_fronto"), {
        "camera.width_px": 96, "camera.height_px": 96, "camera.focal_px": 96.0, "render.spp": 4,
        "sensor.gaussian_sigma": 0.02, "sensor.full_well_e": 2000.0, "sensor.bit_depth": 12})
    a, b, c = render_scene(spec, seed=5), render_scene(spec, seed=5), render_scene(spec, seed=6)
    assert np.array_equal(a.sensor, b.sensor) and np.array_equal(a.linear, b.linear)
    assert a.sensor.dtype == np.uint16
    assert not np.array_equal(a.sensor, c.sensor)
    assert not np.array_equal(a.linear, c.linear)  # the sampler pattern follows the seed too


def test_highlight_truth_plane_and_offset_light():
    spec = scene_from_dict({"camera": {"width_px": 128, "height_px": 128, "fov_deg": 140.0},
                            "render": {"spp": 16},
                            "geometry": {"type": "plane", "tilt_deg": 58.0, "distance_mm": 50.0}})
    r = render_scene(spec)
    (h,) = r.highlights
    assert h.in_frame and (h.k1, h.k2) == (0.0, 0.0)
    # Co-located: the BP normal is minus the viewing ray through the BP pixel (Notes of simtest.geometry.curvature.curvature_ratio).
    assert angle_between_deg(h.normal, -pixel_to_ray(h.bp_px, r.K)) < 1e-9
    assert angle_between_deg(h.normal, plane_normal_cam(spec.geometry)) < 1e-9
    # The rendered image peaks within a pixel of the BP.
    v, u = np.unravel_index(np.argmax(r.specular), r.specular.shape)
    assert np.hypot(u - h.bp_px[0], v - h.bp_px[1]) <= 1.5

    off = with_overrides(spec, {"light.epsilon_mm": 10.0})
    ball = scene_from_dict({**scene_to_dict(off), "geometry": {
        "type": "sphere", "center_mm": [3.0, 4.0, 60.0], "radius_mm": 20.0}})
    for s in (off, ball):
        rr = render_scene(s, seed=3)
        (hh,) = rr.highlights
        # L = epsilon (cos a, sin a, b): a drawn offset of the stated size.
        assert math.isclose(math.hypot(rr.light_pos[0], rr.light_pos[1]), 10.0, rel_tol=1e-12)
        # Off a co-located light the normal bisects the directions to camera and light (the
        # closed form for the plane, a root solve for the sphere). Measured ~1e-14 deg (float64
        # round-off); the solve itself is only accepted below 1e-12 rad = 6e-11 deg
        # (truth.STATIONARY_RESIDUAL_TOL), so 1e-9 deg catches any wrong or unchecked solve.
        assert angle_between_deg(hh.normal, bisector(hh.bp_mm, rr.light_pos)) < 1e-9
        # ... and the BP is where the rendered specular image peaks, within its pixel.
        v, u = np.unravel_index(np.argmax(rr.specular), rr.specular.shape)
        assert np.hypot(u - hh.bp_px[0], v - hh.bp_px[1]) <= 1.5


def test_mesh_highlight_matches_analytic_sphere(tmp_path):
    from simtest.scene.meshes import save_mesh

    R = 20.0
    mesh = trimesh.creation.icosphere(subdivisions=5, radius=R)
    unit = mesh.vertices / np.linalg.norm(mesh.vertices, axis=1, keepdims=True)
    mesh = trimesh.Trimesh(mesh.vertices, mesh.faces, vertex_normals=unit, process=False)
    mesh.vertex_attributes["k1"] = np.full(len(mesh.vertices), 1.0 / R)
    mesh.vertex_attributes["k2"] = np.full(len(mesh.vertices), 1.0 / R)
    save_mesh(mesh, tmp_path / "ball.ply")
    cam = {"width_px": 128, "height_px": 128, "fov_deg": 60.0}
    centre = [6.0, -4.0, 70.0]
    m = render_scene(scene_from_dict({
        "camera": cam, "render": {"spp": 4}, "material": {"n": 30.0},
        "geometry": {"type": "mesh", "path": str(tmp_path / "ball.ply"), "translate_mm": centre}}))
    a = render_scene(scene_from_dict({
        "camera": cam, "render": {"spp": 4}, "material": {"n": 30.0},
        "geometry": {"type": "sphere", "center_mm": centre, "radius_mm": R}}))
    (hm,), (ha,) = m.highlights, a.highlights
    # The icosphere (5 subdivisions, 1.2 deg facets) with interpolated normals stands within
    # ~0.02 mm of the sphere: its BP lands within 0.1 px and 0.1 deg of the analytic one.
    assert np.hypot(*(hm.bp_px - ha.bp_px)) < 0.1
    assert angle_between_deg(hm.normal, ha.normal) < 0.1
    # Constant vertex curvatures interpolate to themselves (float32 storage: 1e-7 relative).
    assert math.isclose(hm.k1, 1.0 / R, rel_tol=1e-6) and math.isclose(hm.k2, 1.0 / R, rel_tol=1e-6)
    assert ha.k1 == ha.k2 == 1.0 / R


def _render_arrays(spec, seed):
    r = render_scene(spec, seed=seed)
    hl = np.array([np.r_[h.bp_px, h.bp_mm, h.normal, h.k1, h.k2] for h in r.highlights])
    return [r.linear, r.specular, r.sensor, r.normals, r.position, r.depth, r.mask, hl]


def _same(a, b):
    return all(np.array_equal(x, y, equal_nan=True) for x, y in zip(a, b, strict=True))


def test_cached_mesh_scene_does_not_leak_between_specs():
    """A mesh scene is loaded once per structure and updated per render (camera pose, light,
    Phong c, n, albedo): rendering A, then B and C, then A again gives A's fresh bits."""
    from simtest.render import scene_load as R

    a = with_overrides(load_scene("colon"), {"camera.width_px": 64, "camera.height_px": 64,
                                             "render.spp": 4})
    cam = a.camera
    shift = np.array([0.0, 0.0, 4.0])
    b = with_overrides(a, {  # same structure as A: reuses A's loaded scene
        "camera.position_mm": (np.array(cam.position_mm) + shift).tolist(),
        "camera.look_at_mm": (np.array(cam.look_at_mm) + shift).tolist(),
        "camera.up": [0.3, 0.95, 0.0], "material.n": 90.0, "material.c": 0.7,
        "material.diffuse_albedo": 0.05, "light.intensity": 300.0})
    c = with_overrides(b, {"light.epsilon_mm": 3.0, "light.falloff": "cancel",
                           "material.diffuse_albedo": 0.0})  # another structure
    R.clear_caches()
    a_fresh = _render_arrays(a, 7)
    b_after_a = _render_arrays(b, 7)
    assert len(R._SCENE_CACHE) == 1  # B updated A's scene instead of loading its own
    c_after_ab = _render_arrays(c, 7)
    a_again = _render_arrays(a, 7)
    R.clear_caches()
    b_fresh = _render_arrays(b, 7)
    R.clear_caches()
    c_fresh = _render_arrays(c, 7)
    assert _same(a_again, a_fresh)
    assert _same(b_after_a, b_fresh)
    assert _same(c_after_ab, c_fresh)
    assert not np.array_equal(a_fresh[0], b_fresh[0])
    assert not np.array_equal(b_fresh[0], c_fresh[0])
    # The camera moved 4 mm along the world z axis: the same wall points come out shifted in the
    # camera frame, so the depth maps differ (a stale pose would leave them equal).
    assert not np.array_equal(a_fresh[5], b_fresh[5], equal_nan=True)


@settings(max_examples=20, deadline=None)
@given(st.integers(0, 2**32 - 1), st.floats(-3.0, 3.0))
def test_bisector_image_colocated_shortcut_is_bit_exact(seed, log_scale):
    """The co-located branch of bisector_cos_image skips the light arithmetic; it must give the
    general formula's bits (unit(unit(-p) + unit(0 - p)), in float32)."""
    rng = np.random.default_rng(seed)
    p = (rng.normal(size=(12, 10, 3)) * 10.0**log_scale).astype(np.float32)
    n = rng.normal(size=(12, 10, 3)).astype(np.float32)
    mask = rng.random((12, 10)) > 0.2
    q = np.where(mask[..., None], p, 1.0).astype(np.float32)
    to_cam = -q / np.sqrt(np.einsum("ijk,ijk->ij", q, q))[..., None]
    to_light = np.float32(0.0) - q
    to_light /= np.sqrt(np.einsum("ijk,ijk->ij", to_light, to_light))[..., None]
    h = to_cam + to_light
    h /= np.sqrt(np.einsum("ijk,ijk->ij", h, h))[..., None]
    expected = np.where(mask, np.einsum("ijk,ijk->ij", np.where(mask[..., None], n, 0.0), h), -1.0)
    assert np.array_equal(bisector_cos_image(n, p, mask, np.zeros(3)), expected)


def _bisector_cos_f64(n, p, mask, light, *, with_length=False):
    """``n . unit(unit(-p) + unit(light - p))`` in float64 from the float32-rounded inputs (the
    reference of bisector_cos_image), -1 outside ``mask``; ``with_length``: and the length of the
    unnormalised bisector ``|unit(-p) + unit(light - p)|`` (0 to 2)."""
    p = p.astype(np.float32).astype(np.float64)
    n = n.astype(np.float32).astype(np.float64)
    to_cam = -p / np.linalg.norm(p, axis=-1, keepdims=True)
    to_light = np.asarray(light, dtype=np.float32).astype(np.float64) - p
    to_light /= np.linalg.norm(to_light, axis=-1, keepdims=True)
    h = to_cam + to_light
    length = np.linalg.norm(h, axis=-1, keepdims=True)
    h /= length
    cos = np.where(mask, np.sum(n * h, axis=-1), -1.0)
    return (cos, length[..., 0]) if with_length else cos


#: float32 rounding of the bisector's ~15 operations on unit vectors: each within a few 6e-8
#: relative; 2e-6 absolute on a cosine leaves a margin of ~3 (the float32 inputs are those of
#: the reference, so only the arithmetic differs). Normalising the bisector divides the rounding
#: of its two unit vectors by its length, which nears 0 where the light lies behind the point as
#: the camera sees it: the bound is this over that length where it is under 1 (seed 4666, an
#: offset light, points 0.07 mm from the camera: 2.7e-6 at a length of 0.024).
BISECTOR_ABS = 2e-6


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**32 - 1), st.floats(-3.0, 3.0), st.sampled_from(["zero", "offset", "far"]),
       st.sampled_from([np.float32, np.float64]))
@example(994, 0.0, "zero", np.float32)  # a masked point at the camera centre besides [0, 0]
def test_bisector_image_is_the_float64_bisector_to_float32_rounding(seed, log_scale, light_kind, dtype):
    # zeros among the coordinates; a masked point at the camera centre has no direction (NaN)
    rng = np.random.default_rng(seed)
    p = (rng.normal(size=(17, 13, 3)) * 10.0**log_scale).astype(dtype)
    n = rng.normal(size=(17, 13, 3)).astype(dtype)
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    p[rng.random((17, 13, 3)) < 0.05] = 0.0
    p[0, 0] = 0.0
    mask = rng.random((17, 13)) > 0.2
    mask[0, 0] = True
    light = {"zero": np.zeros(3), "offset": rng.normal(size=3) * 3.0,
             "far": rng.normal(size=3) * 10.0**log_scale}[light_kind]
    got = bisector_cos_image(n, p, mask, light)
    with np.errstate(divide="ignore", invalid="ignore"):
        want, length = _bisector_cos_f64(n, p, mask, light, with_length=True)
    assert got.dtype == np.float32
    assert np.array_equal(np.isnan(got), np.isnan(want)) and np.isnan(got[0, 0])
    assert np.all(got[~mask] == -1.0)
    ok = ~np.isnan(want) & mask  # (a masked point at the camera centre has no length: NaN)
    assert np.all(np.abs(got[ok] - want[ok]) <= BISECTOR_ABS / np.minimum(length[ok], 1.0))


def test_bisector_image_on_a_rendered_frame():
    # the ground truth of a mesh render (the colon, two lights off the camera) against the
    # float64 bisector
    res = render_scene(with_overrides(load_scene("colon"), {"render.spp": 4}), seed=0)
    for light in (np.zeros(3), np.array([2.5, 0.0, 0.0]), np.array([-2.5, 0.4, 0.0])):
        got = bisector_cos_image(res.normals, res.position, res.mask, light)
        want = _bisector_cos_f64(res.normals, res.position, res.mask, light)
        assert np.abs(got - want).max() <= BISECTOR_ABS
        assert (got[res.mask] > 0.5).any()


def test_saddle_highlight_at_apex():
    spec = with_overrides(load_scene("saddle"), {"camera.width_px": 128, "camera.height_px": 128,
                                                 "render.spp": 4})
    r = render_scene(spec)
    (h,) = r.highlights
    g = spec.geometry
    # Co-located, the apex (0, 0, d) is the only BP (r2 > d); its curvatures 1/r1 and -1/r2 are
    # interpolated from analytic vertex values on a 0.75 mm grid (error ~ (grid / r)^2 ~ 1e-4).
    assert np.allclose(h.bp_px, r.K[:2, 2], atol=1e-3)
    assert math.isclose(h.k1, 1.0 / g.radius1_mm, rel_tol=1e-3)
    assert math.isclose(h.k2, -1.0 / g.radius2_mm, rel_tol=1e-3)
    assert angle_between_deg(h.normal, [0.0, 0.0, -1.0]) < 1e-3


def highlight_complete(specular, bp_px, t=0.1) -> bool:
    """Whether the region ``specular >= t * specular[BP]`` holding the BP pixel (inside the
    image, lit) stays off the image border: the highlight and its isophote t are in frame."""
    H, W = specular.shape
    u, v = int(round(bp_px[0])), int(round(bp_px[1]))
    if not (0 <= u < W and 0 <= v < H) or specular[v, u] <= 0:
        return False
    labels, _ = ndimage.label(specular >= t * specular[v, u])
    region = labels == labels[v, u]
    return not (region[0].any() or region[-1].any() or region[:, 0].any() or region[:, -1].any())


@pytest.mark.slow
def test_bundled_scenes_show_a_complete_highlight():
    for name in bundled_scene_names():
        spec = load_scene(name)
        half = {"camera.width_px": spec.camera.width_px // 2,
                "camera.height_px": spec.camera.height_px // 2, "render.spp": 4}
        if spec.camera.focal_px is not None:
            half["camera.focal_px"] = spec.camera.focal_px / 2
        r = render_scene(with_overrides(spec, half))
        complete = [h for h in r.highlights if h.in_frame and highlight_complete(r.specular, h.bp_px)]
        assert complete, f"{name}: no complete highlight (BP and t = 0.1 isophote in frame)"


def test_microfacet_channels_and_specular_image():
    spec = with_overrides(load_scene("cylinder"), {"camera.width_px": 96, "camera.height_px": 96,
                                                   "render.spp": 4})
    r = render_scene(spec)
    m = r.mask
    # The specular-only image is part of the image; the diffuse part (albedo 0.3) fills the rest.
    assert np.all(r.specular[m] <= r.linear[m] * (1 + 1e-6))
    assert np.median(r.linear[m] - r.specular[m]) > 0
    dull = render_scene(with_overrides(spec, {"material.diffuse_albedo": 0.0}))
    # Without albedo the image is its specular part (float32 arithmetic only).
    assert np.allclose(dull.linear, dull.specular, rtol=1e-6, atol=0)


def test_write_render_files(tmp_path):
    from PIL import Image

    from simtest.geometry.camera_file import load_camera

    spec = with_overrides(load_scene("plane_fronto"), {
        "camera.width_px": 64, "camera.height_px": 48, "camera.focal_px": 64.0, "render.spp": 2})
    r = render_scene(spec, seed=2)
    paths = write_render(r, tmp_path / "out")
    img = np.asarray(Image.open(paths["image"]))
    assert img.shape == (48, 64) and np.array_equal(img, r.sensor)
    intr = load_camera(paths["intrinsics"]).model
    assert np.array_equal(intr.K, r.K) and tuple(intr.image_size) == (64, 48)
    gt = np.load(paths["ground_truth"])
    assert gt["normals"].shape == (48, 64, 3) and gt["normals"].dtype == np.float32
    assert gt["depth"].dtype == np.float32 and gt["mask"].dtype == bool
    meta = json.loads(paths["highlights"].read_text())
    assert meta["seed"] == 2 and len(meta["highlights"]) == 1
    assert np.allclose(meta["highlights"][0]["bp_px"], r.highlights[0].bp_px)
    assert set(meta["highlights"][0]) >= {"bp_px", "normal", "k1", "k2"}


def _one_line_error(res, *words, code=2):
    """A CLI failure: exit ``code`` and nothing but one ``error: ...`` line holding ``words``."""
    assert res.exit_code == code, res.output
    err = res.output  # stdout and stderr together (Click 8.1 and 8.2 alike)
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1, err
    assert lines[0].startswith("error: ") and "Traceback" not in err
    for w in words:
        assert w in lines[0], lines[0]


_TINY = ("[camera]\nwidth_px = 48\nheight_px = 48\nfocal_px = 48.0\n[render]\nspp = 2\n"
         "[geometry]\ntype = 'plane'\ntilt_deg = 10.0\ndistance_mm = 20.0\n")


def test_cli_render(tmp_path):
    from typer.testing import CliRunner

    from simtest.cli import app

    scene = tmp_path / "tiny.toml"
    scene.write_text(_TINY)
    res = CliRunner().invoke(app, ["render", str(scene), "--out", str(tmp_path / "o"), "--seed", "4"])
    assert res.exit_code == 0, res.output
    assert json.loads((tmp_path / "o" / "highlights.json").read_text())["seed"] == 4
    # The largest seed renders (Mitsuba takes 32-bit seeds).
    res = CliRunner().invoke(app, ["render", str(scene), "--out", str(tmp_path / "m"),
                                   "--seed", str(2**31 - 1)])
    assert res.exit_code == 0, res.output


def test_cli_render_bad_scene_files_give_one_line(tmp_path):
    from typer.testing import CliRunner

    from simtest.cli import app

    # Long folder names: a message wrapped at 80 columns would span several lines.
    d = tmp_path / ("a_rather_long_folder_name_for_scene_files_" * 2)
    d.mkdir()
    cases = {
        "missing.toml": ("[geometry]\ntype = 'plane'\ntilt_deg = 10.0\n", "geometry.distance_mm"),
        "unknown.toml": (_TINY + "colour = 'red'\n", "geometry.colour"),
        "nomesh.toml": ("[geometry]\ntype = 'mesh'\npath = 'no_such_mesh_file_anywhere.ply'\n",
                        "geometry.path"),
    }
    for name, (text, key) in cases.items():
        (d / name).write_text(text)
        res = CliRunner().invoke(app, ["render", str(d / name), "--out", str(tmp_path / "o")])
        _one_line_error(res, str(d / name), key)
    assert not (tmp_path / "o").exists()


def test_cli_render_bad_seed_and_output(tmp_path, monkeypatch):
    from typer.testing import CliRunner

    from simtest.cli import app
    from simtest.render import cli as render_module  # the name the command calls

    scene = tmp_path / "tiny.toml"
    scene.write_text(_TINY)
    # Seeds beyond 2^31 - 1 (here 2^33 + 5) are refused by the option, before any render.
    res = CliRunner().invoke(app, ["render", str(scene), "--out", str(tmp_path / "o"),
                                   "--seed", "8589934597"])
    assert res.exit_code == 2 and "Traceback" not in res.output
    # Click's usage error (typer 0.29 names the option and the bound, not the value).
    assert "--seed" in res.output and "2147483647" in res.output
    assert not (tmp_path / "o").exists()

    # --out names a file: refused before rendering (render_scene would raise here).
    a_file = tmp_path / "a_file"
    a_file.write_text("keep me")

    def no_render(*args, **kwargs):
        raise AssertionError("rendered although --out is a file")

    with monkeypatch.context() as m:
        m.setattr(render_module, "render_scene", no_render)
        res = CliRunner().invoke(app, ["render", str(scene), "--out", str(a_file)])
    _one_line_error(res, "--out", str(a_file), "is a file", code=4)
    assert a_file.read_text() == "keep me"

    # A folder below a file: refused before rendering, exit 4 (the output cannot be written).
    with monkeypatch.context() as m:
        m.setattr(render_module, "render_scene", no_render)
        res = CliRunner().invoke(app, ["render", str(scene), "--out", str(a_file / "sub")])
    _one_line_error(res, "--out", str(a_file / "sub"), "is a file", code=4)


def test_render_scene_refuses_out_of_range_seeds():
    from simtest.render.render import MAX_SEED

    spec = scene_from_dict({"camera": {"width_px": 8, "height_px": 8}, "render": {"spp": 1},
                            "geometry": {"type": "plane", "tilt_deg": 0.0, "distance_mm": 20.0}})
    for bad in (-1, 2**31, 8589934597):
        with pytest.raises(ValueError, match=rf"seed {bad} is out of range.*\[0, 2\^31 - 1"):
            render_scene(spec, seed=bad)
    assert MAX_SEED == 2**31 - 1
    # The CLI option uses the same bound (kept as a literal there for a Mitsuba-free start-up).
    from simtest.render.cli import MAX_SEED as CLI_MAX_SEED
    assert CLI_MAX_SEED == MAX_SEED


def test_failed_stationary_solve_is_an_error(monkeypatch):
    """A root solve that does not converge raises instead of returning a non-BP."""
    import scipy.optimize

    from simtest.simulate import truth

    K = np.array([[100.0, 0, 63.5], [0, 100.0, 63.5], [0, 0, 1]])
    c, L = np.array([5.0, -3.0, 80.0]), np.array([8.0, 3.0, 1.0])
    good = truth.sphere_highlight(c, 20.0, L, K, (128, 128))  # the same inputs converge unpatched

    real_root = scipy.optimize.root

    def stalled_root(fun, x0, **kwargs):  # gives up at the start point, as hybr can (status 5)
        sol = real_root(fun, x0, **kwargs)
        sol.x, sol.success, sol.status = np.asarray(x0, dtype=np.float64), False, 5
        sol.message = "The iteration is not making good progress."
        return sol

    with monkeypatch.context() as m:
        m.setattr(scipy.optimize, "root", stalled_root)
        # the fallback (the light-path minimiser) must fail too for the error to be raised
        m.setattr(truth, "circle_reflection", lambda a, b, r: np.array([0.6, 0.8]))
        with pytest.raises(truth.HighlightTruthError,
                           match=rf"sphere .*residual .* > {truth.STATIONARY_RESIDUAL_TOL:g}.*status 5"):
            truth.sphere_highlight(c, 20.0, L, K, (128, 128))
        with pytest.raises(truth.HighlightTruthError, match=r"cylinder .*status 5"):
            truth.cylinder_highlight(c, [1.0, 0.3, 0.2], 15.0, 1000.0, L, K, (128, 128))
    assert angle_between_deg(good.normal, bisector(good.bp_mm, L)) < 1e-9

    # A genuine failure: the camera inside the cylinder (no outside BP); the solve used to return
    # an unconverged point silently.
    with pytest.raises(truth.HighlightTruthError, match="cylinder"):
        truth.cylinder_highlight(np.array([0.0, 10.0, 20.0]), [0.0, 0.0, 1.0], 15.0, 1000.0,
                                 np.array([5.0, 5.0, 0.0]), K, (128, 128))


def test_old_llvm_is_refused_with_the_fix(monkeypatch):
    from simtest._llvm import LLVM_FIX

    monkeypatch.setenv("DRJIT_LIBLLVM_PATH", "/usr/lib/x86_64-linux-gnu/libLLVM-15.so.1")
    with pytest.raises(RendererUnavailable) as info:
        choose_variant("llvm_ad_rgb")
    assert LLVM_FIX in str(info.value) and "LLVM 15" in str(info.value)


def test_an_old_llvm_loaded_by_drjit_itself_is_refused(monkeypatch):
    # No LLVM 16+ found (DRJIT_LIBLLVM_PATH unset): Dr.Jit loads the system's libLLVM, which on a
    # bare Debian 12 is LLVM 15 and aborted the process at the first kernel (a bench run did).
    # The loaded version is faked: the machine running the test may well have LLVM 19 only.
    from simtest._llvm import LLVM_FIX
    from simtest.render import scene_load as render_mod

    monkeypatch.setattr(render_mod._llvm, "configure_llvm_env", lambda: None)
    monkeypatch.setattr(render_mod, "_loaded_llvm_major", lambda dr: 15)
    with pytest.raises(RendererUnavailable) as info:
        choose_variant("llvm_ad_rgb")
    assert LLVM_FIX in str(info.value) and "loaded LLVM 15" in str(info.value)


@settings(max_examples=60, deadline=None)
@given(
    tilt=st.floats(0.0, 80.0),
    az=st.floats(0.0, 360.0),
    eps=st.floats(0.0, 20.0),
    a=st.floats(0.0, 360.0),
    b=st.floats(-0.5, 0.5),
)
@example(tilt=0.0, az=0.0, eps=1.2589744168444878e-08, a=30.0, b=0.0)  # once taken for co-located
def test_analytic_highlights_satisfy_the_bisector_condition(tilt, az, eps, a, b):
    # Pure numpy: the closed forms and root solves of simtest.simulate.truth, for any light offset.
    from simtest.simulate.truth import cylinder_highlight, plane_highlight, sphere_highlight
    from simtest.scene import scene_from_dict as sfd

    K = np.array([[100.0, 0, 63.5], [0, 100.0, 63.5], [0, 0, 1]])
    L = eps * np.array([math.cos(math.radians(a)), math.sin(math.radians(a)), b])
    geo = sfd({"geometry": {"type": "plane", "tilt_deg": tilt, "azimuth_deg": az,
                            "distance_mm": 50.0}}).geometry
    n = plane_normal_cam(geo)
    hp = plane_highlight(n, 50.0, L, K, (128, 128))
    assert math.isclose(np.dot(n, hp.bp_mm), -50.0, rel_tol=1e-9)  # on the plane
    c = np.array([5.0, -3.0, 80.0])
    hs = sphere_highlight(c, 20.0, L, K, (128, 128))
    assert math.isclose(np.linalg.norm(hs.bp_mm - c), 20.0, rel_tol=1e-9)
    axis = np.array([1.0, 0.3, 0.2]) / np.linalg.norm([1.0, 0.3, 0.2])
    hc = cylinder_highlight(c, axis, 15.0, 1000.0, L, K, (128, 128))
    q = hc.bp_mm - c
    assert math.isclose(np.linalg.norm(q - np.dot(q, axis) * axis), 15.0, rel_tol=1e-9)
    for h in (hp, hs, hc):
        # The normal bisects the directions to camera and light: measured <= 2e-14 deg over 2000
        # draws (float64 round-off); the root solves are accepted below 1e-12 rad = 6e-11 deg.
        assert angle_between_deg(h.normal, bisector(h.bp_mm, L)) < 1e-9
        assert np.dot(h.normal, h.bp_mm) < 0  # faces the camera


@pytest.mark.parametrize("distribution", ["beckmann", "ggx"])
def test_microfacet_conductor_peaks_at_the_bp_and_cancels_falloff(distribution):
    spec = scene_from_dict({
        "camera": {"width_px": 96, "height_px": 96, "fov_deg": 90.0},
        "material": {"model": "microfacet", "base": "conductor", "distribution": distribution,
                     "alpha": 0.2},
        "light": {"falloff": "cancel"},
        "geometry": {"type": "plane", "tilt_deg": 25.0, "azimuth_deg": 200.0, "distance_mm": 40.0},
        "render": {"spp": 16},
    })
    r = render_scene(spec)
    (h,) = r.highlights
    v, u = np.unravel_index(np.argmax(r.linear), r.linear.shape)
    # Co-located light: the half vector is the view direction, so the lobe peaks where the view
    # ray is along the normal, within the pixel holding the BP.
    assert np.hypot(u - h.bp_px[0], v - h.bp_px[1]) <= 1.0
    keep = render_scene(with_overrides(spec, {"light.falloff": "keep"}))
    m = r.mask & (r.linear > 1e-3 * r.linear.max())
    # "cancel" multiplies the pixel by its squared light distance (pixel-mean surface point):
    # equal to float32 round-off.
    assert np.allclose(r.linear[m], keep.linear[m] * r.distance[m] ** 2, rtol=1e-4)
