"""`simtest reconstruct` on a folder of frames and on a video file: estimates.parquet (a row per
candidate) or estimates.jsonl (a line per frame) in frame order, the same records as frame-by-frame
calls, whatever the number of workers."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from simtest.cli import app
from simtest.reconstruct import reconstruct
from simtest.reconstruct.frames import _frame_record, open_frames
from simtest.reconstruct.io import estimate_to_dict
from simtest.reconstruct.table import read_frames, read_table
from simtest.reconstruct.settings import ReconSettings
from simtest.simulate.analytic import phong_plane_image

K = np.array([[200.0, 0, 79.5], [0, 200.0, 59.5], [0, 0, 1]])


def _frames(n=5):
    """Frames with one or two highlights that move from frame to frame (so that order matters)."""
    out = []
    for i in range(n):
        img = np.full((120, 160), 20.0)
        for k in range(1 + i % 2):
            Kw = K.copy()
            Kw[0, 2] -= 25 * i + 60 * k - 40
            img += 200.0 * phong_plane_image(Kw, (120, 160), np.array([0.0, 0.0, -1.0]), 50.0, 300.0)
        out.append(np.clip(np.rint(img), 0, 255).astype(np.uint8))
    return out


def _write_k(tmp_path):
    p = tmp_path / "cam.json"
    p.write_text(json.dumps({"K": K.tolist()}))
    return p


def _expected(images):
    return [_frame_record((i, "", img, K, ReconSettings.for_frames(), None, False, None, False))["specularities"]
            for i, img in enumerate(images)]


def test_folder_of_frames_matches_frame_by_frame_calls(tmp_path):
    frames = tmp_path / "frames"
    frames.mkdir()
    images = _frames()
    for i, img in enumerate(images):
        cv2.imwrite(str(frames / f"f{i:03d}.png"), img)
    (frames / "notes.txt").write_text("not a frame")
    for workers, fmt in (("1", "parquet"), ("2", "parquet"), ("2", "jsonl")):
        out = tmp_path / f"out{workers}{fmt}"
        res = CliRunner().invoke(app, ["reconstruct", str(frames), "-k", str(_write_k(tmp_path)),
                                       "-o", str(out), "-j", workers, "--format", fmt])
        assert res.exit_code == 0, res.output
        assert "5 frame(s)" in res.output and "frames/s" in res.output
        assert sorted(p.name for p in out.iterdir()) == [f"estimates.{fmt}"]
        lines = read_frames(out / f"estimates.{fmt}")
        assert [r["frame"] for r in lines] == list(range(5))
        assert [r["source"] for r in lines] == [f"f{i:03d}.png" for i in range(5)]
        assert [r["specularities"] for r in lines] == _expected(images)
        # the highlights moved: the first ok BP of each frame is not the same
        bps = [next(s["bp_px"] for s in r["specularities"] if s["status"] == "ok") for r in lines]
        assert len({round(b[0]) for b in bps}) == 5


def test_video_files_parquet_rows_are_frame_by_frame_calls(tmp_path):
    video = tmp_path / "clip.avi"
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"MJPG"), 25.0, (160, 120))
    assert writer.isOpened()
    for img in _frames(3):
        writer.write(cv2.cvtColor(img, cv2.COLOR_GRAY2BGR))
    writer.release()
    # what OpenCV decodes is the input of both paths (MJPG is lossy)
    decoded = [img for _, _, img in open_frames(video)]
    assert len(decoded) == 3
    out = tmp_path / "out"
    res = CliRunner().invoke(app, ["reconstruct", str(video), "-k", str(_write_k(tmp_path)),
                                   "-o", str(out), "-j", "2"])
    assert res.exit_code == 0, res.output
    # the table's rows, column by column, against reconstruct() called on each decoded frame
    table = read_table(out / "estimates.parquet")
    settings = ReconSettings.for_frames()
    calls = [[json.loads(json.dumps(estimate_to_dict(e))) for e in reconstruct(img, K, settings=settings)]
             for img in decoded]
    assert table.column("frame").to_pylist() == [i for i, c in enumerate(calls) for _ in c]
    assert table.column("source").to_pylist() == [f"video:{i}" for i, c in enumerate(calls) for _ in c]
    assert table.column("candidate").to_pylist() == [k for c in calls for k in range(len(c))]
    for column in ("status", "bp_px", "normal", "confidence", "depth_mm", "ellipse", "fit_residual_px"):
        assert table.column(column).to_pylist() == [s[column] for c in calls for s in c], column
    for name in ("paper_selected", "cone_axis", "bp_ray", "photometric_fit"):
        assert table.column(f"normal_{name}").to_pylist() == [s["normals"][name] for c in calls for s in c]
    # and every field, read back as the frames' records
    lines = read_frames(out / "estimates.parquet")
    assert [r["source"] for r in lines] == [f"video:{i}" for i in range(3)]
    assert [r["specularities"] for r in lines] == calls == _expected(decoded)
    assert sum(r["counts"].get("ok", 0) for r in lines) == sum(s["status"] == "ok" for c in calls for s in c) > 0


def test_empty_folder_and_unreadable_video_are_one_line_errors(tmp_path):
    empty = tmp_path / "empty"
    empty.mkdir()
    bad = tmp_path / "bad.mp4"
    bad.write_bytes(b"not a video")
    res = CliRunner().invoke(app, ["reconstruct", str(empty), "-k", str(_write_k(tmp_path)),
                                   "-o", str(tmp_path / "o"), "--format", "csv"])
    assert res.exit_code == 2 and res.output.strip() == "error: --format csv: not one of parquet, jsonl"
    for path, words in ((empty, "holds no frame"), (bad, "cannot open")):
        res = CliRunner().invoke(app, ["reconstruct", str(path), "-k", str(_write_k(tmp_path)),
                                       "-o", str(tmp_path / "o")])
        assert res.exit_code == 2 and words in res.output and "Traceback" not in res.output


def test_a_folder_honours_the_camera_files_lights_as_a_single_image_does(tmp_path):
    # Issue 39: a folder dropped the camera file's rig (0.07 deg as one image, 5.2 deg inside a
    # folder). An exact plane lit 3 mm off the lens (test_lightaware.plane_case), as one image and
    # as both frames of a folder: every record's specularities equal the single image's, and they
    # carry the light-aware fits and the recommended normal.
    from simtest.geometry.camera_file import save_camera
    from simtest.geometry.cameras import PinholeCamera
    from simtest.geometry.lights import Light, LightRig
    from test_lightaware import plane_case

    rig = LightRig((Light((3.0, 0.0, 0.0), 1.0, "inverse_square"),))
    img, Kp, N, depth, bp = plane_case(20.0, 30.0, rig)
    img = np.clip(np.rint(img / img.max() * 230.0), 0, 255).astype(np.uint8)
    cam = save_camera(tmp_path / "cam.json", PinholeCamera(Kp, image_size=(240, 240)), lights=rig)
    frames = tmp_path / "frames"
    frames.mkdir()
    for i in range(2):
        cv2.imwrite(str(frames / f"f{i}.png"), img)
    cv2.imwrite(str(tmp_path / "one.png"), img)
    one = CliRunner().invoke(app, ["reconstruct", str(tmp_path / "one.png"), "-k", str(cam), "-o",
                                   str(tmp_path / "single"), "--no-overlay"])
    assert one.exit_code == 0, one.output
    single = json.loads((tmp_path / "single" / "estimates.json").read_text())["specularities"]
    assert single and single[0]["normal_from"] == "photometric_fit"
    res = CliRunner().invoke(app, ["reconstruct", str(frames), "-k", str(cam), "-o",
                                   str(tmp_path / "seq"), "-j", "1"])
    assert res.exit_code == 0, res.output
    lines = read_frames(tmp_path / "seq" / "estimates.parquet")
    assert len(lines) == 2
    for rec in lines:
        assert rec["specularities"] == single


def test_records_encoded_in_the_workers_write_the_same_file(tmp_path):
    """reconstruct_frames(encoded="jsonl" or "parquet") (what simtest reconstruct runs: each
    frame's JSON line or rows made in its worker) writes the file of the plain records, in frame
    order."""
    from simtest.reconstruct.frames import FrameRecord, reconstruct_frames, write_frames

    frames = tmp_path / "frames"
    frames.mkdir()
    for i, img in enumerate(_frames(4)):
        cv2.imwrite(str(frames / f"f{i:03d}.png"), img)
    plain, _, _ = write_frames(tmp_path / "plain.jsonl", reconstruct_frames(open_frames(frames), K), fmt="jsonl")
    recs = list(reconstruct_frames(open_frames(frames), K, workers=2, encoded="jsonl"))
    assert all(isinstance(r, FrameRecord) and "specularities" not in r for r in recs)
    assert [r["frame"] for r in recs] == [0, 1, 2, 3]
    enc, _, _ = write_frames(tmp_path / "enc.jsonl", recs, fmt="jsonl")
    assert enc.read_bytes() == plain.read_bytes()
    expected = _expected([img for _, _, img in open_frames(frames)])
    assert [r["specularities"] for r in read_frames(enc)] == expected
    plain_pq, _, _ = write_frames(tmp_path / "plain.parquet", reconstruct_frames(open_frames(frames), K))
    recs = list(reconstruct_frames(open_frames(frames), K, workers=2, encoded="parquet"))
    assert all(isinstance(r, FrameRecord) and r.batch is not None for r in recs)
    enc_pq, _, _ = write_frames(tmp_path / "enc.parquet", recs)
    assert read_table(enc_pq).equals(read_table(plain_pq), check_metadata=True)
    assert read_frames(enc_pq) == read_frames(enc)


def test_estimates_jsonl_is_one_utf8_line_a_record_each_ending_in_a_newline(tmp_path):
    """write_frames writes bytes: each record's compact JSON (UTF-8) and b"\\n", whatever
    the platform's newline; a FrameRecord as its line."""
    from simtest.reconstruct.frames import FrameRecord, write_frames

    enc = FrameRecord({"frame": 1})
    enc.line = b'{"frame":1,"specularities":[]}'
    recs = [{"frame": 0, "source": "caf\u00e9.png", "x": [0.1, 1e-05]}, enc]
    path, n, _ = write_frames(tmp_path / "estimates.jsonl", recs, fmt="jsonl")
    assert n == 2
    lines = path.read_bytes().split(b"\n")
    assert lines[2:] == [b""] and lines[1] == enc.line
    assert json.loads(lines[0].decode("utf-8")) == recs[0]
    assert read_frames(path) == [recs[0], {"frame": 1, "specularities": []}]


def test_a_frame_without_candidates_keeps_its_record_in_the_parquet_file(tmp_path):
    from simtest.reconstruct.frames import reconstruct_frames, write_frames

    frames = tmp_path / "frames"
    frames.mkdir()
    images = _frames(3)
    images[1] = np.full_like(images[1], 20)  # nothing bright: no row
    for i, img in enumerate(images):
        cv2.imwrite(str(frames / f"f{i}.png"), img)
    path, n, _ = write_frames(tmp_path / "e.parquet", reconstruct_frames(open_frames(frames), K))
    recs = read_frames(path)
    assert n == 3 and [r["source"] for r in recs] == ["f0.png", "f1.png", "f2.png"]
    assert recs[1]["specularities"] == [] and recs[1]["image_shape"] == [120, 160]
    assert 1 not in read_table(path).column("frame").to_pylist()
    with pytest.raises(ValueError, match="fmt 'csv'"):  # nothing written, no temporary left
        write_frames(tmp_path / "e.csv", [], fmt="csv")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["e.parquet", "frames"]


def test_frames_through_the_shared_slots_give_frame_by_frame_records(tmp_path):
    """With workers, frames of the first frame's shape and dtype reach the workers through shared
    slots (one per frame in flight, reused: 11 frames through 8 slots) and any other frame in its
    job (a colour frame among gray ones, same size); every record is still that of a frame-by-frame
    call, in order."""
    from simtest.reconstruct.frames import FrameRecord, reconstruct_frames, write_frames

    frames = tmp_path / "frames"
    frames.mkdir()
    images = _frames(11)
    images[4] = np.ascontiguousarray(np.repeat(images[4][..., None], 3, axis=2))
    images[4][..., 0] //= 2  # tinted, so that its record is its own
    for i, img in enumerate(images):
        cv2.imwrite(str(frames / f"f{i:03d}.png"), img[..., ::-1] if img.ndim == 3 else img)
    plain, _, _ = write_frames(tmp_path / "plain.jsonl", reconstruct_frames(open_frames(frames), K), fmt="jsonl")
    recs = list(reconstruct_frames(open_frames(frames), K, workers=2, encoded="jsonl"))
    assert all(isinstance(r, FrameRecord) and isinstance(r.line, bytes) for r in recs)
    assert [r["frame"] for r in recs] == list(range(11))
    enc, _, _ = write_frames(tmp_path / "enc.jsonl", recs, fmt="jsonl")
    assert enc.read_bytes() == plain.read_bytes()
    assert [r["specularities"] for r in read_frames(enc)] == _expected(
        [img for _, _, img in open_frames(frames)])


def test_one_process_runs_one_blas_and_one_opencv_thread(tmp_path, monkeypatch):
    # -j 1 (a folder) and a single image reconstruct in this process: their libraries' extra threads
    # only took CPU (a video at -j 1: 15 s of CPU for 10 s of wall, 10 s with one thread, same files)
    import simtest.reconstruct.cli as cli
    import simtest.reconstruct.frames as frames_mod
    from threadpoolctl import threadpool_info, threadpool_limits

    seen = []

    def counting(*args, **kwargs):
        seen.append((max(d["num_threads"] for d in threadpool_info() if d["user_api"] == "blas"),
                     cv2.getNumThreads()))
        return reconstruct(*args, **kwargs)

    monkeypatch.setattr(frames_mod, "reconstruct", counting)
    monkeypatch.setattr(cli, "reconstruct", counting)
    folder = tmp_path / "frames"
    folder.mkdir()
    for i, img in enumerate(_frames(2)):
        cv2.imwrite(str(folder / f"f{i}.png"), img)
    before = cv2.getNumThreads()
    cv2.setNumThreads(2)  # (an xdist worker runs one: conftest)
    try:
        with threadpool_limits(limits=2):
            for source in (folder, folder / "f0.png"):
                res = CliRunner().invoke(app, ["reconstruct", str(source), "-k", str(_write_k(tmp_path)), "-o",
                                               str(tmp_path / f"out_{source.name}"), "-j", "1"])
                assert res.exit_code == 0, res.output
    finally:
        cv2.setNumThreads(before)
    assert seen and all(s == (1, 1) for s in seen), seen
