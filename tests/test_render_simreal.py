"""Sim-to-real statistics: exact counts on synthetic frames; the CLI writes table and figure."""

from __future__ import annotations

import json

import numpy as np
import pytest
from typer.testing import CliRunner

from simtest.cli import app
from simtest.render.simreal import (
    FACTOR_GOAL,
    STATISTICS,
    banner_frames,
    frame_stats,
    real_reference,
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
    assert st.colour_spread == 0.0  # one tissue colour: no spread of R - G
    # luma of the lit field: tissue 135.94 (BT.601 of (220, 120, 100)) and 38 white pixels
    assert st.luma_p10 == pytest.approx(0.299 * 220 + 0.587 * 120 + 0.114 * 100)
    assert st.luma_p90 == pytest.approx(st.luma_p10)  # 38 of 8000 pixels are white: above p90
    assert set(st.values()) == set(STATISTICS)
    with pytest.raises(ValueError, match="no lit pixel"):
        frame_stats(np.zeros((10, 10, 3), np.uint8))


def test_colour_spread_is_the_iqr_of_red_minus_green():
    f = _frame([])
    f[10:50, 10:-10] = (200, 100, 100)  # R - G = 100 on half the lit rows, 100 on the rest
    f[50:-10, 10:-10] = (220, 100, 100)  # R - G = 120
    st = frame_stats(f)
    assert st.colour_spread == pytest.approx(20.0, abs=1e-9)


def test_real_reference_pools_the_glint_population():
    a, b = _frame([(20, 20, 2), (40, 40, 3)]), _frame([(30, 30, 4)])
    ref = real_reference([a, b])
    lit = (100 - 20) * (120 - 20)
    assert ref["candidates_per_mp"] == pytest.approx(3 / (2 * lit) * 1e6)  # 3 blobs over both frames
    assert ref["saturated_fraction"] == pytest.approx((4 + 9 + 16) / (2 * lit))
    assert ref["median_area_px"] == 9.0  # areas 4, 9, 16 pooled
    assert ref["tissue_r"] == 220.0  # a median over the frames


def test_table_ratios():
    real = [_frame([(20, 20, 2), (40, 40, 3)]), _frame([(30, 30, 4)])]
    rows = {r["statistic"]: r for r in sim_to_real_table(_frame([(20, 20, 2), (40, 40, 3)]), real)}
    assert rows["tissue_r"]["ratio"] == 1.0 and rows["tissue_r"]["within_goal"]
    # Pooled over the real frames: 3 blobs on two frames' lit field against 2 on one rendered.
    assert rows["candidates_per_mp"]["ratio"] == pytest.approx(2 / 1.5)
    assert rows["candidates_per_mp"]["real_pooled"] and not rows["tissue_r"]["real_pooled"]
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
