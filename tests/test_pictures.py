"""Pictures: the overlay (legend, one colour per estimator, hundreds of highlights), the 3D view
rendered off-screen, and reconstruct's outputs as a set with its bad-input refusals."""

from __future__ import annotations

import copy
import json
import os
from collections import Counter

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from typer.testing import CliRunner

from simtest.cli import app
from simtest.geometry import PinholeCamera, save_camera
from simtest.reconstruct import reconstruct
from simtest.reconstruct import overlay as overlay_mod
from simtest.reconstruct.io import estimate_to_dict
from simtest.reconstruct.overlay import draw_overlay, estimator_colour, needle_length_px
from simtest.reconstruct.view3d import render_view
from _quadrics import phong_sphere_image
from simtest.simulate.analytic import phong_plane_image

runner = CliRunner()


def many_highlights(n=300, shape=(1080, 1350), seed=7):
    """A frame with n small elliptical Gaussian highlights on a mid-grey background (8-bit)."""
    rng = np.random.default_rng(seed)
    H, W = shape
    img = np.full(shape, 0.25)
    vv, uu = np.mgrid[0:H, 0:W]
    centres = []
    while len(centres) < n:
        c = rng.uniform([20, 20], [W - 20, H - 20])
        if all(np.hypot(*(c - d)) > 25 for d in centres):
            centres.append(c)
    for c in centres:
        a, b, th = rng.uniform(2.5, 5.0), rng.uniform(1.5, 2.5), rng.uniform(0, np.pi)
        r0, r1, c0, c1 = int(c[1]) - 15, int(c[1]) + 16, int(c[0]) - 15, int(c[0]) + 16
        x, y = uu[r0:r1, c0:c1] - c[0], vv[r0:r1, c0:c1] - c[1]
        xr, yr = np.cos(th) * x + np.sin(th) * y, -np.sin(th) * x + np.cos(th) * y
        img[r0:r1, c0:c1] += 0.75 * np.exp(-0.5 * ((xr / a) ** 2 + (yr / b) ** 2))
    return np.round(np.clip(img, 0, 1) * 255).astype(np.uint8), np.array(centres)


def colour_mask(png, hexcol, tol=40):
    """The pixels of a BGR picture within ``tol`` of ``hexcol`` in every channel."""
    rgb = np.array([int(hexcol[i:i + 2], 16) for i in (1, 3, 5)])
    return np.abs(png[:, :, ::-1].astype(int) - rgb).max(axis=2) <= tol


def colour_pixels(png, hexcol, tol=40):
    return int(np.count_nonzero(colour_mask(png, hexcol, tol)))


def test_overlay_on_a_crowded_real_size_frame(tmp_path):
    img, centres = many_highlights()
    # a scope's wide lens (f 300 px, 132 deg across): the highlights, 25 px apart or more, lie further apart
    # than a glint field's GLINT_FIELD_DEG (21 px here), so each is judged alone
    K = np.array([[300.0, 0, 674.5], [0, 300, 539.5], [0, 0, 1]])
    ests = reconstruct(img, K, [0.3, 0.6])
    ok = [e for e in ests if e.ok]
    assert len(ok) >= 200  # hundreds of highlights drawn
    path = draw_overlay(tmp_path / "overlay.png", img, ests, K, estimators="all")
    png = cv2.imread(str(path))
    assert png.shape[:2] == (1080, 1350)  # the frame's own pixel size
    for name in ("cone_axis", "joint_cone_axis", "paper_selected", "bp_ray"):
        # each estimator visible in its colour (the cone axis and the joint axis coincide here to
        # <0.01 deg: the wider one underneath shows as a rim around the other)
        assert colour_pixels(png, estimator_colour(name)) > 300, name
    # needles shorter than the spacing of the highlights allows, longer than a few pixels
    L = needle_length_px(np.array([e.bp_px for e in ok]), img.shape)
    assert 0.03 * 1350 <= L < 60


