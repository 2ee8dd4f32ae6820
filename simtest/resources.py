"""Where the bundled data are: scenes, suites, dataset configs, meshes and the nightly baseline.

The one lookup of bundled files, for a clone and for an installed wheel alike. In the repository
they live at the top (``scenes/``, ``scenes/suites/``, ``scenes/datasets/``, ``meshes/``,
``reports/baseline.json``); a wheel ships the same folders inside the package, as
``simtest/_data/{scenes,meshes,reports}`` (``pyproject.toml`` maps them there). :func:`data_root`
finds whichever holds them, starting from ``importlib.resources.files("simtest")``.

Examples
--------
>>> (data_root() / "scenes" / "sphere.toml").is_file()
True
"""

from __future__ import annotations

from importlib.resources import files
from pathlib import Path

__all__ = ["bundled", "data_root"]

#: The folders :func:`data_root` holds, as the repository lays them out.
FOLDERS = ("scenes", "meshes", "reports")


def data_root() -> Path:
    """The folder holding the bundled ``scenes/``, ``meshes/`` and ``reports/`` folders.

    Returns
    -------
    Path
        ``<site-packages>/simtest/_data`` from an installed wheel; the repository root when simtest
        runs from a clone (an editable install, or ``python -m`` from the clone's root).
    """
    package = Path(str(files("simtest")))
    shipped = package / "_data"
    if (shipped / "scenes").is_dir():
        return shipped
    return package.parent


def bundled(*parts: str) -> Path:
    """Path of a bundled file or folder, e.g. ``bundled("scenes", "suites")``.

    Parameters
    ----------
    *parts : str
        Path components under :func:`data_root`; the first is one of :data:`FOLDERS`.

    Returns
    -------
    Path
        The path (the file may be missing, e.g. a mesh not built yet).

    Raises
    ------
    ValueError
        If the first component is not one of :data:`FOLDERS`.
    """
    if not parts or parts[0] not in FOLDERS:
        raise ValueError(f"bundled: the first part must be one of {FOLDERS}, got {parts[:1]}")
    return data_root().joinpath(*parts)
