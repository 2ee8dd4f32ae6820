"""Speed of the reconstruction (pytest-benchmark; plain tests under --benchmark-disable), the
`simtest bench` command (a runner in the package, the sections in the clone's benchmarks/) and
the benchmarks' machinery. No timed asserts: the figures are read from the benchmark report."""

from __future__ import annotations

import ast
import os
import re
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

import benchmarks
from benchmarks import inputs, opencv_replay, timing
from benchmarks import reconstruct as rbench
from simtest import bench
from simtest.cli import app

#: The clone's top folder (benchmarks/ and simtest/).
ROOT = Path(__file__).resolve().parents[1]
from simtest.geometry import angle_between_deg
from simtest.reconstruct import reconstruct, reconstruct_roi
from simtest.reconstruct.io import estimate_to_dict


def test_bench_per_specularity(benchmark):
    img, K, bp, normal = inputs.synthetic_roi_image()
    assert img.shape == (100, 100)
    est = benchmark(reconstruct_roi, img, K, 0.1, bp_uv=bp)
    assert est.ok
    # the benchmark image is a valid highlight: analytic, co-located, the normal is recovered
    assert angle_between_deg(est.cone_axis, normal) < 0.1


def test_bench_full_frame(benchmark):
    frame, K, bps = inputs.synthetic_frame()
    assert frame.shape == (1080, 1350, 3) and frame.dtype == np.uint8
    ests = benchmark(reconstruct, frame, K, 0.1)
    assert len(ests) == len(bps) == 10 and all(e.ok for e in ests)
    found = np.array([e.bp_px for e in ests])
    dist = np.linalg.norm(found[:, None, :] - bps[None, :, :], axis=2)
    # every placed BP is found once; 8-bit quantisation of a lobe whose top is flat over a few
    # pixels moves the plateau centroid by a fraction of a pixel: 1 px bounds it
    assert sorted(dist.argmin(axis=0).tolist()) == list(range(10))
    assert dist.min(axis=0).max() < 1.0
    # the frame has the clipped highlights it claims
    assert sum(e.saturated for e in ests) == 2


@pytest.mark.slow
def test_simtest_bench_runs_a_section_of_the_clone_from_the_command_line(tmp_path):
    # the console command, started away from the clone (cwd elsewhere): the package finds the
    # sections in the benchmarks/ beside it and prints the table's rows
    proc = subprocess.run([sys.executable, "-m", "simtest.cli", "bench", "--only", "reconstruct", "--repeat", "1"],
                          cwd=tmp_path, capture_output=True, text=True, timeout=1800,
                          env={**os.environ, "PYTHONPATH": str(ROOT), "COLUMNS": "250"})
    assert proc.returncode == 0, proc.stderr[-2000:]
    out = proc.stdout
    assert "simtest bench (single core)" in out and "per frame" in out and "per highlight" in out
    assert "banner" in out and "video" in out and "isocurve_fit" in out
    assert "colonoscope" in out  # the rendered scope frame (Mitsuba is a dependency)
    assert "of which its OpenCV calls, replayed alone" in out
    # the real tile's light-aware fits, in one process and shared among the workers: at --repeat
    # 1 a quick look at its smallest accepted highlights (the whole tile's fits take minutes)
    assert "assumed rig" in out and "a quick look" in out and "worker processes" in out
    assert "Traceback" not in proc.stderr


def test_bench_command_refuses_unknown_and_lists_missing_sections(monkeypatch):
    res = CliRunner().invoke(app, ["bench", "--only", "nope"])
    assert res.exit_code == 2 and "unknown bench section" in res.output
    monkeypatch.setitem(benchmarks.SECTIONS, "future", "benchmarks.no_such_module:bench_future")
    assert bench.resolve_section("future").startswith("not available")
    res = CliRunner().invoke(app, ["bench", "--only", "future"])
    assert res.exit_code == 0 and "not available" in res.output


def test_without_a_clone_the_bench_says_so_in_one_line(monkeypatch, tmp_path):
    # an install from a wheel: no benchmarks/ beside the package
    monkeypatch.setattr(bench, "CLONE_ROOT", tmp_path)
    res = CliRunner().invoke(app, ["bench", "--only", "reconstruct"])
    assert res.exit_code == 2, res.output
    assert res.output.startswith("error: the benchmarks need a clone of simtest") and res.output.count("\n") == 1
    assert "Traceback" not in res.output


