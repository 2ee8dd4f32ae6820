"""``simtest render SCENE --out DIR`` and ``simtest simreal``.

Mitsuba loads only when a render starts. Errors are one line on stderr, never a traceback: exit 2 for
bad input (or Mitsuba cannot run here), 4 when the output folder cannot be written (checked first).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Optional

import numpy as np
import typer
from PIL import Image
from rich.console import Console

from simtest._exit import CANNOT_WRITE, fail
from simtest._io import OutputFolderError
from simtest._outdir import check_out_folder, write_out_folder
from simtest.constants import MAX_SEED
from simtest.render.render import RENDER_FILES, RendererUnavailable, RenderInputError, render_scene, write_render
from simtest.render.simfit import fit_scene, split_frames
from simtest.render.simreal import (DARK_LEVEL, FACTOR_GOAL, REAL_SPLIT, at_height, banner_tiles, fit_figure,
                                    frames_figure, glint_population, glint_sheet, lit_field, _read_rgb,
                                    sim_to_real_figure, sim_to_real_table, split_indices, split_tables)
from simtest.simulate.truth import HighlightTruthError
from simtest.resources import data_root, real_banner_path
from simtest.scene.spec import RENDER_VARIANTS, SceneError, load_scene, scene_to_toml

__all__ = ["render_command", "simreal_command", "SIMREAL_FILES"]

#: What ``simtest simreal`` writes in its output folder (and all that may be there: it is replaced as a set)
SIMREAL_FILES = ("simreal.json", "simreal.md", "simreal.png", "frames.png", "glints.png", "fitted.toml")


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

    Writes, in the folder OUT (new, empty, or a previous render's; replaced as a whole, so a failure leaves
    the previous set): OUT/image.png (the sensor image, 8 or 16 bit grey), OUT/frame.png (the 8-bit RGB
    video frame), OUT/intrinsics.json (K and the image size), OUT/camera.json (the camera model, its light
    rig and, with a video sensor, its response), OUT/ground_truth.npz (per-pixel normals, depth, distance,
    position, mask, the linear and specular images) and OUT/highlights.json (each highlight's brightest
    point, normal and curvatures). Exit status 2: bad input, or Mitsuba cannot run here; 4: OUT cannot be
    written.
    """
    if variant is not None and variant not in RENDER_VARIANTS:
        fail(f"--variant: {variant!r} is not one of {', '.join(RENDER_VARIANTS)}")
    check_out_folder(out, RENDER_FILES)
    try:
        spec = load_scene(scene)
    except SceneError as exc:
        fail(exc)
    console = Console(stderr=True, soft_wrap=True)
    try:
        with console.status(f"rendering {spec.name} ..."):
            result = render_scene(spec, seed=seed, variant=variant)
    except (RendererUnavailable, RenderInputError) as exc:  # bad input, or Mitsuba cannot run here
        fail(exc)
    except HighlightTruthError as exc:
        fail(f"{spec.source or scene}: geometry: {exc}")
    try:
        paths = write_render(result, out)
    except OutputFolderError as exc:
        fail(exc, CANNOT_WRITE)
    except OSError as exc:
        fail(f"--out: cannot write the render to {out}: {exc.strerror or exc}", CANNOT_WRITE)
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
    """``path`` relative to the data root when inside it (a committed table names no machine's folders)."""
    try:
        return str(Path(path).resolve().relative_to(data_root().resolve()))
    except ValueError:
        return str(path)


def _read_frames(paths: list[Path], option: str) -> tuple[list, list[str]]:
    """RGB uint8 frames of image files (a ``*banner*`` gives its 280 px tiles) and their ids; one-line failures."""
    frames, ids = [], []
    for p in paths:
        if not p.is_file():
            fail(f"{option}: {p}: no such file (give real frames with {option})")
        try:
            tiles = banner_tiles(p) if "banner" in p.name else [(p.name, _read_rgb(p))]
        except ValueError as exc:
            fail(f"{option}: {exc}")
        frames += [f for _, f in tiles]
        ids += [k for k, _ in tiles]
    if len({f.shape[0] for f in frames}) != 1:
        fail(f"{option}: the real frames must share one height")
    for f, i in zip(frames, ids):  # simreal's statistics are of the lit field
        if not lit_field(f)[1].any():
            fail(f"{option}: {i}: no lit pixel (luma at most {DARK_LEVEL} everywhere)")
    return frames, ids


def _fmt(x: float) -> str:
    return f"{x:.3g}" if np.isfinite(x) else "n/a"


