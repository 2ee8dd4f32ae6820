"""``simtest render SCENE --out DIR [--seed S] [--variant V]``: render a scene file to DIR; and
``simtest simreal``.

Mitsuba loads only when a render starts (:func:`simtest._lazy.require`). Errors are one line on stderr,
``error: <file>: <key>: <reason>``, never a traceback: exit code 2 for bad input (scene file,
option, or Mitsuba cannot run here: the line says why), 4 when the output folder cannot be
written (a file in the way, read-only, files that are not a render's inside; checked before
rendering).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Optional

import cv2
import numpy as np
import typer
from PIL import Image
from rich.console import Console

from simtest._exit import BAD_INPUT, CANNOT_WRITE
from simtest._io import OutputFolderError
from simtest._outdir import check_out_folder, write_out_folder
from simtest.constants import MAX_SEED
from simtest.render.render import (
    RENDER_FILES,
    RendererUnavailable,
    RenderInputError,
    render_scene,
    write_render,
)
from simtest.render.simfit import fit_scene, split_frames
from simtest.render.simreal import (
    FACTOR_GOAL,
    at_height,
    banner_frames,
    fit_figure,
    sim_to_real_figure,
    sim_to_real_table,
)
from simtest.reconstruct.images import quiet_stderr
from simtest.simulate.truth import HighlightTruthError
from simtest.resources import data_root, real_banner_path
from simtest.scene.spec import RENDER_VARIANTS, SceneError, load_scene, scene_to_toml

__all__ = ["render_command", "simreal_command", "SIMREAL_FILES"]

#: What ``simtest simreal`` writes in its output folder (and all that may be there: it is replaced
#: as a set, so that a kill never leaves a new simreal.json beside an old simreal.png).
SIMREAL_FILES = ("simreal.json", "simreal.md", "simreal.png", "frames.png", "fitted.toml")


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
    OUT/camera.json (the camera model, its light rig and, with a video sensor, its response),
    OUT/ground_truth.npz (per-pixel normals, depth, distance, position, mask, the linear and
    specular images) and
    OUT/highlights.json (each highlight's brightest point, normal and curvatures). Exit status 2:
    bad input, or Mitsuba cannot run here; 4: OUT cannot be written."""
    if variant is not None and variant not in RENDER_VARIANTS:
        raise _fail(f"--variant: {variant!r} is not one of {', '.join(RENDER_VARIANTS)}")
    check_out_folder(out, RENDER_FILES)
    try:
        spec = load_scene(scene)
    except SceneError as exc:
        raise _fail(str(exc)) from None
    console = Console(stderr=True, soft_wrap=True)
    try:
        with console.status(f"rendering {spec.name} ..."):
            result = render_scene(spec, seed=seed, variant=variant)
    except RendererUnavailable as exc:
        raise _fail(str(exc), BAD_INPUT) from None  # Mitsuba cannot run here
    except HighlightTruthError as exc:
        raise _fail(f"{spec.source or scene}: geometry: {exc}") from None
    except RenderInputError as exc:
        raise _fail(str(exc)) from None
    try:
        paths = write_render(result, out)
    except OutputFolderError as exc:
        raise _fail(exc, CANNOT_WRITE) from None
    except OSError as exc:
        raise _fail(f"--out: cannot write the render to {out}: {exc.strerror or exc}", CANNOT_WRITE) from None
    H, W = result.linear.shape
    console = Console(soft_wrap=True)  # the results on stdout; progress was on stderr
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


def _read_frames(paths: list[Path], option: str) -> list:
    """RGB uint8 frames of image files (a banner of 280 px tiles, ``*banner*``, gives its tiles);
    raises the one-line failure naming ``option`` and the file."""
    frames = []
    for p in paths:
        if not p.is_file():
            raise _fail(f"{option}: {p}: no such file (give real frames with {option})")
        if "banner" in p.name:
            try:
                frames += banner_frames(p)
            except ValueError as exc:
                raise _fail(f"{option}: {exc}") from None
        else:
            with quiet_stderr():  # libpng's own lines (an iCCP profile, ...): ours names the file
                img = cv2.imread(str(p), cv2.IMREAD_COLOR)
            if img is None:
                raise _fail(f"{option}: {p}: not a readable image")
            frames.append(cv2.cvtColor(img, cv2.COLOR_BGR2RGB))
    if len({f.shape[0] for f in frames}) != 1:
        raise _fail(f"{option}: the real frames must share one height")
    return frames