def test_the_package_holds_the_runner_and_no_benchmark_bodies():
    # the sections, their inputs and their machinery live in benchmarks/; the package's runner is
    # short and loads no compiled kernels of its own
    runner = (ROOT / "simtest" / "bench.py").read_text()
    assert len(runner.splitlines()) < 200
    imported = {a.name for n in ast.walk(ast.parse(runner)) if isinstance(n, ast.Import) for a in n.names}
    imported |= {n.module for n in ast.walk(ast.parse(runner)) if isinstance(n, ast.ImportFrom)}
    assert not any(m and m.split(".")[0] in ("numba", "benchmarks") for m in imported), imported
    assert sorted(p.relative_to(ROOT).as_posix() for p in (ROOT / "simtest").rglob("*bench*.py")) == [
        "simtest/bench.py"]
    for path in (ROOT / "simtest").rglob("*.py"):
        assert "BenchResult(" not in path.read_text() or path.name == "bench.py", path


def test_every_registered_section_is_a_function_of_benchmarks():
    for name in benchmarks.SECTIONS:
        fn = bench.resolve_section(name)
        assert callable(fn) and fn.__module__.startswith("benchmarks."), (name, fn)


def test_time_ms_reports_median_and_min():
    calls = []
    med, best = timing.time_ms(lambda: calls.append(1), 5)
    assert len(calls) == 6  # one warm-up
    assert 0 <= best <= med


def test_sections_without_repeat_and_dict_results_are_shown(monkeypatch):
    def legacy():  # no repeat parameter, returns a nested dict
        return {"scenes": {"plane": {"warm": {"median_s": 0.05, "renders_per_s": 20.0}}}, "note": "x"}

    rows = bench.run_section("legacy", legacy, 3)
    assert [(r.name, r.value, r.unit) for r in rows[:2]] == [
        ("scenes/plane/warm/median_s", 0.05, "s"),
        ("scenes/plane/warm/renders_per_s", 20.0, "1/s"),
    ]
    # a string leaf (a variant's name, a scene's error) is a note, not dropped
    assert rows[2].name == "note" and np.isnan(rows[2].value) and rows[2].note == "x"
    assert bench._flatten("s", {"pair": [4, 5]})[0].note == "4 / 5"


def test_the_variant_reaches_only_sections_that_take_one(monkeypatch):
    seen = {}

    def render_like(variant="llvm_ad_rgb"):
        seen["render"] = variant
        return {"config": {"variant": 1.0}}

    def plain(repeat):
        seen["plain"] = repeat
        return []

    bench.run_section("render", render_like, 3, "cuda_ad_rgb")
    bench.run_section("plain", plain, 3, "cuda_ad_rgb")
    bench.run_section("render", render_like, 3)  # no --variant: the section's own default
    assert seen == {"render": "llvm_ad_rgb", "plain": 3}
    bench.run_section("render", render_like, 3, "cuda_ad_rgb")
    assert seen["render"] == "cuda_ad_rgb"
    res = CliRunner().invoke(app, ["bench", "--only", "render", "--variant", "cuda_ad_mono"])
    assert res.exit_code == 2 and "--variant 'cuda_ad_mono' is not one of" in res.output
    assert "Traceback" not in res.output


def test_time_ms_cpu_reports_wall_and_cpu_of_the_same_runs():
    calls = []
    med, best, cpu = timing.time_ms_cpu(lambda: calls.append(sum(range(1000))), 4)
    assert len(calls) == 5  # one warm-up
    assert 0 <= best <= med and cpu >= 0


# ---- the library's share of a frame: OpenCV calls recorded, then replayed alone ----------------


def _cv2_functions() -> dict:
    return {name: getattr(cv2, name) for name in opencv_replay.OPENCV_FUNCTIONS}


def test_opencv_calls_records_copies_in_order_and_puts_cv2_back():
    before = _cv2_functions()
    a = np.zeros((8, 8), np.float32)
    a[4, 4] = 1.0
    with opencv_replay.opencv_calls() as calls:
        blurred = cv2.GaussianBlur(a, (0, 0), 1.0)
        a[4, 4] = 5.0  # the recorded argument is the array as it was at the call
        cv2.resize(a, (4, 4), interpolation=cv2.INTER_AREA)
    assert [c.name for c in calls] == ["GaussianBlur", "resize"]
    assert calls[0].args[0][4, 4] == 1.0 and calls[1].args[0][4, 4] == 5.0
    assert np.array_equal(calls[0].fn(*calls[0].args, **calls[0].kwargs), blurred)
    assert calls[1].kwargs == {"interpolation": cv2.INTER_AREA}
    assert _cv2_functions() == before
    with pytest.raises(RuntimeError, match="inside"):
        with opencv_replay.opencv_calls():
            raise RuntimeError("inside")
    assert _cv2_functions() == before


