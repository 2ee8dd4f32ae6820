"""Two guides' clipped tops fused into one bright region give one row per guide (issue 63).

Frames made here, apart from ``test_rig_pairs.sensor_plane``: GGX microfacet lobes with Schlick's
Fresnel, Lambertian tissue of a random colour under a random albedo texture, each guide a cos^m
profile falling off with the inverse square, shot and read noise before the clip, sRGB or a gamma
2.2 curve, JPEG at random qualities; the camera file states the rig (its profile too). The cases
are the over-exposed ones of the probe this was first seen on (root seed 4): the guides' lobes
fuse into one clipped region over bright tissue, which the detector's background square did not
cover, which came out ``cluster`` or ``not_elliptical``, or whose joint fit held the normal but
not the distance.
"""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from PIL import Image

from _cases import bench_frame_rows
from benchmarks import sensor_like
from test_rig_pairs import (  # the match radius, the must-hold's bound
    MATCH_PX,
    MEDIAN_MAX_DEG,
    _reconstruct,
)

from simtest.geometry.lights import Light, LightRig
from simtest.reconstruct import light_fits
from simtest.reconstruct.lightaware import LightAwareEstimate
from simtest.harness.metrics import MATCH_PX as HARNESS_MATCH_PX
from simtest.geometry.response import srgb_encode
from simtest.reconstruct.rig_lobes import (
    _on_the_tops,
    _roi_index,
    _tops_depth,
    _waisted,
    guide_specular_points,
)

SIZE, FOCAL = 360, 170.0


def ggx_plane(rng: np.random.Generator):
    """One frame of a random plane under two guides (module docstring): ``(frame, camera file,
    normal, true highlights (2, 2))``."""
    tilt, az = rng.uniform(8, 32), rng.uniform(0, 360)
    n = np.array([np.sin(np.radians(tilt)) * np.cos(np.radians(az)),
                  np.sin(np.radians(tilt)) * np.sin(np.radians(az)), -np.cos(np.radians(tilt))])
    h = rng.uniform(14, 30) * np.cos(np.radians(tilt))
    b = rng.uniform(3, 5)
    guides = np.array([[-b, 0, 0], [b, 0, 0]])
    alpha, m = rng.uniform(0.03, 0.08), rng.uniform(0, 3)
    tissue = np.array([rng.uniform(0.6, 0.9), rng.uniform(0.2, 0.4), rng.uniform(0.12, 0.3)])
    K = np.array([[FOCAL, 0, (SIZE - 1) / 2], [0, FOCAL, (SIZE - 1) / 2], [0, 0, 1.0]])
    vv, uu = np.mgrid[0:SIZE, 0:SIZE].astype(float)
    d = np.stack([(uu - K[0, 2]) / FOCAL, (vv - K[1, 2]) / FOCAL, np.ones_like(uu)], -1)
    X = d * (-h / (d @ n))[..., None]
    V = -X / np.linalg.norm(X, axis=-1, keepdims=True)
    diffuse, spec, truth = np.zeros((SIZE, SIZE)), np.zeros((SIZE, SIZE)), []
    for L in guides:
        Ld = L - X
        r = np.linalg.norm(Ld, axis=-1)
        Ld /= r[..., None]
        E = np.maximum(-Ld[..., 2], 0) ** m * np.maximum(Ld @ n, 0) / r**2  # the guide looks along +z
        H = Ld + V
        H /= np.linalg.norm(H, axis=-1, keepdims=True)
        c, a2 = np.clip(H @ n, 0, 1), alpha**2
        D = a2 / (np.pi * (c * c * (a2 - 1) + 1) ** 2)
        F = 0.02 + 0.98 * (1 - np.clip((Ld * H).sum(-1), 0, 1)) ** 5
        spec += E * F * D / 4
        diffuse += E
        Lm = L - 2 * (n @ L + h) * n  # the mirror image: the specular point on the plane
        Xs = Lm * (h / -(n @ Lm))
        truth.append((K @ Xs)[:2] / Xs[2])
    amp, corr = rng.uniform(0, 0.3), rng.uniform(2, 6)
    field = cv2.GaussianBlur(rng.normal(0, 1, (SIZE, SIZE)), (0, 0), corr)
    albedo = np.clip(1 + amp * field / field.std(), 0.3, None)
    s = (diffuse * albedo)[..., None] * tissue / np.pi + spec[..., None]
    s *= rng.uniform(0.35, 0.55) / np.median(diffuse * tissue.max() / np.pi)
    s = np.clip(s + rng.normal(0, 1, s.shape) * np.sqrt(0.0004 * np.maximum(s, 0) + 0.005**2), 0, 1)
    gamma = None if rng.random() < 0.6 else 2.2
    img = np.rint((srgb_encode(s) if gamma is None else s ** (1 / gamma)) * 255).astype(np.uint8)
    q = [None, None, 70, 80, 90, 95][rng.integers(0, 6)]
    if q:
        _, buf = cv2.imencode(".jpg", np.ascontiguousarray(img[..., ::-1]), [cv2.IMWRITE_JPEG_QUALITY, int(q)])
        img = np.ascontiguousarray(cv2.imdecode(buf, cv2.IMREAD_COLOR)[..., ::-1])
    curve = {"curve": "srgb"} if gamma is None else {"curve": "gamma", "gamma": gamma}
    cam = {"model": "pinhole", "K": K.tolist(), "image_size": [SIZE, SIZE],
           "response": {**curve, "white_balance": [1, 1, 1], "exposure": 1.0, "clip": 255.0},
           "lights": [{"position_mm": L.tolist(), "intensity": 1.0, "falloff": "inverse_square",
                       "profile_exponent": float(m)} for L in guides]}
    return img, cam, n, np.array(truth)


