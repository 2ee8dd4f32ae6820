"""Light-aware estimators: normal and depth of a highlight lit by a known rig off the camera centre.

With the light guides a few mm beside the lens (offset epsilon over distance d of 0.05 to 0.5) the
BP ray is off the normal (the normal *bisects* the directions to camera and light), and a calibrated
offset makes the distance observable (the image depends on L/d). The estimators:

- :func:`bisector`: the BP ray corrected by the rig for a *given* depth.
- :func:`isocurve_fit`: the general specular isocurve (paper eq. 2) fitted to the isophote points:
  plane normal, distance h and the cosine level tau of each isovalue.
- :func:`photometric_fit`: the ROI's intensities fitted with the image of a plane lit by the whole
  rig (Phong or GGX-film lobes, falloff, emission profile) plus a linear background.
- :func:`quadric_fit`: the photometric fit with a curved (quadric) patch.
- :func:`cubic_patch_fit`: the quadric patch with its third-order terms, fitted to the lobes of a rig
  of several lights, whose separation fixes the depth (:func:`patch_depth_profile`).

Each returns a :class:`LightAwareEstimate` (normal, depth of the specular point along its ray or None,
1-sigma uncertainties, status from :data:`STATUSES`).

Model (paper eqs. 1 and 2)
--------------------------
Camera frame (OpenCV), camera centre V = 0, mm. Plane ``n . X = -h`` (n unit, facing the camera,
h > 0). The pixel ray d (unit) meets the plane at ``X = d h / (-n . d)``. With ``l`` the unit
direction from X to a light L and ``v = -d``, ``cos beta = r . v = 2 (n . l)(n . v) - l . v``;
its level sets on the plane are the specular isocurve (``cos beta = +tau`` the isophote). The
photometric model is ``I = g sum_j w_j max(0, cos beta_j)^n f_j p_j + b0 + b1 du + b2 dv`` with
``f_j = (h / |L_j - X|)^2`` for an inverse-square light (1 otherwise) and ``p_j`` the emission
profile ``cos^m`` about +z; gain and background are solved linearly (variable projection).

Specular point of a light L: ``X_s = L' h / (-n . L')`` with the mirror image
``L' = L - 2 (n . L + h) n``; ``depth_mm = |X_s|`` (for a rig, of the intensity-weighted mean light).

Parametrisation, start and uncertainty
--------------------------------------
``n = unit(n0 + a e1 + b e2)`` about the start normal n0 ((e1, e2) its tangent basis), distance as
log h. The start is the bisector at the BP at ``nominal_depth_mm``, h then chosen so that the
specular point projects to the BP. Covariance ``s^2 (J^T J)^-1`` at the solution
(``s^2 = sum r^2 / (m - p)``); ``normal_sigma_deg = sqrt(var a + var b)`` in degrees, the depth's
sigma by the delta method. With the residual variance floored at the localisation noise
(``TOL.isophote_noise_px``, ``TOL.photometric_noise_rel``), a relative depth sigma above
``TOL.depth_rel_sigma_max`` (or a singular J^T J) gives status ``depth_not_observable``: no depth,
the normal still given.

The recommendation among the estimators is :mod:`simtest.reconstruct.recommend`.

References
----------
.. [1] K. Makki, A. Bartoli, "Normal Reconstruction from Specularity in the Endoscopic Setting",
       eqs. (1) and (2).
.. [2] B. T. Phong, "Illumination for computer generated pictures", CACM 18(6), 1975.
       https://doi.org/10.1145/360825.360839
.. [3] G. H. Golub, V. Pereyra, SIAM J. Numer. Anal. 10(2), 1973. https://doi.org/10.1137/0710036
       (variable projection).
"""

from __future__ import annotations

from simtest.reconstruct.lightaware.bisector import bisector, reflection_offset_deg
from simtest.reconstruct.lightaware.bound import CramerRaoBound, photometric_crb
from simtest.reconstruct.lightaware.estimate import OK, STATUSES, LightAwareEstimate
from simtest.reconstruct.lightaware.isocurve import isocurve_fit, refine_isophote_points
from simtest.reconstruct.lightaware.model import plane_rig_intensity, specular_point_depth
from simtest.reconstruct.lightaware.cubic import cubic_patch_fit, patch_depth_profile
from simtest.reconstruct.lightaware.patch import quadric_fit
from simtest.reconstruct.lightaware.plane import photometric_fit

__all__ = ["OK", "STATUSES", "LightAwareEstimate", "CramerRaoBound", "bisector", "cubic_patch_fit", "isocurve_fit",
           "patch_depth_profile", "photometric_crb", "photometric_fit", "plane_rig_intensity", "quadric_fit",
           "reflection_offset_deg", "refine_isophote_points", "specular_point_depth"]
