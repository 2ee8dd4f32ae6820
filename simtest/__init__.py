"""simtest: a rendering-validated testbed for normal reconstruction from specular isophotes.

The method under test is Makki and Bartoli, "Normal Reconstruction from Specularity in the
Endoscopic Setting": under Phong's specular model with a point light co-located with the camera,
the specular isophotes on a locally planar patch are concentric circles, imaged as nested ellipses,
and one ellipse gives the patch normal.

Conventions (the README's Conventions section): OpenCV camera frame (x right, y down, z forward); normals are unit
vectors in the camera frame facing the camera; pixel centres at integer (u, v) coordinates; lengths
in millimetres; angles in degrees at interfaces and radians inside.
"""

from __future__ import annotations

from simtest._blas import pin_openblas_kernels
from simtest._version import __version__

pin_openblas_kernels()  # before numpy or scipy loads OpenBLAS: the same kernels on every x86-64 CPU

__all__ = ["__version__"]
