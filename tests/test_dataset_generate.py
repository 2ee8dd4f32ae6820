"""Dataset generation with the real renderer: every family, schedulers, SIGKILL and resume.

Small on purpose (12 samples of 32 x 32 px at 4 spp): the properties tested (bit-identical results
whatever the scheduler, resume after SIGKILL, regeneration of one sample) do not depend on size.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from scipy.ndimage import map_coordinates

import simtest.dataset
from simtest.dataset.config import FAMILIES, config_from_dict, load_config
from simtest.dataset.generate import generate
from simtest.dataset.sample import draw_parameters, render_sample
from simtest.dataset.shards import SHARDS_DIR, array_sha256, read_manifest
from simtest.dataset.verify import verify
from simtest.geometry.conics import conic_to_ellipse

from _cases import sample_ellipse

CONFIG_TOML = """\
count = 12
seed = 77
shard_size = 2
isovalues = [0.1, 0.5]

[families]
planes = 1
spheres = 1
cylinders = 1
colon = 1
liver = 1

[params]
resolution_px = 32
spp = 4
noise_sigma = { dist = "uniform", low = 0.0, high = 0.02 }
full_well_e = 5000.0
light_offset_mm = { dist = "choice", values = [0.0, 1.0] }
"""


def _files(root: Path) -> dict[str, bytes]:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


def _array_hashes(root: Path) -> dict[tuple[int, str], str]:
    return {(r["index"], name): info["sha256"] for r in read_manifest(root)
            for name, info in r["arrays"].items()}


@pytest.fixture(scope="module")
def config_path(tmp_path_factory) -> Path:
    p = tmp_path_factory.mktemp("cfg") / "small.toml"
    p.write_text(CONFIG_TOML)
    return p


@pytest.fixture(scope="module")
def reference(tmp_path_factory, config_path) -> Path:
    """The uninterrupted run: one worker, in this process."""
    out = tmp_path_factory.mktemp("ref") / "ds"
    rep = generate(config_path, out, workers=1, progress=False)
    assert rep.written == 12
    return out


def test_reference_dataset_verifies_with_every_family(reference, config_path):
    rep = verify(reference)
    assert rep.ok, rep.problems
    cfg = load_config(config_path)
    rows = read_manifest(reference)
    assert [r["family"] for r in rows] == [draw_parameters(cfg, i)["family"] for i in range(12)]
    # the seed was chosen so that the 12 samples exercise every family with the real renderer
    assert {r["family"] for r in rows} == set(FAMILIES)
    card = json.loads((reference / "dataset.json").read_text())
    assert card["variants"] and card["counts"]["samples"] == 12
    for r in rows:
        assert r["image_size"] == [32, 32]
        K = np.asarray(r["K"])
        assert K[0, 2] == K[1, 2] == 32 / 2 - 0.5  # README Conventions: M/2 - 0.5
        for h in r["highlights"]:
            assert [iso["t"] for iso in h["isophotes"]] == [0.1, 0.5]
            assert h["k1"] >= h["k2"]


@pytest.mark.slow
def test_two_workers_and_a_dask_cluster_give_identical_datasets(reference, config_path, tmp_path):
    from distributed import LocalCluster

    ref = _files(reference)
    two = tmp_path / "two"
    generate(config_path, two, workers=2, progress=False)
    assert _files(two) == ref
    dask_out = tmp_path / "dask"
    # worker processes, as on a real cluster: samples are pickled and Mitsuba set up per process
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                      dashboard_address=None) as cluster:
        rep = generate(config_path, dask_out, scheduler=cluster.scheduler_address, progress=False)
    assert rep.written == 12
    assert _files(dask_out) == ref


@pytest.mark.slow
def test_sigkill_mid_run_then_rerun_gives_the_uninterrupted_dataset(reference, config_path, tmp_path):
    out = tmp_path / "killed"
    cmd = [sys.executable, "-m", "simtest.cli", "dataset", "generate", str(config_path),
           "--out", str(out), "--workers", "2", "--no-progress"]
    proc = subprocess.Popen(cmd, start_new_session=True, stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE)
    try:
        deadline = time.monotonic() + 120
        # the first shard done, whichever it is (the workers finish them in no fixed order: waiting
        # for shard 0 alone let a run with shard 0 last finish every shard before the kill)
        while not any((out / SHARDS_DIR).glob("*.json")):
            assert proc.poll() is None, proc.stderr.read().decode()
            assert time.monotonic() < deadline, "no shard written within 120 s"
            time.sleep(0.005)
    finally:
        os.killpg(proc.pid, signal.SIGKILL)  # the generator and its worker processes
        proc.wait()
    assert proc.returncode == -signal.SIGKILL
    # killed mid-run: some shards done, the manifest (written last) not yet there
    assert not (out / "manifest.jsonl").exists()
    assert json.loads((out / "dataset.json").read_text())["status"] == "incomplete"
    done_before = {p.name for p in (out / "shards").glob("*.json")}
    assert 0 < len(done_before) < 6

    res = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr
    assert verify(out).ok
    rows = read_manifest(out)
    assert [r["index"] for r in rows] == list(range(12))  # exactly the requested samples, once
    assert _array_hashes(out) == _array_hashes(reference)
    assert _files(out) == _files(reference)


def test_a_sample_regenerated_alone_equals_the_stored_one(reference, config_path):
    cfg = load_config(config_path)
    ds = simtest.dataset.open(reference, keys=["sensor_png", "linear", "specular", "normals", "depth",
                                               "mask", "highlight_mask"])
    for i in (11, 4):  # out of order, in a process that rendered other samples before
        alone = render_sample(cfg, i)
        stored = ds[i]
        for name, a in alone.arrays.items():
            assert array_sha256(a) == stored["record"]["arrays"][name]["sha256"], name
            assert np.array_equal(a, stored[name]), name
        row = {k: v for k, v in stored["record"].items()
               if k not in ("arrays", "shard", "npz", "labels_sha256", "split")}
        assert json.loads(json.dumps(alone.record)) == row
        assert stored["record"]["split"] == cfg.split_of(i)
    ds.close()


def test_stored_normals_match_the_highlight_records(reference):
    ds = simtest.dataset.open(reference, keys=["normals", "mask"])
    checked = 0
    for s in ds:
        for h in s["record"]["highlights"]:
            u, v = (int(round(x)) for x in h["bp_px"])
            if not (h["in_frame"] and 0 <= u < 32 and 0 <= v < 32 and s["mask"][v, u]):
                continue
            n_px = s["normals"][v, u].astype(np.float64)
            # The pixel's normal averages the surface over a pixel footprint of up to half a pixel
            # from the BP; at 32 px and 140 deg (f = 5.8 px) that is a few degrees on the most
            # curved surfaces here, so 0.9 (25 deg) only catches a wrong frame or sign.
            assert n_px @ np.asarray(h["normal"]) > 0.9
            checked += 1
    assert checked > 0
    ds.close()


def test_plane_isophote_labels_are_exact_on_the_rendered_image(tmp_path):
    """Tangent-plane conic at t: the rendered specular image equals t x peak along it (planes)."""
    cfg = config_from_dict({
        "count": 3, "seed": 1, "isovalues": [0.2, 0.5], "families": {"planes": 1.0},
        "params": {"resolution_px": 96, "spp": 16, "fov_deg": 90.0, "diffuse_albedo": 0.0,
                   "phong_n": {"dist": "uniform", "low": 20, "high": 40},
                   "view_angle_deg": {"dist": "uniform", "low": 0.0, "high": 30.0},
                   "distance_mm": {"dist": "uniform", "low": 40.0, "high": 60.0}}})
    for i in range(cfg.count):
        s = render_sample(cfg, i)
        spec = s.arrays["specular"].astype(np.float64)
        (h,) = s.record["highlights"]
        for iso in h["isophotes"]:
            e = conic_to_ellipse(np.asarray(iso["conic"]))
            assert e is not None
            uv = sample_ellipse(e, 64)
            inside = np.all((uv > 1) & (uv < 94), axis=1)
            assert inside.mean() > 0.5
            vals = map_coordinates(spec, [uv[inside, 1], uv[inside, 0]], order=1)
            # c = 1 and the falloff is cancelled, so the isophote's level is t itself. Pixels
            # average the radiance over their area and bilinear interpolation adds a second-order
            # error; with semi-axes of 4 px and more both stay below 1 % (measured 0.1 to 0.9 %):
            # 3 % catches a wrong radius or centre (a 10 % larger radius shifts the level by ~30 %).
            assert abs(vals.mean() / iso["t"] - 1.0) < 0.03, (i, iso["t"], vals.mean())


def test_bench_measures_throughput_and_worker_memory():
    from benchmarks.dataset import measure

    m = measure("planes", count=6, workers=2, seed=5, resolution_px=24, spp=2)
    for label in ("cold", "warm"):
        r = m[label]
        assert r["count"] == 6
        assert r["steady_ms"] > 0 and r["end_to_end_ms"] > 0 and r["cpu_ms"] > 0
        assert 20 < r["peak_rss_mib"] < 4096  # a Python process with Mitsuba: tens to hundreds of MiB


def test_bench_stages_split_the_cost_and_restore_the_thread_count():
    import drjit as dr

    from benchmarks.dataset import stages

    before = dr.thread_count()
    dr.set_thread_count(2)  # not the one thread the stages run on (nor an xdist worker's: conftest)
    try:
        st = stages("colon", count=2, seed=5, resolution_px=24, spp=2, warmup=1)
        assert dr.thread_count() == 2
    finally:
        dr.set_thread_count(before)
    parts = [st[k] for k in ("render", "truth", "encode", "write")]
    assert all(p > 0 for p in parts), st  # each stage was reached and timed
    assert st["total"] == pytest.approx(sum(parts))
    assert st["count"] == 2 and st["wall_ms"] > 0


_THREADS_SCRIPT = """
import hashlib, json, sys
from simtest._llvm import configure_llvm_env
configure_llvm_env()
import drjit as dr
import copy
from simtest.dataset.config import config_from_dict, load_config
from simtest.dataset.sample import render_sample
import numpy as np
raw = copy.deepcopy(load_config("scenes/datasets/example.toml").raw)
raw["params"]["colon"].update(appearance=sys.argv[1],
                              light_rig="point" if sys.argv[1] == "phong" else "colonoscope")
