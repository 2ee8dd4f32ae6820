"""Dataset format, resume, verify and reader, driven by a fast stand-in sample function.

The stand-in draws arrays from the same per-sample generator as the real sampler, so these tests
exercise the writer, the manifest, resume, verification and reading without rendering; the real
renderer is exercised end to end in tests/test_dataset_generate.py.
"""

from __future__ import annotations

import io
import json
import zipfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from PIL import Image

import simtest.dataset
from simtest.dataset.config import config_from_dict
from simtest.dataset.generate import SampleError, generate
from simtest.dataset.sample import Sample, _encode_png, sample_rng
from simtest.dataset.shards import (
    DatasetError,
    array_sha256,
    decode_png,
    read_manifest,
    shard_json_path,
    shard_npz_path,
)
from simtest.dataset.verify import verify


def standin_sample(config, index):
    """Arrays with the real channel layout, drawn from SeedSequence([seed, index])."""
    rng = sample_rng(config.seed, index)
    h = w = 8 + index % 3  # sizes vary between samples, as a resolution distribution allows
    K = np.array([[10.0, 0.0, (w - 1) / 2], [0.0, 10.0, (h - 1) / 2], [0.0, 0.0, 1.0]])
    v, u = np.mgrid[0:h, 0:w]
    rays = np.stack([u, v, np.ones_like(u)], -1) @ np.linalg.inv(K).T
    rays /= np.linalg.norm(rays, axis=-1, keepdims=True)
    jitter = rng.normal(size=(h, w, 3))
    jitter /= np.linalg.norm(jitter, axis=-1, keepdims=True)
    n = -rays + 0.3 * jitter  # n . ray <= -0.7 before normalising: faces the camera
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    mask = rng.random((h, w)) > 0.2
    n = np.where(mask[..., None], n, 0.0).astype(np.float32)
    linear = rng.random((h, w)).astype(np.float32)
    sensor = (np.clip(linear, 0, 1) * 255).astype(np.uint8)
    arrays = {
        "sensor_png": _encode_png(sensor),
        "linear": linear,
        "specular": (linear * 0.5).astype(np.float32),
        "normals": n,
        "depth": np.where(mask, 10.0 + rng.random((h, w)), 0.0).astype(np.float32),
        "mask": mask,
        "highlight_mask": linear > 0.9,
    }
    record = {"index": index, "family": "planes", "params": {"family": "planes", "x": float(rng.random())},
              "K": K.tolist(), "cam_to_world": np.eye(4).tolist(), "image_size": [w, h],
              "variant": "standin", "highlights": [{"bp_px": [1.0, 2.0], "normal": [0.0, 0.0, -1.0],
                                                    "k1": 0.0, "k2": 0.0, "in_frame": True}]}
    return Sample(index=index, arrays=arrays, record=record)


def failing_sample(config, index):
    if index == 5:
        raise RuntimeError("boom")
    return standin_sample(config, index)


def _cfg(count=10, shard_size=3, seed=11):
    return config_from_dict({"count": count, "seed": seed, "shard_size": shard_size,
                             "families": {"planes": 1.0}}, source="standin.toml")


def _files(root: Path) -> dict[str, bytes]:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


def _make(tmp_path, name="ds", **kw):
    cfg = _cfg(**kw)
    out = tmp_path / name
    rep = generate(cfg, out, workers=1, sample_fn=standin_sample, progress=False)
    return cfg, out, rep


def test_layout_card_manifest_and_verify(tmp_path):
    cfg, out, rep = _make(tmp_path)
    assert (rep.written, rep.skipped, rep.count) == (10, 0, 10)
    assert sorted(p.name for p in (out / "shards").iterdir()) == [
        f"shard-{s:05d}.{ext}" for s in range(4) for ext in ("json", "npz")]
    card = json.loads((out / "dataset.json").read_text())
    assert card["status"] == "complete" and card["count"] == 10 and card["seed"] == 11
    assert card["counts"]["samples"] == 10 and card["counts"]["by_family"] == {"planes": 10}
    assert card["config_fingerprint"] == cfg.fingerprint()
    assert {"normals", "depth", "sensor_png"} <= set(card["channels"])
    assert card["conventions"]["lengths"] == "millimetres"
    rows = read_manifest(out)
    assert [r["index"] for r in rows] == list(range(10))
    readme = (out / "README.md").read_text()
    assert "np.load" in readme and "sensor_png" in readme
    rep = verify(out)
    assert rep.ok, rep.problems
    assert (rep.samples, rep.shards) == (10, 4)


def test_rerun_of_a_complete_dataset_changes_nothing(tmp_path):
    cfg, out, _ = _make(tmp_path)
    before = _files(out)
    rep = generate(cfg, out, workers=1, sample_fn=standin_sample, progress=False)
    assert (rep.written, rep.skipped) == (0, 10)
    assert _files(out) == before


