"""The `simtest` command line: one command with subcommands.

Each subcommand lives beside the code it drives (``simtest/<package>/cli.py``) and is registered
here. Those modules must stay cheap to import: no Mitsuba or Dask import at module level, so that
``simtest --help`` answers at once.
"""

from __future__ import annotations

import typer

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
    from simtest import __version__

    typer.echo(__version__)


# --- subcommands (one registration line per package) -------------------------------------------
# reconstruct: simtest/reconstruct/cli.py
app.command("reconstruct")(__import__("simtest.reconstruct.cli", fromlist=["x"]).reconstruct_command)
# render, meshes: simtest/render/cli.py, simtest/scene/cli.py
app.add_typer(__import__("simtest.scene.meshes_cli", fromlist=["x"]).meshes_app, name="meshes")
# validate, nightly: simtest/harness/cli.py
app.command("validate")(__import__("simtest.harness.cli", fromlist=["x"]).validate_command)
app.command("nightly")(__import__("simtest.harness.cli", fromlist=["x"]).nightly_command)
# dataset: simtest/dataset/cli.py
# bench: simtest/bench.py
app.command("bench")(__import__("simtest.bench", fromlist=["x"]).bench_command)
from simtest.render.cli import render_command  # noqa: E402

app.command("render")(render_command)

from simtest.dataset.cli import dataset_app  # noqa: E402

app.add_typer(dataset_app, name="dataset")


def main() -> None:
    """Entry point of the ``simtest`` console script."""
    app()


if __name__ == "__main__":
    main()