def _frame(seed: int, index: int):
    rng = np.random.default_rng(seed)
    for _ in range(index):
        ggx_plane(rng)
    return ggx_plane(rng)


def _nearest_rows(specs, truth):
    """Per true highlight (u, v): its distance (px) to the nearest row's BP, and that row."""
    bps = np.array([s["bp_px"] for s in specs]).reshape(-1, 2)
    for uv in truth:
        d = np.linalg.norm(bps - uv, axis=1)
        yield uv, float(d.min()), specs[int(np.argmin(d))]


def _error_deg(row, n) -> float:
    """The angle (deg) between a row's recommended normal and the true normal ``n``."""
    return float(np.degrees(np.arccos(min(1.0, abs(float(np.dot(row["normal"], n)))))))


def _reconstructed(folder, img, cam) -> list:
    """``simtest reconstruct`` of the frame with its camera file, as test_rig_pairs runs it."""
    Image.fromarray(img).save(folder / "frame.png", compress_level=1)  # (lossless: zlib level 1 is fastest)
    (folder / "camera.json").write_text(json.dumps(cam))
    return _reconstruct(folder)


@pytest.mark.parametrize("index, was, aware", [
    (0, "ok between the guides, the joint fit's depth not observable", True),
    (6, "cluster: the other guide's top its 'other peak'", True),
    # the plane-only fit of a rejected candidate's whole region: its normal is within 0.05 deg
    # but its stated sigma (2.3 deg) does not beat the BP ray's error, which the recommendation
    # then keeps, at each guide's specular point
    (12, "not_elliptical, the joint fit's depth not observable", False),
])
def test_fused_tops_over_bright_tissue_give_both_guides(tmp_path, index, was, aware):
    img, cam, n, truth = _frame(4, index)
    for uv, d, s in _nearest_rows(_reconstructed(tmp_path, img, cam), truth):
        assert d <= MATCH_PX and "fused" in s["detail"], (was, uv, d, s["status"], s["detail"])
        if not aware:
            continue
        assert s["normal_from"] == "photometric_fit", (was, s["normal_from"])
        assert _error_deg(s, n) <= MEDIAN_MAX_DEG, (was, _error_deg(s, n))


@settings(max_examples=40, deadline=None)
@given(tilt=st.floats(0.0, 35.0), az=st.floats(0.0, 360.0), h=st.floats(12.0, 40.0),
       baseline=st.floats(3.0, 5.0), radius=st.floats(4.0, 9.0))
def test_the_tops_distance_centres_each_guides_specular_point(tilt, az, h, baseline, radius):
    # Two clipped discs, each centred on a guide's specular point of a plane (n, h): with the
    # normal given, the distance found from the tops puts the points back on the centres. The
    # centres are found to the distance transform's resolution: its maximum over a disc drawn
    # on the pixel grid is flat within a pixel of the centre, and the h grid steps 1 %
    # (a quarter of a pixel at 25 px from the image centre): 1.5 px.
    t, a = np.radians(tilt), np.radians(az)
    n = np.array([np.sin(t) * np.cos(a), np.sin(t) * np.sin(a), -np.cos(t)])
    K = np.array([[FOCAL, 0, 179.5], [0, FOCAL, 179.5], [0, 0, 1.0]])
    rig = LightRig((Light((-baseline, 0.0, 0.0)), Light((baseline, 0.0, 0.0))))
    pts = guide_specular_points(K, rig, n, h)
    vv, uu = np.mgrid[0:SIZE, 0:SIZE]
    tops = np.zeros((SIZE, SIZE), bool)
    for u, v in pts:
        tops |= (uu - u) ** 2 + (vv - v) ** 2 <= radius**2
    gray = np.where(tops, 255.0, 200.0)
    got = _on_the_tops(_tops_depth(gray, (tops, 0, 0)), (tops, 0, 0), K, rig, n)
    assert got is not None
    assert np.abs(got - pts).max() <= 1.5, (got, pts)


@settings(max_examples=40, deadline=None)
@given(a=st.floats(10.0, 60.0), ratio=st.floats(0.4, 1.0), angle=st.floats(0.0, 180.0), s=st.floats(0.05, 0.95),
       t=st.floats(-0.95, 0.95), holes=st.floats(0.0, 0.08), seed=st.integers(0, 2**16))
def test_one_lobes_clipped_top_has_no_waist_and_two_fused_tops_do(a, ratio, angle, s, t, holes, seed):
    # One plane's clipped top is an ellipse (convex): with noise pixels below the clip punched in it at random
    # (up to 8 %), its holes filled, no segment between two of its points narrows in the middle, however
    # far apart the points (the frame whose single round top, its holes left open, held two guides' points
    # 76 px apart: two ok rows 6.5 deg off). Two discs of radius r fused with their centres r apart narrow by
    # r - sqrt(3) r / 2 between the centres: 2.3 px from r = 17 (at r = 13 the pixel grid leaves 0.6).
    # Up to 8 %: FUSED_TOPS_WAIST_PX allows an edge ragged by one pixel, which 0 of 3000 draws of tops with
    # semi-minor axes 4 to 18 px exceed; at 10 to 20 % punched pixels, notches open to the rim take 1 px off
    # the middle of 9 in 3000 (semi-minor axes 5 to 9.4 px; a=10, ratio 0.5, holes 0.1875, seed 5892), a
    # limit of the rule, not of this check.
    size = 160
    c = (size - 1) / 2.0
    vv, uu = np.mgrid[0:size, 0:size].astype(float)
    th = np.radians(angle)
    x, y = (uu - c) * np.cos(th) + (vv - c) * np.sin(th), -(uu - c) * np.sin(th) + (vv - c) * np.cos(th)
    top = (x / a) ** 2 + (y / (ratio * a)) ** 2 <= 1.0
    gray = np.where(top, 255.0, 200.0)
    gray[top & (np.random.default_rng(seed).random(top.shape) < holes)] = 240.0
    region = (np.ones_like(top), 0, 0)
    pts = np.array([[c + s * a * np.cos(th), c + s * a * np.sin(th)], [c + t * a * np.cos(th), c + t * a * np.sin(th)]])
    assert not _waisted(_tops_depth(gray, region), region, pts)
    r = a / 2.0 + 12.0
    two = np.array([[c - r / 2.0, c], [c + r / 2.0, c]])
    fused = ((uu - two[0, 0]) ** 2 + (vv - c) ** 2 <= r**2) | ((uu - two[1, 0]) ** 2 + (vv - c) ** 2 <= r**2)
    assert _waisted(_tops_depth(np.where(fused, 255.0, 200.0), region), region, two)


