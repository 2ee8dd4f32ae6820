"""``dataset verify`` passes sound datasets of any shard count and fails every damaged card,
manifest, label or shard name once, naming it; the reader refuses edited labels (stand-ins)."""

from __future__ import annotations

import json

import pytest
from test_dataset_format import _cfg, _files, _make, standin_sample
from typer.testing import CliRunner

import simtest.dataset
from simtest.cli import app
from simtest.dataset.generate import generate
from simtest.dataset.shards import DatasetError, read_manifest, shard_json_path, shard_npz_path
from simtest.dataset.verify import verify


@pytest.mark.parametrize("n_shards", [1, 11, 100])
def test_sound_datasets_of_1_11_and_100_shards_verify(tmp_path, n_shards):
    # shard numbers were compared as strings: "10" sorts before "2", so 11+ shards failed
    _, out, _ = _make(tmp_path, count=n_shards, shard_size=1)
    rep = verify(out, check_arrays=n_shards < 100)
    assert rep.ok, rep.problems[:3]
    assert rep.shards == n_shards
    res = CliRunner().invoke(app, ["dataset", "verify", str(out), "--quick"])
    assert res.exit_code == 0 and f"in {n_shards} shards" in res.output


@pytest.mark.parametrize(("key", "value"), [("seed", 12), ("isovalues", [0.2]),
                                            ("conventions", {"lengths": "inches"}), ("count", 9)])
def test_a_value_changed_in_the_card_fails_verify(tmp_path, key, value):
    _, out, _ = _make(tmp_path)
    card = json.loads((out / "dataset.json").read_text())
    card[key] = value
    (out / "dataset.json").write_text(json.dumps(card, indent=1))
    problems = verify(out).problems
    assert any("dataset.json: a value differs from its card_sha256" in p for p in problems), problems


def test_a_card_without_its_hash_fails_verify_and_a_rerun_rewrites_it(tmp_path):
    cfg, out, _ = _make(tmp_path)
    card = json.loads((out / "dataset.json").read_text())
    del card["card_sha256"]
    (out / "dataset.json").write_text(json.dumps(card, indent=1))
    assert any("no card_sha256" in p for p in verify(out).problems)
    rep = generate(cfg, out, workers=1, sample_fn=standin_sample, progress=False)
    assert rep.written == 0 and verify(out).ok


def test_an_edited_manifest_fails_verify_by_its_hash(tmp_path):
    _, out, _ = _make(tmp_path)
    text = (out / "manifest.jsonl").read_text()
    (out / "manifest.jsonl").write_text(text.replace('"split":"', '"split": "', 1))  # same JSON
    problems = verify(out).problems
    assert problems == [f"{out / 'manifest.jsonl'}: sha256 differs from dataset.json's manifest_sha256: "
                        "the manifest was edited or damaged"], problems


def test_a_flipped_fingerprint_is_reported_once_and_generate_repairs_it(tmp_path):
    cfg, ref, _ = _make(tmp_path, "ref")
    _, out, _ = _make(tmp_path)
    card = json.loads((out / "dataset.json").read_text())
    fp = card["config_fingerprint"]
    card["config_fingerprint"] = ("0" if fp[0] != "0" else "1") + fp[1:]
    (out / "dataset.json").write_text(json.dumps(card, indent=1))
    problems = verify(out).problems
    # the card's hash and its fingerprint: the card, not the 4 shards
    assert not [p for p in problems if "shard-" in p], problems
    assert sum("config_fingerprint" in p for p in problems) == 1, problems
    calls: list = []

    def counting(config, index):
        calls.append(index)
        return standin_sample(config, index)

    generate(cfg, out, workers=1, sample_fn=counting, progress=False)  # repairs, renders nothing
    assert calls == [] and verify(out).ok
    assert _files(out) == _files(ref)


def test_a_card_of_another_config_is_one_line_saying_what_to_do(tmp_path):
    _, out, _ = _make(tmp_path)
    with pytest.raises(DatasetError, match=r"pass the config it was made with to resume it, or use "
                                           r"another --out") as err:
        generate(_cfg(seed=99), out, workers=1, sample_fn=standin_sample, progress=False)
    assert "\n" not in str(err.value)


@pytest.mark.parametrize("name", ["shard-000001.npz", "shard-0001.npz", "shard-\u0661\u0660\u0660\u0660\u0660.npz"])
def test_a_shard_name_the_writer_does_not_make_fails_verify(tmp_path, name):
    _, out, _ = _make(tmp_path)
    rows = read_manifest(out)
    # the manifest points shard 1's rows at a non-standard name, and that file exists
    shard_npz_path(out, 1).rename(out / "shards" / name)
    for r in rows:
        if r["shard"] == 1:
            r["npz"] = f"shards/{name}"
    (out / "manifest.jsonl").write_text("".join(json.dumps(r, separators=(",", ":")) + "\n" for r in rows))
    problems = verify(out).problems
    assert any(f"npz 'shards/{name}' is not the file of its shard 1" in p or "refused" in p
               for p in problems), problems
    assert any(f"{name}: unexpected file in shards/" in p for p in problems), problems
    with pytest.raises(DatasetError, match="sample 3: npz"):
        simtest.dataset.open(out)


def test_an_extra_file_in_shards_fails_verify(tmp_path):
    _, out, _ = _make(tmp_path)
    (out / "shards" / "shard-0002.json").write_text(shard_json_path(out, 2).read_text())
    assert any("shard-0002.json: unexpected file" in p for p in verify(out).problems)


def test_the_reader_refuses_labels_that_do_not_match_their_hash(tmp_path):
    _, out, _ = _make(tmp_path)
    rows = read_manifest(out)
    rows[4]["highlights"][0]["bp_px"] = [1.5, 2.0]  # edited, hash kept
    (out / "manifest.jsonl").write_text("".join(json.dumps(r, separators=(",", ":")) + "\n" for r in rows))
    ds = simtest.dataset.open(out)
    assert ds[3]["record"]["index"] == 3  # the others are served
    with pytest.raises(DatasetError, match=r"shard 1, sample 4: labels differ from their labels_sha256"):
        ds[4]
    ds.close()