@settings(max_examples=60, deadline=None)
@given(st.integers(2, 400), st.integers(0, 2**32 - 1), st.booleans())
def test_the_needle_is_one_and_a_half_nearest_spacings_clipped(n, seed, twins):
    # exact: 1.5 times the median distance from a BP to its nearest other BP (every pair measured), within 3 and
    # 12 % of the larger side; BPs on one spot (twins) are 0 apart. 1e-3 px: float32 distances of coordinates
    # below 2000 px (OpenCV's matcher) err by about 1e-4 px
    rng = np.random.default_rng(seed)
    shape = (1080, 1350, 3)
    bps = rng.uniform(0.0, 1349.0, (n, 2)) * rng.uniform(0.01, 1.0)
    if twins:
        bps[1] = bps[0]
    d = np.hypot(*(bps[:, None, :] - bps[None, :, :]).transpose(2, 0, 1))
    np.fill_diagonal(d, np.inf)
    expect = float(np.clip(1.5 * np.median(d.min(axis=1)), 0.03 * 1350, 0.12 * 1350))
    assert needle_length_px(bps, shape) == pytest.approx(expect, abs=1e-3)


def test_overlay_draws_only_ok_estimates_by_default(tmp_path):
    K = np.array([[300.0, 0, 119.5], [0, 300, 119.5], [0, 0, 1]])
    t = np.radians(12)
    img = phong_plane_image(K, (240, 240), [np.sin(t), 0, -np.cos(t)], 500.0, 60)
    img[0:4, 200:204] = 1.0  # an extra highlight on the border: rejected (touches_border)
    ests = reconstruct(img, K, [0.2, 0.4])
    assert any(not e.ok for e in ests) and any(e.ok for e in ests)
    red = estimator_colour("cone_axis")
    a = cv2.imread(str(draw_overlay(tmp_path / "a.png", img, ests, K, estimators="all")))
    b = cv2.imread(str(draw_overlay(tmp_path / "b.png", img, ests, K, estimators="all", show_rejected=True)))
    crop = (slice(0, 40), slice(560, 640))  # around the rejected BP (201.5, 1.5), drawn 700/240 larger
    assert colour_pixels(b[crop], "#ff0000", tol=60) > colour_pixels(a[crop], "#ff0000", tol=60)
    assert colour_pixels(a, red) > 0


def test_by_default_the_overlay_draws_what_the_command_gives_and_names_the_rest(tmp_path, monkeypatch):
    # through the command: the recommended normal and the estimators it came from are drawn; the estimators
    # it did not come from are named in the legend, not drawn, unless asked for
    png, cam = _scene(tmp_path)
    legends, runs = [], {}
    draw_legend = overlay_mod._legend
    monkeypatch.setattr(overlay_mod, "_legend", lambda c, t, e, **kw: (legends.append(e), draw_legend(c, t, e, **kw)))
    for key, extra in (("default", []), ("all", ["--overlay-estimators", "all"]),
                       ("paper", ["--overlay-estimators", "normal", "--overlay-estimators", "paper_selected"])):
        out = tmp_path / key
        assert runner.invoke(app, ["reconstruct", str(png), "-k", str(cam), "-o", str(out), *extra]).exit_code == 0
        runs[key] = cv2.imread(str(out / "overlay.png"))
    doc = json.loads((tmp_path / "default" / "estimates.json").read_text())
    sources = {s["normal_from"] for s in doc["specularities"] if s["status"] == "ok"}
    others = [n for n in ("cone_axis", "joint_cone_axis", "paper_selected", "bp_ray") if n not in sources]
    assert sources and others  # (the scene gives both kinds)
    for name in others:  # (a needle is tens of pixels of its colour; a stray anti-aliased pixel is not)
        assert colour_pixels(runs["default"], estimator_colour(name)) == 0, name
        assert colour_pixels(runs["all"], estimator_colour(name)) > 20, name
    assert colour_pixels(runs["default"], estimator_colour("normal")) > 20
    assert colour_pixels(runs["paper"], estimator_colour("paper_selected")) > 20
    labels = [label for label, *_ in legends[0]]
    assert f"not drawn: {', '.join(others)}" in labels
    assert not any(label.startswith("not drawn") for label, *_ in legends[1])


