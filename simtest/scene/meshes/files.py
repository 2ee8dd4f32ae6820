"""Mesh files: the float32 rounding of a built mesh, its generator record, and the PLY and JSON sidecar files."""

from __future__ import annotations

import dataclasses
import json
import os
import re
from pathlib import Path
from typing import Any

import numpy as np
import trimesh

from simtest._io import atomic_write_bytes, jsonable
from simtest.scene.meshes.curvature import FD_STEP_MM
from simtest.scene.meshes.params import MeshError

_FORMAT_VERSION = 1
_CURVATURE_METHOD = ("closed form; derivatives by 4th-order central finite differences, step "
                     f"{FD_STEP_MM} mm; k positive where the surface bends away from its normal")


def _generator_record(name: str, seed: int, params: Any) -> dict[str, Any]:
    return {"name": name, "function": f"simtest.scene.meshes.build_{name}", "format": _FORMAT_VERSION,
            "seed": seed, "params": dataclasses.asdict(params), "curvature": _CURVATURE_METHOD}


def _assemble(vertices: np.ndarray, faces: np.ndarray, normals: np.ndarray, k1: np.ndarray,
              k2: np.ndarray) -> trimesh.Trimesh:
    """A Trimesh whose per-vertex data are float64 arrays holding float32-representable values.

    The files store float32 (what Mitsuba uses); rounding here makes a saved and reloaded mesh
    equal to the built one, bit for bit (the rounding is below 1e-5 mm and 1e-7 relative).
    """
    def f32(a: np.ndarray) -> np.ndarray:
        return np.ascontiguousarray(np.asarray(a, dtype=np.float64).astype(np.float32), np.float64)

    mesh = trimesh.Trimesh(vertices=f32(vertices), faces=np.ascontiguousarray(faces, dtype=np.int64), process=False,
                           validate=False)
    n = np.asarray(normals, dtype=np.float64)
    mesh.vertex_normals = f32(n / np.linalg.norm(n, axis=1, keepdims=True))
    mesh.vertex_attributes.update(k1=f32(k1), k2=f32(k2))
    return mesh


_PLY_FIELDS = ("x", "y", "z", "nx", "ny", "nz", "k1_0", "k2_0")


def save_mesh(mesh: trimesh.Trimesh, path: str | os.PathLike[str]) -> Path:
    """Write a mesh with normals and curvatures to a binary PLY and its JSON sidecar.

    Parameters
    ----------
    mesh : trimesh.Trimesh
        Must carry ``vertex_attributes["k1"]`` and ``["k2"]``; ``vertex_normals`` are written as
        they are. ``metadata["generator"]`` and ``["centerline"]`` (if present) go to the sidecar.
    path : path-like
        Output ``.ply`` path; the sidecar is the same path with suffix ``.json``.

    Returns
    -------
    Path
        The PLY path; both files are written atomically.

    Raises
    ------
    MeshError
        The mesh lacks k1 or k2, or the path does not end in ``.ply``.
    """
    path = Path(path)
    if path.suffix.lower() != ".ply":
        raise MeshError(f"save_mesh: {path}: expected a .ply path")
    for key in ("k1", "k2"):
        if key not in mesh.vertex_attributes:
            raise MeshError(f"save_mesh: {path}: mesh has no vertex attribute {key!r}")
    cols = (mesh.vertices, mesh.vertex_normals, mesh.vertex_attributes["k1"], mesh.vertex_attributes["k2"])
    data = np.ascontiguousarray(np.column_stack([np.asarray(c, dtype=np.float64) for c in cols]), dtype="<f4")
    faces = np.asarray(mesh.faces)
    face_rec = np.empty(len(faces), dtype=[("n", "u1"), ("idx", "<i4", (3,))])
    face_rec["n"] = 3
    face_rec["idx"] = faces
    header = (
        "ply\nformat binary_little_endian 1.0\n"
        "comment simtest procedural mesh; units mm; k1_0 k2_0: principal curvatures 1/mm, "
        "positive where the surface bends away from its normal\n"
        f"element vertex {len(data)}\n"
        + "".join(f"property float {name}\n" for name in _PLY_FIELDS)
        + f"element face {len(faces)}\nproperty list uchar int vertex_indices\nend_header\n"
    )
    atomic_write_bytes(path, header.encode("ascii") + data.tobytes() + face_rec.tobytes())
    side = {key: mesh.metadata[key] for key in ("generator", "centerline") if key in mesh.metadata}
    side.update(n_vertices=int(len(data)), n_faces=int(len(faces)), ply_vertex_properties=list(_PLY_FIELDS),
                units="positions mm; k1, k2 1/mm (k1 >= k2, positive where bending away from N)")
    text = json.dumps(jsonable(side), indent=1, sort_keys=True)
    # One line per innermost list of numbers (a point, a tangent, a list of arc lengths).
    text = _NUMBER_LIST.sub(lambda m: "[" + ", ".join(x.strip() for x in m[1].split(",")) + "]", text) + "\n"
    atomic_write_bytes(path.with_suffix(".json"), text.encode("utf-8"))
    return path


