"""The command line's output folders: checked before any work, written as a set, one-line errors.

A command's folder is replaced as a whole (:func:`simtest._io.replace_output_folder`), so it must be new,
empty, or hold only what the command writes. Kept apart from :mod:`simtest._exit` so that ``simtest
--help`` never imports numpy.
"""

from __future__ import annotations

import os
from pathlib import Path

from simtest._exit import BAD_INPUT, CANNOT_WRITE, fail, writable_dir
from simtest._io import OutputFolderError, check_output_folder, replace_output_folder

__all__ = ["check_out_folder", "write_out_folder"]


def check_out_folder(out: Path | str, owned, option: str = "--out") -> Path:
    """Check, before any work, an output folder that a command replaces as a whole.

    Parameters
    ----------
    out : path-like
        The folder as given.
    owned : sequence of str
        The patterns of :func:`simtest._io.check_output_folder`.
    option : str
        The option's name, for messages.

    Returns
    -------
    pathlib.Path
        The folder's real path (the one swapped).

    Raises
    ------
    typer.Exit
        With :data:`CANNOT_WRITE` and one line saying why.
    """
    writable_dir(out, option)
    try:
        check_output_folder(out, owned, option)
    except OutputFolderError as exc:
        fail(exc, CANNOT_WRITE)
    target = Path(os.path.realpath(out))
    if target.exists():  # the swap renames OUT itself: its parent must take new entries too
        writable_dir(target.parent, option)
    return target


def write_out_folder(out: Path | str, target: Path | str, fill, owned=None, option: str = "--out") -> Path:
    """:func:`simtest._io.replace_output_folder` with one-line errors.

    Parameters
    ----------
    out : path-like
        The folder as the user gave it, for messages.
    target : path-like
        The folder :func:`check_out_folder` returned.
    fill : callable
        Writes the whole set into the folder it is given.
    owned : sequence of str, optional
        Checked again under the folder's lock just before the swap.
    option : str
        The option's name, for messages.

    Returns
    -------
    pathlib.Path
        ``target``.

    Raises
    ------
    typer.Exit
        :data:`CANNOT_WRITE` for an OSError (disk full, permissions) or files that appeared in
        the folder meanwhile, :data:`BAD_INPUT` for a bad input found while writing (ValueError,
        a missing optional library); the folder keeps its previous set either way.
    """
    try:
        return replace_output_folder(target, fill, owned=owned)
    except OutputFolderError as exc:
        fail(exc, CANNOT_WRITE)
    except OSError as exc:
        fail(f"{option}: cannot write {out}: {exc.strerror or exc}"
             + (f" ({exc.filename})" if getattr(exc, "filename", None) else ""), CANNOT_WRITE)
    except (ValueError, ImportError) as exc:
        fail(exc, BAD_INPUT)
