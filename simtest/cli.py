"""The `simtest` command line: one command with subcommands.

Each subcommand lives beside the code it drives and is listed in :data:`SUBCOMMANDS`; its module is
imported only when it runs or shows its help, so ``simtest --help`` answers at once without Mitsuba.
"""

from __future__ import annotations

import gc
import importlib
import os
import signal
import sys
import warnings

import typer
from typer.core import TyperCommand, TyperGroup

from simtest._exit import BAD_INPUT, INTERRUPTED, exit_on_signal, fail, one_line, signals_interrupt
from simtest._lazy import MissingBackend
from simtest._workers import stop_workers
from simtest._version import __version__

# Click's exceptions, from the Click that Typer uses (its own copy from Typer 0.29, else Click):
# typer.BadParameter is re-exported from that module in every version.
_CLICK_EXC = sys.modules[typer.BadParameter.__module__]
_ABORTS = tuple({typer.Abort, getattr(_CLICK_EXC, "Abort", typer.Abort)})

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
    "render": ("simtest.render.cli", "render_command", "Render a scene with its ground truth."),
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
    """Import the module of subcommand ``name`` and return it as a command (Typer's own Click)."""
    module, attr, _ = SUBCOMMANDS[name]
    obj = getattr(importlib.import_module(module), attr)
    if isinstance(obj, typer.Typer):
        group = typer.main.get_group(obj)
        group.name = name
        return _plain_help(group)
    single = typer.Typer(add_completion=False)
    single.command(name)(obj)
    return _plain_help(typer.main.get_command(single))


def _plain_help(cmd):
    """``cmd`` and its subcommands with Click's plain help (paragraphs rewrapped to the terminal, ``IMAGE`` usage)."""
    cmd.rich_markup_mode = None
    if cmd.help and not cmd.short_help:  # a listing wraps its first paragraph, never cuts it
        cmd.short_help = " ".join(cmd.help.split("\n\n")[0].split())
    for param in getattr(cmd, "params", ()):
        if getattr(param, "param_type_name", "") == "argument":
            shown = (param.metavar or param.name).upper() + ("..." if param.nargs != 1 else "")
            piece = shown if param.required or shown.startswith("[") else f"[{shown}]"
            param.get_usage_pieces = lambda ctx, piece=piece: [piece]
    for sub in getattr(cmd, "commands", {}).values():
        _plain_help(sub)
    return cmd


class _LazyGroup(TyperGroup):
    """Lists every subcommand from :data:`SUBCOMMANDS`; imports one only when it is used."""

    _listing = False

    def list_commands(self, ctx):
        return list(self.commands) + [n for n in SUBCOMMANDS if n not in self.commands]

    def get_command(self, ctx, name):
        if name in SUBCOMMANDS and name not in self.commands:
            if self._listing:  # the top-level --help needs only the name and the one-line help
                return TyperCommand(name, help=SUBCOMMANDS[name][2], short_help=SUBCOMMANDS[name][2],
                                    rich_markup_mode=None)
            self.add_command(load_subcommand(name), name)
        return super().get_command(ctx, name)

    def invoke(self, ctx):
        # SIGTERM as Ctrl-C: KeyboardInterrupt, so that every command's clean-up runs; then the
        # workers a pool left stopped and one line, exit 130 (Click would print "Aborted!", 1)
        with signals_interrupt() as sig:
            try:
                rv = super().invoke(ctx)
            except MissingBackend as exc:
                # an optional back-end the machine lacks: its one line, naming the extra to install
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

    def main(self, args=None, prog_name=None, complete_var=None, standalone_mode=True, **extra):
        """Click's ``main`` with every usage error on one line, ``error: <command>: <what>``, exit 2."""
        if not standalone_mode:
            return super().main(args, prog_name, complete_var, standalone_mode, **extra)
        try:
            rv = super().main(args, prog_name, complete_var, False, **extra)
        except _CLICK_EXC.ClickException as exc:
            ctx = getattr(exc, "ctx", None)
            if type(exc).__name__ == "NoArgsIsHelpError":  # its help is already printed
                sys.exit(exc.exit_code)
            where = f"{ctx.command_path}: " if ctx is not None else ""
            hint = f"; see {ctx.command_path} --help" if ctx is not None else ""
            what = one_line(exc.format_message()).rstrip(".").replace(": Value error, ", ": ")  # (typer's pydantic)
            typer.echo(f"error: {where}{what}{hint}", err=True)
            sys.exit(BAD_INPUT)
        except _ABORTS as exc:
            ctrl_c = isinstance(exc.__cause__, KeyboardInterrupt)
            typer.echo("error: interrupted" if ctrl_c else "error: aborted", err=True)
            sys.exit(INTERRUPTED if ctrl_c else 1)
        sys.exit(rv if isinstance(rv, int) else 0)

    def format_help(self, ctx, formatter):
        self._listing = True
        try:
            return super().format_help(ctx, formatter)
        finally:
            self._listing = False


app = typer.Typer(name="simtest", cls=_LazyGroup,
                  help="Testbed for normal reconstruction from specular isophotes in endoscopy.",
                  no_args_is_help=True, add_completion=False, pretty_exceptions_enable=False,
                  rich_markup_mode=None)  # Click's plain help: see _plain_help


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


def quiet_warnings() -> None:
    """Silence Python warnings here and in worker processes, unless asked for with ``-W`` or ``PYTHONWARNINGS``."""
    if not sys.warnoptions and "PYTHONWARNINGS" not in os.environ:
        warnings.simplefilter("ignore")
        os.environ["PYTHONWARNINGS"] = "ignore"  # worker processes (and their fork server) start with it


def main() -> None:
    """Entry point of the ``simtest`` console script.

    Around the command SIGINT and SIGTERM exit at once (130, one line); during it they raise
    KeyboardInterrupt, so its clean-up runs (:meth:`_LazyGroup.invoke`).
    """
    quiet_warnings()
    for s in (signal.SIGINT, signal.SIGTERM):
        signal.signal(s, exit_on_signal)
    try:
        app(prog_name="simtest")  # also under `python -m simtest.cli`
    finally:  # outputs written: the exit's last collections need not walk every object left, to free what it frees
        gc.freeze()


if __name__ == "__main__":
    main()
