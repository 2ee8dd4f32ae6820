"""Where the bundled data are: scenes, suites, dataset configs, meshes and the nightly baseline.

In a clone they live at the repository's top (``scenes/``, ``meshes/``, ``reports/``); a wheel ships them
as ``simtest/_data/...``. :func:`data_root` finds whichever holds them.

Examples
--------
>>> (data_root() / "scenes" / "sphere.toml").is_file()
True
"""

from __future__ import annotations

from importlib.resources import files
from pathlib import Path

__all__ = ["bundled", "bundled_mesh_path", "bundled_scene_names", "bundled_scene_path", "data_root",
           "real_banner_path", "real_dir", "scenes_dir"]

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


def scenes_dir() -> Path:
    """The folder of bundled scene files, ``scenes/``."""
    return bundled("scenes")


def bundled_mesh_path(name: str) -> Path:
    """Path of the bundled mesh ``name`` (``"colon"`` or ``"liver"``): ``meshes/<name>.ply``.

    Parameters
    ----------
    name : str
        Mesh name (file stem).

    Returns
    -------
    Path
        The path (:func:`simtest.resources.bundled`); the file may be missing (``simtest meshes
        build`` writes it).
    """
    return bundled("meshes", f"{name}.ply")


def bundled_scene_names() -> list[str]:
    """Names of the bundled scenes (file stems in :func:`scenes_dir`), sorted."""
    return sorted(p.stem for p in scenes_dir().glob("*.toml"))


def bundled_scene_path(name: str) -> Path:
    """Path of the bundled scene ``name`` (e.g. ``"plane_58deg"``).

    Raises
    ------
    KeyError
        If no bundled scene has that name; the message lists the known names.
    """
    stem = name[:-5] if name.endswith(".toml") else name
    path = scenes_dir() / f"{stem}.toml"
    if not path.is_file():
        raise KeyError(f"unknown bundled scene {name!r}; known: {', '.join(bundled_scene_names())}")
    return path


def real_dir() -> Path:
    """The folder of the bundled real frames: Hyper-Kvasir frames (CC BY 4.0, Borgli et al. 2020,
    doi:10.1038/s41597-020-00622-y), their hand labels and an assumed camera file.

    A clone keeps them in ``tests/data/real`` (attribution in its ``README.md``); a wheel ships the
    same files as ``simtest/_data/real``.

    Returns
    -------
    Path
        ``<data_root>/real`` from an installed wheel, ``<clone>/tests/data/real`` from a clone.
    """
    shipped = data_root() / "real"
    if shipped.is_dir():
        return shipped
    return data_root() / "tests" / "data" / "real"


def real_banner_path() -> Path:
    """Path of the real-frame banner: 24 Hyper-Kvasir frames side by side.

    ``hyperkvasir_banner.jpg`` in :func:`real_dir` (2240 x 840 JPEG, CC BY 4.0, Borgli et al. 2020,
    doi:10.1038/s41597-020-00622-y), the default real frames of ``simtest simreal`` and the frame
    of the real-image benchmark; a clone and a wheel both carry it.

    Returns
    -------
    Path
        The path under :func:`real_dir`.
    """
    return real_dir() / "hyperkvasir_banner.jpg"
