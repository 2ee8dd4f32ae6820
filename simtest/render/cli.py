"""``simtest render SCENE --out DIR [--seed S] [--variant V]``: render a scene file to DIR.

Cheap to import: Mitsuba loads only when the command runs.
"""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

__all__ = ["render_command"]


def render_command(
    scene: str = typer.Argument(..., help="Scene TOML file, or a bundled scene name such as plane_58deg."),
    out: Path = typer.Option(..., "--out", "-o", help="Output folder (created if needed)."),
    seed: Optional[int] = typer.Option(None, "--seed", min=0, help="Root seed (default: the scene's render.seed)."),
    variant: Optional[str] = typer.Option(
        None, "--variant", help="Mitsuba variant: auto, llvm_ad_rgb, cuda_ad_rgb (default: the scene's)."),
) -> None:
    """Render SCENE and write image.png, intrinsics.json, ground_truth.npz and highlights.json."""
    from rich.console import Console

    from simtest.render.render import RendererUnavailable, render_scene, write_render
    from simtest.scene.spec import RENDER_VARIANTS, SceneError, load_scene

    console = Console(stderr=True)
    if variant is not None and variant not in RENDER_VARIANTS:
        console.print(f"[red]error:[/red] --variant: {variant!r} is not one of {', '.join(RENDER_VARIANTS)}")
        raise typer.Exit(2)
    try:
        spec = load_scene(scene)
    except SceneError as exc:
        console.print(f"[red]error:[/red] {exc}")
        raise typer.Exit(2) from None
    try:
        with console.status(f"rendering {spec.name} ..."):
            result = render_scene(spec, seed=seed, variant=variant)
            paths = write_render(result, out)
    except RendererUnavailable as exc:
        console.print(f"[red]error:[/red] {exc}")
        raise typer.Exit(1) from None
    H, W = result.linear.shape
    console.print(f"{spec.name}: {W} x {H} px, {spec.render.spp} spp, seed {result.seed}, "
                  f"variant {result.variant}, {len(result.highlights)} highlight(s)")
    for h in result.highlights:
        console.print(f"  BP at ({h.bp_px[0]:.2f}, {h.bp_px[1]:.2f}) px, normal "
                      f"({h.normal[0]:.4f}, {h.normal[1]:.4f}, {h.normal[2]:.4f}), "
                      f"k1 {h.k1:.4g} k2 {h.k2:.4g} /mm{'' if h.in_frame else ' (out of frame)'}")
    for role, path in paths.items():
        console.print(f"  {role}: {path}")
