"""Sim-to-real statistics: exact counts on synthetic frames; the CLI writes table and figure."""

from __future__ import annotations

import json

import numpy as np
import pytest
from typer.testing import CliRunner

from simtest.cli import app
from simtest.render.simreal import (
    ALL_STATISTICS,
    FACTOR_GOAL,
    GLINT_STATISTICS,
    REAL_SPLIT,
    banner_tiles,
    frame_stats,
    glint_population,
    real_reference,
    sim_to_real_table,
    split_indices,
)
from simtest.resources import real_banner_path


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
    assert set(st.values()) == set(ALL_STATISTICS)
    with pytest.raises(ValueError, match="no lit pixel"):
        frame_stats(np.zeros((10, 10, 3), np.uint8))


#: Lattice points of a disc x^2 + y^2 <= r^2 for r = 0, 1, 2, ... (Gauss's circle problem, OEIS
#: A000328): the pixel area of the discs drawn below, known without drawing them.
DISC_AREA = (1, 5, 13, 29, 49, 81, 113)


def _discs(radii, size=(200, 260), border=20, white=(255, 255, 255)):
    """A dark frame with a tissue rectangle (the lit field) and a disc of each radius on it."""
    f = np.zeros((*size, 3), np.uint8)
    f[border:-border, border:-border] = (150, 90, 80)  # luma 107: tissue, neither white nor sheen
    yy, xx = np.mgrid[:size[0], :size[1]]
    for i, r in enumerate(radii):
        cy, cx = 40 + 40 * (i // 5), 40 + 40 * (i % 5)
        f[(yy - cy) ** 2 + (xx - cx) ** 2 <= r * r] = white
    return f, (size[0] - 2 * border) * (size[1] - 2 * border)


def test_glint_population_of_discs_of_known_area():
    radii = (1, 1, 2, 3, 3, 4, 5, 6)
    f, lit = _discs(radii)
    areas = sorted(DISC_AREA[r] for r in radii)  # 5 5 13 29 29 49 81 113, 324 px in all
    st, got, cen = glint_population(f)
    assert sorted(got.tolist()) == areas and len(cen) == len(radii)
    assert st["white_blobs_per_mp"] == pytest.approx(8 / lit * 1e6, rel=1e-12)
    assert st["white_median_area_px"] == 29.0  # (29 + 29) / 2
    assert st["white_p90_area_px"] == pytest.approx(81 + 0.3 * (113 - 81))  # numpy's linear rule, rank 6.3
    assert st["white_largest_share"] == pytest.approx(113 / 324)
    assert st["sheen_fraction"] == 0.0
    # the same frame at 16 bit (levels times 257): the same population
    st16, got16, _ = glint_population(f.astype(np.uint16) * 257)
    assert st16 == st and sorted(got16.tolist()) == areas
    # and it is what frame_stats reports, in the table's order
    assert {k: frame_stats(f, detector=False).values()[k] for k in GLINT_STATISTICS} == pytest.approx(st)


def test_white_needs_every_channel_and_blobs_join_diagonally():
    f, lit = _discs((3,), white=(255, 255, 249))  # blue one level short: JPEG's tint, not white
    st, areas, _ = glint_population(f)
    assert len(areas) == 0 and st["white_blobs_per_mp"] == 0.0 and np.isnan(st["white_largest_share"])
    f[100, 100] = f[101, 101] = f[150, 200] = 255  # two diagonal neighbours: one 8-connected blob
    st, areas, _ = glint_population(f)
    assert sorted(areas.tolist()) == [1, 2] and st["white_largest_share"] == pytest.approx(2 / 3)


def test_sheen_is_the_lit_pixels_of_luma_200_to_250():
    f, lit = _discs(())
    f[20:40, 20:70] = (200, 200, 200)  # luma 200: sheen (1000 px)
    f[40:50, 20:70] = (249, 249, 249)  # luma 249: sheen (500 px)
    f[50:60, 20:70] = (199, 199, 199)  # luma 199: below
    f[60:70, 20:70] = (250, 250, 250)  # white: not sheen
    assert glint_population(f)[0]["sheen_fraction"] == pytest.approx(1500 / lit)
    with pytest.raises(ValueError, match="uint8 or uint16"):
        glint_population(f.astype(np.float32))


def test_real_reference_pools_the_white_blobs():
    a, lit = _discs((1, 2, 6))
    b, _ = _discs((3,))
    ref = real_reference([a, b], [frame_stats(a, detector=False), frame_stats(b, detector=False)])
    assert ref["white_blobs_per_mp"] == pytest.approx(4 / (2 * lit) * 1e6)
    assert ref["white_median_area_px"] == (13 + 29) / 2  # areas 5, 13, 29, 113 pooled
    # the largest blob's share: a median of the frames' (113 / 131 and 1)
    assert ref["white_largest_share"] == pytest.approx((113 / 131 + 1) / 2)


def test_the_declared_split_is_by_frame():
    tiles = banner_tiles(real_banner_path())
    ids = [k for k, _ in tiles]
    assert len(ids) == len(set(ids)) == 24 and set(ids) == set(REAL_SPLIT)  # every bundled frame, once
    tuning, held = split_indices(ids)
    assert len(tuning) == len(held) == 12 and not set(tuning) & set(held)
    # each tile is one whole frame: at least three of its corners are black field stop (the fourth
    # may hold an overlay box), so no frame runs on into the next tile
    for _, f in tiles:
        corners = [f[:8, :8], f[:8, -8:], f[-8:, :8], f[-8:, -8:]]
        assert f.shape == (280, 280, 3) and sum(c.mean() < 40 for c in corners) >= 3
    # frames the table does not list: a seeded half and half, the same every time
    other = [f"v{i}.png" for i in range(9)]
    t, h = split_indices(other)
    assert (t, h) == split_indices(other) and len(t) == 5 and sorted(t + h) == list(range(9))


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
    assert [k for k, r in rows.items() if not r["fitted"]] == list(GLINT_STATISTICS)


def test_banner_tiles(tmp_path):
    import cv2

    img = np.zeros((560, 840, 3), np.uint8)
    img[280:, 560:] = (0, 0, 255)  # BGR red in the last tile
    cv2.imwrite(str(tmp_path / "b.png"), img)
    tiles = [f for _, f in banner_tiles(tmp_path / "b.png")]
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
    real, other = tmp_path / "real.png", tmp_path / "other.png"
    cv2.imwrite(str(real), cv2.cvtColor(_frame([(20, 20, 3)]), cv2.COLOR_RGB2BGR))
    cv2.imwrite(str(other), cv2.cvtColor(_frame([(30, 30, 2), (60, 60, 4)]), cv2.COLOR_RGB2BGR))
    res = CliRunner().invoke(app, ["simreal", str(scene), "--out", str(tmp_path / "o"), "--real", str(real),
                                   "--real", str(other)])
    assert res.exit_code == 0, res.output
    data = json.loads((tmp_path / "o" / "simreal.json").read_text())
    assert [r["statistic"] for r in data["rows"]] == list(ALL_STATISTICS)
    # two unlisted frames: one to each part, and a verdict on each part for every statistic
    assert sorted(data["split"]["tuning"] + data["split"]["held_out"]) == ["other.png", "real.png"]
    assert len(data["split"]["tuning"]) == len(data["split"]["held_out"]) == 1
    for part in ("tuning", "held_out"):
        assert [r["statistic"] for r in data["tables"][part]] == list(ALL_STATISTICS)
    md = (tmp_path / "o" / "simreal.md").read_text()
    assert "held-out: ratio" in md and "white_blobs_per_mp (not fitted)" in md
    for name in ("simreal.png", "frames.png", "glints.png"):
        assert (tmp_path / "o" / name).stat().st_size > 10000, name
    res = CliRunner().invoke(app, ["simreal", str(scene), "--out", str(tmp_path / "o"), "--real",
                                   str(tmp_path / "missing.png")])
    assert res.exit_code == 2 and res.output.count("\n") == 1 and "missing.png" in res.output
    # a black frame has no lit field to measure: one line naming it, before anything renders
    cv2.imwrite(str(tmp_path / "black.png"), np.zeros((64, 64, 3), np.uint8))
    res = CliRunner().invoke(app, ["simreal", str(scene), "--out", str(tmp_path / "o"), "--real",
                                   str(tmp_path / "black.png")])
    assert res.exit_code == 2 and res.output.count("\n") == 1 and "black.png: no lit pixel" in res.output