def test_two_splits_of_one_pair_keep_the_surer_fit(tmp_path):
    # root seed 2, frame 1: a merged candidate and a not_elliptical one both split into rows for
    # the same two guides; the merged one's joint fit (GGX, sigma 1.3 deg) put its points 9.5 and
    # 3.6 px off with a normal 2 deg off, the other's (Phong, sigma 0.32 deg) 2.1 and 0.3 px off,
    # 0.37 deg: four rows for two highlights. The split of the smaller stated sigma keeps its rows.
    img, cam, n, truth = _frame(2, 1)
    specs = _reconstructed(tmp_path, img, cam)
    fused = [s for s in specs if "fused" in s["detail"]]
    assert len(fused) == 2, [(s["bp_px"], s["detail"][:40]) for s in fused]
    for uv in truth:
        d = [float(np.linalg.norm(np.asarray(s["bp_px"]) - uv)) for s in fused]
        assert min(d) <= MATCH_PX, d
        s = fused[int(np.argmin(d))]
        assert np.degrees(np.arccos(min(1.0, abs(float(np.dot(s["normal"], n)))))) <= MEDIAN_MAX_DEG


def test_a_top_clipped_in_red_and_green_gives_its_centre_as_the_bp(tmp_path):
    """Seed 4, frame 5 (gamma 2.2, JPEG q80, a broad GGX lobe over red tissue): the second guide's
    lobe clips in red and green but not in blue, so it is no clipped plateau, and its luma is flat
    within 1 to 2 levels over about 60 px. The BP is the centroid of that top within
    CLIP_LUMA_MARGIN_REL of the ceiling, within a pixel of the specular point (the brightest
    pixel of the smoothed luma lay at the top's edge, 3.6 px off); both guides then get their
    photometric normal."""
    img, cam, n, truth = _frame(4, 5)
    for uv, d, s in _nearest_rows(_reconstructed(tmp_path, img, cam), truth):
        assert d <= 1.0, (uv, d, s["status"])
        assert s["normal_from"] == "photometric_fit" and _error_deg(s, n) <= MEDIAN_MAX_DEG, s["normal_from"]


def test_clipped_tops_on_a_near_white_sheen_are_found(tmp_path):
    """Seed 22, frame 11 (guides of profile exponent 2.9, a broad GGX lobe over pale tissue): red
    clips over most of the lit field and the sheen around the two clipped tops reaches luma 235
    to 250, so the tops stand 19.5 levels above the background square's opening, under
    TOPHAT_MIN_REL (20.4): the ceiling cut their height, and the frame had no candidate at all.
    Pixels clipped white are candidates wherever they are local peaks above the background."""
    img, cam, n, truth = _frame(22, 11)
    for uv, d, s in _nearest_rows(_reconstructed(tmp_path, img, cam), truth):
        assert d <= MATCH_PX, (uv, d)
        assert s["normal_from"] == "photometric_fit" and _error_deg(s, n) <= MEDIAN_MAX_DEG, (s["status"], s["normal_from"])


def test_fused_tops_whose_isophote_leaves_the_frame_give_both_guides(tmp_path):
    """Seed 25, frame 14 (tilt 29 deg, guides of profile exponent 2.5, gamma 2.2, JPEG q70): the
    two lobes fuse over a bright sheen that reaches the frame's left side, so the fused
    candidate's isophote runs out of the frame (``contour_cut``) and its one row lay between the
    guides, 19 px from each specular point. The joint plane fit needs no isophote: the candidate
    is split as the other fused statuses are (rig_lobes.SPLIT_STATUSES)."""
    img, cam, n, truth = _frame(25, 14)
    for uv, d, s in _nearest_rows(_reconstructed(tmp_path, img, cam), truth):
        assert d <= MATCH_PX, (uv, d, s["status"])
        assert s["normal_from"] == "photometric_fit" and _error_deg(s, n) <= MEDIAN_MAX_DEG, (s["status"], s["normal_from"])


def test_fused_clipped_tops_whose_joint_fit_misses_them_give_the_pairs_plane(tmp_path):
    """Seed 23, frame 4 (sharp lobes, alpha 0.031, at 15.5 mm): the left guide's clipped top is
    ``merged`` (its isophote encloses texture on the sheen), and the joint plane fitted to its
    region put both guides' rows inside the bright region but 20 to 25 px from the tops, each
    ``ok`` with that plane's normal; refused (clipped lobes clip about each guide's specular
    point), both guides kept the BP ray. The two tops are a stereo pair whose baseline is the
    guides': one row per top at its centroid, with the plane they fix (``rig_pair``, rule 0, 0.11
    deg off), its stated sigma covering its error. Since a fit that is not converged keeps its
    projection, the joint fit's fallback to the darkest channel runs and finds the plane (0.07 deg
    off, rows at the tops): either way one row per top within the bound and its sigma."""
    img, cam, n, truth = _frame(23, 4)
    for uv, d, s in _nearest_rows(_reconstructed(tmp_path, img, cam), truth):
        assert d <= MATCH_PX and s["status"] == "ok", (uv, d, s["status"])
        assert s["normal_from"] in ("rig_pair", "photometric_fit"), s["normal_from"]
        # the must-hold's bound, and within twice the stated 1-sigma (the recommendation's margin)
        assert _error_deg(s, n) <= min(MEDIAN_MAX_DEG, 2.0 * s["normal_sigma_deg"]), (_error_deg(s, n), s["normal_sigma_deg"])


