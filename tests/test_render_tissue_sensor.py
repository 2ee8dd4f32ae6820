"""Procedural tissue (albedo, micro-relief, wet film) and the video sensor, against closed forms."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from simtest.render import render_scene
from simtest.render.scene_load import tissue_texture
from simtest.render.sensor import apply_sensor, field_stop_mask, frame_luma, peak_exposure, video_frame
from simtest.render.tissue import (
    albedo,
    relief_height,
    relief_normal,
    specular_lobe,
    tissue_params,
)
from simtest.scene import scene_from_dict
from simtest.scene.spec import SensorSpec


def _unit(v):
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


@settings(max_examples=20, deadline=None)
# a few texture seeds (their vessel maps, 0.4 s of CPU each, then come from transmission_map's
# cache of 4; the relief's waves differ per seed and with amp and scale); the points drawn apart
@given(seed=st.integers(0, 3), points=st.integers(0, 2**31 - 1), amp=st.floats(0.005, 0.1),
       scale=st.floats(0.05, 1.0))
def test_relief_normal_is_the_bump_of_its_height_field(seed, points, amp, scale):
    t = tissue_params("mucosa", seed, amp, scale)
    rng = np.random.default_rng(points)
    p = rng.normal(size=(50, 3)) * 10.0
    n = _unit(rng.normal(size=(50, 3)))
    ns = np.stack(relief_normal(np, tuple(p.T), tuple(n.T), t), axis=-1)
    # Gradient of h by central differences (h is a sum of sines: step 1e-6 mm gives ~1e-9 error).
    e = 1e-6
    grad = np.stack([(relief_height(np, tuple((p + e * d).T), t) - relief_height(np, tuple((p - e * d).T), t)) / (2 * e)
                     for d in np.eye(3)], axis=-1)
    tang = grad - np.sum(grad * n, axis=1, keepdims=True) * n
    assert np.allclose(ns, _unit(n - tang), atol=1e-7)
    assert np.allclose(np.linalg.norm(ns, axis=1), 1.0, atol=1e-12)
    flat = np.stack(relief_normal(np, tuple(p.T), tuple(n.T), tissue_params("mucosa", seed, 0.0, scale)), -1)
    assert np.array_equal(flat, n / np.linalg.norm(n, axis=1, keepdims=True)) or np.allclose(flat, n, atol=1e-15)


def test_albedo_is_tissue_coloured_and_seeded():
    p = tuple(np.random.default_rng(0).uniform(-20, 20, size=(3, 20000)))
    for kind in ("mucosa", "liver"):
        a = np.stack(albedo(np, p, tissue_params(kind, 1, 0.0, 0.3)), axis=-1)
        assert np.all((a >= 0) & (a <= 1))
        med = np.median(a, axis=0)
        assert med[0] > med[1] > 0 and med[0] > med[2] > 0  # red dominates
        b = np.stack(albedo(np, p, tissue_params(kind, 2, 0.0, 0.3)), axis=-1)
        assert not np.allclose(a, b)
        assert np.array_equal(a, np.stack(albedo(np, p, tissue_params(kind, 1, 0.0, 0.3)), axis=-1))


@pytest.mark.parametrize("lobe", ["beckmann", "ggx"])
def test_microfacet_lobe_reciprocity_and_normal_fresnel(lobe):
    rng = np.random.default_rng(3)
    n = np.array([0.0, 0.0, 1.0])
    wi, wo = _unit(rng.normal(size=(200, 3))), _unit(rng.normal(size=(200, 3)))
    wi[:, 2], wo[:, 2] = np.abs(wi[:, 2]), np.abs(wo[:, 2])
    N = tuple(np.broadcast_to(n, wi.shape).T)
    f1 = specular_lobe(np, N, tuple(wi.T), tuple(wo.T), lobe, 0.2, 50.0, 1.38, 1.0)
    f2 = specular_lobe(np, N, tuple(wo.T), tuple(wi.T), lobe, 0.2, 50.0, 1.38, 1.0)
    assert np.allclose(f1, f2, rtol=1e-12)
    # Mirror configuration at normal incidence: F = ((eta - 1) / (eta + 1))^2, D(0) = 1 / (pi a^2),
    # G = 1, so f = F / (pi a^2) / 4.
    z = (np.array([0.0]), np.array([0.0]), np.array([1.0]))
    f = specular_lobe(np, z, z, z, lobe, 0.2, 50.0, 1.38, 1.0)
    assert f[0] == pytest.approx(((0.38 / 2.38) ** 2) / (math.pi * 0.04) / 4.0, rel=1e-6)


def test_video_frame_defaults_equal_the_grey_sensor():
    lin = np.random.default_rng(1).uniform(0, 1.2, size=(20, 30))
    s = SensorSpec()
    frame = video_frame(lin, s, seed=0)
    assert frame.shape == (20, 30, 3) and frame.dtype == np.uint8
    for c in range(3):
        assert np.array_equal(frame[..., c], apply_sensor(lin, s, 0))
    assert np.array_equal(frame_luma(frame), frame[..., 0])


def test_video_frame_does_not_depend_on_the_thread_count():
    """Each row band has its own noise stream, so the frame is the same on 1 or 3 threads."""
    rgb = np.random.default_rng(4).uniform(0.0, 0.05, size=(50, 40, 3))
    noisy = SensorSpec(full_well_e=500.0, gaussian_sigma=0.01, exposure_mode="auto", vignetting=0.3,
                       tone="srgb", field_stop="octagon", jpeg_quality=80)
    one = video_frame(rgb, noisy, 7, threads=1)
    assert np.array_equal(one, video_frame(rgb, noisy, 7, threads=3))
    assert not np.array_equal(one, video_frame(rgb, noisy, 8, threads=1))


def test_video_frame_steps():
    rng = np.random.default_rng(2)
    rgb = rng.uniform(0.0, 0.05, size=(60, 80, 3))
    auto = SensorSpec(exposure_mode="auto", auto_mean=0.3)
    f = video_frame(rgb, auto, 0).astype(np.float64) / 255
    # Mean luma 0.3 of full scale, up to the 8-bit rounding (0.5 / 255 per pixel, averaged).
    assert np.mean(f @ [0.299, 0.587, 0.114]) == pytest.approx(0.3, abs=2e-3)
    wb = video_frame(np.full((4, 4, 3), 0.2), SensorSpec(white_balance=(2.0, 1.0, 0.5)), 0)
    assert wb[0, 0].tolist() == [102, 51, 26]
    srgb = video_frame(np.array([[[0.5, 0.0031308, 1.0]]]), SensorSpec(tone="srgb"), 0)
    assert srgb[0, 0].tolist() == [188, 10, 255]  # IEC 61966-2-1: 0.7354, 0.04045, 1
    noisy = SensorSpec(full_well_e=1000.0, gaussian_sigma=0.01)
    assert np.array_equal(video_frame(rgb, noisy, 5), video_frame(rgb, noisy, 5))
    assert not np.array_equal(video_frame(rgb, noisy, 5), video_frame(rgb, noisy, 6))
    grey = video_frame(rgb, SensorSpec(color_saturation=0.0, exposure=10.0), 0).astype(int)
    assert np.abs(grey[..., 0] - grey[..., 2]).max() <= 1
    for kind in ("circle", "octagon"):
        stop = field_stop_mask((200, 200), kind, 0.8)
        f = video_frame(np.full((200, 200), 0.5), SensorSpec(field_stop=kind, field_stop_radius=0.8), 0)
        assert np.all(f[~stop] == 0) and np.all(f[stop] == 128)
        area = math.pi * 80**2 if kind == "circle" else 8 * math.tan(math.pi / 8) * 80**2
        assert stop.sum() == pytest.approx(area, rel=0.01)
    jpeg_err = []
    img = rng.uniform(0, 1, size=(64, 64, 3))
    raw = video_frame(img, SensorSpec(), 0).astype(float)
    for q in (95, 30):
        jpeg_err.append(np.abs(video_frame(img, SensorSpec(jpeg_quality=q), 0) - raw).mean())
    assert 0 < jpeg_err[0] < jpeg_err[1]


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), percent=st.floats(0.5, 20.0), spread=st.floats(1.0, 4.0),
       wb=st.tuples(st.floats(0.5, 2.0), st.floats(0.5, 2.0), st.floats(0.5, 2.0)))
def test_peak_protecting_auto_exposure_clips_at_most_the_allowed_share(seed, percent, spread, wb):
    """With ``auto_clip_percent`` the exposure is the mean's target or less, and no more than that
    share of the pixels clips in a channel (without noise; ties on the quantile's value are of
    measure zero for continuous radiance), while the mean alone would clip more where the
    radiance spreads over decades (a wide field's falloff)."""
    rng = np.random.default_rng(seed)
    rgb = np.exp(spread * rng.standard_normal((40, 50, 3)))
    mean_only = SensorSpec(exposure_mode="auto", auto_mean=0.3, white_balance=wb)
    peak = SensorSpec(exposure_mode="auto", auto_mean=0.3, white_balance=wb, auto_clip_percent=percent)
    clipped = (video_frame(rgb, peak, 0) == 255).any(-1).mean() * 100
    # the 8-bit rounding clips the pixels within half a step of saturation too: a margin of 1/255
    # of the exposure
    exposure = peak_exposure(rgb, np.ones(rgb.shape[:2], bool), peak)
    near = ((rgb * np.asarray(wb)).max(-1) * exposure >= 1.0 - 0.5 / 255).mean() * 100
    assert clipped <= near + 1e-9
    assert near <= percent + 100.0 / rgb[..., 0].size + 1.0  # one pixel, and the rounding band
    assert clipped <= (video_frame(rgb, mean_only, 0) == 255).any(-1).mean() * 100
    # 100 % (the default): the mean alone sets the exposure
    assert np.array_equal(video_frame(rgb, mean_only, 0),
                          video_frame(rgb, SensorSpec(exposure_mode="auto", auto_mean=0.3,
                                                      white_balance=wb, auto_clip_percent=100.0), 0))


def test_tissue_render_truth_and_diffuse_closed_form():
    base = {"camera": {"width_px": 48, "height_px": 48, "fov_deg": 60.0},
            "light": {"rig": "colonoscope", "falloff": "keep", "intensity": 300.0, "profile_exponent": 0.0},
            "material": {"model": "tissue", "c": 0.0, "relief_mm": 0.0},
            "geometry": {"type": "plane", "tilt_deg": 0.0, "distance_mm": 20.0},
            "render": {"spp": 16}}
    r = render_scene(scene_from_dict(base), seed=0)
    assert r.rgb.shape == (48, 48, 3) and np.allclose(r.shading_normals, r.normals, atol=1e-6)
    p = r.position.reshape(-1, 3).astype(np.float64)
    a = np.stack(albedo(np, tuple(p.T), tissue_texture(scene_from_dict(base))), -1)  # the plane's own axes
    e = np.zeros(len(p))
    for L in r.light_rig.positions:
        d = L - p
        s = np.linalg.norm(d, axis=1)
        e += 300.0 * (-d[:, 2] / s) / s**2
    expect = a / math.pi * e[:, None]
    got = r.rgb.reshape(-1, 3)
    # Per pixel the albedo's vessel lines vary within the footprint; over the image the pixel
    # means and the centre values agree to the footprint's second-order term (< 1 %).
    assert np.mean(got, axis=0) == pytest.approx(np.mean(expect, axis=0), rel=0.01)
    assert float(r.specular.max()) == 0.0
    rough = scene_from_dict({**base, "material": {"model": "tissue", "relief_mm": 0.05, "distribution": "ggx",
                                                  "alpha": 0.1}})
    q = render_scene(rough, seed=0)
    ns = q.shading_normals[q.mask]
    assert np.allclose(np.linalg.norm(ns, axis=1), 1.0, atol=1e-5)
    ang = np.degrees(np.arccos(np.clip(np.sum(ns * q.normals[q.mask], axis=1), -1, 1)))
    assert 1.0 < np.median(ang) < 60.0 and q.specular.max() > 0
