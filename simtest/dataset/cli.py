"""``simtest dataset``: generate and verify datasets (imported by :mod:`simtest.cli` only when it runs; Mitsuba and Dask load when needed)."""

from __future__ import annotations

import os
from pathlib import Path

import typer

from simtest._exit import BAD_INPUT, CANNOT_WRITE, CHECK_FAILED, INTERRUPTED, fail, writable_dir
from simtest.dataset.config import PARAMS, DatasetConfigError, load_config
from simtest.dataset.export import export
from simtest.dataset.generate import Interrupted, SampleError, generate
from simtest.dataset.shards import DatasetError, DatasetWriteError
from simtest.dataset.show import contact_sheet
from simtest.dataset.verify import verify

dataset_app = typer.Typer(name="dataset", no_args_is_help=True, add_completion=False,
                          pretty_exceptions_enable=False, help="Rendered datasets for learning: generate "
                          "(resumable, local or Dask), verify, show, export.")


@dataset_app.command("generate")
def generate_command(
    config: Path = typer.Argument(..., help="Dataset config (TOML), e.g. scenes/datasets/example.toml."),
    out: Path = typer.Option(..., "--out", "-o", help="Dataset folder (created, or resumed)."),
    workers: int = typer.Option(None, "--workers", "-j", min=0, show_default=False,
                                help="Local worker processes (0, the default: one per core; at most the number of CPUs)."),
    scheduler: str = typer.Option(None, "--scheduler",
                                  help="Dask scheduler address (tcp://host:8786) to run on instead."),
    progress: bool = typer.Option(True, "--progress/--no-progress", help="Show a progress bar."),
) -> None:
    """Render the samples CONFIG describes into shards under OUT; a rerun resumes.

    Writes OUT/dataset.json (the card: config, seed, counts, channels, units, hashes), OUT/manifest.jsonl (one row of labels per sample), OUT/README.md, OUT/shards/shard-XXXXX.npz (the arrays) with OUT/shards/shard-XXXXX.json (their rows), and OUT/.lock; while it runs, OUT/spool/<index>.npz keeps each finished sample of an unfinished shard (removed at the end), so a failure, a kill or a full disk loses at most the samples in flight.

    Exit codes: 0 done, 2 bad config, folder or --workers, 4 OUT cannot be written, 130 interrupted (SIGTERM or Ctrl-C; workers stopped; rerun to resume).
    """
    cpus = os.cpu_count() or 1
    workers = workers or None  # 0 and None: one per core
    if workers is not None and workers > cpus and scheduler is None:
        fail(f"--workers {workers}: more than the {cpus} CPUs here (each worker renders with its "
             f"own threads); use at most {cpus}, or --scheduler for a Dask cluster", BAD_INPUT)
    try:
        cfg = load_config(config)
    except (DatasetConfigError, DatasetError) as exc:
        fail(exc, BAD_INPUT)
    writable_dir(out, "--out")
    try:
        rep = generate(cfg, out, workers=workers, scheduler=scheduler, progress=progress)
    except DatasetWriteError as exc:
        fail(exc, CANNOT_WRITE)
    except Interrupted as exc:
        fail(exc, INTERRUPTED)
    except (DatasetConfigError, DatasetError, SampleError, ValueError) as exc:
        fail(exc, BAD_INPUT)
    if rep.written == 0:
        typer.echo(f"{rep.out_dir}: {rep.count} samples, all already there (nothing to render)")
        return
    rss = ", ".join(f"{v:.0f}" for v in rep.worker_peak_rss_mb.values())
    resumed = f", {rep.resumed} from the spool" if rep.resumed else ""
    typer.echo(f"{rep.out_dir}: {rep.count} samples ({rep.written} written, {rep.skipped} already "
               f"there{resumed}); {rep.samples_per_s:.2f} samples/s; worker peak RSS MiB: {rss}")


