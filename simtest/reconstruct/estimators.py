"""Normal estimators from one or several isophote conics.

- ``paper``: the two circle-pose normals N+ and N- of one isophote ellipse [1]_ [2]_, and a
  *non-oracle* choice between them: the one closer to the BP-ray normal (both make the same
  angle with the cone axis, so that cannot choose; with a co-located light the BP ray is parallel
  to the normal at the BP, an unbiased reference independent of the conic). Ties return N+.
- ``cone_axis``: the eigenvector of C' = K^T C K whose eigenvalue has the unique sign, with the
  eigenvalue gap as a model-violation diagnostic [3]_.
- ``bp_ray``: minus the unit viewing ray through the brightest point (the baseline).
- ``joint_cone_axis``: the axis shared by nested isophotes. A right cone of axis e has C'
  proportional to ``e e^T - cos^2(alpha) I``; with each C'_i sign-normalised (l3' > 0 > l2' >= l1'),
  ``D_i = C'_i - (l1' + l2') / 2 I`` is rank one for an exact right cone, and the joint axis is the
  leading eigenvector of ``sum_i D_i / ||D_i||_F`` (it minimises ``sum_i ||D^_i - e e^T||_F^2``).

All normals are unit vectors in the OpenCV camera frame, facing the camera (n . ray < 0).

References
----------
.. [1] K. Makki, A. Bartoli, "Normal Reconstruction from Specularity in the Endoscopic Setting",
       section 2.3, steps 3 and 4.
.. [2] D. Forsyth et al., "Invariant descriptors for 3-D object recognition and pose", IEEE
       TPAMI 13(10), 1991, appendix A. https://doi.org/10.1109/34.99233
.. [3] dam410/LightModel, public MATLAB code, branch ``vanishing_line_paper_co``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from simtest.geometry.conics import plane_basis, section_centres
from simtest.reconstruct.failures import Failure
from simtest.reconstruct.fit import _THIRDS, _eigh2, _null_vectors
from simtest.tolerances import TOL


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


#: A right circular cone: stands in for a conic that is not one, keeping the stack finite (discarded).
_RIGHT_CONE = np.diag([1.0, 1.0, -1.0])


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
    """Index of the normal of the pair closer in angle to ``reference`` (the BP-ray normal); ties 0.

    Parameters
    ----------
    normals : ndarray of shape (2, 3) or (k, 2, 3)
        N+ and N-, unit, camera frame.
    reference : ndarray of shape (3,) or (k, 3)
        Unit reference normal(s), camera frame.

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
    """True where a cone C' (k, 3, 3) cuts the image plane z = 1 in an ellipse-type conic (k,) bool
    (det C'[:2, :2] > 0): a cone whose image is a hyperbola has no normal facing the camera.
    """
    finite = np.isfinite(cn).all(axis=(1, 2))
    scale = np.where(finite, np.abs(np.where(finite[:, None, None], cn, 0.0)).max(axis=(1, 2)), 0.0)
    a = cn[:, :2, :2] / np.where(scale > 0, scale, 1.0)[:, None, None]
    return finite & (scale > 0) & (a[:, 0, 0] * a[:, 1, 1] - a[:, 0, 1] * a[:, 1, 0] > 1e-12)


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