def _table_md(rows: list[dict], parts: dict[str, list[dict]] | None = None) -> list[str]:
    """The table in Markdown; ``parts`` (name -> rows): a ratio and a within-x2 column for each."""
    parts = parts or {}
    head = "| statistic | rendered | real | real IQR (per frame) | ratio | within x2 |"
    rule = "|---|---|---|---|---|---|"
    for name in parts:
        head += f" {name.replace('_', '-')}: ratio | within x2 |"
        rule += "---|---|"
    lines = [head, rule]
    for i, r in enumerate(rows):
        real = f"{r['real']:.4g}" + (" (pooled)" if r.get("real_pooled") else "")
        line = (f"| {r['statistic']}{'' if r.get('fitted', True) else ' (not fitted)'} | {r['rendered']:.4g} | "
                f"{real} | {_fmt(r['real_q25'])} to {_fmt(r['real_q75'])} | {_fmt(r['ratio'])} | "
                f"{'yes' if r['within_goal'] else 'no'} |")
        for p in parts.values():
            line += f" {_fmt(p[i]['ratio'])} | {'yes' if p[i]['within_goal'] else 'no'} |"
        lines.append(line)
    return lines


def _counts(rows: list[dict]) -> str:
    fitted = [r for r in rows if r.get("fitted", True)]
    glint = [r for r in rows if not r.get("fitted", True)]
    return (f"{sum(r['within_goal'] for r in rows)} of {len(rows)} (fitted statistics "
            f"{sum(r['within_goal'] for r in fitted)} of {len(fitted)}, glint population "
            f"{sum(r['within_goal'] for r in glint)} of {len(glint)})")


def simreal_command(
    scene_arg: Optional[str] = typer.Argument(None, metavar="[SCENE]",
                                              help="Scene to render (a bundled name or a TOML file); "
                                              "default colonoscope."),
    out: Path = typer.Option(..., "--out", "-o", show_default=False,
                             help="Output folder, new, empty or a previous simreal's (replaced as a whole): "
                             "simreal.json, simreal.md, simreal.png, frames.png, glints.png (with --fit also "
                             "fitted.toml)."),
    real: Optional[list[Path]] = typer.Option(
        None, "--real", help="Real frames: images, or a banner of 280 px tiles (*banner*). "
        "Default: the Hyper-Kvasir banner in tests/data/real."),
    fit: Optional[list[Path]] = typer.Option(
        None, "--fit", help="Fit the scene's appearance and sensor to these real frames (images or a "
        "*banner* of 280 px tiles): the tuning frames are fitted, the held-out ones judge."),
    scene_opt: Optional[str] = typer.Option(None, "--scene", help="The scene (same as SCENE)."),
    renders: int = typer.Option(14, "--renders", min=3, max=200,
                                help="With --fit: renders of the search at half the film and 4 spp."),
    polish: int = typer.Option(6, "--polish", min=0, max=100,
                               help="With --fit: renders at the scene's own film and spp that polish the search's "
                               "best point."),
    seed: Optional[int] = typer.Option(None, "--seed", min=0, max=MAX_SEED,
                                       help="Render seed (with --fit: the root seed of the fit)."),
) -> None:
    """Render SCENE and compare its video frame with real frames; with --fit, first fit the scene to them.

    Writes, in the folder OUT (new, empty or a previous simreal's; replaced as a set): OUT/simreal.json
    (the table's rows, the scene, the seed, the real frames and their split), OUT/simreal.md (the table
    against all, the tuning and the held-out real frames), OUT/simreal.png (the figure), OUT/frames.png (the
    frame beside real frames) and OUT/glints.png (crops around the largest white blobs). The real frames
    are split into tuning and held-out ones (the bundled banner's split is declared in
    simtest.render.simreal.REAL_SPLIT; other frames: a seeded half and half). With --fit FRAMES: the
    scene's micro-relief, film roughness, albedo, exposure, noise and tone are fitted to the tuning frames
    (Nelder-Mead on the statistics' log-ratios: --renders at half the film and 4 spp, then --polish at the
    scene's own; about 10 minutes for the colonoscope on 2 cores); OUT/fitted.toml holds the fitted scene
    and the report every statistic before and after. Exit status 2: bad input, or Mitsuba cannot run
    here; 4: OUT cannot be written.
    """
    if scene_arg is not None and scene_opt is not None and scene_arg != scene_opt:
        fail(f"--scene: {scene_opt!r} and SCENE {scene_arg!r} disagree (give one)")
    scene = scene_opt or scene_arg or "colonoscope"
    target = check_out_folder(out, SIMREAL_FILES)
    if fit and real:
        fail("--real: not with --fit (the fit's held-out frames are its check)")
    paths = list(fit or real or [real_banner_path()])
    frames, ids = _read_frames(paths, "--fit" if fit else "--real")
    try:
        spec = load_scene(scene)
    except SceneError as exc:
        fail(exc)
    if fit:
        _simreal_fit(spec, frames, ids, paths, out, target, renders, polish,
                     spec.render.seed if seed is None else seed)
        return
    try:
        result = render_scene(spec, seed=seed)
    except (RenderInputError, RendererUnavailable) as exc:  # bad input, or Mitsuba cannot run here
        fail(exc)
    frame = result.frame
    tuning, held = split_indices(ids)
    tables = split_tables(frame, frames, tuning, held)
    rows = tables["all"]
    parts = {k: v for k, v in tables.items() if k != "all"}
    fig = sim_to_real_figure(frame, frames, rows)
    figs = {"frames.png": frames_figure(frame, frames, ids, tuning, held, title=spec.name),
            "glints.png": glint_sheet(frame, frames, ids, tuning, held, title=spec.name)}
    split = {"tuning": [ids[i] for i in tuning], "held_out": [ids[i] for i in held], "rule": _split_rule(ids)}
    doc = {"scene": spec.name, "seed": result.seed, "real": [_shown(p) for p in paths], "rows": rows,
           "split": split, "tables": parts,
           "within_goal": {name: sum(r["within_goal"] for r in t) for name, t in tables.items()}}
    lines = [f"# simreal: {spec.name} (render seed {result.seed})", "",
             f"Real frames: {', '.join(doc['real'])}: {len(frames)} frames, {len(tuning)} tuning, "
             f"{len(held)} held out ({split['rule']}).", "",
             f"Within x{FACTOR_GOAL:g}: " + "; ".join(f"{name.replace('_', '-')} frames {_counts(t)}"
                                                     for name, t in tables.items()) + ".", ""]
    native = glint_population(frame)[0]
    doc["rendered_own_scale"] = native
    lines += [f"The glint population of the rendered frame at its own {frame.shape[1]} x {frame.shape[0]} px (the "
              f"table compares it at the real frames' height): "
              + ", ".join(f"{k} {_fmt(v)}" for k, v in native.items()) + ".", ""]
    lines += _table_md(rows, parts)
    def fill(tmp: Path) -> None:
        (tmp / "simreal.json").write_text(json.dumps(doc, indent=1) + "\n", encoding="utf-8")
        (tmp / "simreal.md").write_text("\n".join(lines) + "\n", encoding="utf-8")
        fig.savefig(tmp / "simreal.png", format="png", dpi=110)
        for name, f in figs.items():
            f.savefig(tmp / name, format="png", dpi=110)

    write_out_folder(out, target, fill, SIMREAL_FILES)
    typer.echo("\n".join(lines))