def _two_clipped_tops():
    """Two guides' clipped lobes (Gaussian, sigma 10 px, 4 times the clip level at their peaks)
    at the specular points of a plane (tilt 15 deg, 25 mm), joined above half their height:
    ``(image, K, rig, normal, h, specular points (2, 2))``."""
    size, f, h = 240, 300.0, 25.0
    rig = LightRig(tuple(Light((x, 0.0, 0.0), 1.0, "inverse_square", 1.0) for x in (-4.0, 4.0)))
    t, a = np.radians(15.0), np.radians(30.0)
    N = np.array([np.sin(t) * np.cos(a), np.sin(t) * np.sin(a), -np.cos(t)])
    K = np.array([[f, 0, 0], [0, f, 0], [0, 0, 1.0]])
    K[:2, 2] = size / 2 - guide_specular_points(K, rig, N, h).mean(axis=0)  # the pair about the centre
    truth = guide_specular_points(K, rig, N, h)
    v, u = np.mgrid[0:size, 0:size].astype(float)
    img = np.clip(0.3 + sum(4.0 * np.exp(-((u - p[0]) ** 2 + (v - p[1]) ** 2) / 200.0) for p in truth), 0, 1)
    return img, K, rig, N, h, truth


def _candidate(K, bp, roi, status, fit):
    """A clipped candidate at ``bp`` with its ROI (row0, row1, col0, col1) and photometric fit."""
    from simtest.reconstruct._pixels import Roi
    from simtest.reconstruct.assemble import SpecularityEstimate

    ray = np.linalg.solve(K, [bp[0], bp[1], 1.0])
    return SpecularityEstimate(np.asarray(bp, float), 1.0, True, Roi(*roi), status, "", -ray / np.linalg.norm(ray), (),
                               light_aware={"photometric_fit": fit})


def test_a_joint_fit_that_misplaces_two_clipped_tops_gives_way_to_their_pair():
    # the candidate's joint fit holds a plane three times too far, whose specular points fall at
    # the tops' inner edges: its split is refused, and the rows come from the tops, with the
    # plane they fix (rule 0)
    from simtest.reconstruct.lightaware import LightAwareEstimate
    from simtest.reconstruct.rig_lobes import split_fused_lobes

    img, K, rig, N, h, truth = _two_clipped_tops()
    lo, hi = np.floor(truth.min(axis=0)).astype(int) - 40, np.ceil(truth.max(axis=0)).astype(int) + 40
    far = LightAwareEstimate("photometric_fit", "ok", "", N, depth_mm=3 * h, normal_sigma_deg=0.1, distance_mm=3 * h)
    est = _candidate(K, truth[0], (lo[1], hi[1], lo[0], hi[0]), "merged", far)
    rows = split_fused_lobes(img, [est], K, rig, prefitted={0})
    assert len(rows) == 2, [r.detail for r in rows]
    for row, p in zip(rows, truth):
        # a clipped disc's centroid is its centre, but for the other lobe's tail, which lifts the
        # top's inner edge out past the clip (here by about a tenth of a pixel: 0.10 px); a
        # quarter of a pixel bounds it
        assert np.linalg.norm(row.bp_px - p) < 0.25, (row.bp_px, p)
        rec = row.recommended
        assert rec.normal_from == "rig_pair"
        # the centroids within a quarter of a pixel: the plane within a few hundredths of a
        # degree (its stated sigma, a pixel per axis, is several times that)
        assert np.degrees(np.arccos(min(1.0, float(rec.normal @ N)))) < min(0.05, rec.normal_sigma_deg)
        # each top's depth along its ray: the plane met there (each centroid within 0.25 px of a
        # 50 px separation: within 1 %)
        r = np.linalg.solve(K, [p[0], p[1], 1.0])
        depth = np.linalg.norm(r * (-h / float(N @ r)))
        assert abs(row.light_aware["rig_pair"].depth_mm / depth - 1.0) < 1e-2


def test_large_clipped_tops_keep_the_joint_fit_that_places_their_specular_points(tmp_path):
    # broad lobes (Phong n 40) clipped white over pale pink tissue at 13 mm, the plane 33 deg off the
    # axis (tests/phong_frames.py, 480 x 400, f 180): each top's centroid lies 5 to 6 px from its
    # specular point (the falloff and the perspective skew a large top), beyond PAIR_TOL_PX. The joint
    # fit's points lie deep in each top, at the specular points: its split stands (0.03 deg), where
    # the tops' centroids gave the pair's plane 1.2 deg off and rows 5 to 6 px off
    from phong_frames import nearest_row, phong_frame, reconstruct_frame

    normal = np.array([0.4305, 0.3351, -0.8381])
    normal /= np.linalg.norm(normal)
    ax = np.arctan2(4.222, -2.678)
    guides = 5.0 * np.array([[np.cos(ax), np.sin(ax), 0.0], [-np.cos(ax), -np.sin(ax), 0.0]])
    img, K, truth = phong_frame(480, 400, 180.0, guides, normal, 13.3, 40.0, 8.0, (0.85, 0.5, 0.45), 0.36, 0.01, 2)
    specs = reconstruct_frame(tmp_path, img, K, guides)
    for uv in truth:
        d, s = nearest_row(specs, uv)
        # the joint fit's specular points to a fraction of a pixel (0.12 px here; the clip and 1 % noise)
        assert d < 0.5 and s["status"] == "ok" and s["normal_from"] == "photometric_fit", (uv, d, s["detail"])
        assert np.degrees(np.arccos(min(1.0, abs(float(np.dot(s["normal"], normal)))))) < 0.1


