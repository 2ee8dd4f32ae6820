"""Compiled (numba) kernels of the estimators (:mod:`simtest.reconstruct.estimators`).

:func:`cone_estimates` does, for every normalised conic C' of a batch in one compiled call, what
``estimators._estimate_from_conics_numpy`` does with some sixty numpy calls on the whole stack
(:func:`simtest.geometry.conics.cone_poses` and the orientation and choice that follow): the
sign-normalised eigen-decomposition of C', the circle pose N+ and N- with the centres of the
two sections, the cone axis and its eigenvalue gap, the normals turned toward the camera along the
BP ray, and the choice between N+ and N-. :func:`joint_axes` does the same for
``estimators._joint_cone_axes_numpy`` (the least-squares common axis of nested isophotes). A frame
of ten highlights, or one highlight alone, has a stack of a few conics: there the fixed cost of
each numpy call (a few microseconds), not the arithmetic, was the time.

The kernels take the same steps in the same order and call the same LAPACK routines (``dsyevd``
for the eigen-decompositions, ``dgesv`` for the sections' centres; numba calls SciPy's OpenBLAS,
numpy its own: on 3 x 3 and 2 x 2 systems they gave the same bits in every case tried). The one
sum whose rounding the decomposition inherits, the Frobenius norm that scales each cone, is
numpy's (``conics.unit_symmetric_cones``, an ``einsum`` whose SIMD order depends on the
processor), so :func:`cone_estimates` gives the numpy form's bits: an eigenvector's sign, which
decides which of the pair is N+, turns on the last bit of a near-right cone's entries. Its other
sums of three terms decide only a sign (which way a normal faces), or are the sums numpy's
``add.reduce`` also takes in index order (norms, dot products). :func:`joint_axes` scales each
cone's deviatoric part by a norm summed in row-major order, as the numpy form does
(``estimators._frobenius_norms``): it too gives the numpy form's bits.
``tests/test_estimator_kernels.py`` checks both; the numpy forms stay in ``estimators.py`` as
the reference and the fallback.

Where the numpy form fails a conic (not an ellipse, not a real elliptic cone, a section without a
centre, a non-finite normal), the kernel only says that it hands the conic over
(:data:`HANDED_OVER`): ``estimators.py`` runs the numpy form on those conics, whose failure, with
the numbers of its detail string, is the one reported.

Compiled with ``cache=True`` and without ``fastmath``, as :mod:`simtest.reconstruct._fit_kernels`
(no fused multiply-adds: the arithmetic rounds as numpy's). The method and its references (Makki
and Bartoli's circle pose, Forsyth et al.'s appendix A): :mod:`simtest.reconstruct.estimators`.
"""

from __future__ import annotations

import math

import numba
import numpy as np

#: Status codes of :func:`cone_estimates` and :func:`joint_axes`.
OK = 0  #: estimated
HANDED_OVER = 1  #: the numpy form decides (and words the failure)


@numba.njit(cache=True, nogil=True)
def _dot3(a, b):
    """``np.sum(a * b)`` of two 3-vectors: the products summed in index order."""
    return (a[0] * b[0] + a[1] * b[1]) + a[2] * b[2]


@numba.njit(cache=True, nogil=True)
def _unit3(v):
    """``v / np.linalg.norm(v)`` of a 3-vector (``simtest.geometry.angles.unit(v, axis=-1)``)."""
    return v / math.sqrt(_dot3(v, v))


@numba.njit(cache=True, nogil=True)
def _face(n, ray):
    """``estimators.face_reference``: ``-n`` where ``n . ray > 0``, else ``n``."""
    return -n if _dot3(n, ray) > 0 else n


@numba.njit(cache=True, nogil=True)
def _frobenius(m):
    """Frobenius norm of a 3 x 3 matrix, its squares summed in row-major order."""
    acc = 0.0
    for i in range(3):
        for j in range(3):
            acc += m[i, j] * m[i, j]
    return math.sqrt(acc)