for n in (1, 2):
    dr.set_thread_count(n)
    s = render_sample(config_from_dict(raw), 3)
    tiny = {k: int(np.sum((a != 0) & (np.abs(a) < np.finfo(np.float32).tiny)))
            for k, a in s.arrays.items() if a.dtype == np.float32}
    print(json.dumps({"threads": dr.thread_count(), "family": s.record["family"], "tiny": tiny,
                      "size": s.record["image_size"],
                      "sha": {k: hashlib.sha256(a.tobytes()).hexdigest() for k, a in s.arrays.items()}}))
"""


@pytest.mark.parametrize("appearance", ["phong", "tissue"])
def test_a_render_does_not_depend_on_the_drjit_thread_count(appearance):
    """Sample 3 of the example config (colon, 256 x 256 px, 16 spp) with 1 and with 2 Dr.Jit threads,
    grey Phong under one light and the virtual endoscope's tissue under the colonoscope rig.

    With one thread Dr.Jit runs the kernel on the calling thread, which keeps float32 denormals;
    its pool threads flush them to zero. A Phong lobe below 2^-126 once made one `specular` pixel
    of this very sample read 1.4848451e-30 with 1 thread and 1.484845e-30 with 2 (so worker counts
    changed the files); the lobe cut at 2^-100 (simtest.render.phong.LOBE_LOG2_MIN) leaves no
    denormal anywhere in the kernel.
    """
    repo = Path(__file__).resolve().parents[1]
    # both thread counts in one fresh process (not an xdist worker's one thread, conftest): the
    # second render runs the same kernels on Dr.Jit's pool threads, where denormals are flushed
    out = subprocess.run([sys.executable, "-c", _THREADS_SCRIPT, appearance], cwd=repo,
                         capture_output=True, text=True, check=True).stdout
    runs = [json.loads(line) for line in out.splitlines()]
    assert [r["threads"] for r in runs] == [1, 2]
    assert runs[0]["family"] == "colon" and runs[0]["size"] == [256, 256]
    assert runs[0]["sha"] == runs[1]["sha"]
    assert runs[0]["tiny"] == {"linear": 0, "specular": 0, "normals": 0, "depth": 0}


def test_a_dataloader_over_every_family_with_the_default_torch_view(reference):
    """The issue's case: DataLoader over a dataset whose per-family records differ (2 workers)."""
    import torch

    view = simtest.dataset.open(reference).torch()
    loader = torch.utils.data.DataLoader(view, batch_size=4, num_workers=2)
    batches = list(loader)
    assert [b["sensor"].shape for b in batches] == [(4, 1, 32, 32)] * 3
    families = {view.record(i)["family"] for b in batches for i in b["index"].tolist()}
    assert families == set(FAMILIES)