def test_resume_redoes_partial_shards_and_keeps_complete_ones(tmp_path):
    cfg, ref, _ = _make(tmp_path, "ref")
    reference = _files(ref)
    _, out, _ = _make(tmp_path, "out")
    # Simulate a run killed mid-way: shard 1 half-written (temporary file), shard 2 renamed but
    # its row file never written, shard 3 missing, manifest not yet written, card incomplete.
    shard_npz_path(out, 1).rename(shard_npz_path(out, 1).with_name("shard-00001.npz.tmp"))
    shard_json_path(out, 1).unlink()
    shard_json_path(out, 2).unlink()
    shard_npz_path(out, 3).unlink()
    shard_json_path(out, 3).unlink()
    (out / "manifest.jsonl").unlink()
    mtime0 = shard_npz_path(out, 0).stat().st_mtime_ns
    calls = []

    def counting(config, index):  # not picklable, fine inline
        calls.append(index)
        return standin_sample(config, index)

    rep = generate(cfg, out, workers=1, sample_fn=counting, progress=False)
    assert sorted(calls) == list(range(3, 10))  # shards 1..3 redone, shard 0 skipped
    assert (rep.written, rep.skipped) == (7, 3)
    assert shard_npz_path(out, 0).stat().st_mtime_ns == mtime0
    assert _files(out) == reference
    assert verify(out).ok


def test_failed_sample_keeps_complete_shards_and_resumes(tmp_path):
    cfg = _cfg()
    out = tmp_path / "ds"
    with pytest.raises(SampleError, match="sample 5: RuntimeError: boom"):
        generate(cfg, out, workers=1, sample_fn=failing_sample, progress=False)
    assert shard_json_path(out, 0).exists()  # samples 0..2 made it
    assert not list((out / "shards").glob("*.tmp"))  # the partial shard was removed
    assert not (out / "manifest.jsonl").exists()
    assert not verify(out).ok  # incomplete datasets do not verify
    generate(cfg, out, workers=1, sample_fn=standin_sample, progress=False)
    _, ref, _ = _make(tmp_path, "ref")
    assert _files(out) == _files(ref)


def test_refuses_another_configs_folder_and_unrelated_folders(tmp_path):
    cfg, out, _ = _make(tmp_path)
    with pytest.raises(DatasetError, match="different config"):
        generate(_cfg(seed=12), out, workers=1, sample_fn=standin_sample, progress=False)
    other = tmp_path / "other"
    other.mkdir()
    (other / "notes.txt").write_text("mine")
    with pytest.raises(DatasetError, match="not empty"):
        generate(cfg, other, workers=1, sample_fn=standin_sample, progress=False)
    assert sorted(p.name for p in other.iterdir()) == ["notes.txt"]


def test_shards_are_byte_identical_between_runs(tmp_path):
    _, a, _ = _make(tmp_path, "a")
    _, b, _ = _make(tmp_path, "b")
    assert _files(a) == _files(b)


def _rewrite_entry(npz: Path, key: str, arr: np.ndarray) -> None:
    """Replace one entry of a shard (a corruption that keeps the zip valid)."""
    with zipfile.ZipFile(npz) as z:
        entries = {n: z.read(n) for n in z.namelist()}
    buf = io.BytesIO()
    np.lib.format.write_array(buf, arr)
    entries[key + ".npy"] = buf.getvalue()
    with zipfile.ZipFile(npz, "w") as z:
        for n, data in entries.items():
            z.writestr(n, data)


def test_verify_catches_corruption(tmp_path):
    _, out, _ = _make(tmp_path)
    npz = shard_npz_path(out, 1)
    z = np.load(npz)
    normals = z["00000004/normals"].copy()
    z.close()
    normals[normals != 0] *= 1.01  # no longer unit
    _rewrite_entry(npz, "00000004/normals", normals)
    problems = "\n".join(verify(out).problems)
    assert "shard-00001.npz: sha256 differs" in problems
    assert "sample 4: normals: sha256 mismatch" in problems
    assert "sample 4: normals: not unit" in problems

    _, out2, _ = _make(tmp_path, "ds2")
    lines = (out2 / "manifest.jsonl").read_text().splitlines()
    (out2 / "manifest.jsonl").write_text("\n".join(lines[:5] + lines[4:]) + "\n")  # duplicate row 4
    problems = "\n".join(verify(out2).problems)
    assert "duplicated" in problems

    _, out3, _ = _make(tmp_path, "ds3")
    (out3 / "shards" / "shard-00002.npz.tmp").write_bytes(b"x")
    assert any("temporary file" in p for p in verify(out3).problems)

    _, out4, _ = _make(tmp_path, "ds4")
    npz = shard_npz_path(out4, 0)
    with np.load(npz) as z:
        flipped = -z["00000001/normals"]
    _rewrite_entry(npz, "00000001/normals", flipped)
    assert any("sample 1: normals:" in p and "do not face the camera" in p for p in verify(out4).problems)


