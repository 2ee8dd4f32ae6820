"""A frame's deferred isophotes are contoured in batches that bound their boxes' memory, with the
estimates of one batch at the end.

Under the paper's settings (``--detection full_scale --normalise bp -t 0.1 --smooth 0``) an
isophote at a tenth of the BP can span much of the frame, and every candidate's box waited for one
contouring at the end: 1.67 GB peak on the 2240 x 840 banner. ``isophotes._Batches`` contours them
whenever the boxes pending pass ``RESOLVE_PENDING_MAX_BYTES``; a box's contour does not depend on
its batch, so the estimates written must not change, whatever the bound.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from typer.testing import CliRunner

from simtest.cli import app
from simtest.reconstruct import isophotes

DATA = Path(__file__).parent / "data" / "real"
_RESOLVE = isophotes._resolve  # (the module's own, each run's count wraps it afresh)
PAPER = ["--detection", "full_scale", "--normalise", "bp", "-t", "0.1", "--smooth", "0"]


def _run(tmp_path, name, extra, monkeypatch, bound=None):
    """``simtest reconstruct`` of the real mucosa tile (assumed intrinsics): its specularities, and the
    bytes of boxes pending at each batch's contouring (``bound``: RESOLVE_PENDING_MAX_BYTES set so)."""
    pending = []
    monkeypatch.setattr(isophotes, "_resolve", lambda drafts, defer: pending.append(
        sum(d[0][0].nbytes for d in defer)) or _RESOLVE(drafts, defer))
    if bound is not None:
        monkeypatch.setattr(isophotes, "RESOLVE_PENDING_MAX_BYTES", bound)
    out = tmp_path / name
    res = CliRunner().invoke(app, ["reconstruct", str(DATA / "hyperkvasir_tile_r1c7_mucosa.png"), "-k",
                                   str(DATA / "intrinsics_assumed_f140.json"), *extra, "-o", str(out)])
    assert res.exit_code == 0, res.output
    return json.loads((out / "estimates.json").read_text())["specularities"], pending


@pytest.mark.parametrize("extra", [PAPER, []], ids=["paper", "defaults"])
def test_contouring_in_bounded_batches_writes_the_same_estimates(tmp_path, monkeypatch, extra):
    whole, one = _run(tmp_path, "whole", extra, monkeypatch, bound=1 << 62)  # one batch a pass, at its end
    assert one and min(one) > 0
    # a bound of a quarter of the smallest: more batches, each smaller than the pass's whole
    parts, many = _run(tmp_path, "parts", extra, monkeypatch, bound=min(one) // 4)
    assert len(many) >= len(one) + 2, (one, many)
    assert sum(many) == sum(one) and max(many) <= max(one)  # every box contoured once, in more batches
    assert parts == whole
