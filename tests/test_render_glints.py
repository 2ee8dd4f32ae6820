"""The default ``colonoscope`` frame shows a field of glints, not one broad sheen (issue 62).

Measured with issue 62's glint population (:func:`simtest.render.simreal.glint_population`:
white = every channel >= 250 inside the lit field), on the scene's own film (1350 x 1080) at
2 spp, its own seed: about 15 s. The film cannot be halved to save time: a glint of the mucosa's
micro-relief is about 0.05 mm (2 px) across at full size; at half size it is one pixel, which
JPEG's 4:2:0 chroma tints below white, so the half film shows 5 to 8 white blobs whether the
relief makes a glint field or not (19 to 35 per MP, seeds 0 to 2, before and after alike).

Measured (1350 x 1080, seed 0; `simtest simreal colonoscope --seed 0`, 16 spp, in
reports/simreal/README.md): with the former mucosa (0.5 um of relief, slopes 0.01 rad, under the
film's lobe) 10 to 14 white blobs per MP, the largest holding 0.54 to 0.58 of the white pixels
(2 and 4 spp, seeds 0 to 2; 16 spp: 10.3 and 0.565); with the scene's relief (30 um RMS at 0.5 to
4 mm, scenes/colonoscope.toml) 32 to 48 per MP, the largest 0.07 to 0.15 (4 spp, seeds 0 to 2; 2
spp: 39.6 and 0.088; 16 spp: 39.6 and 0.090); with the diffuse light no longer shaded by the
relief (subsurface_mm = 1.0) 35.6 to 42.8, the largest 0.080 to 0.085 (2 spp, seeds 0 to 2; 16
spp: 42.0 and 0.087; reports/simreal/2026-11-26-subsurface/); with the wet film levelling the
relief's short waves (film_thickness_mm = 0.03) 29.3 to 30.9, the largest 0.214 to 0.226 (2 spp,
seeds 0 to 2; 16 spp: 29.3 and 0.213; reports/simreal/2026-11-26-film/): a 0.05 mm film or
thicker merges a crest's glints into one top holding 0.42 to 0.61.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from simtest.render.simreal import banner_tiles, glint_population, split_indices
from simtest.scene import load_scene, with_overrides

#: Largest share of the white pixels one white blob may hold: issue 62's must-hold (real frames:
#: 0.04 in a colonoscopy phantom, 0.18 to 0.25 in vivo). A fold crest lit as one smooth sheen
#: holds more than half of them (0.565 before the relief); the glint field 0.07 to 0.15.
MAX_LARGEST_SHARE = 0.30
#: Fewest white blobs per megapixel of lit field: a field of glints, not a few sheens. The
#: smooth film gives 10 to 14 (one sheen per lit crest and a few), the relief 32 to 48 (seeds
#: 0 to 2); 20 lies between them in log terms (sqrt(12 x 36) = 21) and leaves the glint field a
#: margin of 1.6 for the seed's and the sampling's scatter. Real frames hold more (issue 62: a
#: phantom about 600 per MP), so this is a floor, not the goal.
MIN_WHITE_BLOBS_PER_MP = 20.0
#: Samples per pixel: 2 spp gives the statistics of 16 spp at seed 0 (39.6 per MP both; largest
#: share 0.088 against 0.090), so the test needs no more.
SPP = 2
REAL_DIR = Path(__file__).parent / "data" / "real"
#: Issue 62's factor on the sheen fraction (lit pixels of luma 200 to 250) against the real
#: frames' median; the reference here is the banner's tuning frames (per frame, then the median:
#: 0.037), on which the scene's auto-exposure target was chosen. The scene's frame gives 0.030 at
#: 2 spp and at 16 spp (0.0064 with the former target 0.21).
SHEEN_FACTOR = 2.0


@pytest.mark.render
def test_the_default_colonoscope_shows_a_glint_field():
    from simtest.render import render_scene

    spec = load_scene("colonoscope")
    frame = render_scene(with_overrides(spec, {"render.spp": SPP})).frame
    stats, areas, _ = glint_population(frame)
    assert stats["white_largest_share"] <= MAX_LARGEST_SHARE, stats
    assert stats["white_blobs_per_mp"] >= MIN_WHITE_BLOBS_PER_MP, stats
    tiles = banner_tiles(REAL_DIR / "hyperkvasir_banner.jpg")
    tuning, _ = split_indices([name for name, _ in tiles])
    real = float(np.median([glint_population(tiles[i][1])[0]["sheen_fraction"] for i in tuning]))
    assert real / SHEEN_FACTOR <= stats["sheen_fraction"] <= real * SHEEN_FACTOR, (stats, real)


#: Largest relief shading the default colonoscope's diffuse light may carry: the 95th percentile,
#: over the lit wall, of |I / I_smooth - 1|, I the diffuse-only (material.c = 0) red image and
#: I_smooth that without relief (relief_mm = 0; same rays). The diffuse light leaves the mucosa
#: after a lateral walk of about 1 mm (scenes/colonoscope.toml, subsurface_mm), which averages the
#: 0.5 to 4 mm relief's slopes out: 0.014 (seed 0); taking the shading normal as before (the
#: furry look at grazing angles) 0.148. 0.045 is their geometric mean, a margin of 3 either way.
MAX_DIFFUSE_RELIEF = 0.045


@pytest.mark.render
def test_the_relief_shades_the_film_not_the_diffuse_light():
    from simtest.render import render_scene

    # half film, 1 spp: the diffuse light varies over mm, many pixels; ~15 s for the pair
    base = {"render.spp": 1, "material.c": 0.0, "camera.width_px": 675, "camera.height_px": 540}
    spec = load_scene("colonoscope")
    rough = render_scene(with_overrides(spec, base))
    smooth = render_scene(with_overrides(spec, {**base, "material.relief_mm": 0.0}))
    lit = rough.mask & smooth.mask & (smooth.rgb[..., 0] > 0)
    dev = np.abs(rough.rgb[..., 0][lit] / smooth.rgb[..., 0][lit] - 1.0)
    assert np.percentile(dev, 95) <= MAX_DIFFUSE_RELIEF
    # the film keeps the whole relief: its shading normals are tilted as before
    cos = np.sum(rough.shading_normals[rough.mask] * rough.normals[rough.mask], -1)
    tilt = np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))
    assert np.median(tilt) > 2.0, np.median(tilt)
