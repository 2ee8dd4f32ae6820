"""Hostile inputs to `simtest reconstruct` and `simtest view`: each gives exactly one line
``error: ...`` on stderr (no traceback, no libpng, FFmpeg or VTK line), its documented exit code
(2 bad input, 4 output cannot be written), and leaves earlier outputs intact.

The library noise is written below Python, to file descriptor 2, so it is only seen in a real
process: :func:`test_one_stderr_line_per_failure_in_a_real_process` runs every case in one child
process (one import of simtest) through ``simtest.cli.app`` in standalone mode, with a marker line
between cases, and checks the child's stderr segment by segment.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import cv2
import numpy as np
import pytest
from _cases import assert_one_error_line
from typer.testing import CliRunner

from simtest.cli import app
from simtest.geometry import save_intrinsics
from simtest.simulate.analytic import phong_plane_image

ROOT = Path(__file__).resolve().parents[1]
runner = CliRunner()
SIZE = 120  # px: a small image keeps each reconstruction well under a second


def _K(size=SIZE, f=150.0):
    return np.array([[f, 0, size / 2 - 0.5], [0, f, size / 2 - 0.5], [0, 0, 1.0]])


def _plane(size=SIZE):
    """A 16-bit image of an analytic Phong plane tilted 12 deg: one highlight."""
    t = np.radians(12)
    img = phong_plane_image(_K(size), (size, size), np.array([np.sin(t), 0.0, -np.cos(t)]), 250.0, 60)
    return np.round(img * 60000).astype(np.uint16)


@pytest.fixture
def files(tmp_path):
    """Every hostile input beside a sound image and camera (paths by name)."""
    d = tmp_path / "in"
    d.mkdir()
    f = {"png": d / "plane.png", "K": d / "K.json", "K_other": d / "K_640x480.json"}
    cv2.imwrite(str(f["png"]), _plane())
    save_intrinsics(f["K"], _K())
    save_intrinsics(f["K_other"], _K(), image_size=(640, 480))
    # .npy arrays that are no image: 1-D, 0-D, strings, objects (pickled), complex
    for name, arr in {"one_d": np.zeros(10), "zero_d": np.float64(3.0),
                      "strings": np.array([["a", "b"], ["c", "d"]]), "complex": np.zeros((8, 8), complex)}.items():
        f[name] = d / f"{name}.npy"
        np.save(f[name], arr)
    f["objects"] = d / "objects.npy"
    np.save(f["objects"], np.array([1, None], dtype=object), allow_pickle=True)
    data = f["png"].read_bytes()
    f["truncated"] = d / "truncated.png"
    f["truncated"].write_bytes(data[: len(data) // 2])
    f["fake_mp4"] = d / "fake.mp4"
    f["fake_mp4"].write_bytes(b"not a video at all " * 64)
    # a folder of frames, the second of another size
    f["frames"] = d / "frames"
    f["frames"].mkdir()
    cv2.imwrite(str(f["frames"] / "f000.png"), _plane())
    cv2.imwrite(str(f["frames"] / "f001.png"), _plane(96))
    # ground truth of another size than the image (a render's ground_truth.npz)
    f["truth_other"] = d / "ground_truth.npz"
    np.savez(f["truth_other"], depth=np.full((90, 100), 50.0))
    f["a_file"] = d / "a_file"
    f["a_file"].write_text("keep me")
    return f


_one_line = assert_one_error_line


def test_npy_that_is_no_image_is_one_line_naming_file_shape_and_dtype(files, tmp_path):
    cases = {"one_d": ("(10,)", "float64"), "zero_d": ("()", "float64"), "strings": ("(2, 2)", "<U1"),
             "objects": ("(2,)", "object"), "complex": ("(8, 8)", "complex128")}
    for name, (shape, dtype) in cases.items():
        res = runner.invoke(app, ["reconstruct", str(files[name]), "-k", str(files["K"]),
                                  "-o", str(tmp_path / "o")])
        _one_line(res, 2, f"{name}.npy", shape, dtype, "expected an image")
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("dtype", ["float64", "int16", "uint32"])
def test_a_tiff_of_any_depth_reads_as_rgb_or_is_one_line(files, tmp_path, dtype):
    # a 3-channel TIFF of a depth OpenCV's colour conversion does not take (it takes 8U, 16U, 32F): the
    # float64 one reads as the RGB it holds and reconstructs as its float32 twin does; the integer ones are
    # one line naming the dtype (a traceback from cv2.cvtColor before)
    import tifffile

    # a white highlight on tissue of unequal R, G, B (the channel order shows)
    rgb = np.minimum(_plane()[..., None] / 60000.0 + [0.45, 0.25, 0.2], 1.0)
    tifffile.imwrite(tmp_path / "f.tif", (rgb * (1 if dtype == "float64" else 1000)).astype(dtype),
                     photometric="rgb")
    res = runner.invoke(app, ["reconstruct", str(tmp_path / "f.tif"), "-k", str(files["K"]), "-o", str(tmp_path / "o")])
    if dtype != "float64":
        _one_line(res, 2, "f.tif", dtype, "expected an image")
        return
    assert res.exit_code == 0, res.output
    from simtest.reconstruct.images import load_image

    np.testing.assert_array_equal(load_image(tmp_path / "f.tif"), rgb)  # (RGB as stored, bit for bit)
    tifffile.imwrite(tmp_path / "f32.tif", rgb.astype(np.float32), photometric="rgb")
    twin = runner.invoke(app, ["reconstruct", str(tmp_path / "f32.tif"), "-k", str(files["K"]),
                               "-o", str(tmp_path / "o32")])
    got, want = (json.loads((tmp_path / d / "estimates.json").read_text())["specularities"] for d in ("o", "o32"))
    assert [s["status"] for s in got] == [s["status"] for s in want] and "ok" in [s["status"] for s in got]


def test_frames_of_two_sizes_are_refused_naming_the_frame(files, tmp_path):
    res = runner.invoke(app, ["reconstruct", str(files["frames"]), "-k", str(files["K"]),
                              "-o", str(tmp_path / "o"), "-j", "1"])
    _one_line(res, 2, "f001.png", "96 x 96 px", "f000.png", "120 x 120 px")
    # a camera with a size: every frame is held to it (the sequence path did not check it at all)
    res = runner.invoke(app, ["reconstruct", str(files["frames"]), "-k", str(files["K_other"]),
                              "-o", str(tmp_path / "o"), "-j", "1"])
    _one_line(res, 2, "f000.png", "120 x 120 px", "'image_size' is 640 x 480 px")
    assert not (tmp_path / "o").exists()


def test_view_refuses_a_camera_or_ground_truth_of_another_size(files, tmp_path):
    out = tmp_path / "rec"
    res = runner.invoke(app, ["reconstruct", str(files["png"]), "-k", str(files["K"]), "-o", str(out),
                              "--no-overlay", "-t", "0.3"])
    assert res.exit_code == 0, res.output
    est = out / "estimates.json"
    png = tmp_path / "view.png"
    res = runner.invoke(app, ["view", str(est), "-o", str(png), "--intrinsics", str(files["K_other"])])
    _one_line(res, 2, "--intrinsics", "K_640x480.json", "640 x 480 px", "120 x 120 px")
    res = runner.invoke(app, ["view", str(est), "-o", str(png), "--truth", str(files["truth_other"])])
    _one_line(res, 2, "--truth", "ground_truth.npz", "100 x 90 px", "120 x 120 px")
    assert not png.exists()


def test_unwritable_out_says_why_with_exit_4(files, tmp_path):
    a_file = files["a_file"]
    base = ["reconstruct", str(files["png"]), "-k", str(files["K"])]
    res = runner.invoke(app, [*base, "-o", str(a_file / "sub")])
    _one_line(res, 4, "--out", "a_file", "is a file")
    # a folder holding other files would lose them when the output folder is swapped in
    res = runner.invoke(app, [*base, "-o", str(files["png"].parent)])
    _one_line(res, 4, "--out", "holds files this command does not write", "K.json")
    res = runner.invoke(app, ["view", str(tmp_path / "none.json"), "-o", str(a_file / "v.png")])
    _one_line(res, 4, "--out", "a_file", "is a file")
    assert a_file.read_text() == "keep me"
    if os.geteuid() != 0:  # root writes through any mode bits
        ro = tmp_path / "ro"
        ro.mkdir()
        ro.chmod(0o555)
        try:
            res = runner.invoke(app, [*base, "-o", str(ro / "o")])
            _one_line(res, 4, "--out", "permission denied")
        finally:
            ro.chmod(0o755)


def test_workers_above_the_cpu_count_are_refused(files, tmp_path):
    n = (os.cpu_count() or 1) + 1
    res = runner.invoke(app, ["reconstruct", str(files["frames"]), "-k", str(files["K"]),
                              "-o", str(tmp_path / "o"), "-j", str(n)])
    _one_line(res, 2, f"--workers {n}", "CPU")


_DRIVER = textwrap.dedent("""
    import json, os, sys
    from simtest.cli import app
    codes = []
    for args in json.loads(sys.argv[1]):
        sys.stderr.flush()
        os.write(2, b"@@case\\n")
        try:
            app(args, prog_name="simtest")
            codes.append(0)
        except SystemExit as exc:
            codes.append(exc.code if isinstance(exc.code, int) else 1)
        sys.stderr.flush()
    print(json.dumps(codes))