def _table_md(rows: list[dict]) -> list[str]:
    lines = ["| statistic | rendered | real | real IQR (per frame) | ratio | within x2 |",
             "|---|---|---|---|---|---|"]
    for r in rows:
        real = f"{r['real']:.4g}" + (" (pooled)" if r.get("real_pooled") else "")
        lines.append(f"| {r['statistic']} | {r['rendered']:.4g} | {real} | "
                     f"{r['real_q25']:.3g} to {r['real_q75']:.3g} | {r['ratio']:.3g} | "
                     f"{'yes' if r['within_goal'] else 'no'} |")
    return lines


def simreal_command(
    scene_arg: Optional[str] = typer.Argument(None, metavar="[SCENE]",
                                              help="Scene to render (a bundled name or a TOML file); "
                                              "default colonoscope."),
    out: Path = typer.Option(..., "--out", "-o", show_default=False,
                             help="Output folder, new, empty or a previous simreal's (replaced as a whole): "
                             "simreal.json, simreal.md, simreal.png (with --fit also fitted.toml and frames.png)."),
    real: Optional[list[Path]] = typer.Option(
        None, "--real", help="Real frames: images, or a banner of 280 px tiles (*banner*). "
        "Default: the Hyper-Kvasir banner in tests/data/real."),
    fit: Optional[list[Path]] = typer.Option(
        None, "--fit", help="Fit the scene's appearance and sensor to these real frames (images or a "
        "*banner* of 280 px tiles): alternate frames are fitted, the others held out."),
    scene_opt: Optional[str] = typer.Option(None, "--scene", help="The scene (same as SCENE)."),
    renders: int = typer.Option(14, "--renders", min=3, max=200,
                                help="With --fit: renders of the search at half the film and 4 spp."),
    polish: int = typer.Option(6, "--polish", min=0, max=100,
                               help="With --fit: renders at the scene's own film and spp that polish the search's "
                               "best point."),
    seed: Optional[int] = typer.Option(None, "--seed", min=0, max=MAX_SEED,
                                       help="Render seed (with --fit: the root seed of the fit)."),
) -> None:
    """Render SCENE and compare its video frame with real frames: table (JSON, Markdown) and figure;
    with --fit, first fit the scene to real frames.

    Writes, in the folder OUT (new, empty or a previous simreal's; replaced as a set): OUT/simreal.json
    (the table's rows, the scene, the seed and the real frames), OUT/simreal.md (the table in
    Markdown) and OUT/simreal.png (the figure). With --fit FRAMES: the scene's micro-relief
    (height, spectrum), film roughness, albedo, exposure, noise and tone are fitted to alternate
    frames of FRAMES (scipy's Nelder-Mead on the log-ratios of the statistics; --renders renders
    at half the film and 4 spp, then --polish at the scene's own film and spp: about 10 minutes
    for the colonoscope on 2 cores), and OUT/fitted.toml (the fitted scene),
    OUT/frames.png (before and after beside real frames) are written too, with simreal.json and
    simreal.md holding every statistic before and after on the fitted and the held-out frames.
    Exit status 2: bad input, or Mitsuba cannot run here; 4: OUT cannot be written."""
    if scene_arg is not None and scene_opt is not None and scene_arg != scene_opt:
        raise _fail(f"--scene: {scene_opt!r} and SCENE {scene_arg!r} disagree (give one)")
    scene = scene_opt or scene_arg or "colonoscope"
    target = check_out_folder(out, SIMREAL_FILES)
    if fit:
        if real:
            raise _fail("--real: not with --fit (the fit's held-out frames are its check)")
        frames = _read_frames(list(fit), "--fit")
    else:
        frames = _read_frames(list(real or [real_banner_path()]), "--real")
    try:
        spec = load_scene(scene)
    except SceneError as exc:
        raise _fail(str(exc)) from None
    if fit:
        _simreal_fit(spec, frames, list(fit), out, target, renders, polish,
                     spec.render.seed if seed is None else seed)
        return
    try:
        result = render_scene(spec, seed=seed)
    except RenderInputError as exc:
        raise _fail(str(exc)) from None
    except RendererUnavailable as exc:
        raise _fail(str(exc), BAD_INPUT) from None  # Mitsuba cannot run here
    frame = result.frame
    paths = real or [real_banner_path()]
    rows = sim_to_real_table(frame, frames)
    fig = sim_to_real_figure(frame, frames, rows)
    doc = {"scene": spec.name, "seed": result.seed, "real": [_shown(p) for p in paths], "rows": rows}
    lines = _table_md(rows)
    def fill(tmp: Path) -> None:
        (tmp / "simreal.json").write_text(json.dumps(doc, indent=1) + "\n", encoding="utf-8")
        (tmp / "simreal.md").write_text("\n".join(lines) + "\n", encoding="utf-8")
        fig.savefig(tmp / "simreal.png", format="png", dpi=110)

    write_out_folder(out, target, fill, SIMREAL_FILES)
    typer.echo("\n".join(lines))


