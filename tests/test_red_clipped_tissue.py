"""Tissue whose red channel clips around the lobes (pink mucosa exposed bright, as an auto-exposure on
luma leaves it): a colour projection weighs red negatively, so it cannot value those pixels, and where
they cover the lobe its valued pixels show none. The fit then reads the darkest channel, which does.

Before, the projection's fit of what was left (noise) passed as ``ok``: on the frames below the normals
came 1.0 deg off and the depth four times too far (106 to 114 mm for 26.8), the fused lobes' rows up to
14 px from their specular points."""

from __future__ import annotations

import numpy as np
import pytest

from phong_frames import nearest_row, phong_frame, reconstruct_frame
from simtest.geometry import angle_between_deg
from simtest.reconstruct import lightaware as la
from simtest.reconstruct.lightaware import colour as lam
from simtest.reconstruct.lightaware.plane import _sees_lobe
from test_lightaware_colour import RIG, _colour_plane
from test_rig_pairs import _frame_rows, sensor_plane


def test_a_projection_without_missing_pixels_sees_its_lobe():
    values = np.zeros((20, 20))
    assert _sees_lobe(values, None) and _sees_lobe(values, np.zeros((20, 20), bool))


def test_a_lobe_inside_the_missing_pixels_is_not_seen_and_its_tails_are():
    # a Gaussian lobe (peak 1, sigma 3 px) in 1 % noise, its centre left out to a radius of r px:
    # at 12 px what is valued is noise (the lobe at 3e-4), at 6 px the tails are 0.14 (14 sigma)
    rng = np.random.default_rng(0)
    vv, uu = np.mgrid[0:81, 0:81] - 40.0
    rr = np.hypot(uu, vv)
    values = np.exp(-0.5 * (rr / 3.0) ** 2) + rng.normal(0, 0.01, rr.shape)
    assert not _sees_lobe(values, rr < 12)
    assert _sees_lobe(values, rr < 6)


def test_a_fit_whose_projection_shows_no_lobe_reads_the_darkest_channel():
    # the colour plane's red clipped at 0.4 (its shading's median 0.47): 78 % of the ROI and all of the
    # lobes' significant pixels clip in red, whose projection weight is negative. The projection's fit
    # did not converge; the darkest channel's is ok, the texture's bias in it 0.09 deg (as the
    # colour tests' darkest-channel fit of this plane) and 0.1 % in depth
    rgb, s, K, N, depth, bp = _colour_plane(0)
    clip = np.array([0.4, 1.0, 1.0])
    y = np.minimum(rgb + np.random.default_rng(1).normal(0, 0.005, rgb.shape), clip)
    values, lower, missing, w = lam.specular_image(y, clip, two_channels=False)
    assert w[0] < 0 and missing.mean() > 0.7 and not _sees_lobe(values, missing)
    r = la.photometric_fit(y, (0, 0), bp, K, RIG, clip_level=clip, diffuse=True, censor=True, lobe="phong")
    assert r.ok and r.projection == "darkest_channel" and "show no lobe" in r.detail, r
    assert angle_between_deg(r.normal, N) < 0.2
    assert r.distance_mm == pytest.approx(20.0, rel=0.01)
    # red unclipped: the projection is kept, and exact to the noise
    y = np.minimum(rgb + np.random.default_rng(1).normal(0, 0.005, rgb.shape), 1.2)
    kept = la.photometric_fit(y, (0, 0), bp, K, RIG, clip_level=1.2, diffuse=True, censor=True, lobe="phong")
    assert kept.ok and kept.projection == "body_colours", kept
    assert angle_between_deg(kept.normal, N) < 0.05


@pytest.mark.parametrize("seed, phong_n", [(1, 250.0), (3, 400.0)])
def test_pink_tissue_clipped_in_red_around_the_lobes_gets_both_guides_normals(tmp_path, seed, phong_n):
    # 480 x 400 px, f 180 px; the guides 8 mm apart, the plane 13 deg off the axis at 27.5 mm; the shading's
    # median at 0.45 of full scale in red: red clips over a disc around the two lobes, which clip white.
    # Every guide's row at its specular point (the fused lobes' joint fit places it; a pixel: the BP of
    # a clipped plateau) and its normal within 0.05 deg (the fits reach 0.0013 deg; before 1.02 to 1.07)
    normal = np.array([-0.22907546, 0.01813979, -0.97323963])
    normal /= np.linalg.norm(normal)
    guides = 4.0 * np.array([[np.cos(0.3), np.sin(0.3), 0.0], [-np.cos(0.3), -np.sin(0.3), 0.0]])
    img, K, truth = phong_frame(480, 400, 180.0, guides, normal, 27.5, phong_n, 8.0, (0.8, 0.35, 0.3), 0.45, 0.005,
                                seed)
    assert (img[..., 0] == 255).mean() > 0.03  # red clips over the lobes' surround
    specs = reconstruct_frame(tmp_path, img, K, guides)
    for uv in truth:
        d, s = nearest_row(specs, uv)
        assert d <= 1.0 and s["status"] == "ok" and s["normal_from"] == "photometric_fit", (uv, d, s["detail"])
        assert angle_between_deg(s["normal"], normal) < 0.05


@pytest.mark.parametrize("depth_mm", [12.0, 15.0])
def test_red_clipped_under_noise_makes_no_second_body_colour_on_the_command_line(tmp_path, depth_mm):
    # the tests' sensor plane (Blinn lobes, 1 % noise clipped again at full scale), pink and exposed
    # so that red clips over a fifth of the frame: inside it noise leaves red readings below the
    # clip, which the border counted as a second body colour; its projection (noise gain 9 to 10)
    # fitted one guide 10 to 11 deg off as ok. Both guides' normals within 0.1 deg (their fits' sigma
    # about 0.02 to 0.04 deg)
    img, K, normal, truth = sensor_plane(25.0, depth_mm, 45, shininess=1000.0, size=400, f=150.0,
                                         tissue=(0.8, 0.35, 0.3), median=0.55, azimuth_deg=30.0)
    assert (img[..., 0] == 255).mean() > 0.15
    _, rows = _frame_rows(tmp_path, img, K, normal, truth)
    assert len(rows) == 2 and all(status == "ok" and err is not None and err < 0.1 for status, err in rows), rows
