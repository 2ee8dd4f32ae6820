"""Procedural meshes with ground-truth normals and principal curvatures: colons and a liver.

Seeded generators: :func:`build_colon` (a tube with haustral folds and three taeniae, normals
facing the lumen, open at both ends), :func:`build_haustral_colon` (the colon as CT colonography
measures it, curvatures by automatic differentiation, :mod:`~simtest.scene.meshes.haustral`) and
:func:`build_liver` (a smooth, lobed, watertight surface, normals outward). Every vertex carries
its position (mm), unit normal (``mesh.vertex_normals``) and principal curvatures ``k1 >= k2``
(1/mm, ``mesh.vertex_attributes["k1"]``, ``["k2"]``, float64 rounded to float32 as stored).

Sign convention: the eigenvalues of the Weingarten map ``dN``, so a curvature is positive where the
surface bends away from its normal (a sphere with outward normals: ``k1 = k2 = +1/R``; a cylinder
seen from inside: ``k1 = 0``, ``k2 = -1/R``). For X(u, v) this is ``II_ij = -X_ij . N`` [1]; for
F = 0 with ``N = grad F / |grad F|``, ``P Hess(F) P / |grad F|`` [2]. Derivatives are fourth-order
central finite differences of the closed form in float64 (:mod:`~simtest.scene.meshes.curvature`),
exact to about 1e-8 /mm; the vertices lie exactly on the closed-form surface.

Files (:mod:`~simtest.scene.meshes.files`): a binary PLY with float32 ``x y z nx ny nz k1_0 k2_0``
(Mitsuba exposes ``vertex_k1``, ``vertex_k2``) and a JSON sidecar with the generator, parameters,
seed and the colon's centre line (``mesh.metadata["centerline"]``: per ring ``t``,
``arclength_mm``, ``points``, ``tangents``, ``radius_min_mm``, ``radius_max_mm``; ring i holds
vertices ``i * n_around`` to ``(i + 1) * n_around - 1``). Meshes live in their own world frame, mm.

References
----------
.. [1] M. P. do Carmo, Differential Geometry of Curves and Surfaces, 1976, sec. 3-3 (fundamental
       forms, :func:`parametric_curvature`).
.. [2] R. Goldman, "Curvature formulas for implicit curves and surfaces", CAGD 22, 2005
       (:func:`implicit_curvature`).
"""

from __future__ import annotations

from typing import Any

import trimesh

from simtest.scene.meshes.abdomen import LAPAROSCOPE_ABDOMEN, LAPAROSCOPE_WALL_AXIS, build_liver_in_abdomen
from simtest.scene.meshes.colon import build_colon, colon_centerline
from simtest.scene.meshes.curvature import FD_STEP_MM, implicit_curvature, parametric_curvature
from simtest.scene.meshes.files import load_mesh, save_mesh
from simtest.scene.meshes.haustral import build_haustral_colon, haustral_pose
from simtest.scene.meshes.liver import build_liver
from simtest.scene.meshes.params import DEFAULT_SEED, ColonParams, HaustralParams, LiverParams, MeshError

__all__ = ["DEFAULT_SEED", "FD_STEP_MM", "ColonParams", "HaustralParams", "LiverParams", "MeshError", "build_colon",
           "build_haustral_colon", "build_liver", "build_mesh", "colon_centerline", "haustral_pose",
           "implicit_curvature", "load_mesh", "parametric_curvature", "save_mesh"]


def build_mesh(name: str, seed: int, **params: Any) -> trimesh.Trimesh:
    """Build ``"colon"``, ``"colon_haustral"``, ``"liver"`` or ``"liver_abdomen"`` (dispatch to
    :func:`build_colon`, :func:`build_haustral_colon`, :func:`build_liver`,
    :func:`~simtest.scene.meshes.abdomen.build_liver_in_abdomen`).

    Parameters
    ----------
    name : {"colon", "colon_haustral", "liver", "liver_abdomen"}
        The generator. ``"liver_abdomen"`` is the liver with the wall behind it of
        meshes/liver_abdomen.ply (the laparoscope scene's): its wall's axis and its organs
        default to :data:`~simtest.scene.meshes.abdomen.LAPAROSCOPE_WALL_AXIS` and
        :data:`~simtest.scene.meshes.abdomen.LAPAROSCOPE_ABDOMEN`.
    seed : int
        Root seed (>= 0; 0 is valid).
    **params
        Fields of :class:`ColonParams`, :class:`HaustralParams` or :class:`LiverParams` (lengths
        in mm); for
        ``"liver_abdomen"`` also the wall's keywords of ``build_liver_in_abdomen``.

    Returns
    -------
    trimesh.Trimesh
        As returned by the generator: vertices in mm, unit ``vertex_normals``,
        ``vertex_attributes["k1"]``, ``["k2"]`` in 1/mm (k1 >= k2, module sign convention).

    Raises
    ------
    MeshError
        Unknown name, unknown or out-of-range parameter, or a bad seed.
    """
    def liver_abdomen(seed: int, **p: Any) -> trimesh.Trimesh:
        return build_liver_in_abdomen(seed, **{"wall_axis": LAPAROSCOPE_WALL_AXIS, **LAPAROSCOPE_ABDOMEN, **p})

    builders = {"colon": build_colon, "colon_haustral": build_haustral_colon, "liver": build_liver,
                "liver_abdomen": liver_abdomen}
    if name not in builders:
        raise MeshError(f"build_mesh: name: unknown mesh {name!r}; known: {sorted(builders)}")
    return builders[name](seed, **params)