def test_auto_exposure_brings_the_percentile_to_the_level():
    """A dim colon view (falloff kept): the 99.9th percentile of the surface reaches 0.9 x 255."""
    cfg = config_from_dict({
        "count": 1, "seed": 3, "families": {"colon": 1.0},
        "params": {"resolution_px": 48, "spp": 4, "light_falloff": "keep", "light_intensity": 200.0,
                   "diffuse_albedo": 0.5, "exposure": 1.0, "noise_sigma": 0.0, "full_well_e": 0.0},
    })
    s = render_sample(cfg, 0)
    mask = s.arrays["mask"]
    img = simtest.dataset.shards.decode_png(s.arrays["sensor_png"]).astype(np.float64)
    e = s.record["exposure_applied"]
    linear = s.arrays["linear"].astype(np.float64)
    # the exposure is exactly the one that maps the percentile to the level (noise-free sensor) ...
    assert e == pytest.approx(0.9 / np.percentile(linear[mask], 99.9), rel=1e-6)
    # ... and the 8-bit image shows it: percentiles commute with the scale, then rounding (< 1 level)
    assert abs(np.percentile(img[mask], 99.9) - 0.9 * 255) <= 1.0
    assert e > 1.5  # this view is dim: without auto-exposure it would not use the range


def test_each_sample_carries_its_camera_file(reference, tmp_path):
    """The row's camera file loads with the camera-file reader and matches the render's K and light."""
    from simtest.geometry.camera_file import load_camera

    rows = read_manifest(reference)
    for r in rows:
        path = tmp_path / f"{r['index']}.json"
        path.write_text(json.dumps(r["camera"]))
        cam = load_camera(path)
        assert np.array_equal(cam.model.K, np.asarray(r["K"]))
        assert tuple(cam.model.image_size) == (32, 32)
        (light,) = cam.lights.lights
        cancel = r["params"]["light_falloff"] == "cancel"
        assert light.falloff == ("none" if cancel else "inverse_square")
        # the light sits at epsilon (cos a, sin a, b) with b = 0 here: |position| = epsilon
        assert r["params"]["light_offset_b"] == 0
        assert np.linalg.norm(light.position) == pytest.approx(r["params"]["light_offset_mm"], abs=1e-9)


