"""The commands' transient progress bars: on standard error, and none off a terminal."""

from __future__ import annotations

from rich.console import Console
from rich.progress import Progress, ProgressColumn


def transient_progress(*columns: str | ProgressColumn) -> Progress:
    """A :class:`rich.progress.Progress` (``columns``: rich's default ones if none) that clears itself when
    left. It draws on standard error, so standard output holds only results; where standard error is no
    terminal (a pipe, a file, CI) it is disabled and writes nothing, not even a transient bar's blank line."""
    console = Console(stderr=True)
    return Progress(*columns, console=console, transient=True, disable=not console.is_terminal)
