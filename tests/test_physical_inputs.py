"""Inputs checked for physical sense before any fit, corrupt media refused (issue 61): each bad
input ends ``simtest reconstruct`` with exit 2 and one line naming the file (and key, pixel or
frame), no traceback; a fit whose surface puts a light behind it is not ``ok``."""

from __future__ import annotations

import json
import os
import struct
import subprocess
import sys
import zlib
from pathlib import Path
from types import SimpleNamespace

import cv2
import numpy as np
import pytest

from simtest.geometry.lights import Light, LightRig
from simtest.reconstruct.lightaware.estimate import LightAwareEstimate, light_behind_surface
from simtest.reconstruct.recommend import recommend

K = [[300.0, 0.0, 60.0], [0.0, 300.0, 45.0], [0.0, 0.0, 1.0]]
SIMTEST = [sys.executable, "-c", "from simtest.cli import main; main()"]


def _frame() -> np.ndarray:
    """A 120 x 90 textured tissue frame with one blurred highlight (BGR, 8 bits)."""
    rng = np.random.default_rng(0)
    img = (rng.uniform(0, 1, (90, 120, 3)) * 60 + 60).astype(np.uint8)
    cv2.circle(img, (60, 45), 4, (255, 255, 255), -1)
    return cv2.GaussianBlur(img, (5, 5), 0)


def _run(tmp_path: Path, image: Path, camera: dict | None = None, *, process: bool = True):
    """``simtest reconstruct image --intrinsics cam.json`` in a real process (what a user's shell
    sees: a C library's warnings on stderr too), or with ``process=False`` through the command
    line's app in this process, where the check is Python's own (its return code and stderr)."""
    cam = tmp_path / "cam.json"
    cam.write_text(json.dumps(camera or {"model": "pinhole", "K": K}))
    args = ["reconstruct", str(image), "--intrinsics", str(cam), "-o", str(tmp_path / "out")]
    if not process:
        return _run_here(args)
    env = dict(os.environ, PYTHONPATH=str(Path(__file__).resolve().parents[1]))
    return subprocess.run([*SIMTEST, *args], capture_output=True, text=True, env=env, timeout=600)


def _run_here(args):
    """The command line ``simtest ARGS`` through its app's own main in this process (CliRunner):
    its exit status and stderr, as a finished process's; an exception other than SystemExit (a
    traceback in a shell) fails the test."""
    from typer.testing import CliRunner

    from simtest.cli import app

    out = CliRunner().invoke(app, args, prog_name="simtest")
    assert out.exception is None or isinstance(out.exception, SystemExit), out.exception
    return SimpleNamespace(returncode=out.exit_code, stderr=out.stderr)


def _refused(res, *words):
    """Exit 2, exactly one line on stderr, ``error: ...`` holding ``words``, no traceback."""
    lines = res.stderr.strip().splitlines()
    assert res.returncode == 2, (res.returncode, res.stderr[-2000:])
    assert len(lines) == 1 and lines[0].startswith("error: "), res.stderr[-2000:]
    for w in words:
        assert str(w) in lines[0], lines[0]


# --- a light behind the fitted surface ---------------------------------------------------------


def _plane_fit(depth_mm=10.0, status="ok"):
    return LightAwareEstimate("cubic_patch_fit", status, "", np.array([0.0, 0.0, -1.0]), depth_mm, 0.1,
                              0.05, depth_mm, light_normals=np.array([[0.0, 0.0, -1.0]] * 2))


def test_a_fit_whose_surface_puts_a_light_behind_it_is_refused_and_the_bp_ray_recommended():
    # the tissue at 10 mm facing the camera, the rig's guides at z = 15 mm (behind it): the fit's
    # normal and depth would be kept as ok before; the light's side of the tangent plane is now
    # checked, the status says why, and the recommendation falls back to the BP ray
    behind = LightRig((Light((-4.0, 0, 15.0)), Light((4.0, 0, 15.0))))
    ray = np.array([0.0, 0.0, 1.0])
    r = light_behind_surface(_plane_fit(), ray, behind.positions)
    assert r.status == "light_behind_plane" and r.depth_mm is None
    assert "light 0" in r.detail and "behind the fitted surface" in r.detail
    est = SimpleNamespace(light_aware={"cubic_patch_fit": r}, bp_ray=np.array([0.0, 0.0, -1.0]))
    assert recommend(est).normal_from == "bp_ray"
    # the same fit with the guides at the lens (camera side) is kept
    front = LightRig((Light((-4.0, 0, 0.0)), Light((4.0, 0, 0.0))))
    assert light_behind_surface(_plane_fit(), ray, front.positions).status == "ok"