def test_reader_is_lazy_and_matches_the_manifest(tmp_path):
    cfg, out, _ = _make(tmp_path)
    ds = simtest.dataset.open(out)
    assert len(ds) == 10
    assert ds._open == {}  # nothing read yet
    s = ds[4]
    assert list(ds._open) == ["shards/shard-00001.npz"]  # only the shard holding sample 4
    ref = standin_sample(cfg, 4)
    assert np.array_equal(s["normals"], ref.arrays["normals"])
    assert np.array_equal(s["sensor"], decode_png(ref.arrays["sensor_png"]))
    assert s["record"]["arrays"]["normals"]["sha256"] == array_sha256(ref.arrays["normals"])
    assert [x["index"] for x in ds] == list(range(10))
    assert ds[-1]["index"] == 9
    with pytest.raises(IndexError):
        ds[10]
    sub = simtest.dataset.open(out, keys=["depth"], with_record=False)
    assert set(sub[0]) == {"index", "depth"}
    with pytest.raises(KeyError, match="unknown array"):
        simtest.dataset.open(out, keys=["nope"])
    ds.close()


def test_documented_numpy_and_pil_recipe_reads_a_sample(tmp_path):
    cfg, out, _ = _make(tmp_path)
    rows = [json.loads(line) for line in open(out / "manifest.jsonl")]
    row = rows[7]
    z = np.load(out / row["npz"])
    key = f"{row['index']:08d}/"
    image = np.asarray(Image.open(io.BytesIO(z[key + "sensor_png"].tobytes())))
    ref = standin_sample(cfg, 7)
    assert image.dtype == np.uint8
    assert np.array_equal(image, decode_png(ref.arrays["sensor_png"]))
    assert np.array_equal(z[key + "normals"], ref.arrays["normals"])
    z.close()


def test_an_empty_dataset_is_valid(tmp_path):
    cfg = _cfg(count=0)
    out = tmp_path / "empty"
    rep = generate(cfg, out, workers=1, sample_fn=standin_sample, progress=False)
    assert (rep.written, rep.skipped) == (0, 0)
    assert read_manifest(out) == []
    assert verify(out).ok
    assert len(simtest.dataset.open(out)) == 0


def test_resume_refuses_when_the_bundled_meshes_changed(tmp_path):
    cfg = config_from_dict({"count": 4, "seed": 1, "shard_size": 2, "families": {"colon": 1.0}})
    out = tmp_path / "colon"
    generate(cfg, out, workers=1, sample_fn=standin_sample, progress=False)
    card = json.loads((out / "dataset.json").read_text())
    assert list(card["meshes"]) == ["meshes/colon.ply"]
    assert len(card["meshes"]["meshes/colon.ply"]) == 64  # sha256 of the file the samples used
    card["meshes"]["meshes/colon.ply"] = "0" * 64  # as if the mesh had been rebuilt since
    (out / "dataset.json").write_text(json.dumps(card))
    with pytest.raises(DatasetError, match="mesh files changed"):
        generate(cfg, out, workers=1, sample_fn=standin_sample, progress=False)


@settings(max_examples=15, deadline=None)
@given(order=st.permutations(list(range(5))))
def test_shard_bytes_do_not_depend_on_arrival_order(tmp_path_factory, order):
    from simtest.dataset.shards import ShardWriter

    cfg = _cfg(count=5, shard_size=5)
    samples = {i: standin_sample(cfg, i) for i in range(5)}
    blobs = []
    for k, seq in enumerate((range(5), order)):
        root = tmp_path_factory.mktemp("order")
        w = ShardWriter(root, 0, range(5))
        done = [w.add(samples[i]) for i in seq]
        assert done == [False] * 4 + [True]  # complete exactly when the last sample arrives
        blobs.append((shard_npz_path(root, 0).read_bytes(), shard_json_path(root, 0).read_text()))
    assert blobs[0] == blobs[1]


def test_shard_writer_refuses_duplicates_and_strangers(tmp_path):
    from simtest.dataset.shards import ShardWriter

    cfg = _cfg(count=6, shard_size=3)
    w = ShardWriter(tmp_path, 0, range(3))
    w.add(standin_sample(cfg, 1))
    with pytest.raises(DatasetError, match="given twice"):
        w.add(standin_sample(cfg, 1))
    with pytest.raises(DatasetError, match="does not belong"):
        w.add(standin_sample(cfg, 4))
    w.abort()
    assert not list(tmp_path.rglob("*.tmp"))


def test_unreachable_scheduler_is_refused_before_writing(tmp_path, monkeypatch):
    import simtest.dataset.generate as gen

    monkeypatch.setattr(gen, "CONNECT_TIMEOUT", "1s")
    out = tmp_path / "never"
    with pytest.raises(DatasetError, match="cannot connect"):
        # port 9 (discard) on localhost: nothing listens there
        generate(_cfg(), out, scheduler="tcp://127.0.0.1:9", sample_fn=standin_sample, progress=False)
    assert not out.exists()


def test_verify_command_exit_codes(tmp_path):
    from typer.testing import CliRunner

    from simtest.cli import app

    _, out, _ = _make(tmp_path)
    res = CliRunner().invoke(app, ["dataset", "verify", str(out)])
    assert res.exit_code == 0 and "OK (10 samples in 4 shards)" in res.output
    shard_json_path(out, 2).unlink()
    res = CliRunner().invoke(app, ["dataset", "verify", str(out)])
    assert res.exit_code == 1
    assert "shard-00002" in res.output and "FAILED" in res.output