def test_a_replay_of_an_in_place_call_starts_from_the_recorded_arguments():
    img = np.zeros((12, 12), np.uint8)
    img[3:9, 3:9] = 1
    with opencv_replay.opencv_calls() as calls:
        cv2.floodFill(img, None, (5, 5), 2, 0, 0, 4)
        cv2.dilate(img, np.ones((3, 3), np.uint8))
    assert int(img[5, 5]) == 2 and int(calls[0].args[0][5, 5]) == 1
    med, best, per = opencv_replay.replay_opencv_ms(calls, 3)
    # floodFill wrote into a copy each time: the recorded image is still the one before the fill
    assert int(calls[0].args[0][5, 5]) == 1
    assert set(per) == {"floodFill", "dilate"}
    assert 0 <= best <= med and list(per.values()) == sorted(per.values(), reverse=True)


def test_recording_a_frame_leaves_its_results_alone_and_sees_its_smoothing():
    frame, K, _ = inputs.noisy_frame()
    want = reconstruct(frame, K)
    with opencv_replay.opencv_calls() as calls:
        got = reconstruct(frame, K)
    assert [estimate_to_dict(e, True) for e in got] == [estimate_to_dict(e, True) for e in want]
    # the noisy frame (sigma 2.5 px) is smoothed once whole at half resolution for detection
    # (detect.MULTIRES_SIGMA_MIN_PX), then each candidate's window at full resolution (OpenCV's
    # GaussianBlur, one call a window), then each ROI for itself (10 highlights: fewer than
    # pipeline.LUMA_FRAME_MIN_HIGHLIGHTS, so no frame-wide smoothing for the contours)
    blurs = [c for c in calls if c.name == "GaussianBlur"]
    assert blurs[0].args[0].shape == (frame.shape[0] // 2, frame.shape[1] // 2)
    assert len(blurs) - 1 == 2 * len(want)


def test_every_image_function_the_reconstruction_calls_is_recorded():
    # the replayed row is the library's whole share only if no OpenCV call escapes the recorder
    used = set()
    for sub in ("reconstruct", "geometry"):
        for path in (ROOT / "simtest" / sub).rglob("*.py"):
            used |= set(re.findall(r"cv2\.([A-Za-z_]\w*)\(", path.read_text()))
    io = {"VideoCapture", "VideoWriter", "VideoWriter_fourcc", "imdecode", "imencode", "imread", "imwrite",
          "FileStorage"}
    # the overlay's drawing and its needles' spacing (overlay.png, after the reconstruction; not in the replayed rows)
    draw = {"batchDistance", "circle", "drawMarker", "getTextSize", "line", "polylines", "putText", "rectangle"}
    allowed = set(opencv_replay.OPENCV_FUNCTIONS)
    assert used - io - draw <= allowed, used - io - draw - allowed


def test_the_video_row_tells_the_candidates_and_the_cpu_a_frame(monkeypatch):
    """The video row's note says how many candidates a frame of the MJPG video holds and the CPU
    time a frame took in this process and its workers (the figures that tell per-frame work
    from the pool's overheads)."""
    monkeypatch.setattr(rbench, "VIDEO_WORKERS", 1)
    (row,) = rbench._bench_video(3)
    if row.value != row.value:  # NaN: no banner or no MJPG writer in this environment
        pytest.fail(f"the bench video could not be made: {row.name}")
    got = re.search(r"3 frames of (\d+) candidates .* CPU (\d+) ms a frame", row.note)
    assert got, row.note
    # both rates: from the start (the row's value) and once the pool runs (a long video's)
    rates = re.search(r"([\d.]+) frames/s from the start .*, ([\d.]+) frames/s after the first frame", row.note)
    assert rates and float(rates.group(2)) > 0, row.note
    assert float(rates.group(1)) == pytest.approx(1e3 / row.value, abs=0.051)  # one decimal shown
    assert int(got.group(1)) > 500  # the mosaic's ~640 components and MJPG's blocks
    assert 0 < int(got.group(2)) < 60_000


def test_the_decoded_video_frame_is_the_real_frame_with_thousands_of_components():
    """The real-frame row that speaks for issue 41's frame of about 5000 components is the bench
    video's first frame as the video path decodes it: the mosaic through MJPG, whose blocks
    multiply its bright components (the mosaic alone has about 640); its row's note names the
    count, every component examined."""
    got = inputs.video_first_frame()
    if got is None:
        pytest.fail("the bench video could not be made (no banner or no MJPG codec)")
    frame, K = got
    assert frame.shape == (1080, 1350, 3) and frame.dtype == np.uint8
    mosaic, K_mosaic = inputs.banner_mosaic()
    np.testing.assert_array_equal(K, K_mosaic)
    # decoded, not the mosaic itself: MJPG's error, a few levels
    assert 0 < np.abs(frame.astype(int) - mosaic).mean() < 5
    ests = reconstruct(frame, K)
    assert ests.n_unexamined == 0 and len(ests) == ests.n_components > 2000


def test_the_real_tile_row_counts_its_fits_and_names_the_missing_tile(monkeypatch, tmp_path):
    """The real tile's row (light-aware fits with an assumed rig) says how many highlights were
    fitted and what each was recommended; without the source tree it is one NaN row. The fits
    are stood in for here (they take seconds a highlight; the bench runs them)."""
    import dataclasses

    from simtest.reconstruct.lightaware import LightAwareEstimate

    def fake(img, ests, camera, rig, **kw):
        assert kw["response"].clip == 255.0 and len(rig.lights) == 2
        ok = [k for k, e in enumerate(ests) if e.ok][:3]
        ran_off = {"photometric_fit": LightAwareEstimate("photometric_fit", "not_converged", "stood in")}
        return [dataclasses.replace(e, light_aware=ran_off) if k in ok else e for k, e in enumerate(ests)]

    monkeypatch.setattr(rbench, "with_light_aware", fake)
    row, shared = rbench._bench_real_tile_rig()
    assert row.value > 0 and row.target is None
    got = re.search(r"(\d+) candidates, 3 fitted \(\d+ ms each\), recommended: bp_ray 3; CPU", row.note)
    assert got and int(got.group(1)) > 100, row.note  # the tile's glints, texture and rim
    # the same fits shared among a worker per core, and how much faster that was
    assert f"among {os.cpu_count() or 1} worker processes" in shared.name and shared.value > 0
    assert re.fullmatch(r"\d+\.\d\d times as fast as one process", shared.note), shared.note
    monkeypatch.setattr(rbench, "real_dir", lambda: tmp_path)
    (row,) = rbench._bench_real_tile_rig()
    assert row.value != row.value and "source tree not found" in row.name


def test_the_video_row_runs_on_every_core_even_when_the_bench_is_pinned_to_one():
    """`taskset -c 0 simtest bench` pins the process to one core, which its forked workers
    inherit: the video row (a target for the 2-core VM) widens the affinity for its pool and
    gives the pinning back after."""
    import os

    saved = os.sched_getaffinity(0)
    try:
        os.sched_setaffinity(0, {min(saved)})
        with timing.every_core():
            assert os.sched_getaffinity(0) == set(range(os.cpu_count())) or len(saved) < os.cpu_count()
        assert os.sched_getaffinity(0) == {min(saved)}
    finally:
        os.sched_setaffinity(0, saved)


def test_the_paper_settings_memory_row_reads_a_fresh_processs_peak(tmp_path):
    # the row's machinery on a small real tile (the banner's run is the bench's, at --repeat 5 and over):
    # a fresh `simtest reconstruct` under the paper's settings, its own peak memory and what it found
    tile = ROOT / "tests" / "data" / "real" / "hyperkvasir_tile_r1c7_mucosa.png"
    ballast = np.ones((100, 1024, 1024))  # 800 MB in this process: a child's ru_maxrss would start there
    (row,) = rbench._bench_paper_memory(tile)
    del ballast
    assert row.unit == "MB" and row.target == rbench.PAPER_PEAK_TARGET_MB
    # the child's own peak: an interpreter with numpy and OpenCV holds tens of MB, the tile's work little more
    assert 50.0 < row.value < 400.0, row
    assert "candidate(s)" in row.note and "wall" in row.note
    (missing,) = rbench._bench_paper_memory(tmp_path / "none.png")
    assert np.isnan(missing.value) and "not found" in missing.name
