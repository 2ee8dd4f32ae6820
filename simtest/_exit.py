"""The command line's exit codes, its one-line error, and the checks every output folder passes.

Every subcommand of ``simtest`` ends with one of these codes; a failure prints one line,
``error: <what is wrong and where>``, on standard error and no traceback. The README's table
"Exit codes" is this table.

=====  ==================  ===============================================================
code   name                meaning
=====  ==================  ===============================================================
0      OK                  done
1      CHECK_FAILED        a check found a fault: ``nightly`` saw a regression, ``dataset
                           verify`` found damage
2      BAD_INPUT           bad usage or bad input: a flag, a file, a key, a value, a pixel
3      BAD_BASELINE        ``nightly``: the baseline is missing, malformed, or does not cover
                           the run's gated metrics (a gate that cannot judge is no pass)
4      CANNOT_WRITE        the output cannot be written (not a folder, read-only, disk full);
                           what was written before is left intact
130    INTERRUPTED         stopped by Ctrl-C or SIGTERM; workers stopped, earlier outputs intact
=====  ==================  ===============================================================
"""

from __future__ import annotations

import contextlib
import errno
import os
import re
import signal
import sys
import tempfile
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import NoReturn

import typer

__all__ = ["OK", "CHECK_FAILED", "BAD_INPUT", "BAD_BASELINE", "CANNOT_WRITE", "INTERRUPTED", "fail", "one_line",
           "writable_dir", "safe_name", "SignalInterrupt", "SignalState", "exit_on_signal", "signals_interrupt"]

OK = 0
CHECK_FAILED = 1
BAD_INPUT = 2
BAD_BASELINE = 3
CANNOT_WRITE = 4
INTERRUPTED = 130


def one_line(message: object) -> str:
    """``message`` folded onto one line (runs of whitespace, newlines included, become one space)."""
    return " ".join(str(message).split())


def fail(message: object, code: int = BAD_INPUT) -> NoReturn:
    """Print ``error: <message>`` on one line to standard error and exit with ``code``.

    Parameters
    ----------
    message : object
        What is wrong and where (file, key, pixel, value); folded onto one line.
    code : int
        One of the exit codes of this module.

    Raises
    ------
    typer.Exit
        Always, with ``code``.
    """
    typer.echo(f"error: {one_line(message)}", err=True)
    raise typer.Exit(code)


def writable_dir(path: Path | str, option: str = "--out") -> Path:
    """Check, before any work, that ``path`` is or can become a writable folder.

    The folder is not created: the nearest existing ancestor is checked for being a folder and
    for accepting a new entry (a temporary file is made and removed there), so that a long run
    never ends in an output it cannot write.

    Parameters
    ----------
    path : path-like
        The output folder a command will write (created later, as a set, by the command).
    option : str
        The option that named it, for the message.

    Returns
    -------
    pathlib.Path
        ``path`` as a Path.

    Raises
    ------
    typer.Exit
        With :data:`CANNOT_WRITE` and one line naming the path and why, when ``path`` (or an
        ancestor) is a file, or the folder is not writable.
    """
    p = Path(path)
    probe = p
    while not probe.exists() and probe.parent != probe:
        probe = probe.parent
    if probe.exists() and not probe.is_dir():
        where = f"{p}" if probe == p else f"{p}: {probe}"
        fail(f"{option}: {where} is a file, not a folder", CANNOT_WRITE)
    try:
        fd, name = tempfile.mkstemp(prefix=".simtest-probe-", dir=probe)
        os.close(fd)
        os.unlink(name)
    except OSError as exc:
        why = {errno.EACCES: "permission denied", errno.EROFS: "read-only file system",
               errno.ENOSPC: "no space left on device", errno.EPERM: "permission denied"}.get(
                   exc.errno, exc.strerror or str(exc))
        fail(f"{option}: {p}: cannot write in {probe}: {why}", CANNOT_WRITE)
    return p


_SAFE = re.compile(r"[A-Za-z0-9][A-Za-z0-9._+-]{0,127}")


def safe_name(name: str, option: str) -> str:
    """``name`` if it is one plain folder name (no separator, no ``..``), else exit 2.

    Parameters
    ----------
    name : str
        A run id or other name that becomes one folder under an output root.
    option : str
        The option that gave it, for the message.

    Returns
    -------
    str
        ``name`` unchanged.

    Raises
    ------
    typer.Exit
        With :data:`BAD_INPUT` and one line when ``name`` could leave its root (``..``, ``/``),
        starts with a dot or a dash, or has other characters than letters, digits and ``._+-``.
    """
    if not _SAFE.fullmatch(name) or name in {".", ".."} or ".." in name:
        fail(f"{option}: {name!r} is not a plain folder name (letters, digits and . _ + -, "
             "not starting with . or -, at most 128 characters)", BAD_INPUT)
    return name


class SignalInterrupt(KeyboardInterrupt):
    """Raised in the main thread by the first SIGINT or SIGTERM while a command runs.

    A KeyboardInterrupt, so every ``finally`` and ``except BaseException`` runs for SIGTERM as for Ctrl-C.
    """

    def __init__(self, signum: int) -> None:
        self.signum = signum
        self.signame = signal.Signals(signum).name
        super().__init__(self.signame)


class SignalState:
    """What :func:`signals_interrupt` saw: the first signal's name, or None."""

    signame: str | None = None


@contextlib.contextmanager
def signals_interrupt() -> Iterator[SignalState]:
    """Within the block, SIGINT and SIGTERM raise :class:`SignalInterrupt` in the main thread.

    Only the first signal raises; later ones are ignored, so that the clean-up the first one
    started (stopping workers, removing a temporary folder) is not cut short. The signal is also
    recorded in the state yielded, for the caller to see it where a library swallowed the
    exception or turned it into another one (an import inside Mitsuba turns it into a
    SystemError). On leaving, the previous handlers return. Outside the main thread (where Python
    cannot handle signals) the block runs unchanged.

    Yields
    ------
    SignalState
        Its ``signame`` is set (``"SIGTERM"``, ``"SIGINT"``) once a signal came.
    """
    state = SignalState()
    if threading.current_thread() is not threading.main_thread():
        yield state
        return

    owner = os.getpid()

    def handler(signum, frame):
        if os.getpid() != owner:  # a forked worker before its own set-up (_workers): end quietly
            os._exit(128 + signum)
        if state.signame is not None:
            return
        state.signame = signal.Signals(signum).name
        raise SignalInterrupt(signum)

    previous = {}
    with contextlib.suppress(ValueError, OSError):  # not the main interpreter
        for s in (signal.SIGINT, signal.SIGTERM):
            previous[s] = signal.signal(s, handler)
    try:
        yield state
    finally:
        for s, h in previous.items():
            signal.signal(s, h if h is not None else signal.SIG_DFL)


def exit_on_signal(signum, frame) -> NoReturn:
    """Signal handler around a command (start-up, shut-down): one line on standard error, exit :data:`INTERRUPTED`."""
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(Exception):
            stream.flush()
    with contextlib.suppress(OSError):
        os.write(2, f"error: interrupted by {signal.Signals(signum).name}\n".encode())
    os._exit(INTERRUPTED)
