"""``simtest render SCENE --out DIR [--seed S] [--variant V]``: render a scene file to DIR.

Mitsuba loads only when a render starts (:func:`simtest._lazy.require`). Errors are one line on stderr,
``error: <file>: <key>: <reason>``, never a traceback: exit code 2 for bad input (scene file,
option, output folder), 1 when Mitsuba cannot run here.
"""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import cv2
import typer
from rich.console import Console

from simtest._io import atomic_write, atomic_write_json, atomic_write_text
from simtest.constants import MAX_SEED
from simtest.render.render import (
    OutputFolderError,
    RendererUnavailable,
    RenderInputError,
    check_output_folder,
    render_scene,
    write_render,
)
from simtest.render.simreal import banner_frames, sim_to_real_figure, sim_to_real_table
from simtest.simulate.truth import HighlightTruthError
from simtest.resources import data_root, real_banner_path
from simtest.scene.spec import RENDER_VARIANTS, SceneError, load_scene

__all__ = ["render_command", "simreal_command"]


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


def _shown(path: Path) -> str:
    """``path`` relative to the data root when it lies inside it (so a committed table names no
    machine's folders), else as given."""
    try:
        return str(Path(path).resolve().relative_to(data_root().resolve()))
    except ValueError:
        return str(path)


def simreal_command(
    scene: str = typer.Argument("colonoscope", help="Scene to render (a bundled name or a TOML file)."),
    out: Path = typer.Option(..., "--out", "-o", help="Output folder (created if needed)."),
    real: Optional[list[Path]] = typer.Option(
        None, "--real", help="Real frames: images, or a banner of 280 px tiles (*banner*). "
        "Default: the Hyper-Kvasir banner in tests/data/real."),
    seed: Optional[int] = typer.Option(None, "--seed", min=0, max=MAX_SEED, help="Render seed."),
) -> None:
    """Render SCENE and compare its video frame with real frames: table (JSON, Markdown) and figure."""
    paths = real or [real_banner_path()]
    frames = []
    for p in paths:
        if not p.is_file():
            raise _fail(f"--real: {p}: no such file (give real frames with --real)")
        if "banner" in p.name:
            try:
                frames += banner_frames(p)
            except ValueError as exc:
                raise _fail(f"--real: {exc}") from None
        else:
            img = cv2.imread(str(p), cv2.IMREAD_COLOR)
            if img is None:
                raise _fail(f"--real: {p}: not a readable image")
            frames.append(cv2.cvtColor(img, cv2.COLOR_BGR2RGB))
    if len({f.shape[0] for f in frames}) != 1:
        raise _fail("--real: the real frames must share one height")
    try:
        spec = load_scene(scene)
        result = render_scene(spec, seed=seed)
    except SceneError as exc:
        raise _fail(str(exc)) from None
    except RenderInputError as exc:
        raise _fail(str(exc)) from None
    except RendererUnavailable as exc:
        raise _fail(str(exc), code=1) from None
    frame = result.frame
    rows = sim_to_real_table(frame, frames)
    fig = sim_to_real_figure(frame, frames, rows)
    out.mkdir(parents=True, exist_ok=True)
    atomic_write_json(out / "simreal.json", {"scene": spec.name, "seed": result.seed,
                                             "real": [_shown(p) for p in paths], "rows": rows})
    lines = ["| statistic | rendered | real median | real IQR | ratio | within x2 |",
             "|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['statistic']} | {r['rendered']:.4g} | {r['real_median']:.4g} | "
                     f"{r['real_q25']:.3g} to {r['real_q75']:.3g} | {r['ratio']:.3g} | "
                     f"{'yes' if r['within_goal'] else 'no'} |")
    atomic_write_text(out / "simreal.md", "\n".join(lines) + "\n")
    atomic_write(out / "simreal.png", lambda t: fig.savefig(t, format="png", dpi=110), suffix=".png")
    typer.echo("\n".join(lines))