@dataset_app.command("verify")
def verify_command(
    root: Path = typer.Argument(..., help="Dataset folder."),
    quick: bool = typer.Option(False, "--quick", help="Hashes and counts only; skip array checks."),
) -> None:
    """Check every shard and manifest entry: counts, hashes, shapes, unit normals.

    Writes nothing; prints one line per problem, then a summary. Exit codes: 0 sound, 1 damage found, 2 DIR is not a folder.
    """
    if not root.is_dir():
        fail(f"{root}: not a folder (give a dataset folder made by `simtest dataset generate`)", BAD_INPUT)
    rep = verify(root, check_arrays=not quick)
    for p in rep.problems:
        typer.echo(f"problem: {p}", err=True)
    if not rep.ok:
        typer.echo(f"{root}: FAILED ({len(rep.problems)} problem(s); {rep.samples} samples, "
                   f"{rep.shards} shards checked)", err=True)
        raise typer.Exit(CHECK_FAILED)
    typer.echo(f"{root}: OK ({rep.samples} samples in {rep.shards} shards)")


@dataset_app.command("export")
def export_command(
    root: Path = typer.Argument(..., help="Dataset folder."),
    fmt: str = typer.Option(..., "--format", "-f", help="webdataset (tar shards) or hdf5 (BlenderProc layout)."),
    out: Path = typer.Option(None, "--out", "-o", help="Output folder (default: DIR-<format> beside DIR)."),
) -> None:
    """Export DIR to WebDataset tar shards or HDF5 files, readable without simtest.

    Writes OUT/export.json and, for webdataset, OUT/shard-XXXXX.tar (one per dataset shard), for hdf5, OUT/<index>.hdf5 (one per sample); OUT is replaced as a whole.

    Exit codes: 0 done, 2 bad input, 4 OUT cannot be written (disk full: nothing left behind, an earlier export unchanged).
    """
    target = out if out is not None else root.with_name(f"{root.name}-{fmt}")
    try:
        if not root.is_dir():
            raise DatasetError(f"{root}: not a folder")
        writable_dir(target.parent, "--out")
        path = export(root, fmt, out)
    except DatasetWriteError as exc:
        fail(exc, CANNOT_WRITE)
    except DatasetError as exc:
        fail(exc, BAD_INPUT)
    except OSError as exc:
        fail(f"{exc.filename or target}: cannot write: {exc.strerror or exc}", CANNOT_WRITE)
    typer.echo(f"{path}: {fmt} export written (see {path / 'export.json'} for how to read it)")


@dataset_app.command("show")
def show_command(
    root: Path = typer.Argument(..., help="Dataset folder."),
    out: Path = typer.Option(None, "--out", "-o", help="PNG to write (default: DIR/contact_sheet.png)."),
    count: int = typer.Option(8, "--count", "-n", min=1, help="Samples shown, one row each."),
    start: int = typer.Option(0, "--start", min=0, help="First sample shown."),
) -> None:
    """Write a contact sheet: image with BP markers and isophotes, normals, masks per sample.

    Writes one PNG, OUT (default DIR/contact_sheet.png). Exit codes: 0 done, 2 bad input, 4 OUT cannot be written (disk full, read-only; an earlier sheet is kept).
    """
    try:
        path = contact_sheet(root, out, count=count, start=start)
    except (DatasetError, ValueError) as exc:
        fail(exc, BAD_INPUT)
    except OSError as exc:  # the sheet is written atomically: an earlier one is kept
        fail(f"--out: cannot write {out or root / 'contact_sheet.png'}: {exc.strerror or exc}", CANNOT_WRITE)
    typer.echo(f"{path}: contact sheet written")


@dataset_app.command("params")
def params_command() -> None:
    """List the parameters a dataset config may draw, with units, families and defaults (writes nothing)."""
    for p in PARAMS:
        defaults = "; ".join(f"{k}: {d.as_dict()}" for k, d in p.default.items())
        typer.echo(f"{p.name}  [{', '.join(p.families)}]\n    {p.doc}\n    default {defaults}")
