"""`simtest reconstruct`'s summary line says where the ok estimates' normals come from.

Under a light rig most ok highlights of a glint field fall back on the BP ray, degrees off; a line
that only counted "N reconstructed" hid that. The counts in the line are those of the
``normal_from`` of the ok rows in ``estimates.json``, most first.
"""

from __future__ import annotations

import json
import re
from collections import Counter
from pathlib import Path

from typer.testing import CliRunner

from simtest.cli import app

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
