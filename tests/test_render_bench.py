"""Renderer speed: pytest-benchmark tests (plain tests under --benchmark-disable in CI).

406 x 406 px at 16 spp with the image and all ground truth, llvm, 2 threads, kernel cache warm
(the first call compiles). Targets from the issue: >= 10 renders/s for the plane, >= 2 for the
colon. Speed is reported, never asserted; the assertions check that each timed render did its
whole job. ``simtest.render.bench.bench_render`` adds cold-cache and scene-rebuild figures.
"""

from __future__ import annotations

import numpy as np
import pytest

from simtest.render import render_scene
from simtest.render.bench import _bench_spec, bench_render

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


def test_bench_render_function_reports_per_scene():
    out = bench_render(["plane_fronto", "no_such_scene"], size_px=32, spp=1, repeats=1, cold=False)
    entry = out["scenes"]["plane_fronto"]
    assert entry["warm"]["renders_per_s"] > 0 and entry["warm_rebuild"]["median_s"] > 0
    assert entry["warm_new_view"]["cpu_s"] > 0
    assert entry["highlights"] == 1
    assert "error" in out["scenes"]["no_such_scene"]
    assert out["config"]["threads"] == 2
