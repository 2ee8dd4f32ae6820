"""Atomic file writes (a reader never sees a half-written file), atomic folder sets, and the one JSON coercion.

A file is written to a temporary ``.<name>.<random>.tmp`` in its folder, fsynced, then renamed over the
destination; on failure the destination keeps its previous content.
"""

from __future__ import annotations

import ctypes
import errno
import fcntl
import fnmatch
import json
import os
import shutil
import tempfile
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["TMP_SUFFIX", "OutputFolderError", "atomic_write", "atomic_write_bytes", "atomic_write_json",
           "atomic_write_text", "check_output_folder", "jsonable", "recover_output_folder", "replace_output_folder"]

#: Suffix of every temporary file this module creates.
TMP_SUFFIX = ".tmp"


def jsonable(obj: Any, *, default: Callable[[Any], Any] | None = None) -> Any:
    """A deep copy of ``obj`` made of the types ``json.dumps`` writes.

    Mappings become dicts with ``str`` keys, lists and tuples lists, numpy arrays nested lists, numpy scalars
    Python scalars; ``str``, ``int``, ``float``, ``bool`` and None are kept (``1.0`` stays a float).

    Parameters
    ----------
    obj : object
        Nested mappings, sequences, arrays and scalars.
    default : callable, optional
        Applied to any other value (e.g. ``str`` for TOML dates); without it such a value is kept.

    Returns
    -------
    object

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
    return obj if default is None or obj is None or isinstance(obj, str | int | float) else default(obj)


def _default_mode(bits: int = 0o666) -> int:
    """Permissions a plain ``open(path, "w")`` would give (``os.mkdir`` with 0o777): ``bits`` less the umask."""
    umask = os.umask(0)
    os.umask(umask)
    return bits & ~umask


def atomic_write(path, write: Callable[[str], None], *, suffix: str = TMP_SUFFIX) -> Path:
    """Call ``write(tmp_path)`` on a temporary file, then rename it to ``path`` (its folder created if needed).

    Parameters
    ----------
    path : str or Path
    write : callable
        Writes the whole content to the path it is given (e.g. ``fig.savefig``).
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
        # mkstemp creates the file 0600: give it the mode an ordinary write would
        os.chmod(tmp, _default_mode())
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
    return path


