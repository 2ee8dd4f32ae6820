"""Sim-to-real statistics: exact counts on synthetic frames; the CLI writes table and figure."""

from __future__ import annotations

import json

import numpy as np
import pytest
from typer.testing import CliRunner

from simtest.cli import app
from simtest.render.simreal import (
    FACTOR_GOAL,
    banner_frames,
    frame_stats,
    sim_to_real_table,
)


def _frame(blobs, size=(100, 120), border=10):
    f = np.zeros((*size, 3), np.uint8)
    f[border:-border, border:-border] = (220, 120, 100)  # pink tissue, luma 136
    for r, c, s in blobs:
        f[r:r + s, c:c + s] = 255
    return f


def test_frame_stats_counts_blobs_exactly():
    f = _frame([(20, 20, 2), (40, 40, 3), (60, 60, 5)])
    st = frame_stats(f)
    lit = (100 - 20) * (120 - 20)
    assert st.candidates_per_mp == pytest.approx(3 / lit * 1e6)
    assert sorted(st.areas.tolist()) == [4, 9, 25] and st.median_area_px == 9
    assert st.saturated_fraction == pytest.approx(38 / lit)
    assert st.tissue_rgb == (220.0, 120.0, 100.0)
    with pytest.raises(ValueError, match="no lit pixel"):
        frame_stats(np.zeros((10, 10, 3), np.uint8))


def test_table_ratios():
    real = [_frame([(20, 20, 2), (40, 40, 3)]), _frame([(30, 30, 4)])]
    rows = {r["statistic"]: r for r in sim_to_real_table(_frame([(20, 20, 2), (40, 40, 3)]), real)}
    assert rows["tissue_r"]["ratio"] == 1.0 and rows["tissue_r"]["within_goal"]
    # Medians over the real frames: candidates 1.5 blobs per frame against 2 rendered.
    assert rows["candidates_per_mp"]["ratio"] == pytest.approx(2 / 1.5)
    assert all(r["within_goal"] == (1 / FACTOR_GOAL <= r["ratio"] <= FACTOR_GOAL) for r in rows.values())


def test_banner_tiles(tmp_path):
    import cv2

    img = np.zeros((560, 840, 3), np.uint8)
    img[280:, 560:] = (0, 0, 255)  # BGR red in the last tile
    cv2.imwrite(str(tmp_path / "b.png"), img)
    tiles = banner_frames(tmp_path / "b.png")
    assert len(tiles) == 6 and tiles[-1][0, 0].tolist() == [255, 0, 0]


@pytest.mark.render
def test_simreal_cli(tmp_path):
    import cv2

    scene = tmp_path / "s.toml"
    scene.write_text(
        "[camera]\nwidth_px = 64\nheight_px = 64\nfov_deg = 100.0\n"
        "[light]\nrig = 'colonoscope'\nfalloff = 'keep'\nintensity = 400.0\n"
        "[material]\nmodel = 'tissue'\nalpha = 0.1\ndistribution = 'ggx'\n"
        "[geometry]\ntype = 'plane'\ntilt_deg = 10.0\ndistance_mm = 15.0\n"
        "[sensor]\noutput = 'video'\nexposure_mode = 'auto'\n[render]\nspp = 2\n")
    real = tmp_path / "real.png"
    cv2.imwrite(str(real), cv2.cvtColor(_frame([(20, 20, 3)]), cv2.COLOR_RGB2BGR))
    res = CliRunner().invoke(app, ["simreal", str(scene), "--out", str(tmp_path / "o"), "--real", str(real)])
    assert res.exit_code == 0, res.output
    data = json.loads((tmp_path / "o" / "simreal.json").read_text())
    assert {r["statistic"] for r in data["rows"]} >= {"candidates_per_mp", "saturated_fraction", "tissue_r"}
    assert (tmp_path / "o" / "simreal.png").stat().st_size > 10000
    res = CliRunner().invoke(app, ["simreal", str(scene), "--out", str(tmp_path / "o"), "--real",
                                   str(tmp_path / "missing.png")])
    assert res.exit_code == 2 and res.output.count("\n") == 1 and "missing.png" in res.output
