"""Scene specifications (TOML -> frozen dataclasses) and procedural meshes.

Nothing here imports Mitsuba: the renderer (:mod:`simtest.render`) translates specs into Mitsuba
scenes.
"""

from __future__ import annotations

from pathlib import Path

from simtest.resources import bundled

from simtest.scene.spec import (
    CameraSpec,
    GeometrySpec,
    LightSpec,
    MaterialSpec,
    RenderSpec,
    SceneError,
    SceneSpec,
    SensorSpec,
    load_scene,
    scene_from_dict,
    scene_to_dict,
    with_overrides,
)

__all__ = [
    "CameraSpec",
    "GeometrySpec",
    "LightSpec",
    "MaterialSpec",
    "RenderSpec",
    "SceneError",
    "SceneSpec",
    "SensorSpec",
    "load_scene",
    "scene_from_dict",
    "scene_to_dict",
    "with_overrides",
    "scenes_dir",
    "bundled_mesh_path",
    "bundled_scene_names",
    "bundled_scene_path",
]


def scenes_dir() -> Path:
    """The folder of bundled scene files, ``scenes/`` (:func:`simtest.resources.bundled`)."""
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
