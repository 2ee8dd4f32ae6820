"""Speed of the reconstruction (pytest-benchmark; plain tests under --benchmark-disable) and the
`simtest bench` command. No timed asserts: the figures are read from the benchmark report."""

from __future__ import annotations

import importlib
import os
import re
from pathlib import Path

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from simtest import bench
from simtest.cli import app
from simtest.geometry import angle_between_deg
from simtest.reconstruct import reconstruct, reconstruct_roi
from simtest.reconstruct.io import estimate_to_dict


def test_bench_per_specularity(benchmark):
    img, K, bp, normal = bench.synthetic_roi_image()
    assert img.shape == (100, 100)
    est = benchmark(reconstruct_roi, img, K, 0.1, bp_uv=bp)
    assert est.ok
    # the benchmark image is a valid highlight: analytic, co-located, the normal is recovered
    assert angle_between_deg(est.cone_axis, normal) < 0.1


def test_bench_full_frame(benchmark):
    frame, K, bps = bench.synthetic_frame()
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


def test_bench_command_reconstruct_section():
    res = CliRunner().invoke(app, ["bench", "--only", "reconstruct", "--repeat", "1"])
    assert res.exit_code == 0, res.output
    assert "per frame" in res.output and "per highlight" in res.output and "banner" in res.output
    assert "colonoscope" in res.output  # the rendered scope frame (Mitsuba is a dependency)


def test_bench_command_refuses_unknown_and_lists_missing_sections(monkeypatch):
    res = CliRunner().invoke(app, ["bench", "--only", "nope"])
    assert res.exit_code == 2 and "unknown bench section" in res.output
    monkeypatch.setitem(bench.EXTERNAL_SECTIONS, "future", "simtest.no_such_module:bench_future")
    assert bench.resolve_section("future") is None
    res = CliRunner().invoke(app, ["bench", "--only", "future"])
    assert res.exit_code == 0 and "not available" in res.output


def test_time_ms_reports_median_and_min():
    calls = []
    med, best = bench.time_ms(lambda: calls.append(1), 5)
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
    med, best, cpu = bench.time_ms_cpu(lambda: calls.append(sum(range(1000))), 4)
    assert len(calls) == 5  # one warm-up
    assert 0 <= best <= med and cpu >= 0


# ---- the library's share of a frame: OpenCV calls recorded, then replayed alone ----------------


def _cv2_functions() -> dict:
    return {name: getattr(cv2, name) for name in bench.OPENCV_FUNCTIONS}


def test_opencv_calls_records_copies_in_order_and_puts_cv2_back():
    before = _cv2_functions()
    a = np.zeros((8, 8), np.float32)
    a[4, 4] = 1.0
    with bench.opencv_calls() as calls:
        blurred = cv2.GaussianBlur(a, (0, 0), 1.0)
        a[4, 4] = 5.0  # the recorded argument is the array as it was at the call
        cv2.resize(a, (4, 4), interpolation=cv2.INTER_AREA)
    assert [c.name for c in calls] == ["GaussianBlur", "resize"]
    assert calls[0].args[0][4, 4] == 1.0 and calls[1].args[0][4, 4] == 5.0
    assert np.array_equal(calls[0].fn(*calls[0].args, **calls[0].kwargs), blurred)
    assert calls[1].kwargs == {"interpolation": cv2.INTER_AREA}
    assert _cv2_functions() == before
    with pytest.raises(RuntimeError, match="inside"):
        with bench.opencv_calls():
            raise RuntimeError("inside")
    assert _cv2_functions() == before


def test_a_replay_of_an_in_place_call_starts_from_the_recorded_arguments():
    img = np.zeros((12, 12), np.uint8)
    img[3:9, 3:9] = 1
    with bench.opencv_calls() as calls:
        cv2.floodFill(img, None, (5, 5), 2, 0, 0, 4)
        cv2.dilate(img, np.ones((3, 3), np.uint8))
    assert int(img[5, 5]) == 2 and int(calls[0].args[0][5, 5]) == 1
    med, best, per = bench.replay_opencv_ms(calls, 3)
    # floodFill wrote into a copy each time: the recorded image is still the one before the fill
    assert int(calls[0].args[0][5, 5]) == 1
    assert set(per) == {"floodFill", "dilate"}
    assert 0 <= best <= med and list(per.values()) == sorted(per.values(), reverse=True)