def test_a_split_replaces_an_ok_row_that_has_only_the_bp_ray():
    # second generator, seed 103 frame 1, in exact geometry: one top is an ok candidate (a small
    # ROI about its own lobe) whose fit misfits, so its row has the BP ray; the other is a
    # rejected candidate (not_elliptical) whose ROI holds both tops and whose joint fit places
    # both guides' points at their centres. The split's rows replace the BP ray's row: one row
    # per highlight, each with the fit's normal
    from simtest.reconstruct.lightaware import LightAwareEstimate
    from simtest.reconstruct.rig_lobes import split_fused_lobes

    img, K, rig, N, h, truth = _two_clipped_tops()
    lo, hi = np.floor(truth.min(axis=0)).astype(int) - 40, np.ceil(truth.max(axis=0)).astype(int) + 40
    fits = LightAwareEstimate("photometric_fit", "ok", "", N, depth_mm=h, normal_sigma_deg=0.1, distance_mm=h)
    misfit = LightAwareEstimate("photometric_fit", "plane_misfit", "", N, normal_sigma_deg=5.0)
    (u, v), r = np.rint(truth[1]).astype(int), 20
    own = _candidate(K, truth[1], (v - r, v + r + 1, u - r, u + r + 1), "ok", misfit)
    both = _candidate(K, truth[0], (lo[1], hi[1], lo[0], hi[0]), "not_elliptical", fits)
    assert own.recommended.normal_from == "bp_ray"
    rows = split_fused_lobes(img, [own, both], K, rig, prefitted={1})
    assert len(rows) == 2, [(r.bp_px, r.status, r.detail[:40]) for r in rows]
    for row, p in zip(sorted(rows, key=lambda r: r.bp_px[0]), truth[np.argsort(truth[:, 0])]):
        assert np.linalg.norm(row.bp_px - p) < 1e-6 and row.recommended.normal_from == "photometric_fit"


def _clipped_and_unclipped_lobes():
    """One guide's clipped lobe (Gaussian, sigma 10 px, 4 times the clip level) and the other's
    unclipped one (0.55 of the clip level, as a guide farther from a tilted patch gives), at the
    specular points of a plane (tilt 15 deg, 25 mm), joined above half the clipped one's height:
    ``(image, K, rig, normal, h, specular points (2, 2))``."""
    img, K, rig, N, h, truth = _two_clipped_tops()
    v, u = np.mgrid[0:img.shape[0], 0:img.shape[1]].astype(float)
    lobe = [np.exp(-((u - p[0]) ** 2 + (v - p[1]) ** 2) / 392.0) for p in truth]  # sigma 14 px
    return np.clip(0.3 + 4.0 * lobe[0] + 0.55 * lobe[1], 0, 1), K, rig, N, h, truth


def test_an_unclipped_lobe_fused_to_a_clipped_one_gets_its_row():
    # a tilted patch lights its two guides' lobes unequally: the weaker one stays below the clip
    # (here its peak at 0.86 of it) on the shoulder of the clipped one, so its specular point lies
    # 20 px off the clipped top. The joint fit that places both is split into both rows (before,
    # a point off the tops refused the split: the weaker guide's highlight had no row)
    from simtest.reconstruct.lightaware import LightAwareEstimate
    from simtest.reconstruct.rig_lobes import split_fused_lobes

    img, K, rig, N, h, truth = _clipped_and_unclipped_lobes()
    assert img[tuple(np.rint(truth[1, ::-1]).astype(int))] < 0.9  # the second lobe is not clipped
    lo, hi = np.floor(truth.min(axis=0)).astype(int) - 40, np.ceil(truth.max(axis=0)).astype(int) + 40
    fit = LightAwareEstimate("photometric_fit", "ok", "", N, depth_mm=h, normal_sigma_deg=0.1, distance_mm=h)
    rows = split_fused_lobes(img, [_candidate(K, truth[0], (lo[1], hi[1], lo[0], hi[0]), "ok", fit)], K, rig)
    assert len(rows) == 2, [r.detail for r in rows]
    for row, p in zip(rows, truth):
        assert np.linalg.norm(row.bp_px - p) < 1e-6 and row.recommended.normal_from == "photometric_fit"