@numba.njit(cache=True, nogil=True)
def _images_as_ellipse(c):
    """``estimators._images_as_ellipse_many`` of one cone C' (3, 3): whether it is finite and
    cuts the normalised image plane in an ellipse-type conic (the sign of det C'[:2, :2], scaled
    by the largest entry)."""
    scale = 0.0
    for i in range(3):
        for j in range(3):
            if not np.isfinite(c[i, j]):
                return False
            scale = max(scale, abs(c[i, j]))
    if not scale > 0:
        return False
    a00, a01, a10, a11 = c[0, 0] / scale, c[0, 1] / scale, c[1, 0] / scale, c[1, 1] / scale
    return a00 * a11 - a01 * a10 > 1e-12


@numba.njit(cache=True, nogil=True)
def _symmetric(c):
    """``0.5 * (c + c^T)``."""
    s = np.empty((3, 3))
    for i in range(3):
        for j in range(3):
            s[i, j] = 0.5 * (c[i, j] + c[j, i])
    return s


@numba.njit(cache=True, nogil=True)
def _cone_eigen(s, eps):
    """``conics._cone_eigen_many`` of one cone, given symmetric and of unit Frobenius norm
    (``conics.unit_symmetric_cones``): its decomposition with signs normalised so that
    l1 >= l2 > 0 > l3.

    Returns ``(ok, w, V)``: whether the cone is real and elliptic (finite, signature (2, 1) with
    eigenvalues beyond ``eps``), its eigenvalues (l1, l2, l3) (3,) and eigenvectors as columns in
    that order (3, 3).
    """
    for i in range(3):
        for j in range(3):
            if not np.isfinite(s[i, j]):
                return False, np.zeros(3), np.zeros((3, 3))
    w, v = np.linalg.eigh(s)  # ascending
    n_pos = 0
    n_neg = 0
    for i in range(3):
        if w[i] > eps:
            n_pos += 1
        elif w[i] < -eps:
            n_neg += 1
    flip = n_pos == 1 and n_neg == 2
    ok = flip or (n_pos == 2 and n_neg == 1)
    out_w = np.empty(3)
    out_v = np.empty((3, 3))
    for q in range(3):
        # flipped: (-w0, -w1, -w2) with the columns in place; else (w2, w1, w0), columns reversed
        src = q if flip else 2 - q
        out_w[q] = -w[src] if flip else w[src]
        for i in range(3):
            out_v[i, q] = v[i, src]
    return ok, out_w, out_v


@numba.njit(cache=True, nogil=True)
def _section_centre(Q, n):
    """``conics._section_centres`` of one cone Q (3, 3) and plane normal n (3,): whether the
    section has a centre, and the unit direction of that centre (z > 0)."""
    x, y, z = n[0], n[1], n[2]
    u = np.empty(3)
    if abs(x) >= 0.9:  # n x e_y = (-z, 0, x)
        u[0], u[1], u[2] = -z, 0.0, x
    else:  # n x e_x = (0, z, -y)
        u[0], u[1], u[2] = 0.0, z, -y
    u = _unit3(u)
    w = np.empty(3)
    w[0] = y * u[2] - z * u[1]
    w[1] = z * u[0] - x * u[2]
    w[2] = x * u[1] - y * u[0]
    B = np.empty((3, 2))
    B[:, 0] = u
    B[:, 1] = w
    BtQ = np.empty((2, 3))
    for a in range(2):
        for j in range(3):
            BtQ[a, j] = (B[0, a] * Q[0, j] + B[1, a] * Q[1, j]) + B[2, a] * Q[2, j]
    M = np.empty((2, 2))
    g = np.empty(2)
    for a in range(2):
        for b in range(2):
            M[a, b] = (BtQ[a, 0] * B[0, b] + BtQ[a, 1] * B[1, b]) + BtQ[a, 2] * B[2, b]
        g[a] = (BtQ[a, 0] * n[0] + BtQ[a, 1] * n[1]) + BtQ[a, 2] * n[2]
    try:
        ab = np.linalg.solve(M, g)
    except Exception:  # noqa: BLE001 - LAPACK's singular matrix, raised by numba
        return False, np.full(3, np.nan)
    X = np.empty(3)
    for i in range(3):
        X[i] = n[i] - (B[i, 0] * ab[0] + B[i, 1] * ab[1])
    X = _unit3(X)
    return True, -X if X[2] < 0 else X