@np.errstate(all="ignore")
def estimate_from_conics(Cns: np.ndarray, bp_rays: np.ndarray) -> list[ConeEstimate | Failure]:
    """:func:`estimate_from_conic` of a stack of normalised conics, batched in closed form.

    Parameters
    ----------
    Cns : ndarray of shape (k, 3, 3)
        Normalised conics C' = K^T C K (any scale and sign).
    bp_rays : ndarray of shape (k, 3)
        Their BP-ray normals (unit, facing the camera), camera frame.

    Returns
    -------
    list of ConeEstimate or Failure
        One per conic, in order (each from its own numbers only); ``Failure("pose_failed")`` where
        C' is not a real elliptic cone whose image is an ellipse.
    """
    cns = np.asarray(Cns, dtype=np.float64).reshape(-1, 3, 3)
    refs = np.asarray(bp_rays, dtype=np.float64).reshape(-1, 3)
    k = len(cns)
    elliptic = _images_as_ellipse_many(cns)
    sym = cns + cns.transpose(0, 2, 1)
    unit_cones = sym / np.sqrt((sym * sym).sum(axis=2).sum(axis=1))[:, None, None]
    q, l1, l2, l3, e1, e3, real = _unique_sign_axes(np.where(elliptic[:, None, None], unit_cones, _RIGHT_CONE))
    # circle pose [2]: N+- = +-sin(phi) e1 + cos(phi) e3, each facing the camera against the ray to
    # its circle's centre (n_z < 0 is not the same test)
    sin_phi = np.sqrt(np.maximum(l1 - l2, 0.0) / (l1 - l3))
    cos_phi = np.sqrt(np.maximum(l2 - l3, 0.0) / (l1 - l3))
    n = (np.array([1.0, -1.0])[None, :, None] * (sin_phi[:, None] * e1)[:, None, :]
         + (cos_phi[:, None] * e3)[:, None, :]).reshape(2 * k, 3)
    n /= np.sqrt((n * n).sum(axis=1))[:, None]
    centre, has_centre = section_centres(np.repeat(q, 2, axis=0), n)
    paper = (n * np.where((n * centre).sum(axis=1) > 0, -1.0, 1.0)[:, None]).reshape(k, 2, 3)
    ray = -refs
    paper = face_reference(paper, ray[:, None, :])
    axis = face_reference(e3 * np.where(e3[:, 2] > 0, -1.0, 1.0)[:, None], ray)
    gap = ((l1 - l2) / (l1 - l3)).tolist()
    idx = select_paper_normal(paper, refs)
    ok = elliptic & real & has_centre.reshape(k, 2).all(axis=1)
    finite = np.isfinite(paper).all(axis=(1, 2)) & np.isfinite(axis).all(axis=1)
    selected = paper[np.arange(k), idx]
    if (ok & finite).all():
        return [ConeEstimate(p, sel, i, a, g) for p, sel, i, a, g in zip(paper, selected, idx.tolist(), axis, gap)]
    out: list = []
    for j in range(k):
        if not elliptic[j]:
            out.append(Failure("pose_failed", "the normalised conic is not an ellipse (hyperbola, parabola)"))
        elif not real[j]:
            c = 0.5 * (cns[j] + cns[j].T)
            out.append(Failure("pose_failed", f"C' is not a real elliptic cone: eigenvalues "
                               f"{np.linalg.eigvalsh(c / np.linalg.norm(c)).tolist()} "
                               "(need two of one sign and one of the other)"))
        elif not ok[j]:
            out.append(Failure("pose_failed", "Singular matrix"))
        elif not finite[j]:
            out.append(Failure("pose_failed", "non-finite normal"))
        else:
            out.append(ConeEstimate(paper[j], selected[j], int(idx[j]), axis[j], gap[j]))
    return out


def _unique_sign_axes(s: np.ndarray):
    """Sign-normalised decomposition of unit symmetric cones s (k, 3, 3): the cones signed to eigenvalues (+, +, -)
    (k, 3, 3), l1, l2, l3 (k,), eigenvectors e1 and e3 (k, 3), and which cones are real and elliptic (k,) bool.
    """
    eps = TOL.conic_degenerate_rel
    lam = _symmetric_roots(s)  # descending
    n_pos = (lam > eps).sum(axis=1)
    n_neg = (lam < -eps).sum(axis=1)
    flip = (n_pos == 1) & (n_neg == 2)
    ok = flip | ((n_pos == 2) & (n_neg == 1))
    sign = 1.0 - 2.0 * flip
    s = s * sign[:, None, None]
    l3 = np.where(flip, -lam[:, 0], lam[:, 2])
    e3, defined = _null_vectors(s - l3[:, None, None] * np.eye(3))
    # the same-sign pair: the cone restricted to the plane orthogonal to e3, basis (u, w)
    u, w = plane_basis(e3)
    su, sw = (s @ u[:, :, None])[:, :, 0], (s @ w[:, :, None])[:, :, 0]
    lo, hi, x, y = _eigh2((u * su).sum(axis=1), (u * sw).sum(axis=1), (w * sw).sum(axis=1))
    e1 = -y[:, None] * u + x[:, None] * w  # the eigenvector of hi: (x, y) turned by 90 degrees
    return s, hi, lo, l3, e1, e3, ok & defined


def _symmetric_roots(s: np.ndarray) -> np.ndarray:
    """The eigenvalues (k, 3), descending, of symmetric 3 x 3 matrices (k, 3, 3), from the characteristic cubic."""
    sh = (s[:, 0, 0] + s[:, 1, 1] + s[:, 2, 2]) / 3.0
    b = s - sh[:, None, None] * np.eye(3)
    p = (b * b).sum(axis=2).sum(axis=1) / 6.0  # p / 3 of b's cubic mu^3 - p mu - q (b traceless, symmetric)
    r = np.sqrt(p)
    c = np.clip(np.linalg.det(b) / (2.0 * r * r * r), -1.0, 1.0)
    c = np.where(p > 0, c, 1.0)
    return sh[:, None] + (2.0 * r)[:, None] * np.cos((np.arccos(c) / 3.0)[:, None] - _THIRDS)