def test_a_tilted_patch_whose_tangent_plane_puts_one_guide_behind_it_is_refused():
    # the audit's case: depth 17 mm beyond guides at z = 15 mm, the normal 51 deg off towards +x:
    # the guide at +4 mm lies behind that tangent plane although both lie nearer than the depth
    t = np.radians(51.0)
    fit = LightAwareEstimate("cubic_patch_fit", "ok", "", np.array([-np.sin(t), 0.0, -np.cos(t)]), 17.0, 9.7)
    rig = LightRig((Light((-4.0, 0, 15.0)), Light((4.0, 0, 15.0))))
    r = light_behind_surface(fit, np.array([0.0, 0.0, 1.0]), rig.positions)
    assert r.status == "light_behind_plane" and "light 1" in r.detail


# --- the camera file's values within their physical ranges -------------------------------------


@pytest.mark.parametrize("key, camera", [
    ("response.gamma", {"response": {"curve": "gamma", "gamma": 1e308}}),
    ("response.exposure", {"response": {"curve": "srgb", "exposure": 1e-320}}),
    ("response.clip", {"response": {"curve": "srgb", "clip": 1e300}}),
    ("profile_exponent", {"lights": [{"position_mm": [3, 0, 0], "profile_exponent": 1e300}]}),
])
def test_camera_values_outside_their_physical_range_are_one_line(tmp_path, key, camera):
    # the first in a real process, the others (the same check of the camera file) in this one
    png = tmp_path / "f.png"
    cv2.imwrite(str(png), _frame())
    res = _run(tmp_path, png, {"model": "pinhole", "K": K, **camera}, process=key == "response.gamma")
    _refused(res, "cam.json", key, "e+")


# --- frames whose values do not fit the camera's response --------------------------------------


def test_a_float_frame_in_0_1_read_with_an_8_bit_clip_is_refused(tmp_path):
    npy = tmp_path / "f.npy"
    np.save(npy, _frame()[..., ::-1].astype(np.float32) / 255.0)
    res = _run(tmp_path, npy, {"model": "pinhole", "K": K, "response": {"curve": "linear", "clip": 255}},
               process=False)
    _refused(res, "cam.json", "response.clip", "255", "f.npy")


def test_a_negative_pixel_is_refused_naming_it(tmp_path):
    img = _frame().astype(np.float32)
    img[5, 7, 1] = -3.0
    npy = tmp_path / "neg.npy"
    np.save(npy, img)
    _refused(_run(tmp_path, npy, process=False), "neg.npy", "row 5, col 7", "-3")


# --- corrupt media ----------------------------------------------------------------------------


def test_a_jpeg_with_an_overwritten_scan_is_refused(tmp_path):
    good = tmp_path / "good.jpg"
    cv2.imwrite(str(good), _frame())
    b = bytearray(good.read_bytes())
    n = len(b)
    b[n // 3: n // 3 + 400] = np.random.default_rng(1).integers(0, 255, 400, dtype=np.uint8).tobytes()
    bad = tmp_path / "bad.jpg"
    bad.write_bytes(bytes(b))
    _refused(_run(tmp_path, bad), "bad.jpg", "Corrupt JPEG data")


def test_a_damaged_lzw_tiff_is_refused(tmp_path):
    good = tmp_path / "good.tif"
    big = cv2.resize(_frame(), (320, 240))
    cv2.imwrite(str(good), big, [cv2.IMWRITE_TIFF_COMPRESSION, 5])  # LZW
    b = bytearray(good.read_bytes())
    m = len(b) // 2
    b[m: m + 200] = bytes(200)
    bad = tmp_path / "bad.tif"
    bad.write_bytes(bytes(b))
    _refused(_run(tmp_path, bad), "bad.tif", "damaged")


def test_a_video_cut_to_half_is_refused_naming_the_frame(tmp_path):
    video = tmp_path / "v.avi"
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"MJPG"), 10.0, (120, 90))
    for _ in range(8):
        writer.write(_frame())
    writer.release()
    cut = tmp_path / "cut.avi"
    cut.write_bytes(video.read_bytes()[: video.stat().st_size // 2])
    _refused(_run(tmp_path, cut), "cut.avi", "decoding stopped at frame", "of the 8")


# --- the pixel limit ---------------------------------------------------------------------------


def _png(w: int, h: int, idat: bytes) -> bytes:
    def chunk(t, d):
        return struct.pack(">I", len(d)) + t + d + struct.pack(">I", zlib.crc32(t + d) & 0xFFFFFFFF)

    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 0, 0, 0, 0))
            + chunk(b"IDAT", idat) + chunk(b"IEND", b""))