def test_a_joint_fit_with_no_point_on_the_clipped_top_is_not_split():
    # a small clipped lobe (sigma 6 px) and a faint one on a broad sheen that joins them above half
    # the BP's height; a fit whose plane (the true one turned by 4 deg about the image's horizontal)
    # puts both guides' points 22 px up, inside the bright region but off the clipped top, fitted
    # something else: the candidate keeps its one row
    from simtest.geometry.angles import unit
    from simtest.reconstruct._pixels import uv_to_rc
    from simtest.reconstruct.lightaware import LightAwareEstimate
    from simtest.reconstruct.rig_lobes import (
        _bright_region,
        _inside,
        _tops,
        split_fused_lobes,
    )

    _, K, rig, N, h, truth = _two_clipped_tops()
    v, u = np.mgrid[0:240, 0:240].astype(float)
    d2 = [(u - p[0]) ** 2 + (v - p[1]) ** 2 for p in (*truth, truth.mean(axis=0))]
    img = np.clip(0.3 + 4.0 * np.exp(-d2[0] / 72.0) + 0.08 * np.exp(-d2[1] / 72.0) + 0.65 * np.exp(-d2[2] / 5000.0), 0, 1)
    c, s_ = np.cos(np.radians(4.0)), np.sin(np.radians(4.0))
    turned = unit(np.array([[1.0, 0.0, 0.0], [0.0, c, -s_], [0.0, s_, c]]) @ N)
    fit = LightAwareEstimate("photometric_fit", "ok", "", turned, depth_mm=h, normal_sigma_deg=0.1, distance_mm=h)
    lo, hi = np.floor(truth.min(axis=0)).astype(int) - 40, np.ceil(truth.max(axis=0)).astype(int) + 40
    est = _candidate(K, truth[0], (lo[1], hi[1], lo[0], hi[0]), "ok", fit)
    pts = guide_specular_points(K, rig, turned, h)
    region = _bright_region(img, est)
    tops = np.argwhere(_tops(img, region)) + region[1:]
    gap = [np.linalg.norm(tops - uv_to_rc(p), axis=1).min() for p in pts]
    assert _inside(region, pts).all() and min(gap) > 2.0, (pts - truth, gap)  # the case: in the region, off the top
    rows = split_fused_lobes(img, [est], K, rig)
    assert len(rows) == 1 and rows[0] is est, [(r.bp_px, r.detail) for r in rows]


def _plane_under_guides(seed: int, guides, dist_mm: float, tilt_deg: float, azimuth_deg: float, exponent: float,
                        ks: float, scale: float = 1.0):
    """A frame (960 x 720, f 520 px; all three times ``scale``) of a plane ``dist_mm`` away along the optical axis, tilted
    ``tilt_deg`` towards ``azimuth_deg``: normalised Blinn-Phong lobes (``exponent``, specular albedo
    ``ks``) and Lambertian tissue under the guides (J, 3) mm (cos profile, inverse square), exposed
    so that the shading's median is 0.35, shot-like noise of 1 %, sRGB, 8 bits: ``(frame, camera
    file, normal, true highlights (J, 2))``. A sensor model of our own, not simtest's renderer."""
    W, H, f = round(960 * scale), round(720 * scale), 520.0 * scale
    K = np.array([[f, 0, (W - 1) / 2], [0, f, (H - 1) / 2], [0, 0, 1.0]])
    t, a = np.radians(tilt_deg), np.radians(azimuth_deg)
    n = np.array([np.sin(t) * np.cos(a), np.sin(t) * np.sin(a), -np.cos(t)])
    h = dist_mm * np.cos(t)  # the plane n . X = -h
    vv, uu = np.mgrid[0:H, 0:W].astype(float)
    d = np.stack([(uu - K[0, 2]) / f, (vv - K[1, 2]) / f, np.ones_like(uu)], -1)
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    X = d * (-h / (d @ n))[..., None]
    guides = np.asarray(guides, float)
    diffuse, spec, truth = np.zeros((H, W)), np.zeros((H, W)), []
    for L in guides:
        Ld = L - X
        r = np.linalg.norm(Ld, axis=-1)
        Ld /= r[..., None]
        E = np.maximum((X[..., 2] - L[2]) / r, 0.0) / r**2
        half = Ld - d
        half /= np.linalg.norm(half, axis=-1, keepdims=True)
        diffuse += E * np.maximum(Ld @ n, 0.0)
        spec += E * np.maximum(half @ n, 0.0) ** exponent
        Lm = L - 2 * (n @ L + h) * n
        Xs = Lm * (h / -(n @ Lm))
        truth.append((K @ Xs)[:2] / Xs[2])
    lin = (diffuse[..., None] * np.array([0.75, 0.42, 0.36]) + ks * spec[..., None] * (exponent + 8) / 8)
    lin *= 0.35 / np.median(diffuse)
    lin += 0.01 * np.random.default_rng(seed).standard_normal(lin.shape) * np.sqrt(np.clip(lin, 0, None) + 0.01)
    img = np.rint(srgb_encode(np.clip(lin, 0, 1)) * 255).astype(np.uint8)
    cam = {"model": "pinhole", "K": K.tolist(), "image_size": [W, H],
           "response": {"curve": "srgb", "clip": 255.0},
           "lights": [{"position_mm": L.tolist(), "intensity": 1.0, "falloff": "inverse_square",
                       "profile_exponent": 1.0} for L in guides]}
    return img, cam, n, np.array(truth)


def _tilted_across_the_guides(seed: int):
    """A plane 26.4 mm away tilted 28 deg across two guides' baseline (4 mm either side of the lens,
    azimuth 188 deg; exponent 253, specular albedo 0.065): the nearer guide's lobe clips, the other's
    peaks just below the ceiling on its shoulder (:func:`_plane_under_guides`)."""
    return _plane_under_guides(seed, [[-4.0, 0.0, 0.0], [4.0, 0.0, 0.0]], 26.39, 28.18, 188.24, 253.1, 0.065)


def test_a_plane_tilted_across_the_guides_gives_both_their_rows(tmp_path):
    # end to end: the weaker guide's lobe is a shoulder of the clipped one (its luma 246 to 249,
    # no peak of its own), the joint fit of the clipped candidate places both specular points;
    # before, the shoulder's point lay 2.8 px off the clipped top and only the clipped guide had
    # a row (the other's nearest candidate, too_small, 47 px away)
    img, cam, n, truth = _tilted_across_the_guides(9019)
    for uv, d, s in _nearest_rows(_reconstructed(tmp_path, img, cam), truth):
        assert d <= MATCH_PX, (uv, d, s["status"])
        assert s["normal_from"] == "photometric_fit" and _error_deg(s, n) <= MEDIAN_MAX_DEG, (s["status"], s["normal_from"])