def test_recording_a_frame_leaves_its_results_alone_and_sees_its_smoothing():
    frame, K, _ = bench.noisy_frame()
    want = reconstruct(frame, K)
    with bench.opencv_calls() as calls:
        got = reconstruct(frame, K)
    assert [estimate_to_dict(e, True) for e in got] == [estimate_to_dict(e, True) for e in want]
    # the noisy frame (sigma 2.5 px) is smoothed once whole at half resolution for detection
    # (detect.MULTIRES_SIGMA_MIN_PX; each candidate's window at full resolution by a compiled
    # kernel, _detect_kernels.window_component), then each ROI for itself (10 highlights: fewer
    # than pipeline.LUMA_FRAME_MIN_HIGHLIGHTS, so no frame-wide smoothing for the contours)
    blurs = [c for c in calls if c.name == "GaussianBlur"]
    assert blurs[0].args[0].shape == (frame.shape[0] // 2, frame.shape[1] // 2)
    assert len(blurs) - 1 == len(want)


def test_every_image_function_the_reconstruction_calls_is_recorded():
    # the replayed row is the library's whole share only if no OpenCV call escapes the recorder
    root = Path(bench.__file__).resolve().parent
    used = set()
    for sub in ("reconstruct", "geometry"):
        for path in (root / sub).glob("*.py"):
            used |= set(re.findall(r"cv2\.([A-Za-z_]\w*)\(", path.read_text()))
    io = {"VideoCapture", "imdecode", "imread", "imwrite", "FileStorage"}
    assert used - io <= set(bench.OPENCV_FUNCTIONS), used - io - set(bench.OPENCV_FUNCTIONS)


# ---- the compiled kernels' share of a frame: timed in place -------------------------------------


def _kernel_functions() -> dict:
    out = {}
    for mod_name in bench.KERNEL_MODULES:
        mod = importlib.import_module(mod_name)
        out.update({(mod_name, n): getattr(mod, n) for n in bench._dispatchers(mod)})
    return out


def test_kernel_times_sums_each_kernel_and_puts_the_modules_back():
    from simtest.reconstruct import _kernels

    before = _kernel_functions()
    assert ("simtest.reconstruct._kernels", "border_median") in before
    vals = np.arange(30.0).reshape(5, 6)
    frame, K, _ = bench.noisy_frame()
    want = reconstruct(frame, K)
    with bench.kernel_times() as times:
        m = _kernels.border_median(vals)
        _kernels.border_median(vals)
        got = reconstruct(frame, K)
    assert m == np.median(np.concatenate([vals[0], vals[-1], vals[1:-1, 0], vals[1:-1, -1]]))
    # each call went through its timer (the frame's own border medians among them), and the
    # frame's results are those of an untimed run
    assert times["border_median"] > 0 and {"top_hat_rows", "peak_mask_rows"} <= set(times)
    assert [estimate_to_dict(e, True) for e in got] == [estimate_to_dict(e, True) for e in want]
    assert _kernel_functions() == before
    with pytest.raises(RuntimeError, match="inside"):
        with bench.kernel_times():
            raise RuntimeError("inside")
    assert _kernel_functions() == before
    med, best, per = bench.kernel_ms(lambda: _kernels.border_median(vals), 3)
    assert list(per) == ["border_median"] and 0 < best <= med


def test_every_compiled_kernel_the_reconstruction_calls_is_timed():
    # the in-place row is the kernels' whole share only if the pipeline calls each of them as an
    # attribute of its module (a name imported from it would escape the timer)
    root = Path(bench.__file__).resolve().parent / "reconstruct"
    alias = {"_kernels": "simtest.reconstruct._kernels", "_dk": "simtest.reconstruct._detect_kernels"}
    wrapped = {mod: set(bench._dispatchers(importlib.import_module(mod))) for mod in bench.KERNEL_MODULES}
    called = set()
    for path in root.glob("*.py"):
        if path.stem in {m.rsplit(".", 1)[1] for m in bench.KERNEL_MODULES}:
            continue
        text = path.read_text()
        for a, name in re.findall(r"\b(_kernels|_dk)\.([A-Za-z_]\w*)\(", text):
            called.add((alias[a], name))
        for mod, names in re.findall(r"from simtest\.reconstruct\.(_\w*kernels) import ([^\n]+)", text):
            imported = {n.split(" as ")[0].strip() for n in names.split(",")}
            assert not imported & wrapped[f"simtest.reconstruct.{mod}"], (path.name, imported)
    assert called and all(name in wrapped[mod] for mod, name in called), called


def test_the_video_row_tells_the_candidates_and_the_cpu_a_frame(monkeypatch):
    """The video row's note says how many candidates a frame of the MJPG video holds and the CPU
    time a frame took in this process and its workers (the figures that tell per-frame work
    from the pool's overheads)."""
    monkeypatch.setattr(bench, "VIDEO_WORKERS", 1)
    (row,) = bench._bench_video(3)
    if row.value != row.value:  # NaN: no banner or no MJPG writer in this environment
        pytest.fail(f"the bench video could not be made: {row.name}")
    got = re.search(r"3 frames of (\d+) candidates .* CPU (\d+) ms a frame", row.note)
    assert got, row.note
    # both rates: from the start (the row's value) and once the pool runs (a long video's)
    rates = re.search(r"([\d.]+) frames/s from the start .*, ([\d.]+) frames/s after the first frame", row.note)
    assert rates and float(rates.group(2)) > 0, row.note
    assert float(rates.group(1)) == pytest.approx(1e3 / row.value, rel=0.06)  # one decimal shown
    assert int(got.group(1)) > 500  # the mosaic's ~640 components and MJPG's blocks
    assert 0 < int(got.group(2)) < 60_000


def test_the_decoded_video_frame_is_the_real_frame_with_thousands_of_components():
    """The real-frame row that speaks for issue 41's frame of about 5000 components is the bench
    video's first frame as the video path decodes it: the mosaic through MJPG, whose blocks
    multiply its bright components (the mosaic alone has about 640); its row's note names the
    count, every component examined."""
    got = bench.video_first_frame()
    if got is None:
        pytest.fail("the bench video could not be made (no banner or no MJPG codec)")
    frame, K = got
    assert frame.shape == (1080, 1350, 3) and frame.dtype == np.uint8
    mosaic, K_mosaic = bench.banner_mosaic()
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

    monkeypatch.setattr(bench, "with_light_aware", fake)
    row, shared = bench._bench_real_tile_rig()
    assert row.value > 0 and row.target is None
    got = re.search(r"(\d+) candidates, 3 fitted \(\d+ ms each\), recommended: bp_ray 3; CPU", row.note)
    assert got and int(got.group(1)) > 100, row.note  # the tile's glints, texture and rim
    # the same fits shared among a worker per core, and how much faster that was
    assert f"among {os.cpu_count() or 1} worker processes" in shared.name and shared.value > 0
    assert re.fullmatch(r"\d+\.\d\d times as fast as one process", shared.note), shared.note
    monkeypatch.setattr(bench, "real_dir", lambda: tmp_path)
    (row,) = bench._bench_real_tile_rig()
    assert row.value != row.value and "source tree not found" in row.name


def test_the_video_row_runs_on_every_core_even_when_the_bench_is_pinned_to_one():
    """`taskset -c 0 simtest bench` pins the process to one core, which its forked workers
    inherit: the video row (a target for the 2-core VM) widens the affinity for its pool and
    gives the pinning back after."""
    import os

    saved = os.sched_getaffinity(0)
    try:
        os.sched_setaffinity(0, {min(saved)})
        with bench._every_core():
            assert os.sched_getaffinity(0) == set(range(os.cpu_count())) or len(saved) < os.cpu_count()
        assert os.sched_getaffinity(0) == {min(saved)}
    finally:
        os.sched_setaffinity(0, saved)
