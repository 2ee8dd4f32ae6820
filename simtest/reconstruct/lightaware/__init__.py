"""Light-aware estimators: normal and depth of a highlight lit by a known rig off the camera centre.

With the light exactly at the camera centre the BP ray is the normal at the BP and the image of a
plane is invariant to the plane's distance. Real endoscopes carry their light guides a few
millimetres beside the lens, at 5 to 50 mm from the tissue: the offset over the distance,
epsilon/d, is 0.05 to 0.5, and the BP ray is then off the normal by about half the angle the
offset subtends (the BP is where the normal *bisects* the directions to camera and light). A known
(calibrated) offset also breaks the scale ambiguity: the image depends on L/d, so the distance
becomes observable. Three estimators use the rig:

- :func:`bisector`: the BP ray corrected by the rig for a *given* depth (a depth map, a stereo
  depth): exact for a plane when the depth is exact.
- :func:`isocurve_fit`: the general specular isocurve (paper eq. 2, any light and viewer) with the
  calibrated light position, fitted to the isophote points taken as rays: plane normal, distance h,
  and the cosine level tau of each isovalue (nested isovalues tie their taus through the
  roughness n).
- :func:`quadric_fit`: the photometric fit with a curved (quadric) patch, for curved surfaces
  where the plane model explains the curvature's compression of the lobe by roughness and depth
  (:func:`photometric_fit` then reports ``plane_misfit``).
- :func:`photometric_fit`: the ROI's intensities fitted with the image of a plane lit by the whole
  rig (sum of the lights' Phong lobes with their falloff and emission profile) plus a smooth linear
  background: normal, distance, roughness and gain; clipped pixels are left out (or censored);
  optionally the rig's Lambertian shading as a further column, and a GGX lobe under a dielectric
  film (the renderer's wet film) in place of Phong's, or chosen beside it per fit (``lobe``).
- :func:`cubic_patch_fit`: the quadric patch with its four third-order terms, fitted to the lobes
  of every light of a rig of several lights (a depth profile, then the free fit): with one light
  the surface's third-order shape stands in for the light's offset and the depth is not
  observable; two lights apart shift their lobes apart while the shape acts on both alike, which
  fixes the depth (:func:`patch_depth_profile` measures it), and with it each light's specular
  point and normal.

Each returns a :class:`LightAwareEstimate`: the normal, the depth in mm of the specular point along
its ray (None when not observable), a 1-sigma angular uncertainty from the fit's Jacobian, and a
status with its cause (:data:`STATUSES`).

Model (paper eq. 1 with the mirror direction of eq. 2)
------------------------------------------------------
Camera frame (OpenCV), camera centre V = 0, mm. Plane ``n . X = -h`` (n unit, facing the camera,
h > 0). The pixel ray d (unit) meets the plane at ``X = d h / (-n . d)``. With ``l`` the unit
direction from X to a light L and ``v = -d`` the direction to the camera, the mirror direction
of the light is ``r = 2 (n . l) n - l`` and

``cos beta = r . v = 2 (n . l)(n . v) - l . v``,

the quantity whose level sets on the plane are the general specular isocurve (eq. 2:
``Q(p) = 0`` is ``cos^2 beta = tau^2``; the isophote is the branch ``cos beta = +tau``). The
photometric model is ``I = g sum_j w_j max(0, cos beta_j)^n f_j p_j + b0 + b1 du + b2 dv`` with
``f_j = (h / |L_j - X|)^2`` for an inverse-square light (1 otherwise), ``p_j`` the emission profile
``cos^m`` about +z, gain g and a linear background (b0, b1, b2), solved linearly for each value of
the nonlinear parameters (variable projection).

Specular point and depth: on the plane (n, h) the specular point of a light L is where the
segment from the camera centre to the mirror image ``L' = L - 2 (n . L + h) n`` meets the plane,
``X_s = L' h / (-n . L')``; ``depth_mm = |X_s|``, its distance along its viewing ray. For a rig of
several lights the depth reported is that of the intensity-weighted mean light position.

Parametrisation, start and uncertainty
--------------------------------------
The normal is ``n = unit(n0 + a e1 + b e2)`` about the start normal n0 ((e1, e2) a basis of its
tangent plane), the distance enters as log h. The start is the bisector at the BP with a nominal
distance (``nominal_depth_mm``) whose h is then made consistent with the BP: for the start
normal, the depth along the BP ray at which the specular point projects to the BP. The
covariance of the parameters is ``s^2 (J^T J)^-1`` at the solution, J the Jacobian re-taken about
the solution, s^2 the residual variance ``sum r^2 / (m - p)``; ``normal_sigma_deg`` is
``sqrt(var a + var b)`` in degrees (the RMS angle of the normal's error) and the depth's
standard deviation follows by the delta method.

Depth observability: the depth's relative standard deviation is computed again with the residual
variance floored at the localisation noise of a contour point or a pixel
(``TOL.isophote_noise_px`` and ``TOL.photometric_noise_rel``); above ``TOL.depth_rel_sigma_max``
(or with a singular J^T J, as at epsilon = 0 where the image does not depend on h) the depth is
reported as None with status ``depth_not_observable``; the normal is still given (the fit's flat
direction in h leaves the normal determined).


Package layout
--------------
One module per job, so that each is found in one place:

- :mod:`~simtest.reconstruct.lightaware.estimate`: :class:`LightAwareEstimate` and :data:`STATUSES`;
- :mod:`~simtest.reconstruct.lightaware.model`: the image model (rays, the rig's lobes on a plane and
  their derivatives, the specular point's depth, the ROI's pixel grid);
- :mod:`~simtest.reconstruct.lightaware.colour`: the specular image of a colour ROI (the tissue's
  body colours projected out);
- :mod:`~simtest.reconstruct.lightaware.solve`: the fitting machinery the fits share (start,
  Levenberg-Marquardt with a robust loss, covariance and the depth's observability, misfit tests);
- :mod:`~simtest.reconstruct.lightaware.bisector`, :mod:`~simtest.reconstruct.lightaware.isocurve`,
  :mod:`~simtest.reconstruct.lightaware.plane` (:func:`photometric_fit`, its stages in
  ``plane_model``, ``plane_solve`` and ``plane_sigma``), :mod:`~simtest.reconstruct.lightaware.patch`
  (:func:`quadric_fit`) and :mod:`~simtest.reconstruct.lightaware.cubic` (:func:`cubic_patch_fit`):
  the estimators;
- :mod:`~simtest.reconstruct.lightaware.bound`: the Cramer-Rao bound of the plane model.

The recommendation that chooses among them is :mod:`simtest.reconstruct.recommend`.

References
----------
.. [1] K. Makki, A. Bartoli, "Normal Reconstruction from Specularity in the Endoscopic Setting",
       eqs. (1) and (2).
.. [2] B. T. Phong, "Illumination for computer generated pictures", CACM 18(6), 1975.
       https://doi.org/10.1145/360825.360839
.. [3] G. H. Golub, V. Pereyra, "The differentiation of pseudo-inverses and nonlinear least squares
       problems whose variables separate", SIAM J. Numer. Anal. 10(2), 1973.
       https://doi.org/10.1137/0710036 (variable projection).
.. [4] J. Iranzo et al., "EndoMetric: near-light metric scale monocular SLAM", MICCAI 2025,
       arXiv 2410.15065 (the same near-light baseline, for scale from diffuse shading).
"""

from __future__ import annotations

from simtest.reconstruct.lightaware.bisector import bisector
from simtest.reconstruct.lightaware.bound import CramerRaoBound, photometric_crb
from simtest.reconstruct.lightaware.estimate import OK, STATUSES, LightAwareEstimate
from simtest.reconstruct.lightaware.isocurve import isocurve_fit, refine_isophote_points
from simtest.reconstruct.lightaware.model import plane_rig_intensity, specular_point_depth
from simtest.reconstruct.lightaware.cubic import cubic_patch_fit, patch_depth_profile
from simtest.reconstruct.lightaware.patch import quadric_fit
from simtest.reconstruct.lightaware.plane import photometric_fit

__all__ = ["OK", "STATUSES", "LightAwareEstimate", "CramerRaoBound", "bisector", "cubic_patch_fit", "isocurve_fit",
           "patch_depth_profile", "photometric_crb", "photometric_fit", "plane_rig_intensity", "quadric_fit",
           "refine_isophote_points", "specular_point_depth"]