#: Three guides about the lens (4 mm off it, a triangle as on some colonoscopes).
_THREE_GUIDES = [[3.24, 0.55, 0.0], [-2.77, 2.66, 0.0], [-1.27, -3.14, 0.0]]


@pytest.mark.parametrize("seed, geometry, was", [
    # two of the three lobes clip and fuse: one candidate, "merged: 2 saturated plateaus"
    (9020, (22.64, 20.71, 253.02, 420.2, 0.062), "merged"),
    # unclipped lobes whose isophotes at t = 0.7 enclose one another's BPs (640 x 480, f 347 px: the same
    # angles, a third of the fits' cost): each "merged" until the other guides' lobes, where the rig puts
    # them, stopped counting as merges; now "ok", and split for the other guides' rows
    (9021, (18.43, 10.45, 199.92, 319.4, 0.0631, 2 / 3), "ok"),
])
def test_three_guides_lobes_fused_into_one_give_every_guide_its_row(tmp_path, seed, geometry, was):
    # the tops of three lobes make a triangle, not a line: a test of stretch along the rig's curve,
    # which tells two guides' fused lobes from one lobe, refused them (no fit, every row the BP ray)
    img, cam, n, truth = _plane_under_guides(seed, _THREE_GUIDES, *geometry)
    specs = _reconstructed(tmp_path, img, cam)
    for uv, d, s in _nearest_rows(specs, truth):
        assert d <= MATCH_PX, (uv, d, s["status"])
        assert s["normal_from"] == "photometric_fit" and _error_deg(s, n) <= MEDIAN_MAX_DEG, (s["status"], s["detail"])
        assert f"of 3 fused into one highlight ({was}" in s["detail"], s["detail"]


def test_broad_weak_lobes_of_the_papers_roughness_get_light_aware_normals(tmp_path):
    # two guides 4 mm either side, a plane 17.4 mm away tilted 12.7 deg, exponent 200, specular
    # albedo 0.068: each guide's lobe is a broad sheen whose peak is tissue-tinted (255, 231, 222)
    img, cam, n, truth = _plane_under_guides(9022, [[-4.0, 0.0, 0.0], [4.0, 0.0, 0.0]], 17.41, 12.69, 146.09,
                                             200.0, 0.0682)
    # until each lobe was searched again on a 3 times wider background square (BROAD_LOBE_SCALE), the
    # 72 px square's opening held the lobe: its colour read pale against its own shoulders (not_specular)
    rows = list(_nearest_rows(_reconstructed(tmp_path, img, cam), truth))
    assert len({id(s) for _, _, s in rows}) == len(truth)  # a row per guide
    for uv, d, s in rows:
        # a broad lobe's brightest point lies off its specular point: the diffuse shading's slope
        # moves the top of a wide lobe by several px (here 5.9), within the harness's match radius
        assert d <= HARNESS_MATCH_PX, (uv, d, s["status"])
        assert s["normal_from"] == "photometric_fit" and _error_deg(s, n) <= MEDIAN_MAX_DEG, (s["status"], s["detail"])


@settings(max_examples=60, deadline=None)
@given(pts=st.lists(st.tuples(st.sampled_from([np.nan, np.inf, -3.6, -0.5, 0.0, 0.49, 0.5, 2.5, 7.49, 7.5, 11.2]),
                              st.sampled_from([np.nan, -1.0, 0.0, 3.5, 4.49, 5.5, 6.0, 9.7])), max_size=12),
       origin=st.tuples(st.integers(-3, 3), st.integers(-3, 3)))
def test_the_roi_index_is_each_points_rounded_pixel_on_the_array(pts, origin):
    # exact, point by point: a finite point's pixel is its (v, u) rounded half to even, less the ROI's
    # (row, col) origin; it counts where that pixel lies on the (6, 8) array, a non-finite point never
    rc, ok = _roi_index(np.array(pts, np.float64).reshape(-1, 2), (6, 8), origin)
    assert rc.shape == (len(pts), 2) and ok.shape == (len(pts),)
    for (u, v), got, inside in zip(pts, rc, ok):
        finite = np.isfinite(u) and np.isfinite(v)
        want = (int(np.rint(v)) - origin[0], int(np.rint(u)) - origin[1]) if finite else None
        assert inside == (finite and 0 <= want[0] < 6 and 0 <= want[1] < 8)
        if inside:
            assert tuple(got) == want


def test_clipped_noise_pixels_beside_one_fused_top_leave_the_joint_fits_split():
    # both guides' lobes clip into one top (Gaussian, sigma 20 px, 4 times the clip level, 50 px
    # apart); the sensor's noise clips a single pixel of a lobe's tail beyond it, on the guides'
    # line. A one-pixel top is no guide's specular point: the pair of tops is not that pixel and
    # the fused top, and the joint fit, which places both points on the fused top, gives the rows
    # (outside generator, seed 777 frame 43: the split was refused for such a pixel)
    from simtest.reconstruct.lightaware import LightAwareEstimate
    from simtest.reconstruct.rig_lobes import split_fused_lobes

    img, K, rig, N, h, truth = _two_clipped_tops()
    v, u = np.mgrid[0:img.shape[0], 0:img.shape[1]].astype(float)
    img = np.clip(0.3 + sum(4.0 * np.exp(-((u - p[0]) ** 2 + (v - p[1]) ** 2) / 800.0) for p in truth), 0, 1)
    out = truth[1] + 40.0 * (truth[1] - truth[0]) / np.linalg.norm(truth[1] - truth[0])  # in the tail, not clipped
    r, c = np.rint(out[::-1]).astype(int)
    assert 0.65 < img[r, c] < 0.99  # above the region's half height, below the clip
    img[r, c] = 1.0
    lo, hi = np.floor(truth.min(axis=0)).astype(int) - 60, np.ceil(truth.max(axis=0)).astype(int) + 60
    fit = LightAwareEstimate("photometric_fit", "ok", "", N, depth_mm=h, normal_sigma_deg=0.1, distance_mm=h)
    est = _candidate(K, truth.mean(axis=0), (lo[1], hi[1], lo[0], hi[0]), "merged", fit)
    rows = split_fused_lobes(img, [est], K, rig, prefitted={0})
    assert len(rows) == 2, [r.detail for r in rows]
    for row, p in zip(rows, truth):
        # the rows at the joint fit's specular points, with its normal
        assert np.linalg.norm(row.bp_px - p) < 1e-6 and row.recommended.normal_from == "photometric_fit", row.detail


