"""A dataset cannot be corrupted silently: folder lock, content-hash resume, verify, confined paths,
full disk, bad scheduler address (stand-in samples, no rendering)."""

from __future__ import annotations

import errno
import json
import os
import shutil
import socket
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st
from test_dataset_format import _cfg, _files, _make, standin_sample
from typer.testing import CliRunner

import simtest.dataset
from simtest.cli import app
from simtest.dataset import generate as gen_mod
from simtest.dataset.generate import LOCK_NAME, generate
from simtest.dataset.shards import DatasetError, read_manifest, shard_json_path, shard_npz_path
from simtest.dataset.verify import verify

REPO = Path(__file__).resolve().parents[1]


def _counting(calls: list):
    def fn(config, index):  # not picklable, fine inline
        calls.append(index)
        return standin_sample(config, index)
    return fn


# ------------------------------------------------------------------------------------------------
# lock


def test_a_second_run_on_a_locked_folder_refuses_at_once_naming_the_holder(tmp_path):
    out = tmp_path / "ds"
    holder = subprocess.Popen(
        [sys.executable, "-c", textwrap.dedent(f"""
            import sys
            from simtest.dataset.generate import _locked
            from pathlib import Path
            with _locked(Path({str(out)!r})):
                print("locked", flush=True)
                sys.stdin.readline()
        """)], cwd=REPO, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "locked"
        with pytest.raises(DatasetError) as err:
            generate(_cfg(), out, workers=1, sample_fn=standin_sample, progress=False)
        msg = str(err.value)
        assert f"pid {holder.pid} on {socket.gethostname()} since " in msg, msg
        assert "\n" not in msg
        assert sorted(p.name for p in out.iterdir()) == [LOCK_NAME]  # nothing written
        res = CliRunner().invoke(app, ["dataset", "generate", str(REPO / "scenes/datasets/example.toml"),
                                       "--out", str(out), "--workers", "1"])
        assert res.exit_code == 2
        lines = res.output.strip().splitlines()
        assert len(lines) == 1 and f"pid {holder.pid}" in lines[0], res.output
    finally:
        holder.communicate("\n", timeout=30)
    # released: the run goes through and the lock file is left empty (same bytes for every run)
    generate(_cfg(), out, workers=1, sample_fn=standin_sample, progress=False)
    assert (out / LOCK_NAME).read_bytes() == b""
    assert verify(out).ok


def test_two_configs_on_one_folder_cannot_both_succeed(tmp_path):
    out = tmp_path / "ds"
    with gen_mod._locked(out):  # the first run is still going
        with pytest.raises(DatasetError, match="in use by another"):
            generate(_cfg(seed=99), out, workers=1, sample_fn=standin_sample, progress=False)
    generate(_cfg(), out, workers=1, sample_fn=standin_sample, progress=False)
    with pytest.raises(DatasetError, match="different config"):
        generate(_cfg(seed=99), out, workers=1, sample_fn=standin_sample, progress=False)


# ------------------------------------------------------------------------------------------------
# resume checks content, not sizes


def test_resume_rewrites_a_shard_with_a_flipped_byte(tmp_path):
    cfg, ref, _ = _make(tmp_path, "ref")
    _, out, _ = _make(tmp_path, "out")
    npz = shard_npz_path(out, 1)
    data = bytearray(npz.read_bytes())
    data[len(data) // 2] ^= 0x01  # same size, other content
    npz.write_bytes(bytes(data))
    calls: list = []
    rep = generate(cfg, out, workers=1, sample_fn=_counting(calls), progress=False)
    assert sorted(calls) == [3, 4, 5] and rep.written == 3
    assert _files(out) == _files(ref)
    assert verify(out).ok


@pytest.mark.parametrize("what", ["both", "npz only", "json only"])
def test_a_shard_from_a_dataset_with_another_seed_fails_verify_and_is_rewritten(tmp_path, what):
    cfg, ref, _ = _make(tmp_path, "ref")
    _, other, _ = _make(tmp_path, "other", seed=12)
    _, out, _ = _make(tmp_path, "out")
    if what in ("both", "npz only"):
        shutil.copy(shard_npz_path(other, 2), shard_npz_path(out, 2))
    if what in ("both", "json only"):
        shutil.copy(shard_json_path(other, 2), shard_json_path(out, 2))
    problems = verify(out).problems
    assert problems and all("shard-00002" in p or "sample 6" in p or "sample 7" in p or "sample 8" in p
                            for p in problems), problems
    if what == "both":  # consistent within itself: only the fingerprints can tell
        assert any("another dataset" in p for p in problems), problems
        assert any("zip comment" in p for p in problems), problems
    calls: list = []
    generate(cfg, out, workers=1, sample_fn=_counting(calls), progress=False)
    assert sorted(calls) == [6, 7, 8]
    assert _files(out) == _files(ref)


# ------------------------------------------------------------------------------------------------
# verify: every problem a line naming the file, never a traceback


@settings(max_examples=25, deadline=None)
@given(shard=st.integers(0, 3), where=st.floats(0.0, 1.0, exclude_max=True), bit=st.integers(0, 7))
@example(shard=3, where=0.9241639172349799, bit=6)  # the central directory's "version needed": zipfile's NotImplementedError
def test_verify_reports_any_flipped_bit_as_lines_naming_the_file(tmp_path_factory, shard, where, bit):
    _, out, _ = _make(tmp_path_factory.mktemp("flip"))
    npz = shard_npz_path(out, shard)
    data = bytearray(npz.read_bytes())
    data[int(where * len(data))] ^= 1 << bit
    npz.write_bytes(bytes(data))
    rep = verify(out)  # never raises
    assert rep.problems
    assert all(str(npz) in p for p in rep.problems), rep.problems


def test_verify_cli_prints_lines_not_a_traceback_for_a_truncated_shard(tmp_path):
    _, out, _ = _make(tmp_path)
    npz = shard_npz_path(out, 0)
    npz.write_bytes(npz.read_bytes()[:200])  # BadZipFile territory
    res = CliRunner().invoke(app, ["dataset", "verify", str(out)])
    assert res.exit_code == 1
    assert "Traceback" not in res.output
    assert res.exception is None or isinstance(res.exception, SystemExit)
    assert "shard-00000.npz" in res.output


def test_labels_are_covered_by_hashes(tmp_path):
    _, out, _ = _make(tmp_path)
    # a label changed the same way in the manifest and in the shard's row file
    rows = read_manifest(out)
    rows[4]["highlights"][0]["bp_px"] = [1.5, 2.0]
    (out / "manifest.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    doc = json.loads(shard_json_path(out, 1).read_text())
    doc["samples"][1]["highlights"][0]["bp_px"] = [1.5, 2.0]
    shard_json_path(out, 1).write_text(json.dumps(doc))
    problems = "\n".join(verify(out, check_arrays=False).problems)
    assert "shard-00001.json: sample 4: labels differ from their labels_sha256" in problems
    assert "sample 4: manifest labels differ" in problems
    # and a resume rewrites that shard
    calls: list = []
    generate(_cfg(), out, workers=1, sample_fn=_counting(calls), progress=False)
    assert sorted(calls) == [3, 4, 5] and verify(out).ok


# ------------------------------------------------------------------------------------------------
# manifest paths stay inside the dataset folder


@pytest.mark.parametrize("bad", ["../other/shards/shard-00000.npz", "ABS", "shards/../../x/shards/shard-00000.npz",
                                 "shards/shard-00002.npz"])
def test_reader_and_verify_refuse_manifest_paths_outside_the_folder(tmp_path, bad):
    _, out, _ = _make(tmp_path)
    _, other, _ = _make(tmp_path, "other", seed=12)
    if bad == "ABS":
        bad = str(shard_npz_path(other, 0))
    rows = read_manifest(out)
    rows[0]["npz"] = bad
    (out / "manifest.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    with pytest.raises(DatasetError, match="sample 0: npz"):
        simtest.dataset.open(out)
    problems = verify(out).problems
    assert any("manifest.jsonl: sample 0: npz" in p and ("refused" in p or "not the file of its shard" in p)
               for p in problems), problems


# ------------------------------------------------------------------------------------------------
# full disk


def _enospc(*args, **kwargs):
    raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))


@pytest.mark.parametrize("target", ["shard", "card", "manifest"])
def test_a_full_disk_gives_one_line_and_leaves_no_temporary_file(tmp_path, monkeypatch, target):
    import simtest._io

    cfg = _cfg()
    out = tmp_path / "ds"
    if target == "shard":
        monkeypatch.setattr(np.lib.format, "write_array", _enospc)
    elif target == "card":
        monkeypatch.setattr(Path, "write_text", _enospc)
    else:  # the manifest, after every shard is written
        real = simtest._io.atomic_write_text

        def failing(path, text):
            if Path(path).name == "manifest.jsonl":
                return simtest._io.atomic_write(path, _enospc)
            return real(path, text)
        monkeypatch.setattr("simtest.dataset.shards.atomic_write_text", failing)
    with pytest.raises(DatasetError) as err:
        generate(cfg, out, workers=1, sample_fn=standin_sample, progress=False)
    msg = str(err.value)
    assert "no space left on device" in msg and "\n" not in msg, msg
    assert not [p for p in out.rglob("*") if p.name.endswith(".tmp")]
    monkeypatch.undo()
    generate(cfg, out, workers=1, sample_fn=standin_sample, progress=False)  # resumes
    assert verify(out).ok


def test_cli_full_disk_is_one_line_exit_4(tmp_path, monkeypatch):
    cfg = tmp_path / "c.toml"
    cfg.write_text('count = 2\nseed = 1\n[families]\nplanes = 1\n')
    monkeypatch.setattr(Path, "write_text", _enospc)
    res = CliRunner().invoke(app, ["dataset", "generate", str(cfg), "--out", str(tmp_path / "ds"),
                                   "--workers", "1", "--no-progress"])
    assert res.exit_code == 4, res.output  # simtest._exit.CANNOT_WRITE
    assert len(res.output.strip().splitlines()) == 1 and "no space left" in res.output


# ------------------------------------------------------------------------------------------------
# scheduler address


@pytest.mark.parametrize(("address", "says"), [
    ("notaurl", "not a scheduler address"),
    ("tcp://no-such-host.invalid:8786", "does not resolve"),
    ("tcp://127.0.0.1:9", "cannot connect"),  # nothing listens on the discard port
])
def test_a_bad_scheduler_address_is_one_line_before_writing(tmp_path, address, says):
    out = tmp_path / "never"
    with pytest.raises(DatasetError) as err:
        generate(_cfg(), out, scheduler=address, sample_fn=standin_sample, progress=False)
    assert says in str(err.value) and "\n" not in str(err.value)
    assert not out.exists()
