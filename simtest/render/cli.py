"""``simtest render SCENE --out DIR [--seed S] [--variant V]``: render a scene file to DIR.

Mitsuba loads only when a render starts (:func:`simtest._lazy.require`). Errors are one line on stderr,
``error: <file>: <key>: <reason>``, never a traceback: exit code 2 for bad input (scene file,
option, output folder), 1 when Mitsuba cannot run here.
"""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer
from rich.console import Console

from simtest.render.render import (
    OutputFolderError,
    RendererUnavailable,
    RenderInputError,
    check_output_folder,
    render_scene,
    write_render,
)
from simtest.render.truth import HighlightTruthError
from simtest.scene.spec import RENDER_VARIANTS, SceneError, load_scene

__all__ = ["render_command"]

#: Largest render seed: the scene files' ``render.seed`` range (Mitsuba's samplers take 32-bit seeds).
MAX_SEED = 2**31 - 1  # = simtest.render.render.MAX_SEED (not imported: Mitsuba-free start-up)


def _fail(message: str, code: int = 2) -> typer.Exit:
    """Print ``error: message`` as one unwrapped line on stderr; return the Exit to raise."""
    typer.echo(f"error: {' '.join(str(message).split())}", err=True)
    return typer.Exit(code)


def render_command(
    scene: str = typer.Argument(..., help="Scene TOML file, or a bundled scene name such as plane_58deg."),
    out: Path = typer.Option(..., "--out", "-o", help="Output folder (created if needed)."),
    seed: Optional[int] = typer.Option(None, "--seed", min=0, max=MAX_SEED,
                                       help="Root seed in [0, 2^31 - 1] (default: the scene's render.seed)."),
    variant: Optional[str] = typer.Option(
        None, "--variant", help="Mitsuba variant: auto, llvm_ad_rgb, cuda_ad_rgb (default: the scene's)."),
) -> None:
    """Render SCENE and write image.png, intrinsics.json, ground_truth.npz and highlights.json."""
    if variant is not None and variant not in RENDER_VARIANTS:
        raise _fail(f"--variant: {variant!r} is not one of {', '.join(RENDER_VARIANTS)}")
    try:
        check_output_folder(out)
    except OutputFolderError as exc:
        raise _fail(f"--out: {exc}") from None
    try:
        spec = load_scene(scene)
    except SceneError as exc:
        raise _fail(str(exc)) from None
    console = Console(stderr=True, soft_wrap=True)
    try:
        with console.status(f"rendering {spec.name} ..."):
            result = render_scene(spec, seed=seed, variant=variant)
    except RendererUnavailable as exc:
        raise _fail(str(exc), code=1) from None
    except HighlightTruthError as exc:
        raise _fail(f"{spec.source or scene}: geometry: {exc}") from None
    except RenderInputError as exc:
        raise _fail(str(exc)) from None
    try:
        paths = write_render(result, out)
    except OutputFolderError as exc:
        raise _fail(f"--out: {exc}") from None
    except OSError as exc:
        raise _fail(f"--out: cannot write the render to {out}: {exc}") from None
    H, W = result.linear.shape
    console.print(f"{spec.name}: {W} x {H} px, {spec.render.spp} spp, seed {result.seed}, "
                  f"variant {result.variant}, {len(result.highlights)} highlight(s)", highlight=False)
    for h in result.highlights:
        console.print(f"  BP at ({h.bp_px[0]:.2f}, {h.bp_px[1]:.2f}) px, normal "
                      f"({h.normal[0]:.4f}, {h.normal[1]:.4f}, {h.normal[2]:.4f}), "
                      f"k1 {h.k1:.4g} k2 {h.k2:.4g} /mm{'' if h.in_frame else ' (out of frame)'}",
                      highlight=False)
    for role, path in paths.items():
        console.print(f"  {role}: {path}", markup=False, highlight=False)