""")


def test_one_stderr_line_per_failure_in_a_real_process(files, tmp_path):
    """libpng (truncated PNG), FFmpeg (fake .mp4) and VTK (every off-screen view) write to fd 2
    themselves: each failing case must leave exactly its own ``error:`` line there, and a
    successful view nothing at all."""
    rec = tmp_path / "rec"
    k = str(files["K"])
    cases = [
        (["reconstruct", str(files["png"]), "-k", k, "-o", str(rec), "-t", "0.3", "--no-overlay"], 0, []),
        (["view", str(rec / "estimates.json"), "-o", str(tmp_path / "view.png")], 0, []),
        (["reconstruct", str(files["truncated"]), "-k", k, "-o", str(tmp_path / "o")], 2, ["truncated.png"]),
        (["reconstruct", str(files["fake_mp4"]), "-k", k, "-o", str(tmp_path / "o")], 2, ["fake.mp4"]),
        (["reconstruct", str(files["one_d"]), "-k", k, "-o", str(tmp_path / "o")], 2, ["one_d.npy", "(10,)"]),
        (["view", str(rec / "estimates.json"), "-o", str(tmp_path / "v2.png"),
          "--truth", str(files["truth_other"])], 2, ["ground_truth.npz"]),
    ]
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""),
               COLUMNS="80", TERM="dumb")
    env.pop("DISPLAY", None)  # as on the VM: VTK's "bad X server connection" comes from here
    proc = subprocess.run([sys.executable, "-c", _DRIVER, json.dumps([c[0] for c in cases])],
                          capture_output=True, text=True, env=env, timeout=300, cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    codes = json.loads(proc.stdout.strip().splitlines()[-1])
    segments = proc.stderr.split("@@case\n")
    assert segments[0] == "", segments[0]  # nothing at import
    for (args, code, words), got, seg in zip(cases, codes, segments[1:], strict=True):
        lines = [ln for ln in seg.splitlines() if ln.strip()]
        assert got == code, (args, seg)
        if code == 0:
            assert lines == [], (args, seg)  # a view prints nothing on stderr (no VTK warning)
            continue
        assert len(lines) == 1 and lines[0].startswith("error: "), (args, seg)
        for w in words:
            assert w in lines[0], lines[0]
    assert (tmp_path / "view.png").stat().st_size > 0
    assert json.loads((rec / "estimates.json").read_text())["schema"] == 2


def test_other_commands_check_out_first_with_exit_4(files, tmp_path, monkeypatch):
    """render, simreal, meshes build and evaluate c3vd refuse an --out below a file before any
    work (render_scene is never called), with exit 4 and one line."""
    from simtest.render import cli as render_cli

    def no_render(*args, **kwargs):
        raise AssertionError("rendered although --out cannot be written")

    monkeypatch.setattr(render_cli, "render_scene", no_render)
    below_file = str(files["a_file"] / "sub")
    for args in (["render", "plane_fronto", "-o", below_file],
                 ["simreal", "-o", below_file],
                 ["meshes", "build", "-o", below_file, "--only", "liver"],
                 ["evaluate", "c3vd", str(tmp_path), "-k", str(files["K"]), "-o", below_file]):
        res = runner.invoke(app, args)
        _one_line(res, 4, "--out", "a_file", "is a file")
    # evaluate's OUT is replaced as a whole: a folder holding other files is refused
    res = runner.invoke(app, ["evaluate", "c3vd", str(tmp_path), "-k", str(files["K"]),
                              "-o", str(files["png"].parent)])
    _one_line(res, 4, "--out", "holds files this command does not write")
    assert files["a_file"].read_text() == "keep me"


def test_reconstruct_requires_out(files, tmp_path, monkeypatch):
    """No default output folder (it used to be the current folder, mixing outputs with inputs)."""
    monkeypatch.chdir(tmp_path)
    res = runner.invoke(app, ["reconstruct", str(files["png"]), "-k", str(files["K"])])
    assert res.exit_code == 2 and "--out" in res.output
    assert sorted(p.name for p in tmp_path.iterdir()) == ["in"]


def test_a_video_of_no_frame_is_one_line_and_writes_nothing(files, tmp_path):
    # as an empty folder is: a video whose container opens but holds no frame (a writer closed at once)
    video = tmp_path / "empty.avi"
    cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"MJPG"), 10, (SIZE, SIZE)).release()
    res = runner.invoke(app, ["reconstruct", str(video), "-k", str(files["K"]), "-o", str(tmp_path / "o")])
    _one_line(res, 2, "empty.avi", "decoded no frame")
    assert not (tmp_path / "o").exists()
