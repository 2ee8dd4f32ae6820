"""``simtest render SCENE --out DIR [--seed S] [--variant V]``: render a scene file to DIR; and
``simtest simreal``.

Mitsuba loads only when a render starts (:func:`simtest._lazy.require`). Errors are one line on stderr,
``error: <file>: <key>: <reason>``, never a traceback: exit code 2 for bad input (scene file,
option), 4 when the output folder cannot be written (a file in the way, read-only, files that are
not a render's inside; checked before rendering), 1 when Mitsuba cannot run here.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Optional

import cv2
import typer
from rich.console import Console

from simtest._exit import CANNOT_WRITE, writable_dir
from simtest._io import atomic_write_set
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
    out: Path = typer.Option(..., "--out", "-o", show_default=False,
                             help="Output folder, new, empty or a previous render's (replaced as a whole): "
                             "image.png, frame.png, intrinsics.json, camera.json, ground_truth.npz, "
                             "highlights.json."),
    seed: Optional[int] = typer.Option(None, "--seed", min=0, max=MAX_SEED,
                                       help="Root seed in [0, 2^31 - 1] (default: the scene's render.seed)."),
    variant: Optional[str] = typer.Option(
        None, "--variant", help="Mitsuba variant: auto, llvm_ad_rgb, cuda_ad_rgb (default: the scene's)."),
) -> None:
    """Render SCENE with its ground truth.

    Writes, in the folder OUT (new, empty, or a previous render's; replaced as a whole, so a
    failure leaves the previous set): OUT/image.png (the sensor image, 8 or 16 bit grey),
    OUT/frame.png (the 8-bit RGB video frame), OUT/intrinsics.json (K and the image size),
    OUT/camera.json (the camera model and its light rig), OUT/ground_truth.npz (per-pixel
    normals, depth, distance, position, mask, the linear and specular images) and
    OUT/highlights.json (each highlight's brightest point, normal and curvatures). Exit status 2:
    bad input; 4: OUT cannot be written; 1: Mitsuba cannot run here."""
    if variant is not None and variant not in RENDER_VARIANTS:
        raise _fail(f"--variant: {variant!r} is not one of {', '.join(RENDER_VARIANTS)}")
    writable_dir(out, "--out")
    try:
        check_output_folder(out)
    except OutputFolderError as exc:
        raise _fail(f"--out: {exc}", CANNOT_WRITE) from None
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
        raise _fail(f"--out: {exc}", CANNOT_WRITE) from None
    except OSError as exc:
        raise _fail(f"--out: cannot write the render to {out}: {exc.strerror or exc}", CANNOT_WRITE) from None
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
    out: Path = typer.Option(..., "--out", "-o", show_default=False,
                             help="Output folder (created if needed): simreal.json, simreal.md, simreal.png."),
    real: Optional[list[Path]] = typer.Option(
        None, "--real", help="Real frames: images, or a banner of 280 px tiles (*banner*). "
        "Default: the Hyper-Kvasir banner in tests/data/real."),
    seed: Optional[int] = typer.Option(None, "--seed", min=0, max=MAX_SEED, help="Render seed."),
) -> None:
    """Render SCENE and compare its video frame with real frames: table (JSON, Markdown) and figure.

    Writes, in the folder OUT (the three replaced as a set; other files there are kept):
    OUT/simreal.json (the table's rows, the scene, the seed and the real frames),
    OUT/simreal.md (the table in Markdown) and OUT/simreal.png (the figure). Exit status 2: bad
    input; 4: OUT cannot be written; 1: Mitsuba cannot run here."""
    writable_dir(out, "--out")
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
    doc = {"scene": spec.name, "seed": result.seed, "real": [_shown(p) for p in paths], "rows": rows}
    lines = ["| statistic | rendered | real median | real IQR | ratio | within x2 |",
             "|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['statistic']} | {r['rendered']:.4g} | {r['real_median']:.4g} | "
                     f"{r['real_q25']:.3g} to {r['real_q75']:.3g} | {r['ratio']:.3g} | "
                     f"{'yes' if r['within_goal'] else 'no'} |")
    try:
        atomic_write_set({
            out / "simreal.json": lambda t: Path(t).write_text(json.dumps(doc, indent=1) + "\n", encoding="utf-8"),
            out / "simreal.md": lambda t: Path(t).write_text("\n".join(lines) + "\n", encoding="utf-8"),
            out / "simreal.png": lambda t: fig.savefig(t, format="png", dpi=110),
        })
    except OSError as exc:
        raise _fail(f"--out: cannot write {out}: {exc.strerror or exc}", CANNOT_WRITE) from None
    typer.echo("\n".join(lines))
