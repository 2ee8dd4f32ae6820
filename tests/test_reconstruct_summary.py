"""`simtest reconstruct`'s summary line and overlay legend say where the ok estimates' normals come from.

Under a light rig most ok highlights of a glint field fall back on the BP ray, degrees off, whose needle
points at the camera and is too short to see; a line that only counted "N reconstructed" and a legend
that only named the needles hid that. The counts are those of the ``normal_from`` of the ok rows in
``estimates.json``, most first.
"""

from __future__ import annotations

import json
import re
from collections import Counter
from pathlib import Path

from typer.testing import CliRunner

from simtest.cli import app
from simtest.reconstruct import overlay

DATA = Path(__file__).resolve().parent / "data" / "real"


def test_the_summary_counts_the_ok_estimates_by_the_estimator_of_their_normal(tmp_path):
    out = tmp_path / "out"
    res = CliRunner().invoke(app, ["reconstruct", str(DATA / "hyperkvasir_tile_r2c3_polyp.png"), "-k",
                                   str(DATA / "intrinsics_assumed_f140.json"), "-o", str(out), "--no-overlay"])
    assert res.exit_code == 0, res.output
    rows = json.loads((out / "estimates.json").read_text())["specularities"]
    want = Counter(r["normal_from"] for r in rows if r["status"] == "ok")
    assert sum(want.values()) > 0
    line = res.output.strip().splitlines()[-1]
    m = re.search(r"(\d+) reconstructed \(normal from ([^)]*)\)", line)
    assert m is not None, line
    got = [(k, int(v)) for k, v in (part.rsplit(" ", 1) for part in m.group(2).split(", "))]
    assert dict(got) == dict(want) and int(m.group(1)) == sum(want.values())
    assert [v for _, v in got] == sorted((v for _, v in got), reverse=True)  # most first


def test_the_overlay_legend_counts_the_recommended_normals_of_each_estimator(tmp_path, monkeypatch):
    legends = []
    monkeypatch.setattr(overlay, "_legend", lambda canvas, title, entries, **_: legends.append(entries))
    out = tmp_path / "out"
    res = CliRunner().invoke(app, ["reconstruct", str(DATA / "hyperkvasir_tile_r2c3_polyp.png"), "-k",
                                   str(DATA / "intrinsics_assumed_f140.json"), "-o", str(out)])
    assert res.exit_code == 0, res.output
    rows = json.loads((out / "estimates.json").read_text())["specularities"]
    want = Counter(r["normal_from"] for r in rows if r["status"] == "ok")
    (entries,) = legends
    labels = {label.split(" ")[0]: label for label, _, kind in entries if kind in ("line", "dash", "outlined")}  # the needles
    for name, n in want.items():  # every source is drawn (the tile's: isophote estimators) and counted
        assert labels[name] == f"{name} (recommended for {n})", labels
    assert all(label == name for name, label in labels.items() if name not in want and name != "normal")


def test_a_folders_summary_and_records_count_the_ok_normals_by_estimator(tmp_path):
    from simtest.reconstruct.table import read_frames

    frames = tmp_path / "frames"
    frames.mkdir()
    for name in ("hyperkvasir_tile_r2c3_polyp.png", "hyperkvasir_tile_r1c7_mucosa.png"):
        (frames / name).write_bytes((DATA / name).read_bytes())
    lines = {}
    for fmt in ("parquet", "jsonl"):
        out = tmp_path / fmt
        res = CliRunner().invoke(app, ["reconstruct", str(frames), "-k", str(DATA / "intrinsics_assumed_f140.json"),
                                       "-o", str(out), "-j", "1", "--format", fmt])
        assert res.exit_code == 0, res.output
        records = read_frames(next(out.glob("estimates.*")))
        for rec in records:  # each frame's count is its ok rows'
            assert rec["normals_from"] == dict(Counter(s["normal_from"] for s in rec["specularities"]
                                                       if s["status"] == "ok"))
        want = sum((Counter(rec["normals_from"]) for rec in records), Counter())
        assert sum(want.values()) > 0
        lines[fmt] = res.output.strip().splitlines()[-1]
        m = re.search(r"reconstructed \(normal from ([^)]*)\)", lines[fmt])
        assert m is not None and dict((k, int(v)) for k, v in (p.rsplit(" ", 1) for p in m.group(1).split(", "))) \
            == dict(want), lines[fmt]