def atomic_write_bytes(path, data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically."""
    return atomic_write(path, lambda tmp: Path(tmp).write_bytes(data))


def atomic_write_text(path, text: str) -> Path:
    """Write ``text`` (UTF-8) to ``path`` atomically."""
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


class OutputFolderError(ValueError):
    """An output folder that cannot take a command's set of files (a file, foreign files)."""


def _owned(rel: tuple[str, ...], is_dir: bool, owned) -> bool:
    """Whether the entry at relative path ``rel`` matches a pattern of ``owned`` (a folder: one a pattern crosses)."""
    for pat in owned:
        parts = tuple(pat.split("/"))
        n = len(rel)
        if len(parts) < n or (len(parts) == n and is_dir) or (len(parts) > n and not is_dir):
            continue
        if all(fnmatch.fnmatchcase(a, b) for a, b in zip(rel, parts)):
            return True
    return False


def check_output_folder(out, owned, option: str = "--out") -> Path:
    """Refuse an output folder that replacing it as a set would damage.

    The folder must be new, empty, or hold only what the command writes (the patterns ``owned``, not a
    marker file: a user may since have saved a file of their own there).

    Parameters
    ----------
    out : str or Path
        The folder a command replaces as a whole.
    owned : sequence of str
        ``fnmatch`` patterns of the files the command writes, relative to ``out`` with ``/`` between folders
        (``"figures/*.png"`` owns the folder ``figures`` and its PNGs).
    option : str
        The option that named ``out``, for the messages.

    Returns
    -------
    Path
        ``out``.

    Raises
    ------
    OutputFolderError
        If ``out`` is a file, is the current folder or an ancestor of it, or holds an entry no pattern
        matches (the message names up to three).

    Examples
    --------
    >>> import tempfile
    >>> d = Path(tempfile.mkdtemp())
    >>> _ = (d / "crb.json").write_text("{}")
    >>> check_output_folder(d, ["crb.json", "crb.png"]) == d
    True
    >>> _ = (d / "thesis.tex").write_text("")
    >>> check_output_folder(d, ["crb.json", "crb.png"])  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    simtest._io.OutputFolderError: --out: ... holds files this command does not write (thesis.tex); ...
    """
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise OutputFolderError(f"{option}: {out} is a file, not a folder")
    if not out.exists():
        return out
    here = Path.cwd().resolve()
    full = out.resolve()
    if full == here or full in here.parents:
        raise OutputFolderError(f"{option}: {out} is the current folder or holds it; the outputs are "
                                "replaced as one folder: give a new or empty folder")
    other: list[str] = []
    for root, dirs, files in os.walk(full):
        base = Path(root).relative_to(full).parts
        for name in sorted(dirs):
            if os.path.islink(os.path.join(root, name)) or not _owned((*base, name), True, owned):
                other.append("/".join((*base, name)))
                dirs.remove(name)  # not looked into: it is not ours as a whole
        other += ["/".join((*base, name)) for name in sorted(files) if not _owned((*base, name), False, owned)]
    if other:
        raise OutputFolderError(
            f"{option}: {out} holds files this command does not write ({', '.join(other[:3])}"
            f"{', ...' if len(other) > 3 else ''}); its outputs replace the folder as a whole: "
            "give a new or empty folder")
    return out


#: The prefix of a previous set renamed aside by the fallback swap (``.<name>.old-*``).
_OLD = ".old-"
_libc = None


def _exchange(a: Path, b: Path) -> bool:
    """Swap two paths atomically (Linux ``renameat2(RENAME_EXCHANGE)``); False, nothing changed, where unsupported."""
    global _libc
    if _libc is None:
        try:
            _libc = ctypes.CDLL(None, use_errno=True)
        except OSError:
            _libc = False
    fn = getattr(_libc, "renameat2", None) if _libc else None
    if fn is None:
        return False
    at_fdcwd, rename_exchange = -100, 2
    if fn(ctypes.c_int(at_fdcwd), os.fsencode(a), ctypes.c_int(at_fdcwd), os.fsencode(b),
          ctypes.c_uint(rename_exchange)) == 0:
        return True
    err = ctypes.get_errno()
    if err in (errno.ENOSYS, errno.EINVAL, errno.ENOTSUP, errno.EOPNOTSUPP):
        return False
    raise OSError(err, os.strerror(err), str(b))


def _fsync_dir(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def recover_output_folder(out) -> bool:
    """Put back the previous set if a kill left ``out`` missing between the two renames of the
    fallback swap (the previous set then sits beside it as ``.<name>.old-*``), and remove what
    killed runs left beside ``out`` (their temporary folders). Call it holding the parent's lock.

    Returns
    -------
    bool
        True if a previous set was put back.
    """
    out = Path(out)
    if not out.parent.is_dir():
        return False
    for stale in out.parent.glob(f".{out.name}.*.tmp"):  # a killed fill's folder (caller holds the lock)
        if stale.is_dir():
            shutil.rmtree(stale, ignore_errors=True)
    if out.exists():
        for old in out.parent.glob(f".{out.name}{_OLD}*"):  # a killed cleanup's previous set
            shutil.rmtree(old, ignore_errors=True)
        return False
    olds = sorted(out.parent.glob(f".{out.name}{_OLD}*"), key=lambda p: p.stat().st_mtime)
    if not olds:
        return False
    os.rename(olds[-1], out)
    return True


def _swap_by_two_renames(tmp: Path, out: Path) -> None:
    """The fallback swap: ``out`` aside to ``.<name>.old-*``, then ``tmp`` in."""
    old = Path(tempfile.mkdtemp(prefix=f".{out.name}{_OLD}", dir=out.parent))
    os.rmdir(old)
    try:
        os.rename(out, old)
        os.rename(tmp, out)
    except BaseException:  # the caller removes tmp
        if old.exists() and not out.exists():
            os.rename(old, out)
        raise
    shutil.rmtree(old, ignore_errors=True)


def replace_output_folder(out, fill: Callable[[Path], None], owned=None) -> Path:
    """Write a folder as a set: ``fill(tmp)`` fills a fresh folder beside ``out``, which then replaces ``out``.

    Whatever stops the process, ``out`` holds its whole previous set or the whole new one: the swap is
    ``renameat2(RENAME_EXCHANGE)``, or two renames that :func:`recover_output_folder` completes after a kill.
    Writers of one folder are serialised by ``flock`` on its parent; with ``owned`` the
    :func:`check_output_folder` check is repeated under the lock just before the swap.

    Parameters
    ----------
    out : str or Path
        The output folder (created; its parent too).
    fill : callable
        Writes the whole set into the folder it is given.
    owned : sequence of str, optional
        The patterns of :func:`check_output_folder`.

    Returns
    -------
    Path
        ``out``.

    Raises
    ------
    OSError
        From writing or renaming; ``out`` keeps its previous set.
    OutputFolderError
        With ``owned``: ``out`` holds what the command does not write; nothing was replaced.
    """
    out = Path(out)
    parent = out.parent
    parent.mkdir(parents=True, exist_ok=True)
    lock = os.open(parent, os.O_RDONLY)
    try:
        fcntl.flock(lock, fcntl.LOCK_EX)
        recover_output_folder(out)
        tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.", suffix=".tmp", dir=parent))
        try:
            fill(tmp)
            os.chmod(tmp, _default_mode(0o777))
            for f in tmp.iterdir():
                if f.is_file():
                    with open(f, "rb+") as fh:
                        os.fsync(fh.fileno())
            _fsync_dir(tmp)
            if owned is not None:
                check_output_folder(out, owned)
            if not out.exists():
                os.rename(tmp, out)
            elif not _exchange(tmp, out):
                _swap_by_two_renames(tmp, out)
        finally:  # a failure's half-filled folder, or the previous set the exchange put in tmp
            shutil.rmtree(tmp, ignore_errors=True)
        _fsync_dir(parent)
    finally:
        os.close(lock)
    return out
