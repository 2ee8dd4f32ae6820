"""Atomic file writes (a reader never sees a half-written file) and the one JSON coercion.

Every writer in simtest goes through :func:`atomic_write`: the content is written to a temporary
file in the destination folder (same file system), flushed to disk, then renamed over the
destination with ``os.replace``. If writing fails or the process is killed, the destination keeps
its previous content and the temporary file (``.<name>.<random>.tmp``) is removed when possible.
"""

from __future__ import annotations

import json
import os
import tempfile
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["TMP_SUFFIX", "atomic_write", "atomic_write_bytes", "atomic_write_json", "atomic_write_set",
           "atomic_write_text", "jsonable"]

#: Suffix of every temporary file this module creates.
TMP_SUFFIX = ".tmp"


def jsonable(obj: Any, *, default: Callable[[Any], Any] | None = None) -> Any:
    """A deep copy of ``obj`` made of the types ``json.dumps`` writes, for every room's JSON files.

    Mappings become dicts with ``str`` keys, lists and tuples become lists, numpy arrays nested
    lists (``tolist``), numpy scalars Python scalars (``item``); ``str``, ``int``, ``float``,
    ``bool`` and None are kept as they are (so ``1.0`` stays a float and a case key written from it
    does not change).

    Parameters
    ----------
    obj : object
        Nested mappings, sequences, arrays and scalars.
    default : callable, optional
        Applied to any other value (e.g. ``str`` for the dates TOML reads); without it such a value
        is kept as it is (``json.dumps`` then refuses it).

    Returns
    -------
    object
        The converted copy; ``json.loads(json.dumps(jsonable(obj)))`` equals it for string keys.

    Examples
    --------
    >>> jsonable({"a": (1, np.float64(2.5)), "b": np.arange(2)})
    {'a': [1, 2.5], 'b': [0, 1]}
    """
    if isinstance(obj, Mapping):
        return {str(k): jsonable(v, default=default) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [jsonable(v, default=default) for v in obj]
    if isinstance(obj, np.ndarray):
        return jsonable(obj.tolist(), default=default)
    if isinstance(obj, np.generic):
        return obj.item()
    if default is None or obj is None or isinstance(obj, str | int | float):
        return obj
    return default(obj)


def _default_mode() -> int:
    """Permissions a plain ``open(path, "w")`` would give: 0o666 less the process umask."""
    umask = os.umask(0)
    os.umask(umask)
    return 0o666 & ~umask


def atomic_write(path, write: Callable[[str], None], *, suffix: str = TMP_SUFFIX) -> Path:
    """Call ``write(tmp_path)`` on a temporary file, then rename it to ``path``.

    Parameters
    ----------
    path : str or Path
        Destination; its folder is created if needed.
    write : callable
        Writes the whole content to the path it is given (e.g. ``fig.savefig``, ``np.savez``).
    suffix : str
        Suffix of the temporary file, for writers that infer the format from it (e.g. ``".png"``).

    Returns
    -------
    Path
        The destination.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=suffix, dir=path.parent)
    os.close(fd)
    try:
        write(tmp)
        with open(tmp, "rb+") as fh:
            os.fsync(fh.fileno())
        # mkstemp creates the file 0600; give it the mode an ordinary write would, so datasets
        # and reports are readable by the people they are shared with.
        os.chmod(tmp, _default_mode())
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
    return path


def atomic_write_bytes(path, data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically (see the module docstring)."""
    return atomic_write(path, lambda tmp: Path(tmp).write_bytes(data))


def atomic_write_text(path, text: str) -> Path:
    """Write ``text`` (UTF-8) to ``path`` atomically (see the module docstring)."""
    return atomic_write(path, lambda tmp: Path(tmp).write_text(text, encoding="utf-8"))


def atomic_write_json(path, obj, *, indent: int = 1, **dumps_kwargs) -> Path:
    """Write ``obj`` as JSON, ``json.dumps(obj, indent=indent, **dumps_kwargs)`` and a newline.

    Parameters
    ----------
    path : str or Path
        Destination, written atomically (see the module docstring).
    obj : object
        JSON-serialisable value.
    indent : int
        Indentation of ``json.dumps``.
    **dumps_kwargs
        Further ``json.dumps`` options (``sort_keys``, ``allow_nan``, ...).

    Returns
    -------
    Path
        The destination.

    Raises
    ------
    TypeError, ValueError
        From ``json.dumps`` (not serialisable, or NaN with ``allow_nan=False``); nothing is written.
    """
    return atomic_write_text(path, json.dumps(obj, indent=indent, **dumps_kwargs) + "\n")


def atomic_write_set(writers: dict) -> list[Path]:
    """Replace several files as a set: every new file is written before any old one is replaced.

    Each ``writers[path](tmp_path)`` writes one file's whole content to a temporary file beside its
    destination. Only when all of them succeeded are the temporaries renamed over the destinations
    (``os.replace``, which does not fail for lack of space); if any writer fails, every temporary is
    removed and every destination keeps its previous content, so a reader never finds new files
    beside old ones (e.g. a new ``estimates.json`` beside an old ``overlay.png``).

    Parameters
    ----------
    writers : dict of {str or Path: callable}
        Destination -> function writing the content to the path it is given. The temporary keeps
        the destination's suffix (for writers that infer the format from it).

    Returns
    -------
    list of Path
        The destinations, in the order given.
    """
    done: list[tuple[str, Path]] = []
    try:
        for path, write in writers.items():
            path = Path(path)
            path.parent.mkdir(parents=True, exist_ok=True)
            fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=path.suffix + TMP_SUFFIX, dir=path.parent)
            os.close(fd)
            done.append((tmp, path))
            write(tmp)
            with open(tmp, "rb+") as fh:
                os.fsync(fh.fileno())
            os.chmod(tmp, _default_mode())
    except BaseException:
        for tmp, _ in done:
            if os.path.exists(tmp):
                os.unlink(tmp)
        raise
    for tmp, path in done:
        os.replace(tmp, path)
    return [path for _, path in done]
