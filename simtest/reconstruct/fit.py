"""Direct least-squares ellipse fit (Fitzgibbon et al. 1999, in the Halir-Flusser form).

Step 2 of the method: the isophote points are fitted by the closed-form ellipse-specific
least-squares conic [2], computed in the numerically stable block form of Halir and Flusser [1],
on points first centred and scaled to unit RMS radius (without that, the scatter matrix of points
~500 px from the origin is ill-conditioned by ~1e11). The result is the 3x3 point conic C in
pixel coordinates (``x^T C x = 0`` for ``x = (u, v, 1)``), the ellipse parameters, and an RMS
Sampson residual in pixels.

A failed fit returns a falsy :class:`~simtest.reconstruct.failures.Failure` naming its cause
(``too_few_points``, ``non_finite_points``, ``degenerate_points``, ``not_an_ellipse``), as
scikit-image's ``EllipseModel.from_estimate`` does; a wrong array shape raises ValueError.

Why not OpenCV: ``cv2.fitEllipse`` (and in some versions ``fitEllipseDirect``) switch to a
different algorithm or a circle fallback on near-circular point sets with many points; the
isophotes of a fronto-parallel patch are exactly such sets. ``tests/test_fit.py`` records the
installed OpenCV's behaviour on a 2000-point near-circle.

References
----------
.. [1] R. Halir and J. Flusser, "Numerically stable direct least squares fitting of ellipses",
       Proc. WSCG 1998, pp. 125-132. Equation numbers below follow the numbering used in
       scikit-image's ``EllipseModel`` which implements the same paper.
.. [2] A. Fitzgibbon, M. Pilu and R. B. Fisher, "Direct least square fitting of ellipses",
       IEEE TPAMI 21(5):476-480, 1999. https://doi.org/10.1109/34.765658
.. [3] R. Hartley, A. Zisserman, Multiple View Geometry, 2nd ed., 2003, sec. 4.2.6 (Sampson
       error). https://doi.org/10.1017/CBO9780511811685
.. [4] K. Makki, A. Bartoli, "Normal Reconstruction from Specularity in the Endoscopic Setting",
       section 2.3, step 2 (ellipse fit of the isophote).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from simtest._records import fast_init
from simtest.geometry.conics import Ellipse, conic_kind
from simtest.reconstruct.failures import Failure
from simtest.tolerances import TOL

#: An ellipse has 5 degrees of freedom; one more point gives a residual.
MIN_FIT_POINTS = 6
#: Reciprocal condition number of the (normalised) linear scatter S3 below which the points are
#: called collinear: S3 of centred unit-RMS points has eigenvalues O(1) unless they are degenerate.
_S3_RCOND = 1e-10

#: A fitted semi-major axis longer than this many times the largest distance of a point from the
#: points' mean is refused: the points (a line, parallel lines, a short flat arc) do not bound it.
#: An arc of 60 degrees of a circle already gives a ratio under 4; 10 leaves room for short arcs.
MAX_AXIS_TO_SPREAD = 10.0

#: Exponents (i, j) of the monomials x^i y^j whose sums make the scatter matrix S = D^T D of the
#: design rows d = (x^2, xy, y^2, x, y, 1): every product d_a d_b is one of these 15.
_MONOMIALS = [(i, s - i) for s in range(5) for i in range(s, -1, -1)]
_D_EXPONENTS = [(2, 0), (1, 1), (0, 2), (1, 0), (0, 1), (0, 0)]
#: ``S[a, b]`` is the sum of monomial ``_S_INDEX[a, b]`` (6, 6).
_S_INDEX = np.array([[_MONOMIALS.index((a[0] + b[0], a[1] + b[1])) for b in _D_EXPONENTS]
                     for a in _D_EXPONENTS], dtype=np.int64)
#: The point conic [[a, b/2, d/2], [b/2, c, e/2], [d/2, e/2, f]] of the coefficients (a .. f).
_CONIC_OF_COEFFS = np.array([[0, 1, 3], [1, 2, 4], [3, 4, 5]])
_CONIC_HALVES = np.array([[1.0, 0.5, 0.5], [0.5, 1.0, 0.5], [0.5, 0.5, 1.0]])
#: From this many sets on, the eigenvalue checks are first cleared by a written-out Cholesky bound
#: (:func:`_least_eigenvalue_above`, some 40 numpy calls): below, the stacked LAPACK calls cost less.
_SHORTCUT_MIN_SETS = 32
_TINY = np.finfo(np.float64).tiny
_MONO_I = np.array([i for i, _ in _MONOMIALS], dtype=np.int64)
_MONO_J = np.array([j for _, j in _MONOMIALS], dtype=np.int64)
#: Inverse of the constraint matrix C1 of 4ac - b^2 = 1 [1, eqn. 18].
_C1_INV = np.linalg.inv(np.array([[0.0, 0.0, 2.0], [0.0, -1.0, 0.0], [2.0, 0.0, 0.0]]))


@fast_init
@dataclass(frozen=True)
class EllipseFit:
    """A successful ellipse fit (truthy).

    Attributes
    ----------
    conic : ndarray of shape (3, 3)
        Symmetric point conic C in pixel coordinates, ``x^T C x = 0`` with ``x = (u, v, 1)``;
        unit Frobenius norm, sign chosen so that the quadratic part is positive definite
        (``x^T C x < 0`` inside the ellipse).
    ellipse : simtest.geometry.conics.Ellipse
        Centre (u, v) px, semi-axes (a >= b) px, angle of the major axis from +u toward +v, rad.
    residual_px : float
        RMS Sampson distance of the points to the conic, px (first-order geometric distance).
    n_points : int
        Number of points fitted.
    """

    conic: np.ndarray
    ellipse: object
    residual_px: float
    n_points: int

    def __bool__(self) -> bool:
        return True


def sampson_distance_px(conic: np.ndarray, points_uv: np.ndarray) -> np.ndarray:
    """Sampson distance of each point to a point conic [3].

    The first-order geometric distance ``|x^T C x| / ||grad_(u,v) (x^T C x)||`` with
    ``x = (u, v, 1)``.

    Parameters
    ----------
    conic : ndarray of shape (3, 3) or (N, 3, 3)
        Symmetric point conic in pixel coordinates (any scale: the ratio is scale-free), or one
        per point.
    points_uv : ndarray of shape (N, 2)
        Points (u, v), px, pixel centres at integer coordinates.

    Returns
    -------
    ndarray of shape (N,)
        Distances in px (>= 0); a point where the gradient vanishes (the conic's centre) gets
        ``|x^T C x| / tiny``, a very large value rather than a division by zero.
    """
    c = np.asarray(conic, dtype=np.float64)
    u, v = points_uv[:, 0], points_uv[:, 1]
    gu = c[..., 0, 0] * u + c[..., 0, 1] * v + c[..., 0, 2]  # half the gradient of x^T C x
    gv = c[..., 1, 0] * u + c[..., 1, 1] * v + c[..., 1, 2]
    f = gu * u + gv * v + c[..., 2, 0] * u + c[..., 2, 1] * v + c[..., 2, 2]
    return np.abs(f) / np.maximum(2.0 * np.hypot(gu, gv), _TINY)


def _segment_sums(values: np.ndarray, starts: np.ndarray) -> np.ndarray:
    """Sums of ``values`` (M, ...) over the consecutive segments that begin at ``starts`` (k,)."""
    return np.add.reduceat(values, starts, axis=0)


def fit_ellipse(points_uv) -> EllipseFit | Failure:
    """Fit an ellipse to 2D points by direct least squares (Fitzgibbon; Halir-Flusser form).

    Parameters
    ----------
    points_uv : array_like of shape (N, 2)
        Points (u, v) in pixels, N >= 6.

    Returns
    -------
    EllipseFit or Failure
        Failure reasons: ``too_few_points``, ``non_finite_points``, ``degenerate_points``,
        ``not_an_ellipse`` (also when the points fit a non-ellipse clearly better, or the fitted
        ellipse is more than :data:`MAX_AXIS_TO_SPREAD` times the points' spread).

    Raises
    ------
    ValueError
        If ``points_uv`` is not of shape (N, 2).

    Notes
    -----
    One call of :func:`fit_ellipses`, which holds the method.

    Examples
    --------
    >>> t = np.linspace(0, 2 * np.pi, 50, endpoint=False)
    >>> fit = fit_ellipse(np.column_stack([10 + 5 * np.cos(t), 20 + 3 * np.sin(t)]))
    >>> np.round(fit.ellipse.center, 6).tolist(), np.round(fit.ellipse.semi_axes, 6).tolist()
    ([10.0, 20.0], [5.0, 3.0])
    """
    return fit_ellipses([points_uv])[0]


def point_sets(points_list) -> list[np.ndarray]:
    """Point sets as float64 arrays (views where they already are).

    Parameters
    ----------
    points_list : sequence of array_like of shape (N_i, 2)
        Points (u, v), px.

    Returns
    -------
    list of ndarray of shape (N_i, 2), float64

    Raises
    ------
    ValueError
        If a set is not of shape (N, 2).
    """
    out = []
    for p in points_list:
        p = np.asarray(p, dtype=np.float64)
        if p.ndim != 2 or p.shape[1] != 2:
            raise ValueError(f"points_uv must have shape (N, 2), got {p.shape}")
        out.append(p)
    return out


def fit_ellipses(points_list) -> list[EllipseFit | Failure]:
    """Fit one ellipse to each of several point sets, batched (Fitzgibbon; Halir-Flusser form).

    Parameters
    ----------
    points_list : sequence of array_like of shape (N_i, 2)
        Point sets (u, v) in pixels, each N_i >= 6 to be fitted.

    Returns
    -------
    list of EllipseFit or Failure
        One per point set, in order. Failure reasons: ``too_few_points``, ``non_finite_points``,
        ``degenerate_points``, ``not_an_ellipse`` (also when the points fit a non-ellipse clearly
        better, or the fitted ellipse is more than :data:`MAX_AXIS_TO_SPREAD` times the points'
        spread).

    Raises
    ------
    ValueError
        If a point set is not of shape (N, 2).

    Notes
    -----
    Each set is centred and scaled to unit RMS distance from its mean (Hartley-style
    conditioning). The scatter matrix S = D^T D of the design rows (x^2, xy, y^2, x, y, 1) [eqn.
    17 of 1] is assembled from the sums of the 15 monomials x^i y^j (i + j <= 4) of each set;
    then come the reduced 3 x 3 eigenproblem [eqn. 28-29 of 1] and the checks, for all sets in
    one numpy pass over the stack (:func:`fit_stacked`). A set's fit does not depend on the other
    sets of the batch (each set's own rows are summed, and LAPACK runs on each matrix of a stack
    alone).
    """
    pts_all = point_sets(points_list)
    if not pts_all:
        return []
    return fit_stacked(np.concatenate(pts_all, axis=0), np.array([len(p) for p in pts_all], dtype=np.int64))


def fit_stacked(pts: np.ndarray, counts: np.ndarray) -> list[EllipseFit | Failure]:
    """:func:`fit_ellipses` of point sets given concatenated (ragged: points and counts).

    Parameters
    ----------
    pts : ndarray of shape (M, 2), float64
        The point sets (u, v), px, one after the other.
    counts : ndarray of shape (k,), int
        Points per set (``counts.sum() == M``).

    Returns
    -------
    list of EllipseFit or Failure
        One per set, as :func:`fit_ellipses`.

    Notes
    -----
    One numpy pass over the whole stack: per-set sums by ``np.add.reduceat`` over the rows, then
    stacked 3 x 3 and 6 x 6 LAPACK calls (``solve``, ``eig``, ``eigvalsh``), each matrix of a
    stack solved alone, so a set's fit does not depend on the other sets of the batch.
    """
    counts = np.asarray(counts, dtype=np.int64)
    pts = np.asarray(pts, dtype=np.float64).reshape(-1, 2)
    out: list = [None] * len(counts)
    few = counts < MIN_FIT_POINTS
    for i in np.flatnonzero(few).tolist():
        out[i] = Failure("too_few_points", f"{int(counts[i])} points < {MIN_FIT_POINTS}")
    todo = np.flatnonzero(~few)
    if not len(todo):
        return out
    if few.any():  # the rows of the sets to fit
        pts = pts[np.repeat(~few, counts)]
    n = counts[todo]
    starts = np.concatenate([[0], np.cumsum(n)[:-1]])
    item = np.repeat(np.arange(len(n)), n)
    bad_rows = _segment_sums((~np.isfinite(pts)).any(axis=1).astype(np.int64), starts)
    with np.errstate(all="ignore"):
        fits = _fit_stack(pts, n, starts, item, bad_rows)
    for i, f in zip(todo.tolist(), fits):
        out[i] = f
    return out


def _sum_rows(a: np.ndarray) -> np.ndarray:
    """``a[0] + a[1] + ...`` (first axis), added in that order whatever the other axes' sizes (a
    numpy reduction's order depends on the layout and the batch: a set's fit would depend on its
    batch in the last bit)."""
    acc = a[0] + a[1]
    for row in a[2:]:
        acc += row
    return acc


def _least_eigenvalue_above(s: np.ndarray, base: np.ndarray) -> np.ndarray:
    """Which of the symmetric positive semi-definite matrices ``s`` (k, n, n) certainly have a
    least eigenvalue (as LAPACK computes it) above ``base (1 + 1e-9) + 2e-10 trace(s)`` (k,):
    those for which ``s - tau I``, ``tau = base (1 + 1e-9) + 2.1e-10 trace(s)``, has a Cholesky
    factorisation (a stacked one, written out over the stack). False decides nothing (the caller
    computes those matrices' eigenvalues).

    Notes
    -----
    A Cholesky factorisation that succeeds in floating point is exact for ``s - tau I + E`` with
    ``|E|`` of the order of ``n^2 eps trace(s)`` (below ``1e-14 trace(s)`` for n <= 6) [5, thm.
    10.3], so the exact least eigenvalue exceeds ``tau - 1e-14 trace(s)`` and LAPACK's, backward
    stable, exceeds ``base (1 + 1e-9) + 2e-10 trace(s)``. On the sets of a frame the checks of
    :func:`_fit_stack` pass by orders of magnitude, and the stacked eigenvalue calls are saved.

    References
    ----------
    .. [5] N. J. Higham, *Accuracy and Stability of Numerical Algorithms*, 2nd ed., SIAM, 2002.
           https://doi.org/10.1137/1.9780898718027
    """
    k, n = s.shape[0], s.shape[1]
    tau = base * (1.0 + 1e-9) + 2.1e-10 * np.trace(s, axis1=1, axis2=2)
    low = np.zeros_like(s)
    ok = np.ones(k, dtype=bool)
    for j in range(n):
        d = s[:, j, j] - tau - np.einsum("kq,kq->k", low[:, j, :j], low[:, j, :j])
        ok &= d > 0.0
        ljj = np.sqrt(np.where(ok, d, 1.0))
        low[:, j, j] = ljj
        low[:, j + 1:, j] = (s[:, j + 1:, j] - np.einsum("kiq,kq->ki", low[:, j + 1:, :j], low[:, j, :j])) / ljj[:, None]
    return ok


def ellipses_of(c: np.ndarray):
    """Ellipse parameters of symmetric finite point conics, stacked.

    Parameters
    ----------
    c : ndarray of shape (k, 3, 3)
        Symmetric point conics (any scale or sign), finite.

    Returns
    -------
    ok : ndarray of shape (k,), bool
        Which are real ellipses (not imaginary, a hyperbola, a parabola, a point or lines); the
        other results are meaningless where not.
    centre : ndarray of shape (k, 2)
        Centres, in the conics' coordinates.
    axes : ndarray of shape (k, 2)
        Semi-axes, a >= b.
    angle : ndarray of shape (k,)
        Angle of the major axis from +u toward +v, rad, in (-pi/2, pi/2].

    Notes
    -----
    The classification of :func:`simtest.geometry.conics.conic_kind` (in the frame centred on the
    conic's centre it reads diag-block (A2, f0)), with ``TOL.conic_degenerate_rel`` as the
    relative size under which an eigenvalue of the quadratic part, or the conic's value at its
    centre, counts as zero; then the axes from the eigen-decomposition of A2 made positive
    definite.
    """
    eps = TOL.conic_degenerate_rel
    norm = np.sqrt(_sum_rows((c * c).reshape(len(c), 9).T))
    ok = norm > 0.0
    # scaled to unit norm, the sign made that of a positive trace (the centre is the same)
    cn = c * (np.where(c[:, 0, 0] + c[:, 1, 1] < 0, -1.0, 1.0) / np.where(ok, norm, 1.0))[:, None, None]
    w, vec = np.linalg.eigh(cn[:, :2, :2])  # ascending: w[:, 0] gives the major axis
    lam_max = np.abs(w).max(axis=1)
    det = w[:, 0] * w[:, 1]
    ok &= (lam_max > eps) & (np.abs(det) > eps * lam_max**2)  # else a parabola or lines (no centre)
    a, b, d = cn[:, 0, 0], cn[:, 0, 1], cn[:, 1, 1]
    det2 = np.where(ok, a * d - b * b, 1.0)  # the centre -A2^-1 (g, h) by Cramer's rule
    g, h = cn[:, 0, 2], cn[:, 1, 2]
    centre = np.stack([-(d * g - b * h) / det2, -(a * h - b * g) / det2], axis=1)
    cross = cn[:, 2, 0] * centre[:, 0] + cn[:, 2, 1] * centre[:, 1]
    f0 = cn[:, 2, 2] + cross
    ok &= np.abs(f0) > eps * np.maximum(lam_max, np.abs(cn[:, 2, 2]) + np.abs(cross))  # else a point or line pair
    ok &= (det > 0) & (f0 < 0)  # else a hyperbola, or imaginary
    angle = np.arctan2(vec[:, 1, 0], vec[:, 0, 0])
    angle = np.where(angle <= -np.pi / 2, angle + np.pi, np.where(angle > np.pi / 2, angle - np.pi, angle))
    with np.errstate(invalid="ignore", divide="ignore"):
        axes = np.sqrt(-f0[:, None] / w)
    return ok, centre, axes, angle


def _fit_stack(pts, n, starts, item, bad_rows):
    """The fits of :func:`fit_ellipses` of the point sets concatenated in ``pts`` (M, 2): set j has
    ``n[j]`` >= 6 points from row ``starts[j]``; ``item`` (M,) is each row's set."""
    k = len(n)
    fail: list = [None] * k
    alive = np.ones(k, dtype=bool)  # no failure yet

    def refuse(mask, reason, detail):
        mask = mask & alive
        if mask.any():
            for j in np.flatnonzero(mask):
                fail[j] = Failure(reason, detail(j))
            alive[mask] = False

    refuse(bad_rows > 0, "non_finite_points", lambda j: f"{int(bad_rows[j])} of {int(n[j])} points")
    clean = np.where(np.isfinite(pts), pts, 0.0) if (bad_rows > 0).any() else pts
    mean = _segment_sums(clean, starts) / n[:, None]
    centred = clean - mean[item]
    scale = np.sqrt(_segment_sums((centred**2).sum(axis=1), starts) / n)
    refuse(~(scale > 0.0), "degenerate_points", lambda j: "all points coincide")
    safe_scale = np.where(scale > 0.0, scale, 1.0)
    xy = (centred / safe_scale[item][:, None]).T  # (2, M): each coordinate's row contiguous
    x, y = xy[0], xy[1]

    # Scatter matrix S = D^T D [eqn. 17] from [1], from the sums of the monomials x^i y^j
    xp = np.empty((5, len(x)))
    yp = np.empty((5, len(x)))
    for pw, v in ((xp, x), (yp, y)):
        pw[0] = 1.0
        pw[1] = v
        np.multiply(v, v, out=pw[2])
        np.multiply(pw[2], v, out=pw[3])
        np.multiply(pw[2], pw[2], out=pw[4])
    mono = xp[_MONO_I] * yp[_MONO_J]  # (15, M)
    # (k, 6, 6), C-contiguous: matmul's result on a strided stack depends on the stack's size
    s_full = np.ascontiguousarray(np.add.reduceat(mono, starts, axis=1).T[:, _S_INDEX])
    if not alive.all():
        s_full[~alive] = np.eye(6)
    s1, s2, s3 = s_full[:, :3, :3], s_full[:, :3, 3:], s_full[:, 3:, 3:]
    # collinear points: S3 near singular (its eigenvalues only where a Cholesky bound leaves doubt)
    shortcut = k >= _SHORTCUT_MIN_SETS
    doubt = (np.flatnonzero(~_least_eigenvalue_above(s3, _S3_RCOND * np.trace(s3, axis1=1, axis2=2)))
             if shortcut else np.arange(k))
    if len(doubt):
        ev3 = np.full((k, 3), 1.0)
        ev3[doubt] = np.linalg.eigvalsh(s3[doubt])
        refuse(~(ev3[:, 0] > _S3_RCOND * ev3[:, -1]), "degenerate_points",
               lambda j: f"linear scatter is singular (eigenvalues {ev3[j].tolist()})")
        if not alive.all():
            s_full[~alive] = np.eye(6)
    # T = -S3^-1 S2^T, so that a2 = T a1 [eqn. 24] from [1]
    t = -np.linalg.solve(s3, np.swapaxes(s2, 1, 2))
    # Reduced scatter matrix M = C1^-1 (S1 + S2 T) [eqn. 29] from [1]
    m = _C1_INV @ (s1 + s2 @ t)
    usable = alive & np.isfinite(m).all(axis=(1, 2))
    if not usable.all():
        m = np.where(usable[:, None, None], m, np.eye(3))
    # M a1 = lambda a1: eigenvectors of the reduced problem [eqn. 28] from [1]
    eigvec = np.real(np.linalg.eig(m)[1])
    # The ellipse solution satisfies the constraint a1^T C1 a1 = 4ac - b^2 > 0 [eqn. 14/30] from [1]
    cond = 4.0 * eigvec[:, 0] * eigvec[:, 2] - eigvec[:, 1] ** 2  # (k, 3): one per eigenvector
    valid = cond > 0
    refuse(~valid.any(axis=1), "not_an_ellipse", lambda j: "no eigenvector meets 4ac - b^2 > 0")
    # coefficient vectors (a, b, c, d, e, f) of the three eigenvectors [eqn. 19] from [1]
    cand = np.concatenate([eigvec, t @ eigvec], axis=1)  # (k, 6, 3)
    # normally one is valid; with rounding keep the smallest algebraic residual |D a|^2 = a^T S a
    prod = cand * (s_full @ cand)
    resid = _sum_rows([prod[:, i] for i in range(6)])
    best = np.argmin(np.where(valid, resid, np.inf), axis=1)
    a_vec = cand[np.arange(k), :, best]  # (k, 6)

    # Ellipse-specific fitting always returns an ellipse, even for points on a hyperbola or a line
    # pair. Guard: the unconstrained algebraic fit (smallest eigenvector of S [eqn. 17] from [1])
    # is the exact conic of noise-free data; if it is not an ellipse and explains the points
    # clearly better (algebraic residual 4x smaller), the data are not an ellipse.
    prod, sq = a_vec * (s_full @ a_vec[:, :, None])[:, :, 0], a_vec * a_vec
    r_ellipse = _sum_rows([prod[:, i] for i in range(6)]) / _sum_rows([sq[:, i] for i in range(6)])
    doubt = np.flatnonzero(alive & (r_ellipse > 1e-24)
                           & (~_least_eigenvalue_above(s_full, r_ellipse / 3.96) if shortcut else True))
    if len(doubt):
        w_full = np.linalg.eigvalsh(s_full[doubt])
        doubt = doubt[r_ellipse[doubt] > 3.96 * np.maximum(w_full[:, 0] - 1e-12 * w_full[:, -1], 0.0)]
    for j in doubt.tolist():  # eigh's own eigenvalue and vector where it matters
        w_j, v_j = np.linalg.eigh(s_full[j])
        r_gen = max(float(w_j[0]), 0.0)
        if r_ellipse[j] > 4.0 * r_gen:
            g = v_j[:, 0]
            g_conic = np.array([[g[0], g[1] / 2, g[3] / 2], [g[1] / 2, g[2], g[4] / 2], [g[3] / 2, g[4] / 2, g[5]]])
            kind = conic_kind(g_conic)
            if kind != "ellipse":
                refuse(np.arange(k) == j, "not_an_ellipse", lambda _: (
                    f"the points fit a {kind} better (algebraic residual {r_gen:.3g} vs {r_ellipse[j]:.3g})"))

    # Point conic in normalised coordinates, then back to pixels: C = T^T A T with x' = T x.
    a_norm = a_vec[:, _CONIC_OF_COEFFS] * _CONIC_HALVES  # the symmetric conic of (a, b, c, d, e, f)
    tmat = np.zeros((k, 3, 3))
    tmat[:, 0, 0] = tmat[:, 1, 1] = 1 / safe_scale
    tmat[:, 0, 2] = -mean[:, 0] / safe_scale
    tmat[:, 1, 2] = -mean[:, 1] / safe_scale
    tmat[:, 2, 2] = 1.0
    conic = np.swapaxes(tmat, 1, 2) @ a_norm @ tmat
    conic = 0.5 * (conic + np.swapaxes(conic, 1, 2))
    conic = conic / np.sqrt(_sum_rows((conic * conic).reshape(k, 9).T))[:, None, None]
    conic = np.where((conic[:, 0, 0] + conic[:, 1, 1] < 0)[:, None, None], -conic, conic)
    refuse(~np.isfinite(conic).all(axis=(1, 2)), "degenerate_points", lambda j: "non-finite conic")
    # Ellipse parameters from the conic of the *normalised* points, then back to pixels: a unit-norm
    # pixel conic of a few-px ellipse ~10^3 px from the origin has singular values down to ~1e-13,
    # where a degeneracy test in pixel coordinates would misclassify it; the normalised conic is
    # O(1)-conditioned for any ellipse.
    usable = alive & np.isfinite(a_norm).all(axis=(1, 2))
    is_ellipse, centre, axes, angle = ellipses_of(
        a_norm if usable.all() else np.where(usable[:, None, None], a_norm, np.eye(3)))
    refuse(~is_ellipse, "not_an_ellipse", lambda j: "the fitted conic is not a real ellipse")
    # Points on a line or two parallel lines are fitted exactly by ever longer ellipses: an ellipse
    # far larger than the points' spread is not determined by them.
    spread = np.sqrt(np.maximum.reduceat(x * x + y * y, starts))
    refuse(axes[:, 0] > MAX_AXIS_TO_SPREAD * spread, "not_an_ellipse", lambda j: (
        f"unbounded: semi-major axis {scale[j] * axes[j, 0]:.4g} px is more than "
        f"{MAX_AXIS_TO_SPREAD:g} times the points' spread (a line or parallel lines)"))
    # RMS Sampson distance of each set's points to its conic, px
    c9 = conic.reshape(k, 9).T[:, item]  # (9, M): each point's conic, row by row
    u, v = clean[:, 0], clean[:, 1]
    gu = c9[0] * u + c9[1] * v + c9[2]  # half the gradient of x^T C x
    gv = c9[3] * u + c9[4] * v + c9[5]
    dist = np.abs(gu * u + gv * v + c9[6] * u + c9[7] * v + c9[8]) / np.maximum(2.0 * np.hypot(gu, gv), _TINY)
    residual = np.sqrt(_segment_sums(dist**2, starts) / n).tolist()
    # each ellipse's centre and semi-axes rows of two arrays (views made at once, not two arrays a fit)
    centres = list(mean + scale[:, None] * centre)
    semi = list(scale[:, None] * axes)
    out = []
    for j, (cen, ax, ang, r, nj) in enumerate(zip(centres, semi, angle.tolist(), residual, n.tolist())):
        out.append(fail[j] if fail[j] is not None else EllipseFit(conic[j], Ellipse(cen, ax, ang), r, nj))
    return out