def test_the_recommended_normal_is_drawn_over_the_other_needles(tmp_path, monkeypatch):
    # the normal a user gets is drawn last (a cyan core outlined in black) over the estimators drawn under it,
    # whether they agree with it or not; the legend names every source with its count
    K = np.array([[300.0, 0, 119.5], [0, 300, 119.5], [0, 0, 1]])
    t = np.radians(12)
    img = phong_plane_image(K, (240, 240), [np.sin(t), 0, -np.cos(t)], 500.0, 60)
    ok = [e for e in reconstruct(img, K, [0.2, 0.4]) if e.ok]
    assert ok and all(e.recommended.normal_from in overlay_mod.DRAWABLE_ESTIMATORS for e in ok)
    legends = []
    monkeypatch.setattr(overlay_mod, "_legend", lambda canvas, title, entries, **_: legends.append(entries))
    png = cv2.imread(str(draw_overlay(tmp_path / "a.png", img, ok, K)))
    cyan = colour_pixels(png, estimator_colour("normal"), tol=30)
    one = cv2.imread(str(draw_overlay(tmp_path / "b.png", img, ok, K, estimators=["normal"])))
    # as many of its pixels show as where it is drawn alone: nothing is drawn over it but the BPs' dots (10 %
    # allows for the anti-aliased edges over other colours), and its colour is the one at the middle of each
    # of its needles, where the estimators under it that agree with it are drawn too
    assert cyan >= 0.9 * colour_pixels(one, estimator_colour("normal"), tol=30) > 0
    length, scale = needle_length_px(np.array([e.bp_px for e in ok]), img.shape), 700 / 240
    for e in ok:
        u, v = (np.asarray(e.bp_px) + 0.5 * length * np.asarray(e.recommended.normal)[:2] + 0.5) * scale - 0.5
        assert colour_pixels(png[int(round(v)):int(round(v)) + 1, int(round(u)):int(round(u)) + 1],
                             estimator_colour("normal"), tol=40) == 1, e.bp_px
    label = next(lab for lab, _, kind in legends[0] if lab.startswith("normal"))
    whence = sorted(Counter(e.recommended.normal_from for e in ok).items(), key=lambda kv: (-kv[1], kv[0]))
    assert label == "normal (recommended: " + ", ".join(f"{k} {v}" for k, v in whence) + ")"


def test_overlay_too_large_for_memory_is_refused_before_anything_is_written(tmp_path, monkeypatch):
    with pytest.raises(ValueError, match="20000 x 20000 px image .* over the 64 Mpx"):
        overlay_mod.check_overlay_size((20000, 20000))
    monkeypatch.setattr(overlay_mod, "_available_memory_bytes", lambda: 10**6)
    with pytest.raises(ValueError, match="GiB are free"):
        overlay_mod.check_overlay_size((1080, 1350))
    # through the CLI: nothing is written
    png, cam = _scene(tmp_path)
    out = tmp_path / "out"
    res = runner.invoke(app, ["reconstruct", str(png), "--intrinsics", str(cam), "--out", str(out)])
    assert res.exit_code == 2 and "use --no-overlay" in res.output and not out.exists()


def _scene(tmp_path):
    K = np.array([[300.0, 0, 119.5], [0, 300, 119.5], [0, 0, 1]])
    t = np.radians(12)
    img = phong_plane_image(K, (240, 240), [np.sin(t), 0, -np.cos(t)], 500.0, 60)
    png = tmp_path / "plane.png"
    cv2.imwrite(str(png), np.round(img * 60000).astype(np.uint16))
    return png, save_camera(tmp_path / "cam.json", PinholeCamera(K, None, (240, 240)))


