"""The `simtest` command line: one command with subcommands.

Each subcommand lives beside the code it drives (``simtest/<package>/cli.py``) and is registered
here. Those modules must stay cheap to import: no Mitsuba or Dask import at module level, so that
``simtest --help`` answers at once.
"""

from __future__ import annotations

import typer

from simtest._version import __version__

app = typer.Typer(
    name="simtest",
    help="Testbed for normal reconstruction from specular isophotes in endoscopy.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)


@app.command("version")
def version_command() -> None:
    """Print the simtest version."""
    typer.echo(__version__)


# --- subcommands: each lives beside the code it drives --------------------------------------------
from simtest.bench import bench_command  # noqa: E402
from simtest.dataset.cli import dataset_app  # noqa: E402
from simtest.evaluate.cli import evaluate_app  # noqa: E402
from simtest.harness.cli import nightly_command, validate_command  # noqa: E402
from simtest.reconstruct.cli import reconstruct_command, view_command  # noqa: E402
from simtest.render.cli import render_command  # noqa: E402
from simtest.scene.meshes_cli import meshes_app  # noqa: E402

app.command("validate")(validate_command)
app.command("nightly")(nightly_command)
app.command("reconstruct")(reconstruct_command)
app.command("view")(view_command)
app.command("render")(render_command)
app.add_typer(meshes_app, name="meshes")
app.add_typer(dataset_app, name="dataset")
app.add_typer(evaluate_app, name="evaluate")
app.command("bench")(bench_command)


def main() -> None:
    """Entry point of the ``simtest`` console script."""
    app()


if __name__ == "__main__":
    main()
