"""Normal estimators from one or several isophote conics.

- ``paper``: the two circle-pose normals N+ and N- of one isophote ellipse (Makki and Bartoli,
  step four; Forsyth et al. 1991 appendix A), and a *non-oracle* choice between them.
- ``cone_axis``: the eigenvector of C' = K^T C K whose eigenvalue has the unique sign, with the
  eigenvalue gap as a model-violation diagnostic (prior art: dam410/LightModel,
  ``vanishing_line_paper_co``).
- ``bp_ray``: minus the unit viewing ray through the brightest point (the baseline).
- ``joint_cone_axis``: the axis shared by the cones of several nested isophotes.

All normals are unit vectors in the OpenCV camera frame, facing the camera (n . ray < 0).

Selection rule for the paper's pair (non-oracle)
------------------------------------------------
N+ and N- are ``+-sin(phi) e1 + cos(phi) e3`` in the eigenbasis of C' (``simtest.geometry.conics.
circle_pose``): both make the *same* angle phi with the cone axis e3, so "the one closer to the cone
axis" is a tie by construction and cannot choose. The rule used here picks the one closer to the
BP-ray normal: with a co-located light the BP ray is parallel to the normal at the BP
(whatever the curvature: the Notes of :func:`simtest.geometry.curvature.curvature_ratio`), so the BP ray is an unbiased (if noisy) reference that is independent of the
conic. Ties (N+ = N-, a right circular cone) return N+.

Joint cone axis
---------------
A right circular cone of axis e and half-angle alpha has C' proportional to
``e e^T - cos^2(alpha) I``. Nested isophotes of one highlight share e but not alpha. For each
normalised conic, sign-normalised so that the unique-sign eigenvalue is positive (eigenvalues
l3' > 0 > l2' >= l1'), remove the isotropic part with the mean of the same-sign pair:
``D_i = C'_i - (l1' + l2') / 2 I``; for an exact right cone ``D_i = s_i e e^T`` is rank one.
The joint axis is the unit e maximising ``sum_i e^T D_i e / ||D_i||``, the leading eigenvector of
``sum_i D_i / ||D_i||_F``. This is the least-squares common rank-one axis: since
``||D^_i - e e^T||^2 = ||D^_i||^2 + 1 - 2 e^T D^_i e``, it minimises
``sum_i ||D^_i - e e^T||_F^2`` over unit e. Each isophote has equal weight.

References
----------
.. [1] K. Makki, A. Bartoli, "Normal Reconstruction from Specularity in the Endoscopic Setting",
       section 2.3, steps 3 and 4 (C' = K^T C K and circle pose).
.. [2] D. Forsyth, J. L. Mundy, A. Zisserman, C. Coelho, A. Heller, C. Rothwell, "Invariant
       descriptors for 3-D object recognition and pose", IEEE TPAMI 13(10), 1991, appendix A.
       https://doi.org/10.1109/34.99233
.. [3] dam410/LightModel, public MATLAB code, branch ``vanishing_line_paper_co`` (prior art of
       the cone-axis estimator).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from simtest.geometry.angles import unit
from simtest.geometry.camera import bp_ray_normal
from simtest.geometry.conics import cone_pose
from simtest.reconstruct.failures import Failure


@dataclass(frozen=True)
class ConeEstimate:
    """Normals from one normalised conic C' (all (3,) unit, camera frame, facing the camera).

    Attributes
    ----------
    paper : ndarray of shape (2, 3)
        N+ and N- (circle pose).
    paper_selected : ndarray of shape (3,)
        The one of N+ and N- closer to ``reference`` (the BP-ray normal).
    paper_selected_index : int
        0 for N+, 1 for N-.
    cone_axis : ndarray of shape (3,)
        Eigenvector of the unique-sign eigenvalue.
    eigenvalue_gap : float
        ``(l1 - l2) / (l1 - l3)`` in [0, 1): 0 for a right circular cone.
    """

    paper: np.ndarray
    paper_selected: np.ndarray
    paper_selected_index: int
    cone_axis: np.ndarray
    eigenvalue_gap: float

    def __bool__(self) -> bool:
        return True


def face_reference(n: np.ndarray, ray: np.ndarray) -> np.ndarray:
    """Flip ``n`` so that ``n . ray <= 0`` (faces the camera along that viewing ray).

    Parameters
    ----------
    n : ndarray of shape (3,)
        A normal, camera frame.
    ray : ndarray of shape (3,)
        A viewing direction from the camera (z > 0), camera frame.

    Returns
    -------
    ndarray of shape (3,)
        ``n`` or ``-n`` (same length as ``n``).
    """
    return -n if float(np.dot(n, ray)) > 0 else n


def select_paper_normal(normals: np.ndarray, reference: np.ndarray) -> int:
    """Index of the normal of the pair closer in angle to ``reference``.

    The non-oracle rule of this module (see the module docstring): the reference is the BP-ray
    normal. Ties go to index 0.

    Parameters
    ----------
    normals : ndarray of shape (2, 3)
        N+ and N-, unit, camera frame.
    reference : ndarray of shape (3,)
        Unit reference normal (the BP-ray normal), camera frame.

    Returns
    -------
    int
        0 (N+) or 1 (N-).
    """
    # for unit vectors the smaller angle is the larger dot product (monotone arccos)
    d = np.asarray(normals, dtype=np.float64) @ np.asarray(reference, dtype=np.float64)
    return int(d[1] > d[0])


def _images_as_ellipse(cn) -> bool:
    """True if the cone C' cuts the normalised image plane z = 1 in an ellipse-type conic.

    C' is also the image conic in normalised coordinates (O(1)-conditioned for any visible
    highlight); its type is the sign of det C'[:2, :2] (> 0: ellipse type). A real cone whose
    image is a hyperbola (axis nearly parallel to the image plane) has no normal facing the
    camera. Real versus imaginary is left to the signature test of ``circle_pose``.
    """
    cn = np.asarray(cn, dtype=np.float64)
    if cn.shape != (3, 3) or not np.isfinite(cn).all():
        return False
    scale = float(np.abs(cn).max())
    if scale == 0.0:
        return False
    a = cn[:2, :2] / scale
    return bool(a[0, 0] * a[1, 1] - a[0, 1] * a[1, 0] > 1e-12)


def estimate_from_conic(Cn: np.ndarray, bp_ray: np.ndarray) -> ConeEstimate | Failure:
    """The ``paper`` and ``cone_axis`` estimates from one normalised conic.

    Parameters
    ----------
    Cn : ndarray of shape (3, 3)
        Normalised conic C' = K^T C K (any scale and sign).
    bp_ray : ndarray of shape (3,)
        BP-ray normal (unit, facing the camera), the reference of the selection rule and of the
        orientation of the returned normals.

    Returns
    -------
    ConeEstimate or Failure
        ``Failure("pose_failed")`` if C' is not a real elliptic cone whose image is an ellipse.
    """

    try:
        if not _images_as_ellipse(Cn):
            return Failure("pose_failed", "the normalised conic is not an ellipse (hyperbola, parabola)")
        pose, ax = cone_pose(Cn)
    except (ValueError, np.linalg.LinAlgError) as exc:
        return Failure("pose_failed", str(exc))
    ray = -bp_ray
    paper = np.array([face_reference(unit(n), ray) for n in pose.normals])
    axis = face_reference(unit(ax.axis), ray)
    if not (np.isfinite(paper).all() and np.isfinite(axis).all()):
        return Failure("pose_failed", "non-finite normal")
    idx = select_paper_normal(paper, bp_ray)
    return ConeEstimate(paper, paper[idx], idx, axis, float(ax.eigenvalue_gap))


def bp_ray(bp_uv, K) -> np.ndarray:
    """The ``bp_ray`` estimator: minus the unit viewing ray through the BP.

    Same as :func:`simtest.geometry.camera.bp_ray_normal`; pass the *undistorted* BP.

    Parameters
    ----------
    bp_uv : array_like of shape (2,)
        Brightest point (u, v), px, pixel centres at integer coordinates.
    K : ndarray of shape (3, 3)
        Intrinsics, px.

    Returns
    -------
    ndarray of shape (3,)
        ``-K^{-1} (u, v, 1) / ||K^{-1} (u, v, 1)||``: unit, OpenCV camera frame, facing the camera.
    """

    return bp_ray_normal(bp_uv, K)


def joint_cone_axis(cns, bp_ray: np.ndarray) -> np.ndarray | Failure:
    """Least-squares common axis of several normalised conics (nested isophotes).

    Parameters
    ----------
    cns : sequence of ndarray of shape (3, 3)
        Normalised conics C'_i (any scale and sign), at least one.
    bp_ray : ndarray of shape (3,)
        BP-ray normal, to orient the result toward the camera.

    Returns
    -------
    ndarray of shape (3,) or Failure
        Unit axis facing the camera; ``Failure("pose_failed")`` if a conic is not a real
        elliptic cone or none is given. Method: module docstring ("Joint cone axis").
    """
    acc = np.zeros((3, 3))
    n_used = 0
    for cn in cns:
        cn = np.asarray(cn, dtype=np.float64)
        if not _images_as_ellipse(cn):
            return Failure("pose_failed", "a normalised conic is not an ellipse")
        cn = 0.5 * (cn + cn.T)
        w, v = np.linalg.eigh(cn)
        n_pos = int(np.sum(w > 0))
        if n_pos == 2:  # make the unique-sign eigenvalue positive
            cn, w = -cn, -w[::-1]
        elif n_pos != 1 or np.any(w == 0):
            return Failure("pose_failed", f"conic eigenvalues {w.tolist()} are not those of a real cone")
        # w ascending: w[0] <= w[1] < 0 < w[2]; remove the isotropic part of the same-sign pair
        d = cn - 0.5 * (w[0] + w[1]) * np.eye(3)
        nd = np.linalg.norm(d)
        if not nd > 0:
            return Failure("pose_failed", "a conic is isotropic")
        acc += d / nd
        n_used += 1
    if n_used == 0:
        return Failure("pose_failed", "no conic given")
    w, v = np.linalg.eigh(acc)
    axis = face_reference(unit(v[:, -1]), -bp_ray)
    if not np.isfinite(axis).all():
        return Failure("pose_failed", "non-finite joint axis")
    return axis
