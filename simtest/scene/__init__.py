"""Scene specifications (TOML -> frozen dataclasses) and procedural meshes.

Nothing here imports Mitsuba: the renderer (:mod:`simtest.render`) translates specs into Mitsuba
scenes.
"""

from __future__ import annotations

from simtest.resources import bundled_mesh_path, bundled_scene_names, bundled_scene_path, scenes_dir
from simtest.scene.spec import (CameraSpec, CylinderGeometry, GeometrySpec, LightSpec, MaterialSpec, MeshGeometry,
                                PlaneGeometry, RenderSpec, SaddleGeometry, SceneError, SceneSpec, SensorSpec,
                                SphereGeometry, load_scene, scene_from_dict, scene_to_dict, with_overrides)

__all__ = ["CameraSpec", "GeometrySpec", "PlaneGeometry", "SphereGeometry", "CylinderGeometry", "SaddleGeometry",
           "MeshGeometry", "LightSpec", "MaterialSpec", "RenderSpec", "SceneError", "SceneSpec", "SensorSpec",
           "load_scene", "scene_from_dict", "scene_to_dict", "with_overrides", "scenes_dir", "bundled_mesh_path",
           "bundled_scene_names", "bundled_scene_path"]