def joint_cone_axis(cns, bp_ray: np.ndarray) -> np.ndarray | Failure:
    """Least-squares common axis of several normalised conics (nested isophotes; module docstring).

    Parameters
    ----------
    cns : sequence of ndarray of shape (3, 3)
        Normalised conics C'_i (any scale and sign), at least one.
    bp_ray : ndarray of shape (3,)
        BP-ray normal, to orient the result toward the camera.

    Returns
    -------
    ndarray of shape (3,) or Failure
        Unit axis facing the camera; ``Failure("pose_failed")`` if a conic is not a real elliptic
        cone or none is given.
    """
    cns = [np.asarray(c, dtype=np.float64) for c in cns]
    if not cns:
        return Failure("pose_failed", "no conic given")
    if any(c.shape != (3, 3) for c in cns):
        return Failure("pose_failed", "a normalised conic is not an ellipse")
    return joint_cone_axes(np.stack(cns), np.zeros(len(cns), dtype=int),
                           np.asarray(bp_ray, dtype=np.float64).reshape(1, 3))[0]


@np.errstate(all="ignore")
def joint_cone_axes(cns: np.ndarray, group: np.ndarray, bp_rays: np.ndarray) -> list[np.ndarray | Failure]:
    """:func:`joint_cone_axis` of several groups of conics at once (each group from its own conics only).

    Parameters
    ----------
    cns : ndarray of shape (m, 3, 3)
        Normalised conics C'_i (any scale and sign), grouped by highlight.
    group : ndarray of shape (m,), int
        Each conic's group 0 .. g-1.
    bp_rays : ndarray of shape (g, 3)
        Each group's BP-ray normal, to orient its axis toward the camera.

    Returns
    -------
    list of ndarray of shape (3,) or Failure
        Per group, its unit axis facing the camera, or ``Failure("pose_failed")``.
    """
    cns = np.asarray(cns, dtype=np.float64).reshape(-1, 3, 3)
    group = np.asarray(group, dtype=int)
    refs = np.asarray(bp_rays, dtype=np.float64).reshape(-1, 3)
    g = len(refs)
    elliptic = _images_as_ellipse_many(cns)
    sym = 0.5 * (cns + cns.transpose(0, 2, 1))
    sym = np.where(elliptic[:, None, None], sym, _RIGHT_CONE)
    w = _symmetric_roots(sym)  # descending
    n_pos = (w > 0).sum(axis=1)
    flip = n_pos == 2  # make the unique-sign eigenvalue positive
    real = flip | ((n_pos == 1) & ~(w == 0).any(axis=1))
    # minus the isotropic part of the same-sign pair: half the trace less the unique eigenvalue
    tr = sym[:, 0, 0] + sym[:, 1, 1] + sym[:, 2, 2]
    sign = 1.0 - 2.0 * flip
    half = 0.5 * sign * (tr - np.where(flip, w[:, 2], w[:, 0]))
    d = sym * sign[:, None, None] - half[:, None, None] * np.eye(3)
    nd = np.sqrt((d * d).sum(axis=2).sum(axis=1))
    isotropic = ~(nd > 0)
    bad = ~elliptic | ~real | isotropic
    acc = np.zeros((g, 3, 3))
    np.add.at(acc, group, d / np.where(isotropic, 1.0, nd)[:, None, None])
    used = np.bincount(group, minlength=g) > 0
    failed = np.bincount(group, weights=bad, minlength=g) > 0
    top = _symmetric_roots(acc)[:, 0]
    axis, _ = _null_vectors(acc - top[:, None, None] * np.eye(3))
    axis = face_reference(axis, -refs)
    finite = np.isfinite(axis).all(axis=1)
    if used.all() and not failed.any() and finite.all():
        return list(axis)
    fail: list = [None] * g
    for i in np.flatnonzero(bad):  # the first bad conic of a group words its failure
        j = group[i]
        if fail[j] is not None:
            continue
        if not elliptic[i]:
            fail[j] = Failure("pose_failed", "a normalised conic is not an ellipse")
        elif not real[i]:
            fail[j] = Failure("pose_failed", f"conic eigenvalues {np.linalg.eigvalsh(sym[i]).tolist()} "
                              "are not those of a real cone")
        else:
            fail[j] = Failure("pose_failed", "a conic is isotropic")
    out: list = []
    for j in range(g):
        if fail[j] is not None:
            out.append(fail[j])
        elif not used[j]:
            out.append(Failure("pose_failed", "no conic given"))
        elif not finite[j]:
            out.append(Failure("pose_failed", "non-finite joint axis"))
        else:
            out.append(axis[j])
    return out
