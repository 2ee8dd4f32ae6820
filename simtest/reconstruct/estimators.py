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

from simtest._records import fast_init
from simtest.geometry.angles import unit
from simtest.geometry.camera import bp_ray_normal
from simtest.geometry.conics import cone_poses
from simtest.reconstruct.failures import Failure


@fast_init
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
    n : ndarray of shape (..., 3)
        Normal(s), camera frame.
    ray : ndarray of shape (..., 3)
        Viewing direction(s) from the camera (z > 0), camera frame, broadcast against ``n``.

    Returns
    -------
    ndarray of shape (..., 3)
        Each ``n`` or ``-n`` (same length).
    """
    n = np.asarray(n, dtype=np.float64)
    d = np.sum(n * np.asarray(ray, dtype=np.float64), axis=-1, keepdims=True)
    return np.where(d > 0, -n, n)


def select_paper_normal(normals: np.ndarray, reference: np.ndarray):
    """Index of the normal of the pair closer in angle to ``reference``.

    The non-oracle rule of this module (see the module docstring): the reference is the BP-ray
    normal. Ties go to index 0.

    Parameters
    ----------
    normals : ndarray of shape (2, 3) or (k, 2, 3)
        N+ and N-, unit, camera frame (a stack of pairs for several highlights).
    reference : ndarray of shape (3,) or (k, 3)
        Unit reference normal(s) (the BP-ray normal), camera frame.

    Returns
    -------
    int or ndarray of shape (k,), int
        0 (N+) or 1 (N-), per pair.
    """
    # for unit vectors the smaller angle is the larger dot product (monotone arccos)
    normals = np.asarray(normals, dtype=np.float64)
    d = np.sum(normals * np.asarray(reference, dtype=np.float64)[..., None, :], axis=-1)
    idx = (d[..., 1] > d[..., 0]).astype(int)
    return int(idx) if normals.ndim == 2 else idx


def _images_as_ellipse_many(cn: np.ndarray) -> np.ndarray:
    """True where a cone C' (k, 3, 3) cuts the normalised image plane z = 1 in an ellipse-type
    conic (k,) bool.

    C' is also the image conic in normalised coordinates (O(1)-conditioned for any visible
    highlight); its type is the sign of det C'[:2, :2] (> 0: ellipse type). A real cone whose
    image is a hyperbola (axis nearly parallel to the image plane) has no normal facing the
    camera. Real versus imaginary is left to the signature test of ``circle_pose``.
    """
    finite = np.isfinite(cn).all(axis=(1, 2))
    scale = np.where(finite, np.abs(np.where(finite[:, None, None], cn, 0.0)).max(axis=(1, 2)), 0.0)
    a = cn[:, :2, :2] / np.where(scale > 0, scale, 1.0)[:, None, None]
    return finite & (scale > 0) & (a[:, 0, 0] * a[:, 1, 1] - a[:, 0, 1] * a[:, 1, 0] > 1e-12)


def _images_as_ellipse(cn) -> bool:
    """:func:`_images_as_ellipse_many` of one cone (any shape: False unless (3, 3))."""
    cn = np.asarray(cn, dtype=np.float64)
    return cn.shape == (3, 3) and bool(_images_as_ellipse_many(cn[None])[0])


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
    Cn = np.asarray(Cn, dtype=np.float64)
    if Cn.shape != (3, 3):
        return Failure("pose_failed", "the normalised conic is not an ellipse (hyperbola, parabola)")
    return estimate_from_conics(Cn[None], np.asarray(bp_ray, dtype=np.float64).reshape(1, 3))[0]


def estimate_from_conics(Cns: np.ndarray, bp_rays: np.ndarray) -> list[ConeEstimate | Failure]:
    """:func:`estimate_from_conic` of a stack of normalised conics, batched.

    Parameters
    ----------
    Cns : ndarray of shape (k, 3, 3)
        Normalised conics C' = K^T C K (any scale and sign).
    bp_rays : ndarray of shape (k, 3)
        Their BP-ray normals (unit, facing the camera), camera frame.

    Returns
    -------
    list of ConeEstimate or Failure
        One per conic, in order; ``Failure("pose_failed")`` where C' is not a real elliptic cone
        whose image is an ellipse.

    Notes
    -----
    One batched eigen-decomposition and circle pose for all conics
    (:func:`simtest.geometry.conics.cone_poses`). Each conic's result depends on its own numbers
    only.
    """
    Cns = np.asarray(Cns, dtype=np.float64).reshape(-1, 3, 3)
    refs = np.asarray(bp_rays, dtype=np.float64).reshape(-1, 3)
    k = len(Cns)
    elliptic = _images_as_ellipse_many(Cns)
    pose = cone_poses(Cns if elliptic.all() else np.where(elliptic[:, None, None], Cns, np.diag([1.0, 1.0, -1.0])))
    with np.errstate(invalid="ignore", divide="ignore"):
        paper = unit(pose["normals"], axis=-1)
        axis = unit(pose["axis"], axis=-1)
    ray = -refs
    paper = face_reference(paper, ray[:, None, :])
    axis = face_reference(axis, ray)
    finite = np.isfinite(paper).all(axis=(1, 2)) & np.isfinite(axis).all(axis=1)
    idx = select_paper_normal(paper, refs)
    out: list = []
    for j in range(k):
        if not elliptic[j]:
            out.append(Failure("pose_failed", "the normalised conic is not an ellipse (hyperbola, parabola)"))
        elif not pose["ok"][j]:
            out.append(Failure("pose_failed", pose["error"][j]))
        elif not finite[j]:
            out.append(Failure("pose_failed", "non-finite normal"))
        else:
            out.append(ConeEstimate(paper[j], paper[j, idx[j]], int(idx[j]), axis[j],
                                    float(pose["eigenvalue_gap"][j])))
    return out


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
    cns = [np.asarray(c, dtype=np.float64) for c in cns]
    if not cns:
        return Failure("pose_failed", "no conic given")
    if any(c.shape != (3, 3) for c in cns):
        return Failure("pose_failed", "a normalised conic is not an ellipse")
    return joint_cone_axes(np.stack(cns), np.zeros(len(cns), dtype=int),
                           np.asarray(bp_ray, dtype=np.float64).reshape(1, 3))[0]


def joint_cone_axes(cns: np.ndarray, group: np.ndarray, bp_rays: np.ndarray) -> list[np.ndarray | Failure]:
    """:func:`joint_cone_axis` of several groups of conics at once.

    Parameters
    ----------
    cns : ndarray of shape (m, 3, 3)
        Normalised conics C'_i (any scale and sign), grouped by highlight.
    group : ndarray of shape (m,), int
        Each conic's group 0 .. g-1, non-decreasing (the conics of a group consecutive).
    bp_rays : ndarray of shape (g, 3)
        Each group's BP-ray normal, to orient its axis toward the camera.

    Returns
    -------
    list of ndarray of shape (3,) or Failure
        Per group, its unit axis facing the camera, or ``Failure("pose_failed")`` (a conic is
        not a real elliptic cone, or the group is empty).
    """
    cns = np.asarray(cns, dtype=np.float64).reshape(-1, 3, 3)
    group = np.asarray(group, dtype=int)
    refs = np.asarray(bp_rays, dtype=np.float64).reshape(-1, 3)
    g = len(refs)
    fail: list = [None] * g
    elliptic = _images_as_ellipse_many(cns)
    sym = 0.5 * (cns + np.swapaxes(cns, 1, 2))
    sym = np.where(elliptic[:, None, None], sym, np.diag([1.0, 1.0, -1.0]))
    w, v = np.linalg.eigh(sym)
    n_pos = np.sum(w > 0, axis=1)
    flip = n_pos == 2  # make the unique-sign eigenvalue positive
    real = flip | ((n_pos == 1) & ~np.any(w == 0, axis=1))
    sym = np.where(flip[:, None, None], -sym, sym)
    w = np.where(flip[:, None], -w[:, ::-1], w)
    # w ascending: w[0] <= w[1] < 0 < w[2]; remove the isotropic part of the same-sign pair
    d = sym - 0.5 * (w[:, 0] + w[:, 1])[:, None, None] * np.eye(3)
    nd = np.sqrt(np.einsum("kij,kij->k", d, d))  # Frobenius norms
    isotropic = ~(nd > 0)
    for i in range(len(cns)):
        j = group[i]
        if fail[j] is not None:
            continue
        if not elliptic[i]:
            fail[j] = Failure("pose_failed", "a normalised conic is not an ellipse")
        elif not real[i]:
            fail[j] = Failure("pose_failed", f"conic eigenvalues {w[i].tolist()} are not those of a real cone")
        elif isotropic[i]:
            fail[j] = Failure("pose_failed", "a conic is isotropic")
    acc = np.zeros((g, 3, 3))
    np.add.at(acc, group, d / np.where(isotropic, 1.0, nd)[:, None, None])
    used = np.bincount(group, minlength=g) > 0
    acc = np.where((used & np.array([f is None for f in fail], dtype=bool))[:, None, None], acc, np.eye(3))
    _, vv = np.linalg.eigh(acc)
    with np.errstate(invalid="ignore", divide="ignore"):
        axis = unit(vv[:, :, -1], axis=-1)
    axis = face_reference(axis, -refs)
    out: list = []
    for j in range(g):
        if fail[j] is not None:
            out.append(fail[j])
        elif not used[j]:
            out.append(Failure("pose_failed", "no conic given"))
        elif not np.isfinite(axis[j]).all():
            out.append(Failure("pose_failed", "non-finite joint axis"))
        else:
            out.append(axis[j])
    return out
