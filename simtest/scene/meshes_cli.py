"""``simtest meshes``: build the procedural colon and liver meshes (the liver also in its abdomen).

Imported by :mod:`simtest.cli` only when the command runs (``simtest --help`` stays fast).
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console
from rich.table import Table

from simtest._exit import BAD_INPUT, CANNOT_WRITE, fail, writable_dir
from simtest._progress import transient_progress
from simtest.scene.meshes import MeshError, build_mesh, save_mesh

meshes_app = typer.Typer(name="meshes", no_args_is_help=True, add_completion=False,
                         help="Procedural meshes (colon, colon_haustral, liver, liver_abdomen) with ground-truth "
                         "normals and curvatures.")

_NAMES = ("colon", "colon_haustral", "liver", "liver_abdomen")


@meshes_app.callback()
def meshes_callback() -> None:
    """Procedural meshes (colon, colon_haustral, liver, liver_abdomen) with ground-truth normals and curvatures."""


def _parse_overrides(items: list[str]) -> dict[str, dict[str, float]]:
    """``["colon.fold_depth_mm=8", ...]`` -> ``{"colon": {"fold_depth_mm": 8.0}}``."""
    out: dict[str, dict[str, float]] = {name: {} for name in _NAMES}
    for item in items:
        key, sep, value = item.partition("=")
        name, dot, field = key.strip().partition(".")
        if not sep or not dot or name not in out or not field:
            raise typer.BadParameter(f"{item!r}: expected MESH.PARAM=VALUE with MESH one of {', '.join(_NAMES)}",
                                     param_hint="--set")
        try:
            number = float(value)
        except ValueError:
            raise typer.BadParameter(f"{item!r}: {value!r} is not a number", param_hint="--set")
        out[name][field] = int(number) if number.is_integer() and "." not in value else number
    return out


@meshes_app.command("build")
def build_command(
    out: Annotated[Path, typer.Option("--out", "-o", help="Output folder: colon.ply, colon.json, colon_haustral.ply, "
                                      "colon_haustral.json, liver.ply, liver.json, liver_abdomen.ply, liver_abdomen.json (those of --only).")]
    = Path("meshes"),
    seed: Annotated[int, typer.Option("--seed", min=0, help="Root seed of the generators.")] = 0,
    only: Annotated[list[str] | None, typer.Option("--only", help="Build only this mesh (colon, colon_haustral, liver "
                                                   "or liver_abdomen); repeatable.")] = None,
    set_: Annotated[list[str] | None, typer.Option("--set", help="Override a generator parameter, e.g. "
                                                   "colon.fold_depth_mm=8; repeatable.")] = None,
) -> None:
    """Build the procedural meshes with their ground truth.

    Writes, in the folder OUT (default meshes/ under the current folder; other files there are
    kept): OUT/colon.ply, OUT/colon_haustral.ply (the colon with semilunar folds, taeniae and
    haustra that scenes/colonoscope.toml and colonoscope_wall.toml render), OUT/liver.ply and
    OUT/liver_abdomen.ply (the liver, its gallbladder and the wall behind them that scenes/laparoscope_liver.toml
    renders; the meshes with per-vertex normals and principal curvatures k1, k2) and a .json
    beside each (the generator's parameters and seed); with --only, those of the meshes named. Exit status 2: bad
    option; 4: OUT cannot be written."""
    names = list(only) if only else list(_NAMES)
    for name in names:
        if name not in _NAMES:
            fail(f"--only: {name!r}: expected one of {', '.join(_NAMES)}", BAD_INPUT)
    try:
        overrides = _parse_overrides(list(set_ or []))
    except typer.BadParameter as exc:
        fail(f"--set: {exc}", BAD_INPUT)
    writable_dir(out, "--out")

    console = Console()
    table = Table(title=f"meshes (seed {seed})")
    for col in ("mesh", "vertices", "faces", "MB", "k1 1/mm", "k2 1/mm", "build s"):
        table.add_column(col)
    with transient_progress() as progress:
        task = progress.add_task("building meshes", total=len(names))
        for name in names:
            progress.update(task, description=f"building {name}")
            start = time.perf_counter()
            try:
                mesh = build_mesh(name, seed, **overrides[name])
            except MeshError as exc:
                fail(exc, BAD_INPUT)
            elapsed = time.perf_counter() - start
            try:
                path = save_mesh(mesh, out / f"{name}.ply")
            except OSError as exc:
                fail(f"--out: cannot write {out / (name + '.ply')}: {exc.strerror or exc}", CANNOT_WRITE)
            k1, k2 = mesh.vertex_attributes["k1"], mesh.vertex_attributes["k2"]
            table.add_row(name, str(len(mesh.vertices)), str(len(mesh.faces)), f"{path.stat().st_size / 1e6:.2f}",
                          f"{k1.min():.3f}..{k1.max():.3f}", f"{k2.min():.3f}..{k2.max():.3f}", f"{elapsed:.2f}")
            progress.advance(task)
    console.print(table)
    console.print(f"wrote {', '.join(str(out / f'{n}.ply') for n in names)} (+ .json)")
