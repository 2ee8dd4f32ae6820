"""The `simtest` command line: one command with subcommands.

Each subcommand lives beside the code it drives (``simtest/<package>/cli.py``, ``simtest/bench.py``)
and is listed in :data:`SUBCOMMANDS` with its one-line help. A subcommand's module, which imports
the science at its top (numpy, scipy, trimesh, matplotlib, ...), is imported only when that
subcommand runs or shows its own help, so that ``simtest --help`` and ``simtest version`` answer at
once and never import Mitsuba.
"""

from __future__ import annotations

import importlib
import signal

import typer
from typer.core import TyperCommand, TyperGroup

from simtest._exit import BAD_INPUT, INTERRUPTED, exit_on_signal, fail, signals_interrupt
from simtest._lazy import MissingBackend
from simtest._workers import stop_workers
from simtest._version import __version__

#: name -> (module, attribute: a command function or a Typer app, one-line help for the listing)
SUBCOMMANDS: dict[str, tuple[str, str, str]] = {
    "validate": ("simtest.harness.cli", "validate_command",
                 "Run a validation suite and write its report (the main job)."),
    "nightly": ("simtest.harness.cli", "nightly_command",
                "Run the nightly (or --quick) suite and compare it with the committed baseline."),
    "crb": ("simtest.harness.crb", "crb_command",
            "The photometric fit against its Cramer-Rao bound (analytic planes; figure)."),
    "reconstruct": ("simtest.reconstruct.cli", "reconstruct_command",
                    "Estimate the normal at every specular highlight of IMAGE."),
    "view": ("simtest.reconstruct.cli", "view_command",
             "Render a 3D view of the estimated normals (off-screen: works without a display)."),
    "render": ("simtest.render.cli", "render_command",
               "Render a scene with its ground truth."),
    "simreal": ("simtest.render.cli", "simreal_command",
                "Render an endoscope scene and compare its video frame with real frames."),
    "meshes": ("simtest.scene.meshes_cli", "meshes_app",
               "Procedural meshes (colon, liver) with ground-truth normals and curvatures."),
    "dataset": ("simtest.dataset.cli", "dataset_app",
                "Rendered datasets for learning: generate, verify, show, export."),
    "evaluate": ("simtest.evaluate.cli", "evaluate_app",
                 "Score reconstructions against datasets with ground-truth normals."),
    "bench": ("simtest.bench", "bench_command", "Speed benchmarks."),
}


def load_subcommand(name: str) -> TyperCommand | TyperGroup:
    """Import the module of subcommand ``name`` and return it as a command (Typer's Click).

    simtest never imports Click itself: Typer 0.29 and later carry their own copy of it and no
    longer install Click, so every command object here comes from Typer."""
    module, attr, _ = SUBCOMMANDS[name]
    obj = getattr(importlib.import_module(module), attr)
    if isinstance(obj, typer.Typer):
        group = typer.main.get_group(obj)
        group.name = name
        return group
    single = typer.Typer(add_completion=False)
    single.command(name)(obj)
    return typer.main.get_command(single)


class _LazyGroup(TyperGroup):
    """Lists every subcommand from :data:`SUBCOMMANDS`; imports one only when it is used."""

    _listing = False

    def list_commands(self, ctx):
        return list(self.commands) + [n for n in SUBCOMMANDS if n not in self.commands]

    def get_command(self, ctx, name):
        if name in SUBCOMMANDS and name not in self.commands:
            if self._listing:  # the top-level --help needs only the name and the one-line help
                return TyperCommand(name, help=SUBCOMMANDS[name][2])
            self.add_command(load_subcommand(name), name)
        return super().get_command(ctx, name)

    def invoke(self, ctx):
        # SIGTERM as Ctrl-C: KeyboardInterrupt, so that every command's clean-up runs; then the
        # workers a pool left stopped and one line, exit 130 (Click would print "Aborted!", 1)
        with signals_interrupt() as sig:
            try:
                rv = super().invoke(ctx)
            except MissingBackend as exc:
                # an optional back-end a subcommand needs and the machine lacks (Dask for
                # --scheduler, PyTorch, ...): its one line, naming the extra to install
                if sig.signame is None:
                    fail(exc, BAD_INPUT)
            except typer.Exit as exc:
                if sig.signame is None or exc.exit_code == INTERRUPTED:
                    raise  # a command's own line (dataset generate says how to resume)
            except BaseException:
                if sig.signame is None:
                    raise
                # the signal's exception, or what a library made of it (Mitsuba's import turns it
                # into a SystemError): interrupted all the same
            if sig.signame is None:
                return rv
            n = stop_workers()  # those a pool left running (its own block stops the rest)
            fail(f"interrupted by {sig.signame}" + (f"; {n} worker(s) stopped" if n else "")
                 + "; outputs written before are intact", INTERRUPTED)

    def format_help(self, ctx, formatter):
        self._listing = True
        try:
            return super().format_help(ctx, formatter)
        finally:
            self._listing = False


app = typer.Typer(
    name="simtest",
    cls=_LazyGroup,
    help="Testbed for normal reconstruction from specular isophotes in endoscopy.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)


def _print_version(value: bool) -> None:
    if value:
        typer.echo(__version__)
        raise typer.Exit(0)


@app.callback()
def _root(
    version: bool = typer.Option(False, "--version", "-V", is_eager=True, callback=_print_version,
                                 help="Print the simtest version and exit."),
) -> None:
    # a callback makes the app a group even with one eagerly registered command
    pass


@app.command("version")
def version_command() -> None:
    """Print the simtest version."""
    typer.echo(__version__)


def main() -> None:
    """Entry point of the ``simtest`` console script.

    Around the command (while Python starts it, and while it shuts down after it), SIGINT and
    SIGTERM end the process at once with exit status 130 and one line; during the command they
    raise KeyboardInterrupt, so that its clean-up runs (:meth:`_LazyGroup.invoke`).
    """
    for s in (signal.SIGINT, signal.SIGTERM):
        signal.signal(s, exit_on_signal)
    app()


if __name__ == "__main__":
    main()
