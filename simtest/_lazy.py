"""The one lazy-import helper, for the optional heavy back-ends.

simtest imports its dependencies at module top, except back-ends that are heavy to import or not
installed everywhere (:data:`BACKENDS`): code that needs one calls :func:`require` where it is used, and a
missing back-end gives one line naming what to install instead of an ``ImportError`` at ``import simtest``.

Examples
--------
>>> require("no_such_backend")
Traceback (most recent call last):
...
ValueError: simtest._lazy.require: 'no_such_backend' is not one of the optional back-ends (dask, distributed, drjit, matplotlib, mitsuba, pyarrow, pyvista, scipy, tifffile, torch, vtkmodules)
"""

from __future__ import annotations

import importlib
from types import ModuleType

__all__ = ["BACKENDS", "MissingBackend", "install_hint", "require"]

#: Top-level package of each optional back-end -> the extra of simtest that installs it, or None for one
#: that plain ``pip install simtest`` brings (lazy because it is slow to import and often not needed)
BACKENDS: dict[str, str | None] = {"mitsuba": None, "drjit": None, "dask": "dask", "distributed": "dask",
                                   "pyvista": "view", "vtkmodules": "view", "torch": "torch", "pyarrow": None,
                                   "scipy": None, "matplotlib": None, "tifffile": None}


def install_hint(package: str) -> str:
    """The command that installs the back-end ``package`` (a key of :data:`BACKENDS`)."""
    extra = BACKENDS[package]
    if extra is None:
        return f"pip install simtest  ({package} is a dependency of simtest: reinstall it)"
    return f'pip install "simtest[{extra}]"'


class MissingBackend(ImportError):
    """An optional back-end is not installed; the message is one line naming what to install."""


def require(module: str, *, purpose: str | None = None) -> ModuleType:
    """Import an optional heavy back-end (or one of its submodules) when it is first needed.

    Parameters
    ----------
    module : str
        Dotted module name whose top-level package is in :data:`BACKENDS`, e.g. ``"mitsuba"``,
        ``"distributed"`` or ``"torch.utils.data"``.
    purpose : str, optional
        What needs it, for the error message (e.g. ``"--scheduler"``).

    Returns
    -------
    module
        The imported module (``sys.modules`` caches it: a second call costs a dict lookup).

    Raises
    ------
    MissingBackend
        If the back-end is not installed: ``"<purpose> needs <package>, which is not installed:
        <install command>"``.
    ValueError
        If ``module`` is not one of the optional back-ends (every other import belongs at module
        top).
    """
    top = module.split(".", 1)[0]
    if top not in BACKENDS:
        raise ValueError(f"simtest._lazy.require: {top!r} is not one of the optional back-ends "
                         f"({', '.join(sorted(BACKENDS))})")
    try:
        return importlib.import_module(module)
    except ModuleNotFoundError as exc:
        if exc.name is None or exc.name.split(".", 1)[0] != top:
            raise  # the back-end is there but one of *its* dependencies is missing: show that
        who = purpose or "this"
        raise MissingBackend(f"{who} needs {top}, which is not installed: {install_hint(top)}") from None
