"""Renderer speed: pytest-benchmark tests (plain tests under --benchmark-disable in CI).

406 x 406 px at 16 spp with the image and all ground truth, llvm, 2 threads, kernel cache warm
(the first call compiles). Targets from the issue: >= 10 renders/s for the plane, >= 2 for the
colon. Speed is reported, never asserted; the assertions check that each timed render did its
whole job. ``benchmarks.render.bench_render`` adds cold-cache and scene-rebuild figures.
"""

from __future__ import annotations

import numpy as np
import pytest

from simtest.render import render_scene
from simtest.scene import with_overrides
from benchmarks.render import _bench_spec, bench_render

pytestmark = pytest.mark.render


@pytest.mark.parametrize("scene", ["plane_58deg", "colon"])
def test_bench_render_406_16spp(benchmark, scene):
    import drjit as dr

    spec = _bench_spec(scene, 406, 16)
    render_scene(spec, seed=0, variant="llvm_ad_rgb")  # compile (or load cached kernels)
    dr.set_thread_count(2)
    seeds = iter(range(1, 1_000_000))
    result = benchmark(lambda: render_scene(spec, seed=next(seeds), variant="llvm_ad_rgb"))
    assert result.linear.shape == (406, 406)
    assert result.mask.any() and np.isfinite(result.normals[result.mask]).all()
    assert len(result.highlights) >= 1


@pytest.mark.slow
def test_bench_render_function_reports_per_scene(monkeypatch):
    # the endoscope part (bench_endoscope, every preset, the plain-Mitsuba and tube comparisons) runs on
    # its presets shrunk to a tenth of their film at 1 spp: the runner is checked, not the speed
    import benchmarks.render as brender

    full = brender.load_scene

    def tenth(name):
        spec = full(name)
        return with_overrides(spec, {"camera.width_px": round(spec.camera.width_px / 10),
                                     "camera.height_px": round(spec.camera.height_px / 10), "render.spp": 1})

    monkeypatch.setattr(brender, "load_scene", tenth)
    out = bench_render(["plane_fronto", "no_such_scene"], size_px=32, spp=1, repeats=1, cold=False)
    entry = out["scenes"]["plane_fronto"]
    assert entry["warm"]["renders_per_s"] > 0 and entry["warm_rebuild"]["median_s"] > 0
    assert entry["warm_new_view"]["cpu_s"] > 0
    assert entry["highlights"] == 1
    assert "error" in out["scenes"]["no_such_scene"]
    assert out["config"]["threads"] == 2
    endo = out["endoscope"]
    assert sorted(endo["presets"]) == sorted(brender.ENDOSCOPE_PRESETS)
    for name, row in endo["presets"].items():
        assert row["renders_per_s"] > 0 and row["cpu_s"] > 0 and row["spp"] == 1, name
        assert row["film_px"] < 150 * 150, name  # the shrunk film: the patched loader was used
    plain = endo["colonoscope_vs_plain"]
    assert plain["tissue_s"] > 0 and plain["plain_mitsuba_s"] > 0
    assert plain["ratio"] == plain["tissue_s"] / plain["plain_mitsuba_s"]
    tube = endo["colonoscope_vs_tube"]  # issue 62's bound: the haustral colon against the former tube
    assert tube["haustral_s"] > 0 and tube["tube_s"] > 0 and tube["ratio"] == tube["haustral_s"] / tube["tube_s"]
    assert tube["ratio_target"] == brender.TUBE_RATIO_TARGET


def test_compare_variants_of_one_variant_finds_no_difference_and_names_a_missing_one():
    # the same variant twice in two processes: a render repeats bit for bit, so every measured
    # difference is exactly zero (the GPU's figures beside the CPU's come from this function)
    from benchmarks.render import compare_variants

    out = compare_variants("plane_58deg", ("llvm_ad_rgb", "llvm_ad_rgb"))
    assert out["hit_differs_px"] == 0 and out["linear_max_rel"] == 0.0
    assert out["normal_p999_deg"] == 0.0 and out["depth_p999_rel"] == 0.0
    assert out["sensor_equal_frac"] == 1.0 and out["bp_max_px"] == 0.0
    assert out["highlights"] == [1, 1] and out["px"] > 0  # (its figures: test_variant_differences_...)
    # the missing variant first: its process fails before any render (the loop names whichever
    # variant fails; with it second, a render of the first came before, 1/3 of the test's CPU)
    bad = compare_variants("plane_58deg", ("no_such_variant", "llvm_ad_rgb"))
    assert set(bad) == {"error"} and bad["error"].startswith("no_such_variant: ") and "Traceback" not in bad["error"]


def test_variant_differences_measure_a_known_perturbation():
    # a render against itself with one hit pixel lost, its linear image 1 % brighter, its normals
    # turned 0.1 deg about x, its depth 2 % deeper, its BP 0.5 px off and a quarter of its sensor
    # values changed: each figure is that change, over the pixels both hit
    from benchmarks.render import variant_differences

    rng = np.random.default_rng(0)
    mask = np.ones((8, 8), bool)
    mask[0, :3] = False
    t = np.radians(0.1)
    normals = np.tile([0.0, 0.0, -1.0], (8, 8, 1))
    a = {"mask": mask, "linear": rng.uniform(0.5, 1.0, (8, 8)), "normals": normals, "depth": np.full((8, 8), 20.0),
         "bp_px": np.array([[3.0, 4.0]]), "sensor": np.zeros((8, 8), np.uint8)}
    rot = np.array([[1.0, 0.0, 0.0], [0.0, np.cos(t), -np.sin(t)], [0.0, np.sin(t), np.cos(t)]])
    sensor = a["sensor"].copy()
    sensor[:2] = 1
    b = {"mask": mask & ~np.eye(8, dtype=bool), "linear": a["linear"] * 1.01, "normals": normals @ rot.T,
         "depth": a["depth"] * 1.02, "bp_px": a["bp_px"] + [0.5, 0.0], "sensor": sensor}
    out = variant_differences(a, b)
    both = mask & ~np.eye(8, dtype=bool)
    assert out["px"] == both.sum() == 64 - 3 - 7 and out["hit_differs_px"] == 7  # (0, 0) is in both
    ref = np.percentile(a["linear"][both], 99)
    assert out["linear_max_rel"] == pytest.approx(0.01 * a["linear"][both].max() / ref, rel=1e-12)
    assert out["normal_p999_deg"] == pytest.approx(0.1, abs=1e-9)
    assert out["depth_p999_rel"] == pytest.approx(0.02, rel=1e-12)
    assert out["bp_max_px"] == 0.5 and out["sensor_equal_frac"] == 0.75 and out["highlights"] == [1, 1]