_NUMBER_LIST = re.compile(r"\[\s*([-+0-9.eE,\s]+?)\s*\]")


def load_mesh(path: str | os.PathLike[str]) -> trimesh.Trimesh:
    """Read a PLY written by :func:`save_mesh` (or any PLY with k1, k2 vertex properties).

    Parameters
    ----------
    path : path-like
        The ``.ply`` file. A sidecar ``.json`` next to it, if present, fills ``metadata``
        (``generator``, ``centerline``).

    Returns
    -------
    trimesh.Trimesh
        Vertices in file order (``process=False``), ``vertex_normals`` from nx ny nz,
        ``vertex_attributes["k1"]``, ``["k2"]`` float64.

    Raises
    ------
    FileNotFoundError
        The file does not exist (the message names the path).
    MeshError
        The file is not a triangle mesh with normals and k1/k2 (``k1_0`` or ``k1``) properties.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"load_mesh: {path}: no such mesh file")
    try:
        loaded = trimesh.load(path, file_type="ply", process=False)
    except Exception as exc:  # trimesh raises assorted types on corrupt files
        raise MeshError(f"load_mesh: {path}: not a readable PLY ({exc})") from exc
    if not isinstance(loaded, trimesh.Trimesh) or len(loaded.faces) == 0:
        raise MeshError(f"load_mesh: {path}: not a triangle mesh")
    raw = loaded.metadata.get("_ply_raw", {}).get("vertex", {}).get("data")
    names = raw.dtype.names if raw is not None and raw.dtype.names else ()
    attrs = {}
    for key in ("k1", "k2"):
        field = next((f for f in (f"{key}_0", key) if f in names), None)
        if field is None:
            raise MeshError(f"load_mesh: {path}: vertex property {key!r} (or {key}_0) missing")
        attrs[key] = np.asarray(raw[field], dtype=np.float64).ravel()
    if not all(f in names for f in ("nx", "ny", "nz")):
        raise MeshError(f"load_mesh: {path}: vertex normals (nx, ny, nz) missing")
    normals = np.stack([np.asarray(raw[f], dtype=np.float64).ravel() for f in ("nx", "ny", "nz")], 1)
    mesh = trimesh.Trimesh(vertices=np.asarray(loaded.vertices, dtype=np.float64),
                           faces=np.asarray(loaded.faces, dtype=np.int64), process=False, validate=False)
    mesh.vertex_normals = normals
    mesh.vertex_attributes.update(attrs)
    side = path.with_suffix(".json")
    if side.is_file():
        try:
            meta = json.loads(side.read_text(encoding="utf-8"))
        except json.JSONDecodeError as exc:
            raise MeshError(f"load_mesh: {side}: invalid JSON ({exc})") from exc
        for key in ("generator", "centerline"):
            if key in meta:
                mesh.metadata[key] = meta[key]
    return mesh