@numba.njit(cache=True, nogil=True)
def _circle_poses(w, V):
    """``conics._circle_poses_of`` of one sign-normalised decomposition (:func:`_cone_eigen`):
    whether both poses are defined, and the normals N+ and N- (2, 3) facing the camera (against
    the rays to their circles' centres)."""
    l1, l2, l3 = w[0], w[1], w[2]
    sin_phi = math.sqrt(max(l1 - l2, 0.0) / (l1 - l3))
    cos_phi = math.sqrt(max(l2 - l3, 0.0) / (l1 - l3))
    Q = np.empty((3, 3))  # the sign-normalised unit cone V diag(w) V^T
    for i in range(3):
        for j in range(3):
            Q[i, j] = (V[i, 0] * w[0] * V[j, 0] + V[i, 1] * w[1] * V[j, 1]) + V[i, 2] * w[2] * V[j, 2]
    normals = np.empty((2, 3))
    for s in range(2):
        sgn = 1.0 if s == 0 else -1.0
        n = np.empty(3)
        for i in range(3):
            n[i] = sgn * sin_phi * V[i, 0] + cos_phi * V[i, 2]
        n = _unit3(n)
        ok, c = _section_centre(Q, n)
        if not ok:
            return False, normals
        normals[s] = -n if _dot3(n, c) > 0 else n
    return True, normals


@numba.njit(cache=True, nogil=True)
def cone_estimates(cns, unit_cones, refs, eps):
    """The ``paper`` and ``cone_axis`` estimates of a stack of normalised conics.

    Parameters
    ----------
    cns : ndarray of shape (k, 3, 3), float64
        Normalised conics C' = K^T C K (any scale and sign).
    unit_cones : ndarray of shape (k, 3, 3), float64
        Their symmetric parts at unit Frobenius norm (``conics.unit_symmetric_cones``, whose
        ``einsum`` is numpy's: the eigen-decomposition starts from the numpy form's bits).
    refs : ndarray of shape (k, 3), float64
        Their BP-ray normals (unit, facing the camera), camera frame.
    eps : float
        ``TOL.conic_degenerate_rel``: an eigenvalue of the unit-norm cone within it of zero has
        no sign.

    Returns
    -------
    status : ndarray of shape (k,), int64
        :data:`OK` or :data:`HANDED_OVER`; the other results of a conic are meaningful only
        where it is OK.
    paper : ndarray of shape (k, 2, 3)
        N+ and N-, unit, facing the camera along the BP ray.
    index : ndarray of shape (k,), int64
        The one of N+ (0) and N- (1) closer to the BP-ray normal (ties to 0).
    axis : ndarray of shape (k, 3)
        The cone axis (eigenvector of the unique-sign eigenvalue), unit, facing the camera.
    gap : ndarray of shape (k,)
        The eigenvalue gap ``(l1 - l2) / (l1 - l3)``.

    Notes
    -----
    Each conic is estimated from its own numbers only, in its own loop iteration, so its results
    do not depend on the other conics of the batch.
    """
    k = cns.shape[0]
    status = np.full(k, HANDED_OVER, dtype=np.int64)
    paper = np.full((k, 2, 3), np.nan)
    index = np.zeros(k, dtype=np.int64)
    axis = np.full((k, 3), np.nan)
    gap = np.full(k, np.nan)
    for j in range(k):
        c = cns[j]
        if not _images_as_ellipse(c):
            continue
        ok, w, V = _cone_eigen(unit_cones[j], eps)
        if not ok:
            continue
        ok, normals = _circle_poses(w, V)
        if not ok:
            continue
        e3 = _unit3(np.ascontiguousarray(V[:, 2]))
        if e3[2] > 0:  # conics._toward_camera_many
            e3 = -e3
        ray = -refs[j]
        # the numpy form scales the axis and the pair to unit length once more (``unit`` in
        # estimators.estimate_from_conics, on vectors already unit): the kernel too, for its bits
        a = _face(_unit3(e3), ray)
        finite = np.isfinite(a).all()
        for s in range(2):
            paper[j, s] = _face(_unit3(np.ascontiguousarray(normals[s])), ray)
            finite = finite and np.isfinite(paper[j, s]).all()
        if not finite:
            continue
        axis[j] = a
        gap[j] = (w[0] - w[1]) / (w[0] - w[2])
        index[j] = 1 if _dot3(paper[j, 1], refs[j]) > _dot3(paper[j, 0], refs[j]) else 0
        status[j] = OK
    return status, paper, index, axis, gap


