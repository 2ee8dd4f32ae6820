"""simtest: a rendering-validated testbed for normal reconstruction from specular isophotes.

The method under test is Makki and Bartoli, "Normal Reconstruction from Specularity in the
Endoscopic Setting": under Phong's specular model with a point light co-located with the camera,
the specular isophotes on a locally planar patch are concentric circles, imaged as nested ellipses,
and one ellipse gives the patch normal.

Conventions (see DESIGN.md): OpenCV camera frame (x right, y down, z forward); normals are unit
vectors in the camera frame facing the camera; pixel centres at integer (u, v) coordinates; lengths
in millimetres; angles in degrees at interfaces and radians inside.
"""

from __future__ import annotations

__version__ = "0.1.0"

__all__ = ["__version__", "reconstruct"]


def __getattr__(name: str):
    # Lazy so that `import simtest` stays cheap (the CLI imports it on every call).
    if name == "reconstruct":
        from simtest.reconstruct.pipeline import reconstruct

        return reconstruct
    raise AttributeError(f"module 'simtest' has no attribute {name!r}")