def test_reconstruct_outputs_are_replaced_as_a_set(tmp_path, monkeypatch):
    png, cam = _scene(tmp_path)
    out = tmp_path / "out"
    assert runner.invoke(app, ["reconstruct", str(png), "-k", str(cam), "-o", str(out), "-t", "0.2"]).exit_code == 0
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    assert set(before) == {"estimates.json", "overlay.png"}

    def full_disk(*args, **kwargs):
        raise OSError(28, "No space left on device")

    import simtest.reconstruct.cli as recon_cli  # the module whose name the command calls

    monkeypatch.setattr(recon_cli, "draw_overlay", full_disk)
    res = runner.invoke(app, ["reconstruct", str(png), "-k", str(cam), "-o", str(out), "-t", "0.4"])
    assert res.exit_code == 4 and "No space left on device" in res.output  # CANNOT_WRITE
    # the new estimates (t = 0.4) were not put beside the old overlay: the old set is intact
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before


@pytest.mark.parametrize(
    ("args", "msg"),
    [(["--smooth", "1e6"], "error: --smooth: must be finite and in [0, 100] px, got 1000000.0"),
     (["--smooth", "nan"], "error: --smooth: must be finite and in [0, 100] px, got nan"),
     (["-t", "0.3", "-t", "0.3"], "error: --isovalue: 0.3 is given twice"),
     (["-t", "1.5"], "error: --isovalue: 1.5 is outside the open interval (0, 1)"),
     (["--normalise", "peak"], "error: --normalise: 'peak' is not one of"),
     (["--detection", "blob"], "error: --detection: 'blob' is not one of"),
     (["--overlay-estimators", "cone"], "Invalid value for '--overlay-estimators': 'cone' is not one of 'all', ")],
)
def test_reconstruct_refuses_bad_options_in_one_line(tmp_path, args, msg):
    # the line names the option the user typed, not the setting's field behind it
    png, cam = _scene(tmp_path)
    out = tmp_path / "out"
    res = runner.invoke(app, ["reconstruct", str(png), "-k", str(cam), "-o", str(out), *args])
    assert res.exit_code == 2 and msg in res.output and len(res.output.strip().splitlines()) == 1
    assert not out.exists()