def test_a_png_header_claiming_50000_squared_pixels_is_one_line(tmp_path):
    png = tmp_path / "huge.png"
    png.write_bytes(_png(50000, 50000, zlib.compress(b"\x00" * 100)))
    _refused(_run(tmp_path, png), "huge.png", "Mpx")


def test_a_zlib_bomb_of_9000_squared_pixels_is_refused_before_decoding(tmp_path):
    # 81 Mpx of zeros in about 80 KB: over the 67 Mpx limit, under Pillow's own (89 Mpx), so the
    # message gives the header's size
    w = 9000
    co = zlib.compressobj(9)
    row = b"\x00" * (w + 1)
    data = b"".join(co.compress(row) for _ in range(w)) + co.flush()
    png = tmp_path / "bomb.png"
    png.write_bytes(_png(w, w, data))
    _refused(_run(tmp_path, png), "bomb.png", "9000 x 9000 px")


def test_a_float16_array_is_read(tmp_path):
    npy = tmp_path / "f16.npy"
    np.save(npy, _frame()[..., ::-1].astype(np.float16))
    res = _run(tmp_path, npy)
    assert res.returncode == 0, res.stderr[-2000:]


# --- malformed detection labels --------------------------------------------------------------


def _good_row():
    return {"u": 20.0, "v": 21.0, "u_peak": 20, "v_peak": 21, "area_px": 6, "kind": "isolated"}


@pytest.mark.parametrize("tiles, where", [
    ([_good_row()], "key 'tiles'"),
    ({"r0c0": {"u": 1}}, "tiles.r0c0"),
    ({"r0c0": ["row"]}, "tiles.r0c0[0]"),
    ({"x1": [_good_row()]}, "tile id 'x1'"),
    ({"r5c0": [_good_row()]}, "tiles.r5c0"),
    ({"r0c0": [_good_row() | {"area_px": 1e9}]}, "tiles.r0c0[0].area_px: 1000000000.0"),
    ({"r0c0": [_good_row() | {"u_peak": 5000}]}, "tiles.r0c0[0].u_peak: 5000"),
    ({"r0c0": [_good_row() | {"v_peak": "12"}]}, "tiles.r0c0[0].v_peak"),
    ({"r0c0": [{k: v for k, v in _good_row().items() if k != "area_px"}]}, "tiles.r0c0[0].area_px"),
])
def test_malformed_or_impossible_detection_labels_are_one_line(tmp_path, tiles, where):
    # the first case in a real process (what a user's shell sees, warnings and all); the others,
    # the same command's same error path, through the command line's app in this process
    cv2.imwrite(str(tmp_path / "frame.png"), cv2.resize(_frame(), (64, 64)))
    labels = tmp_path / "labels.json"
    labels.write_text(json.dumps({"header": {"image": "frame.png", "tile_px": 64}, "tiles": tiles}))
    args = ["evaluate", "detection", str(labels), "-o", str(tmp_path / "out")]
    if where == "key 'tiles'":
        env = dict(os.environ, PYTHONPATH=str(Path(__file__).resolve().parents[1]))
        res = subprocess.run([*SIMTEST, *args], capture_output=True, text=True, env=env, timeout=600)
    else:
        res = _run_here(args)
    _refused(res, "labels.json", where)
