"""``simtest dataset``: generate and verify datasets (imported by :mod:`simtest.cli` only when it runs; Mitsuba and Dask load when needed)."""

from __future__ import annotations

from pathlib import Path

import typer

from simtest.dataset.config import PARAMS, DatasetConfigError, load_config
from simtest.dataset.export import export
from simtest.dataset.generate import SampleError, generate
from simtest.dataset.shards import DatasetError
from simtest.dataset.show import contact_sheet
from simtest.dataset.verify import verify

dataset_app = typer.Typer(
    name="dataset",
    help="Rendered datasets for learning: generate (resumable, local or Dask), verify, show, export.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)


@dataset_app.command("generate")
def generate_command(
    config: Path = typer.Argument(..., help="Dataset config (TOML), e.g. scenes/datasets/example.toml."),
    out: Path = typer.Option(..., "--out", "-o", help="Dataset folder (created, or resumed)."),
    workers: int = typer.Option(None, "--workers", "-j", min=1,
                                help="Local worker processes (default: number of CPUs)."),
    scheduler: str = typer.Option(None, "--scheduler",
                                  help="Dask scheduler address (tcp://host:8786) to run on instead."),
    progress: bool = typer.Option(True, "--progress/--no-progress", help="Show a progress bar."),
) -> None:
    """Render the samples CONFIG describes into shards under OUT; a rerun resumes."""

    try:
        cfg = load_config(config)
        rep = generate(cfg, out, workers=workers, scheduler=scheduler, progress=progress)
    except (DatasetConfigError, DatasetError, SampleError) as exc:
        typer.echo(f"error: {exc}", err=True)
        raise typer.Exit(2) from None
    if rep.written == 0:
        typer.echo(f"{rep.out_dir}: {rep.count} samples, all already there (nothing to render)")
        return
    rss = ", ".join(f"{v:.0f}" for v in rep.worker_peak_rss_mb.values())
    typer.echo(f"{rep.out_dir}: {rep.count} samples ({rep.written} written, {rep.skipped} already "
               f"there); {rep.samples_per_s:.2f} samples/s; worker peak RSS MiB: {rss}")


@dataset_app.command("verify")
def verify_command(
    root: Path = typer.Argument(..., help="Dataset folder."),
    quick: bool = typer.Option(False, "--quick", help="Hashes and counts only; skip array checks."),
) -> None:
    """Check every shard and manifest entry: counts, hashes, shapes, unit normals."""

    rep = verify(root, check_arrays=not quick)
    for p in rep.problems:
        typer.echo(f"problem: {p}", err=True)
    if not rep.ok:
        typer.echo(f"{root}: FAILED ({len(rep.problems)} problem(s); {rep.samples} samples, "
                   f"{rep.shards} shards checked)", err=True)
        raise typer.Exit(1)
    typer.echo(f"{root}: OK ({rep.samples} samples in {rep.shards} shards)")


@dataset_app.command("export")
def export_command(
    root: Path = typer.Argument(..., help="Dataset folder."),
    fmt: str = typer.Option(..., "--format", "-f", help="webdataset (tar shards) or hdf5 (BlenderProc layout)."),
    out: Path = typer.Option(None, "--out", "-o", help="Output folder (default: DIR-<format> beside DIR)."),
) -> None:
    """Export DIR to WebDataset tar shards or HDF5 files, readable without simtest."""

    try:
        path = export(root, fmt, out)
    except DatasetError as exc:
        typer.echo(f"error: {exc}", err=True)
        raise typer.Exit(2) from None
    except OSError as exc:
        typer.echo(f"error: {exc.filename or out or root}: cannot write: {exc.strerror or exc}", err=True)
        raise typer.Exit(2) from None
    typer.echo(f"{path}: {fmt} export written (see {path / 'export.json'} for how to read it)")


@dataset_app.command("show")
def show_command(
    root: Path = typer.Argument(..., help="Dataset folder."),
    out: Path = typer.Option(None, "--out", "-o", help="PNG to write (default: DIR/contact_sheet.png)."),
    count: int = typer.Option(8, "--count", "-n", min=1, help="Samples shown, one row each."),
    start: int = typer.Option(0, "--start", min=0, help="First sample shown."),
) -> None:
    """Write a contact sheet: image with BP markers and isophotes, normals, masks per sample."""

    try:
        path = contact_sheet(root, out, count=count, start=start)
    except (DatasetError, ValueError) as exc:
        typer.echo(f"error: {exc}", err=True)
        raise typer.Exit(2) from None
    typer.echo(f"{path}: contact sheet written")


@dataset_app.command("params")
def params_command() -> None:
    """List the parameters a dataset config may draw, with units, families and defaults."""

    for p in PARAMS:
        defaults = "; ".join(f"{k}: {d.as_dict()}" for k, d in p.default.items())
        typer.echo(f"{p.name}  [{', '.join(p.families)}]\n    {p.doc}\n    default {defaults}")