def _split_rule(ids: list[str]) -> str:
    listed = sum(k in REAL_SPLIT for k in ids)
    rule = []
    if listed:
        rule.append(f"{listed} by the declared split, simtest.render.simreal.REAL_SPLIT")
    if listed < len(ids):
        rule.append(f"{len(ids) - listed} by a permutation drawn with SPLIT_SEED")
    return "; ".join(rule)


def _simreal_fit(spec, frames: list, ids: list[str], paths: list[Path], out: Path, target: Path, renders: int,
                 polish: int, seed: int) -> None:
    """``simreal --fit``: fit, then write the fitted scene and the before/after report."""
    fit_frames, held = split_frames(frames, ids)
    tuning_idx, held_idx = split_indices(ids)
    console = Console(stderr=True, soft_wrap=True)
    try:
        res = fit_scene(spec, fit_frames, seed=seed, outer_evals=renders, polish_evals=polish,
                        progress=lambda s: console.print(s, markup=False, highlight=False))
    except (ValueError, RenderInputError, RendererUnavailable) as exc:  # bad input, or Mitsuba cannot run here
        fail(exc)
    tables = {name: {"before": sim_to_real_table(res.before, fr), "after": sim_to_real_table(res.after, fr)}
              for name, fr in (("fitted", fit_frames), ("held_out", held)) if fr}
    counts = {name: {when: sum(r["within_goal"] for r in rows) for when, rows in t.items()} for name, t in tables.items()}
    n_stats = len(tables["fitted"]["after"])
    src = [_shown(p) for p in paths]
    header = (f"{spec.name}, fitted by `simtest simreal --fit` to {len(fit_frames)} real frames "
              f"(the tuning frames of {', '.join(src)}; {len(held)} held out: {_split_rule(ids)}), "
              f"root seed {seed}.\n"
              f"Within x{FACTOR_GOAL:g} of the real frames after the fit: "
              + "; ".join(f"{n.replace('_', '-')} {c['after']} of {n_stats}" for n, c in counts.items()) + ".\n"
              + "Fitted: " + ", ".join(f"{k} {v:.4g}" for k, v in res.params.items()))
    doc = {"scene": spec.name, "seed": seed, "real": src, "fit_frames": len(fit_frames),
           "held_out_frames": len(held),
           "split": {"tuning": [ids[i] for i in tuning_idx], "held_out": [ids[i] for i in held_idx],
                     "rule": _split_rule(ids)},
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
    sheet = glint_sheet(res.after, frames, ids, tuning_idx, held_idx, title="fitted")
    def fill(tmp: Path) -> None:
        sheet.savefig(tmp / "glints.png", format="png", dpi=110)
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
    parts = [x for f in row for x in (f, gap)]
    return np.concatenate(parts[:-1], axis=1)
