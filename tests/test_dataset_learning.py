"""What a learner uses: the PyTorch view, seeded splits, WebDataset and HDF5 exports readable without
simtest, the contact sheet, compression (stand-in samples, no rendering)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
import zipfile

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from PIL import Image
from test_dataset_format import _cfg, _make, standin_sample
from typer.testing import CliRunner

import simtest.dataset
from simtest.cli import app
from simtest.dataset.config import config_from_dict
from simtest.dataset.export import READ_HDF5, READ_WEBDATASET, export
from simtest.dataset.generate import generate
from simtest.dataset.shards import DEFLATED, DatasetError, decode_png, read_manifest, shard_npz_path


def crop8(item: dict) -> dict:
    """A transform (module level, so DataLoader workers can pickle it): the top-left 8 x 8 pixels."""
    import torch  # here, not at the top: each xdist worker collects this module, few run it

    return {k: (v[..., :8, :8] if isinstance(v, torch.Tensor) and v.ndim >= 2 else v) for k, v in item.items()}


def test_dir_shows_open():
    assert {"open", "collate"} <= set(dir(simtest.dataset))


def test_torch_view_through_a_dataloader_with_two_worker_processes(tmp_path):
    import torch

    _, out, _ = _make(tmp_path)
    ds = simtest.dataset.open(out)
    view = ds.torch(keys=("sensor", "normals", "mask", "K"), transform=crop8)
    loader = torch.utils.data.DataLoader(view, batch_size=4, num_workers=2, shuffle=False)
    seen = []
    for batch in loader:
        assert batch["sensor"].dtype == torch.float32 and batch["sensor"].shape[1:] == (1, 8, 8)
        assert batch["normals"].shape[1:] == (3, 8, 8) and batch["mask"].dtype == torch.bool
        for b, i in enumerate(batch["index"].tolist()):
            s = ds[i]
            assert torch.equal(batch["sensor"][b, 0], torch.from_numpy(s["sensor"][:8, :8] / np.float32(255)))
            assert torch.equal(batch["normals"][b], torch.from_numpy(np.moveaxis(s["normals"], -1, 0)[:, :8, :8]))
            assert torch.equal(batch["mask"][b], torch.from_numpy(s["mask"][:8, :8]))
            assert np.array_equal(batch["K"][b].numpy(), np.asarray(s["record"]["K"], np.float32))
            seen.append(i)
    assert seen == list(range(10))
    # the rows (which differ between families) come along with the collate of simtest.dataset
    rec_loader = torch.utils.data.DataLoader(ds.torch(keys=("mask",), transform=crop8, with_record=True),
                                             batch_size=3, collate_fn=simtest.dataset.collate)
    first = next(iter(rec_loader))
    assert [r["index"] for r in first["record"]] == first["index"].tolist() == [0, 1, 2]


def test_torch_view_refuses_unknown_keys(tmp_path):
    _, out, _ = _make(tmp_path)
    with pytest.raises(KeyError, match="nope"):
        simtest.dataset.open(out).torch(keys=("sensor", "nope"))


# ------------------------------------------------------------------------------------------------
# splits


@settings(max_examples=20, deadline=None)
@given(seed=st.integers(0, 2**32), small=st.integers(0, 30), extra=st.integers(1, 30))
def test_a_samples_split_does_not_change_when_the_count_grows(seed, small, extra):
    a = config_from_dict({"count": small, "seed": seed, "families": {"planes": 1}})
    b = config_from_dict({"count": small + extra, "seed": seed, "families": {"planes": 1}})
    assert [a.split_of(i) for i in range(small)] == [b.split_of(i) for i in range(small)]


def test_split_frequencies_follow_the_fractions():
    cfg = config_from_dict({"count": 1, "seed": 5, "families": {"planes": 1},
                            "splits": {"train": 0.7, "val": 0.2, "test": 0.1}})
    n = 20000
    names = [cfg.split_of(i) for i in range(n)]
    for name, p in cfg.splits:
        k = names.count(name)
        sigma = (n * p * (1 - p)) ** 0.5
        assert abs(k - n * p) < 5 * sigma, (name, k)  # 5 sigma: a real bias fails, chance does not


def test_split_views_partition_the_dataset(tmp_path):
    cfg, out, _ = _make(tmp_path, count=40, shard_size=7)
    rows = read_manifest(out)
    assert [r["split"] for r in rows] == [cfg.split_of(i) for i in range(40)]
    parts = {s: [d["index"] for d in simtest.dataset.open(out, keys=("mask",), split=s)]
             for s in ("train", "val", "test")}
    assert sorted(sum(parts.values(), [])) == list(range(40))
    assert all(rows[i]["split"] == s for s, idx in parts.items() for i in idx)
    card = json.loads((out / "dataset.json").read_text())
    assert card["counts"]["by_split"] == {s: len(v) for s, v in parts.items()}


# ------------------------------------------------------------------------------------------------
# compression


def test_shards_are_compressed_by_default_and_the_card_gives_bytes_per_sample(tmp_path):
    _, out, _ = _make(tmp_path)
    with zipfile.ZipFile(shard_npz_path(out, 0)) as z:
        deflated = {i.filename.split("/")[1][:-4] for i in z.infolist() if i.compress_type == zipfile.ZIP_DEFLATED}
        assert deflated == DEFLATED == {"mask", "highlight_mask", "specular"}
    card = json.loads((out / "dataset.json").read_text())
    total = sum(shard_npz_path(out, s).stat().st_size for s in range(4))
    assert card["counts"]["shard_bytes"] == total
    assert card["counts"]["bytes_per_sample"] == round(total / 10)


# ------------------------------------------------------------------------------------------------
# exports


def _run_without_simtest(code: str, cwd) -> dict:
    """Run a reading recipe in a fresh interpreter; fail if it imports simtest."""
    prog = code + textwrap.dedent("""
        import sys as _s, pickle as _p
        assert not [m for m in _s.modules if m.split(".")[0] == "simtest"], "simtest was imported"
        _s.stdout.buffer.write(_p.dumps({k: v for k, v in dict(globals()).items()
                                         if k in ("samples", "image", "normals", "record")}))
    """)
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    res = subprocess.run([sys.executable, "-c", prog], cwd=cwd, capture_output=True, env=env, check=True)
    import pickle

    return pickle.loads(res.stdout)


def test_webdataset_export_reads_with_tarfile_alone_and_is_deterministic(tmp_path):
    _, out, _ = _make(tmp_path)
    dest = export(out, "webdataset", tmp_path / "wds")
    assert sorted(p.name for p in dest.iterdir()) == ["export.json"] + [f"shard-{s:05d}.tar" for s in range(4)]
    got = _run_without_simtest(READ_WEBDATASET.replace("OUT/shard-00000.tar", str(dest / "shard-00001.tar")),
                               tmp_path)["samples"]
    assert sorted(got) == ["00000003", "00000004", "00000005"]
    ds = simtest.dataset.open(out)
    for key, s in got.items():
        ref = ds[int(key)]
        assert np.array_equal(s["sensor"], ref["sensor"])
        for f in ("normals", "depth", "linear", "specular", "mask", "highlight_mask"):
            assert s[f].dtype == ref[f].dtype and np.array_equal(s[f], ref[f]), f
        assert s["record"] == ref["record"]
    first = (dest / "shard-00000.tar").read_bytes()
    again = export(out, "webdataset", tmp_path / "wds")  # replaces the old export as a whole
    assert (again / "shard-00000.tar").read_bytes() == first


def test_hdf5_export_reads_with_h5py_alone(tmp_path):
    _, out, _ = _make(tmp_path)
    dest = export(out, "hdf5", tmp_path / "h5")
    assert len(list(dest.glob("*.hdf5"))) == 10
    got = _run_without_simtest(READ_HDF5.replace("OUT/3.hdf5", str(dest / "3.hdf5")), tmp_path)
    ref = simtest.dataset.open(out)[3]
    assert np.array_equal(got["image"], ref["sensor"])
    assert np.array_equal(got["normals"], ref["normals"])
    assert got["record"] == ref["record"]


def test_export_refuses_a_folder_that_is_not_an_export(tmp_path):
    _, out, _ = _make(tmp_path)
    other = tmp_path / "mine"
    other.mkdir()
    (other / "notes.txt").write_text("keep")
    with pytest.raises(DatasetError, match="not a simtest export"):
        export(out, "hdf5", other)
    res = CliRunner().invoke(app, ["dataset", "export", str(out), "--format", "parquet"])
    assert res.exit_code == 2 and "parquet" in res.output
    assert (other / "notes.txt").read_text() == "keep"


# ------------------------------------------------------------------------------------------------
# contact sheet


def test_show_writes_a_contact_sheet_with_one_row_per_sample(tmp_path):
    _, out, _ = _make(tmp_path)
    sizes = []
    for n in (1, 3):
        png = tmp_path / f"sheet{n}.png"
        res = CliRunner().invoke(app, ["dataset", "show", str(out), "--count", str(n), "--out", str(png)])
        assert res.exit_code == 0, res.output
        with Image.open(png) as im:
            sizes.append(im.size)
    assert sizes[0][0] == sizes[1][0] and sizes[1][1] > 2.5 * sizes[0][1]  # rows grow with the count
    # a file given for the folder (an image, say) is one line, as a folder without a card is
    (tmp_path / "frame.png").write_bytes(b"\x89PNG")
    for root in (tmp_path / "frame.png", tmp_path):
        res = CliRunner().invoke(app, ["dataset", "show", str(root), "--out", str(tmp_path / "s.png")])
        assert res.exit_code == 2 and "missing: not a simtest dataset folder" in res.output, res.output


def test_generate_then_read_a_dataset_of_fixed_size_with_the_default_torch_path(tmp_path):
    import torch

    cfg = _cfg(count=6, shard_size=4)

    def fixed(config, index):  # every sample 8 x 8, as a single-resolution config gives
        s = standin_sample(config, 3 * index)
        return type(s)(index=index, arrays=s.arrays, record={**s.record, "index": index})

    out = tmp_path / "ds"
    generate(cfg, out, workers=1, sample_fn=fixed, progress=False)
    batch = next(iter(torch.utils.data.DataLoader(simtest.dataset.open(out).torch(), batch_size=6)))
    assert batch["sensor"].shape == (6, 1, 8, 8) and batch["normals"].shape == (6, 3, 8, 8)
    img = simtest.dataset.open(out, keys=("sensor_png",))[5]["sensor_png"]
    assert torch.equal(batch["sensor"][5, 0], torch.from_numpy(decode_png(img) / np.float32(255)))


def test_a_dataset_mixing_grey_and_rgb_samples_batches_with_three_channels(tmp_path):
    """Grey Phong and RGB tissue samples in one dataset: every split's sensor tensor is (3, H, W)."""
    import torch

    from simtest.dataset.sample import _encode_png

    cfg = _cfg(count=6, shard_size=4)

    def mixed(config, index):  # every sample 8 x 8; odd indices RGB
        s = standin_sample(config, 3 * index)
        arrays, record = dict(s.arrays), {**s.record, "index": index, "color": "grey"}
        if index % 2:
            grey = decode_png(arrays["sensor_png"])
            arrays["sensor_png"] = _encode_png(np.stack([grey, grey // 2, grey // 3], axis=-1))
            record["color"] = "rgb"
        return type(s)(index=index, arrays=arrays, record=record)

    out = tmp_path / "ds"
    generate(cfg, out, workers=1, sample_fn=mixed, progress=False)
    batch = next(iter(torch.utils.data.DataLoader(simtest.dataset.open(out).torch(), batch_size=6)))
    assert batch["sensor"].shape == (6, 3, 8, 8)
    for b in range(6):
        png = decode_png(simtest.dataset.open(out, keys=("sensor_png",))[b]["sensor_png"])
        want = np.moveaxis(png, -1, 0) if png.ndim == 3 else np.repeat(png[None], 3, axis=0)
        assert torch.equal(batch["sensor"][b], torch.from_numpy(want / np.float32(255)))
    for split in ("train", "val", "test"):  # a split holding only grey samples keeps 3 channels
        view = simtest.dataset.open(out, split=split).torch()
        assert all(view[i]["sensor"].shape == (3, 8, 8) for i in range(len(view)))