def _unclipped_lobes(seed: int, lobes: int):
    """``lobes`` (1 or 2) Gaussian guide lobes (sigma 17 px, 0.6 above a 0.3 background, unclipped) at
    the specular points of :func:`_two_clipped_tops`' plane, white noise of 0.01, and a candidate at
    the first whose joint fit holds the normal but not the distance: ``(image, K, rig, candidate,
    specular points)``."""
    import dataclasses

    from simtest.reconstruct.lightaware import LightAwareEstimate

    _, K, rig, N, h, truth = _two_clipped_tops()
    v, u = np.mgrid[0:240, 0:240].astype(float)
    img = 0.3 + sum(0.6 * np.exp(-((u - p[0]) ** 2 + (v - p[1]) ** 2) / 578.0) for p in truth[:lobes])
    img = img + np.random.default_rng(seed).normal(0.0, 0.01, img.shape)
    lo, hi = np.floor(truth.min(axis=0)).astype(int) - 45, np.ceil(truth.max(axis=0)).astype(int) + 45
    fit = LightAwareEstimate("photometric_fit", "depth_not_observable", "", N, normal_sigma_deg=0.3)
    est = _candidate(K, truth[0], (lo[1], hi[1], lo[0], hi[0]), "merged", fit)
    return img, K, rig, dataclasses.replace(est, saturated=False, bp_intensity=float(img.max())), truth


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_unclipped_fused_lobes_whose_fit_has_no_depth_are_placed_on_their_peaks(seed):
    # two guides' unclipped lobes 50 px apart fused above half their height (the valley between
    # them 0.19 below the peaks, 48 sigmas of its noise): the joint fit holds the normal only, and the
    # distance that puts one guide's specular point on each peak gives both rows (the read-noise
    # and JPEG frames of the endoscope suite's flat mucosa, whose second guide went undetected)
    from simtest.reconstruct.rig_lobes import split_fused_lobes

    img, K, rig, est, truth = _unclipped_lobes(seed, 2)
    rows = split_fused_lobes(img, [est], K, rig, prefitted={0})
    assert len(rows) == 2, [r.detail for r in rows]
    for row, p in zip(rows, truth):
        # each peak 0.7 px inward (the other lobe's slope) and to a pixel (the noise): the pair
        # placed within PAIR_TOL_PX of them
        assert np.linalg.norm(row.bp_px - p) < 2.0 and row.status == "ok", (row.bp_px, p)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_one_unclipped_lobe_whose_fit_has_no_depth_is_not_split(seed):
    # one lobe only: its noise gives local maxima but no valley of SIGNIFICANCE_MIN sigmas between
    # two of them, so no distance is chosen and the candidate stays one row
    from simtest.reconstruct.rig_lobes import split_fused_lobes

    img, K, rig, est, _ = _unclipped_lobes(seed, 1)
    rows = split_fused_lobes(img, [est], K, rig, prefitted={0})
    assert len(rows) == 1 and rows[0].status == "merged", [r.detail for r in rows]


def test_lobes_fused_above_a_noisy_clip_get_both_guides_rows(tmp_path):
    # tuning frame (CODED_NOISE, root 5, frame 54): two Cook-Torrance lobes 60 px apart fused into one clipped top,
    # the noise (1.8 %) added to the 8-bit codes after the clip. Their sum peaks between the specular points, so the
    # top is no longer along the rig's curve than across (78 x 58 px) and the luma cannot dip between them: it lies
    # on the clip there. Every merged piece's joint plane fit put both guides' points within 0.6 px of the truth, and
    # the dip rule refused them all (too_small twice); the clipped middle now stands for the dip
    # The noise leaves 8 maxima on the top, each a merged candidate; one joint fit of the top is enough (they all
    # gave the same normal to 1e-4): the first fits alone, 24 -> 4 s for the frame.
    fits, fit = [], light_fits.light_aware_estimates
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(light_fits, "light_aware_estimates", lambda *a, **k: fits.append(a[1].bp_px) or fit(*a, **k))
        _, rows = bench_frame_rows(tmp_path, 5, 54, sensor_like.CODED_NOISE)
    assert all(s == "ok" and e is not None and e <= MEDIAN_MAX_DEG for s, e in rows), rows
    assert len(fits) == 1, fits


def test_the_other_pieces_of_a_noisy_clipped_top_are_fitted_where_the_first_fails(tmp_path):
    # the same frame, every fit failing (not_converged, no solve run): the top's first piece fitted, then each
    # other piece in turn, as before a top's pieces were told apart; none gets a row of its own from a failed fit
    fits = []

    def failing(image, est, *a, **k):
        fits.append(tuple(est.bp_px))
        return {"photometric_fit": LightAwareEstimate("photometric_fit", "not_converged", "test", None)}

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(light_fits, "light_aware_estimates", failing)
        _, rows = bench_frame_rows(tmp_path, 5, 54, sensor_like.CODED_NOISE)
    assert len(fits) == len(set(fits)) == 8, fits
    assert all(e is None for _, e in rows), rows
