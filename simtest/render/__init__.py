"""The renderer: scene specs -> Mitsuba 3 renders with per-pixel and per-highlight ground truth.

The only package that imports Mitsuba, and only when a render is asked for.

Examples
--------
>>> from simtest.scene import bundled_scene_path, load_scene
>>> from simtest.render import render_scene
>>> result = render_scene(load_scene(bundled_scene_path("plane_58deg")), seed=1)
>>> result.sensor.shape, result.normals.shape, len(result.highlights)
((406, 406), (406, 406, 3), 1)

``write_render(result, "out/")`` then writes the files ``simtest render`` writes.
"""

from __future__ import annotations

from simtest.render.render import RendererUnavailable, RenderResult, choose_variant, render_scene, write_render
from simtest.simulate.truth import HighlightTruth

__all__ = ["HighlightTruth", "RenderResult", "RendererUnavailable", "choose_variant", "render_scene", "write_render"]
