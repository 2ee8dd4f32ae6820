"""scenes/colonoscope_fitted.toml: the colonoscope calibrated by `simtest simreal --fit` is the fit's
own output (reports/simreal/2026-11-24-fit-seeds/fitted.toml), and a cheap render of it stays
within x2 of the real frames it was fitted to where a reduced film can tell.

The full check (the scene's own film and spp, render seeds 0 to 6: 12 of 12 statistics within x2
on the fitted frames at six seeds, 11 of 12 at seed 3; 11 of 12 on the held-out frames at every
seed) takes a minute and is in reports/simreal/README.md.
"""

from __future__ import annotations

import dataclasses

import pytest

from simtest.resources import data_root, real_banner_path
from simtest.render.simfit import split_frames
from simtest.render.simreal import ALL_STATISTICS, STATISTICS, banner_tiles, sim_to_real_table
from simtest.scene import load_scene, with_overrides

REPORT = data_root() / "reports" / "simreal" / "2026-11-24-fit-seeds"

#: Statistics a half-size, 4 spp render cannot be held to: the median blob area (at the real
#: frames' 280 px a glint of the full frame is 1 to 2 px, the real frames' median 3 px: 1 px more
#: or less is a factor 1.5 to 3, and the half film's glints are fewer pixels), and the detector's
#: candidate density (the half film's frame, brought to 280 px, has other noise than the full
#: one's: 2.05 to 2.28 times the real frames' at seeds 0 to 2, against 1.4 to 1.5 at full size).
FILM_DEPENDENT = ("median_area_px", "detector_per_mp")


def test_the_bundled_scene_is_the_fits_output():
    bundled = load_scene("colonoscope_fitted")
    fitted = load_scene(REPORT / "fitted.toml")
    assert bundled.geometry.path == fitted.geometry.path  # the same mesh file, resolved
    same = {"name": "", "description": "", "source": ""}
    assert dataclasses.replace(bundled, **same) == dataclasses.replace(fitted, **same)
    assert bundled.name == "colonoscope_fitted" and bundled.render.seed == 0


@pytest.mark.render
def test_a_cheap_render_stays_within_x2_of_the_real_frames():
    spec = load_scene("colonoscope_fitted")
    # half the film (C3VD's lens scaled with it: the same field of view) at 4 spp: about 1 s
    small = with_overrides(spec, {"camera.width_px": spec.camera.width_px // 2,
                                  "camera.height_px": spec.camera.height_px // 2, "render.spp": 4})
    from simtest.render import render_scene

    frame = render_scene(small).frame
    tiles = banner_tiles(real_banner_path())
    fit, held = split_frames([f for _, f in tiles], [k for k, _ in tiles])
    rows = {r["statistic"]: r for r in sim_to_real_table(frame, fit)}
    assert set(rows) == set(ALL_STATISTICS)
    # the fitted statistics (the glint population of issue 62 was not fitted: reported only)
    off = {k: round(r["ratio"], 3) for k, r in rows.items()
           if k in STATISTICS and k not in FILM_DEPENDENT and not r["within_goal"]}
    assert not off, f"fitted frames: statistics beyond x2 at half film: {off}"
    # held out: the saturated fraction is the one beyond x2 (2.2: the held-out frames saturate
    # 2.6 times less than the fitted ones), at full size too
    held_rows = [r for r in sim_to_real_table(frame, held) if r["fitted"]]
    assert sum(r["within_goal"] for r in held_rows) >= len(STATISTICS) - 1 - len(FILM_DEPENDENT)