def _simreal_fit(spec, frames: list, paths: list[Path], out: Path, target: Path, renders: int, polish: int,
                 seed: int) -> None:
    """``simreal --fit``: fit, then write the fitted scene and the before/after report."""

    fit_frames, held = split_frames(frames)
    console = Console(stderr=True, soft_wrap=True)
    try:
        res = fit_scene(spec, fit_frames, seed=seed, outer_evals=renders, polish_evals=polish,
                        progress=lambda s: console.print(s, markup=False, highlight=False))
    except ValueError as exc:
        raise _fail(str(exc)) from None
    except RenderInputError as exc:
        raise _fail(str(exc)) from None
    except RendererUnavailable as exc:
        raise _fail(str(exc), BAD_INPUT) from None  # Mitsuba cannot run here
    tables = {}
    for name, fr in (("fitted", fit_frames), ("held_out", held)):
        if fr:
            tables[name] = {"before": sim_to_real_table(res.before, fr), "after": sim_to_real_table(res.after, fr)}
    counts = {name: {when: sum(r["within_goal"] for r in rows) for when, rows in t.items()} for name, t in tables.items()}
    n_stats = len(tables["fitted"]["after"])
    src = [_shown(p) for p in paths]
    header = (f"{spec.name}, fitted by `simtest simreal --fit` to {len(fit_frames)} real frames "
              f"(alternate frames of {', '.join(src)}; {len(held)} held out), root seed {seed}.\n"
              f"Within x{FACTOR_GOAL:g} of the real frames after the fit: "
              + "; ".join(f"{n.replace('_', '-')} {c['after']} of {n_stats}" for n, c in counts.items()) + ".\n"
              + "Fitted: " + ", ".join(f"{k} {v:.4g}" for k, v in res.params.items()))
    doc = {"scene": spec.name, "seed": seed, "real": src, "fit_frames": len(fit_frames),
           "held_out_frames": len(held), "split": "alternate frames: even indices fitted, odd held out",
           "params": res.params, "renders": res.renders, "history": res.history, "within_goal": counts,
           "tables": tables, "rows": tables["fitted"]["after"]}
    lines = [f"# simreal --fit: {spec.name}", "", header.replace("\n", "\n\n"), ""]
    for name, t in tables.items():
        for when in ("before", "after"):
            lines += [f"## {name.replace('_', '-')} frames, {when} the fit ({counts[name][when]} of {n_stats} within "
                      f"x{FACTOR_GOAL:g})", ""] + _table_md(t[when]) + [""]
    fig = fit_figure(res.before, res.after, fit_frames, held, tables)
    toml = scene_to_toml(res.spec, out, header)
    strip = _side_by_side(res.before, res.after, fit_frames, held)
    def fill(tmp: Path) -> None:
        (tmp / "simreal.json").write_text(json.dumps(doc, indent=1) + "\n", encoding="utf-8")
        (tmp / "simreal.md").write_text("\n".join(lines) + "\n", encoding="utf-8")
        fig.savefig(tmp / "simreal.png", format="png", dpi=100)
        Image.fromarray(strip).save(tmp / "frames.png", format="PNG")
        (tmp / "fitted.toml").write_text(toml, encoding="utf-8")

    write_out_folder(out, target, fill, SIMREAL_FILES)
    typer.echo("\n".join(lines))


def _side_by_side(before, after, fit_frames, held) -> np.ndarray:
    """Before and after at the real frames' height beside four fitted and four held-out frames."""
    h = fit_frames[0].shape[0]
    row = [at_height(before, h), at_height(after, h)] + list(fit_frames[:2]) + list(held[:2])
    gap = np.full((h, 6, 3), 255, np.uint8)
    parts = []
    for f in row:
        parts += [f, gap]
    return np.concatenate(parts[:-1], axis=1)