@numba.njit(cache=True, nogil=True)
def joint_axes(cns, group, refs):
    """The joint cone axis of each group of nested isophotes' conics
    (``estimators._joint_cone_axes_numpy``: the leading eigenvector of ``sum_i D_i / ||D_i||``).

    Parameters
    ----------
    cns : ndarray of shape (m, 3, 3), float64
        Normalised conics C'_i (any scale and sign), grouped by highlight.
    group : ndarray of shape (m,), int64
        Each conic's group 0 .. g-1.
    refs : ndarray of shape (g, 3), float64
        Each group's BP-ray normal, to orient its axis toward the camera.

    Returns
    -------
    status : ndarray of shape (g,), int64
        :data:`OK` or :data:`HANDED_OVER` (a conic of the group is not a real elliptic cone or
        is isotropic, the group is empty, or its axis is not finite).
    axis : ndarray of shape (g, 3)
        Unit axes facing the camera, where OK.
    """
    g = refs.shape[0]
    status = np.full(g, OK, dtype=np.int64)
    used = np.zeros(g, dtype=np.bool_)
    acc = np.zeros((g, 3, 3))
    for i in range(cns.shape[0]):
        j = group[i]
        used[j] = True
        if status[j] != OK:
            continue
        c = cns[i]
        if not _images_as_ellipse(c):
            status[j] = HANDED_OVER
            continue
        sym = _symmetric(c)
        w, _ = np.linalg.eigh(sym)  # ascending
        n_pos = 0
        any_zero = False
        for q in range(3):
            if w[q] > 0:
                n_pos += 1
            elif w[q] == 0:
                any_zero = True
        flip = n_pos == 2  # make the unique-sign eigenvalue positive
        if not (flip or (n_pos == 1 and not any_zero)):
            status[j] = HANDED_OVER
            continue
        if flip:
            sym = -sym
            half = 0.5 * (-w[2] + -w[1])
        else:
            half = 0.5 * (w[0] + w[1])
        d = np.empty((3, 3))  # minus the isotropic part of the same-sign pair, half * I
        for p in range(3):
            for q in range(3):
                d[p, q] = sym[p, q] - half * (1.0 if p == q else 0.0)
        nd = _frobenius(d)
        if not nd > 0:
            status[j] = HANDED_OVER
            continue
        acc[j] += d / nd
    axis = np.full((g, 3), np.nan)
    for j in range(g):
        if not used[j]:
            status[j] = HANDED_OVER
        if status[j] != OK:
            continue
        _, vv = np.linalg.eigh(acc[j])
        a = _face(_unit3(np.ascontiguousarray(vv[:, 2])), -refs[j])
        if not np.isfinite(a).all():
            status[j] = HANDED_OVER
            continue
        axis[j] = a
    return status, axis