def test_3d_view_renders_off_screen_without_a_display(tmp_path, monkeypatch):
    """The headless path CI takes: no DISPLAY, pyvista off-screen (VTK falls back to EGL/OSMesa)."""
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    K = np.array([[180.0, 0, 79.5], [0, 180, 79.5], [0, 0, 1]])
    cam = PinholeCamera(K, None, (160, 160))
    centre, radius = np.array([3.0, -2.0, 60.0]), 20.0
    img = phong_sphere_image(K, (160, 160), centre, radius, 30)
    ests = reconstruct(img, cam, [0.3, 0.6])
    est_path = tmp_path / "out"
    # the estimates file, then `simtest view` with the ground-truth surface of a render-like npz
    from simtest.reconstruct.io import write_estimates

    write_estimates(est_path / "estimates.json", ests, K=K, camera=cam, isovalues=[0.3, 0.6])
    # and an ok highlight without a BP ray (no disc: the truth panel's discs stay those of the others)
    doc = json.loads((est_path / "estimates.json").read_text())
    doc["specularities"].append(copy.deepcopy(doc["specularities"][0]))
    doc["specularities"][-1]["normals"]["bp_ray"] = None
    (est_path / "estimates.json").write_text(json.dumps(doc))
    vv, uu = np.mgrid[0:160, 0:160]
    d = cam.pixel_to_ray(np.stack([uu.ravel(), vv.ravel()], 1).astype(float)).reshape(160, 160, 3)
    b = d @ centre
    disc = b * b - (centre @ centre - radius**2)
    lam = np.where(disc > 0, b - np.sqrt(np.maximum(disc, 0)), np.nan)
    np.savez(tmp_path / "ground_truth.npz", depth=(d * lam[..., None])[..., 2])
    res = runner.invoke(app, ["view", str(est_path / "estimates.json"), "--out", str(tmp_path / "view.png"),
                              "--truth", str(tmp_path / "ground_truth.npz")])
    assert res.exit_code == 0, res.output
    png = cv2.imread(str(tmp_path / "view.png"))
    assert png is not None and png.shape[1] > png.shape[0]  # two panels side by side
    # the discs are drawn, in the colour of the recommended normal (schema 2's "normal")
    assert colour_pixels(png, estimator_colour("normal"), tol=80) > 30
    left, right = png[:, : png.shape[1] // 2], png[:, png.shape[1] // 2:]
    assert (right.std(axis=2) > 10).mean() > 0.05  # the shaded ground-truth surface is there
    assert left.min() < 100  # the camera centre (black) and the rays
    assert [estimate_to_dict(e)["status"] for e in ests] == ["ok"]
    # reconstruct --view writes it with the other outputs
    png_in = tmp_path / "sphere.png"
    cv2.imwrite(str(png_in), np.round(img / img.max() * 255).astype(np.uint8))
    camf = save_camera(tmp_path / "cam.json", cam)
    res = runner.invoke(app, ["reconstruct", str(png_in), "-k", str(camf), "-o", str(tmp_path / "r"), "-t", "0.3", "--view"])
    assert res.exit_code == 0, res.output
    assert sorted(p.name for p in (tmp_path / "r").iterdir()) == ["estimates.json", "overlay.png", "view.png"]
    assert json.loads((tmp_path / "r" / "estimates.json").read_text())["camera"]["model"] == "pinhole"
    assert "DISPLAY" not in os.environ


def test_every_mapped_setting_is_a_field_set_by_an_option_of_the_command():
    # the map from a refused setting to the option that set it cannot go stale: each key is a
    # ReconSettings field and each option is one that `simtest reconstruct` and `evaluate c3vd` take
    import dataclasses

    from simtest.reconstruct.cli import SETTING_OPTIONS, option_message
    from simtest.reconstruct.settings import ReconSettings, SettingError

    fields = {f.name for f in dataclasses.fields(ReconSettings)}
    assert set(SETTING_OPTIONS) <= fields
    c3vd = {"isovalues", "normalise", "smooth_sigma_px", "detection"}  # the settings evaluate c3vd takes
    for command, taken in ((["reconstruct", "--help"], set(SETTING_OPTIONS)), (["evaluate", "c3vd", "--help"], c3vd)):
        text = runner.invoke(app, command, env={"COLUMNS": "200"}).output
        assert all(SETTING_OPTIONS[name] in text for name in taken), (command, text)
    # a setting a user cannot pass keeps its field name; another error is left as it is
    assert option_message(SettingError("peak_rel", "must be in (0, 1), got 2")) == "peak_rel: must be in (0, 1), got 2"
    assert option_message(ValueError("frame.png: cannot decode")) == "frame.png: cannot decode"


def _blobs(shape, centres):
    """An 8-bit grey frame with an elliptical Gaussian highlight (axes 4 and 2.5 px) at each (u, v) of ``centres``."""
    vv, uu = np.mgrid[0:shape[0], 0:shape[1]]
    img = np.full(shape, 0.25)
    for u, v in centres:
        img += 0.75 * np.exp(-0.5 * (((uu - u) / 4.0) ** 2 + ((vv - v) / 2.5) ** 2))
    return np.round(np.clip(img, 0, 1) * 255).astype(np.uint8)


@pytest.mark.parametrize("corner", [(215.0, 20.0), (25.0, 20.0)])
def test_the_legend_goes_where_it_hides_no_highlight(tmp_path, corner):
    # a highlight under where the legend box would stand in the upper right (and, second, in the upper left
    # too): the box moves to a corner that holds none, and the highlight's BP dot shows white, not darkened to
    # a quarter under the box
    K = np.array([[300.0, 0, 119.5], [0, 300, 119.5], [0, 0, 1]])
    centres = [corner, (120.0, 120.0)] + ([(215.0, 20.0)] if corner[0] < 100 else [])
    img = _blobs((240, 240), centres)
    ok = [e for e in reconstruct(img, K, [0.3, 0.6]) if e.ok]
    assert len(ok) == len(centres)
    png = cv2.imread(str(draw_overlay(tmp_path / "o.png", img, ok, K)))
    # the box: 75 % black over the frame's grey of 64 (16 under it), in a corner, holding no BP
    # (the largest dark component: the BPs' dots have black rims)
    _, _, stats, _ = cv2.connectedComponentsWithStats((png.max(axis=2) <= 24).astype(np.uint8))
    c0, r0, bw, bh, area = stats[1 + np.argmax(stats[1:, 4])]
    r1, c1 = r0 + bh - 1, c0 + bw - 1
    assert area > 0.05 * 700 * 700
    assert (r0 < 10 or r1 > 690) and (c0 < 10 or c1 > 690)
    scale = 700 / 240
    for e in ok:
        u, v = (np.asarray(e.bp_px) + 0.5) * scale - 0.5
        assert not (r0 <= v <= r1 and c0 <= u <= c1), e.bp_px
        assert png[int(round(v)), int(round(u))].min() >= 200, e.bp_px  # its white dot, not darkened


@settings(max_examples=200, deadline=None)
@given(st.integers(50, 900), st.integers(50, 900), st.integers(10, 400), st.integers(10, 300),
       st.lists(st.tuples(st.floats(0, 900), st.floats(0, 900)), max_size=30))
def test_the_legend_corner_hides_the_fewest_points(w, h, bw, bh, pts):
    # the chosen box lies in the canvas, and no other corner's box (the same rule: 4 px in, or flush where the
    # box hardly fits) holds fewer of the points; an empty corner is chosen where there is one
    bw, bh = min(bw, w), min(bh, h)
    pts = np.array(pts, np.float64).reshape(-1, 2)
    x0, y0 = overlay_mod._legend_corner((h, w, 3), (bw, bh), pts)
    assert 0 <= x0 <= w - bw and 0 <= y0 <= h - bh

    def inside(x, y):
        return int(np.count_nonzero((pts[:, 0] >= x - 1) & (pts[:, 0] <= x + bw + 1) & (pts[:, 1] >= y - 1)
                                    & (pts[:, 1] <= y + bh + 1)))
    xs = {w - bw - 4 if w > bw + 4 else 0, 4 if w > bw + 4 else 0}
    ys = {4 if h > bh + 4 else 0, h - bh - 4 if h > bh + 4 else 0}
    assert inside(x0, y0) == min(inside(x, y) for x in xs for y in ys)


def test_the_3d_views_truth_panel_shows_the_highlights_on_a_lumens_far_wall(tmp_path):
    # a tube of radius 10 mm seen from its axis (a colon's lumen) with 12 highlights around its wall, each with the
    # wall's inward normal: from the view's oblique eye the near wall turns its back, and drawn whole it hid most of
    # the discs (6 glyph blobs of at least 20 px); drawn on the side the camera saw only, each shows its disc or
    # arrow (14 blobs here; 10 allows for glyphs that overlap or show edge-on)
    K = np.array([[120.0, 0, 79.5], [0, 120, 79.5], [0, 0, 1]])
    cam = PinholeCamera(K, None, (160, 160))
    vv, uu = np.mgrid[0:160, 0:160]
    d = cam.pixel_to_ray(np.stack([uu.ravel(), vv.ravel()], 1).astype(float)).reshape(160, 160, 3)
    d /= np.linalg.norm(d, axis=2, keepdims=True)
    wall = d * (10.0 / np.hypot(d[..., 0], d[..., 1]))[..., None]
    wall[wall[..., 2] > 60.0] = np.nan
    specs = []
    for a in np.linspace(0.0, 2 * np.pi, 12, endpoint=False):
        u, v = 79.5 + 45 * np.cos(a), 79.5 + 45 * np.sin(a)
        p, ray = wall[int(round(v)), int(round(u))], d[int(round(v)), int(round(u))]
        specs.append({"status": "ok", "bp_px": [u, v], "normal": [-p[0] / 10.0, -p[1] / 10.0, 0.0],
                      "normals": {"bp_ray": (-ray).tolist()}})
    png = cv2.imread(str(render_view(tmp_path / "v.png", specs, truth_points=wall)))
    right = png[:, png.shape[1] // 2:]
    stats = cv2.connectedComponentsWithStats(colour_mask(right, estimator_colour("normal"), 80).astype(np.uint8))[2]
    assert int((stats[1:, 4] >= 20).sum()) >= 10
