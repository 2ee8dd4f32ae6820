"""The renderer: scene specs -> Mitsuba 3 renders with per-pixel and per-highlight ground truth.

The only package of simtest that imports Mitsuba, and only when a render is asked for: importing
``simtest.render`` is cheap.

Examples
--------
>>> from simtest.scene import load_scene                      # doctest: +SKIP
>>> from simtest.render import render_scene, write_render     # doctest: +SKIP
>>> result = render_scene(load_scene("plane_58deg"), seed=1)  # doctest: +SKIP
>>> write_render(result, "out/")                              # doctest: +SKIP
"""

from __future__ import annotations

from simtest.render.render import (
    RendererUnavailable,
    RenderResult,
    choose_variant,
    render_scene,
    write_render,
)
from simtest.render.truth import HighlightTruth

__all__ = [
    "HighlightTruth",
    "RenderResult",
    "RendererUnavailable",
    "choose_variant",
    "render_scene",
    "write_render",
]