def test_tissue_samples_are_rgb_video_frames_lit_by_their_rig(tmp_path):
    """appearance "tissue": an sRGB frame of the virtual endoscope's tissue, with the rig in the row."""
    import torch

    from simtest.geometry.camera_file import load_camera

    cfg = config_from_dict({
        "count": 4, "seed": 11, "shard_size": 2, "families": {"colon": 1.0, "liver": 1.0, "planes": 1.0},
        "params": {"resolution_px": 32, "spp": 4, "appearance": "tissue", "relief_mm": 0.002,
                   "light_falloff": "keep", "light_intensity": 400.0,
                   "light_rig": {"dist": "choice", "values": ["colonoscope", "laparoscope", "point"]}},
    })
    out = tmp_path / "ds"
    generate(cfg, out, workers=1, progress=False)
    assert verify(out).ok
    n_lights = {"colonoscope": 2, "laparoscope": 8, "point": 1}
    ds = simtest.dataset.open(out)
    for i in range(cfg.count):
        item = ds[i]
        r, img, mask = item["record"], item["sensor"], item["mask"]
        assert r["color"] == "rgb" and img.shape == (32, 32, 3) and img.dtype == np.uint8
        # procedural mucosa and liver are red-dominant: a grey image copied to 3 channels is not
        assert img[mask][:, 0].mean() > img[mask][:, 2].mean() + 10
        path = tmp_path / f"{i}.json"
        path.write_text(json.dumps(r["camera"]))
        assert len(load_camera(path).lights.lights) == n_lights[r["params"]["light_rig"]]
        again = render_sample(cfg, i)  # a sample is a pure function of (config, index)
        assert all(np.array_equal(again.arrays[k], v) for k, v in item.items() if k in again.arrays)
    batch = next(iter(torch.utils.data.DataLoader(ds.torch(), batch_size=2)))
    assert batch["sensor"].shape == (2, 3, 32, 32)


def test_the_appearance_parameters_leave_the_earlier_draws_alone():
    """They come last in the draw order: a config written before them draws the same values."""
    base = {"count": 8, "seed": 5, "families": {"planes": 1.0, "colon": 1.0},
            "params": {"phong_n": {"dist": "uniform", "low": 30, "high": 90}}}
    old = config_from_dict(base)
    new = config_from_dict({**base, "params": {**base["params"], "appearance": {
        "dist": "choice", "values": ["phong", "tissue"]}, "light_rig": "colonoscope"}})
    for i in range(old.count):
        a, b = draw_parameters(old, i), draw_parameters(new, i)
        assert a["appearance"] == "phong" and a["light_rig"] == "point"
        assert {k: v for k, v in a.items() if k not in ("appearance", "light_rig", "render_seed")} == \
               {k: v for k, v in b.items() if k not in ("appearance", "light_rig", "render_seed")}
    assert old.fingerprint() != new.fingerprint()
