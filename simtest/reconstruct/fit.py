"""Direct least-squares ellipse fit (Fitzgibbon et al. 1999 [2]_, in the Halir-Flusser form [1]_).

Step 2 of the method [4]_: the isophote points, centred and scaled to unit RMS radius, are fitted
by the closed-form ellipse-specific least-squares conic. The result is the 3x3 point conic C in
pixel coordinates (``x^T C x = 0`` for ``x = (u, v, 1)``), the ellipse parameters, and an RMS
Sampson residual [3]_ in pixels. A failed fit returns a falsy
:class:`~simtest.reconstruct.failures.Failure` naming its cause; a wrong array shape raises ValueError.

Not ``cv2.fitEllipse``: it switches algorithm or falls back to a circle on near-circular point
sets, which the isophotes of a fronto-parallel patch are (``tests/test_fit.py``).

References
----------
.. [1] R. Halir and J. Flusser, "Numerically stable direct least squares fitting of ellipses",
       Proc. WSCG 1998, pp. 125-132 (equation numbers as in scikit-image's ``EllipseModel``).
.. [2] A. Fitzgibbon, M. Pilu and R. B. Fisher, "Direct least square fitting of ellipses",
       IEEE TPAMI 21(5):476-480, 1999. https://doi.org/10.1109/34.765658
.. [3] R. Hartley, A. Zisserman, Multiple View Geometry, 2nd ed., 2003, sec. 4.2.6 (Sampson
       error). https://doi.org/10.1017/CBO9780511811685
.. [4] K. Makki, A. Bartoli, "Normal Reconstruction from Specularity in the Endoscopic Setting",
       section 2.3, step 2.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from simtest.decisions import MIN_FIT_POINTS, MAX_AXIS_TO_SPREAD
from simtest.geometry.conics import Ellipse, conic_kind
from simtest.reconstruct.failures import Failure
from simtest.tolerances import TOL

#: Reciprocal condition number of the (normalised) linear scatter S3 below which the points are
#: called collinear: S3 of centred unit-RMS points has eigenvalues O(1) unless they are degenerate.
_S3_RCOND = 1e-10
#: Exponents (i, j) of the monomials x^i y^j whose sums make the scatter matrix S = D^T D of the
#: design rows d = (x^2, xy, y^2, x, y, 1): every product d_a d_b is one of these 15.
_MONOMIALS = [(i, s - i) for s in range(5) for i in range(s, -1, -1)]
_D_EXPONENTS = [(2, 0), (1, 1), (0, 2), (1, 0), (0, 1), (0, 0)]
#: ``S[a, b]`` is the sum of monomial ``_S_INDEX[a, b]`` (6, 6).
_S_INDEX = np.array([[_MONOMIALS.index((a[0] + b[0], a[1] + b[1])) for b in _D_EXPONENTS] for a in _D_EXPONENTS])
#: Inverse of the constraint matrix C1 of 4ac - b^2 = 1 [eqn. 18 of 1].
_C1_INV = np.linalg.inv(np.array([[0.0, 0.0, 2.0], [0.0, -1.0, 0.0], [2.0, 0.0, 0.0]]))


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


def fit_ellipse(points_uv) -> EllipseFit | Failure:
    """Fit an ellipse to 2D points by direct least squares (one call of :func:`fit_ellipses`).

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
    """Fit one ellipse to each of several point sets, batched.

    Each set is centred and scaled to unit RMS distance from its mean; the scatter matrix of the
    design rows (x^2, xy, y^2, x, y, 1) [eqn. 17 of 1] comes from the sums of the 15 monomials of
    each set, then the reduced 3 x 3 eigenproblem [eqn. 28-29 of 1]. A set's fit does not depend on
    the other sets of the batch.

    Parameters
    ----------
    points_list : sequence of array_like of shape (N_i, 2)
        Point sets (u, v) in pixels, each N_i >= 6 to be fitted.

    Returns
    -------
    list of EllipseFit or Failure
        One per point set, in order; failure reasons as :func:`fit_ellipse`.

    Raises
    ------
    ValueError
        If a point set is not of shape (N, 2).
    """
    pts_all = point_sets(points_list)
    if not pts_all:
        return []
    return fit_stacked(np.concatenate(pts_all, axis=0), np.array([len(p) for p in pts_all], dtype=np.int64))


def fit_stacked(pts: np.ndarray, counts: np.ndarray) -> list[EllipseFit | Failure]:
    """:func:`fit_ellipses` of point sets given concatenated (closed forms over the stack, LAPACK
    where a closed form declines).

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
    """
    counts = np.asarray(counts, dtype=np.int64)
    pts = np.asarray(pts, dtype=np.float64)
    few = counts < MIN_FIT_POINTS
    fits = iter(() if few.all() else _fit_stack(pts[np.repeat(~few, counts)] if few.any() else pts, counts[~few]))
    return [Failure("too_few_points", f"{c} points < {MIN_FIT_POINTS}") if f else next(fits)
            for f, c in zip(few.tolist(), counts.tolist())]


#: Degree i + j of each monomial x^i y^j (:data:`_MONOMIALS`), and where x^2, y^2 are among them.
_DEGREE = np.array([i + j for i, j in _MONOMIALS], dtype=float)
_X2, _Y2 = _MONOMIALS.index((2, 0)), _MONOMIALS.index((0, 2))
#: The monomials of the linear scatter S3's cofactors ``cof[i, j] = S3[i1, j1] S3[i2, j2] -
#: S3[i1, j2] S3[i2, j1]`` (i1 = i + 1, i2 = i + 2 mod 3, likewise j), S3's entries being
#: ``_S_INDEX[3 + i, 3 + j]``.
_CYC1, _CYC2 = np.array([1, 2, 0]), np.array([2, 0, 1])
_COF_A = _S_INDEX[3 + _CYC1[:, None], 3 + _CYC1[None, :]]
_COF_B = _S_INDEX[3 + _CYC2[:, None], 3 + _CYC2[None, :]]
_COF_C = _S_INDEX[3 + _CYC1[:, None], 3 + _CYC2[None, :]]
_COF_D = _S_INDEX[3 + _CYC2[:, None], 3 + _CYC1[None, :]]
#: The row pairs whose cross products :func:`_null_vectors` compares.
_ROW_A, _ROW_B = np.array([0, 0, 1]), np.array([1, 2, 2])
_EYE3 = np.eye(3)
_THIRDS = 2.0 * np.pi / 3.0 * np.arange(3)
_ZERO = np.zeros(1, dtype=np.int64)


def _null_vectors(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit null vectors of rank-2 3 x 3 matrices (..., 3, 3) (the largest cross product of two rows,
    sign arbitrary), and which are defined (...,) bool.
    """
    ra, rb = a[..., _ROW_A, :], a[..., _ROW_B, :]
    cr = ra[..., _CYC1] * rb[..., _CYC2] - ra[..., _CYC2] * rb[..., _CYC1]  # (..., 3 pairs, 3)
    n2 = (cr * cr).sum(axis=-1)
    flat = n2.reshape(-1, 3)
    best = flat.argmax(axis=1) + np.arange(0, flat.size, 3)
    nb = flat.reshape(-1)[best]
    ok = (nb > 0) & (nb < np.inf)
    v = cr.reshape(-1, 3)[best] / np.sqrt(nb)[:, None]
    return v.reshape(a.shape[:-1]), ok.reshape(a.shape[:-2])


def _cubic_roots(m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The eigenvalues (k, 3) of 3 x 3 matrices (k, 3, 3) with three real distinct ones (trigonometric
    formula), and where that holds (k,) bool.
    """
    sh = (m[:, 0, 0] + m[:, 1, 1] + m[:, 2, 2]) / 3.0
    b = m - sh[:, None, None] * _EYE3
    # b's cubic mu^3 - p mu - q = 0 (mu = lambda - tr/3): p = tr(b^2) / 2 (b is traceless), q = det b
    p = (b * b.transpose(0, 2, 1)).sum(axis=2).sum(axis=1) / 6.0  # p / 3
    r = np.sqrt(p)
    c = np.linalg.det(b) / (2.0 * r * r * r)
    ok = (p > 0) & (np.abs(c) < 1.0)  # False for NaN
    lam = sh[:, None] + (2.0 * r)[:, None] * np.cos((np.arccos(c) / 3.0)[:, None] - _THIRDS)
    return lam, ok


def _eigh2(a, b, c):
    """The eigenvalues (lo <= hi) of symmetric 2 x 2 matrices [[a, b], [b, c]] and the unit eigenvector
    (x, y) of lo, in closed form ((1, 0) for a multiple of the identity).
    """
    mid = 0.5 * (a + c)
    half = np.hypot(0.5 * (a - c), b)
    big = mid + np.copysign(half, mid)
    small = (a * c - b * b) / big  # NaN where big == 0 (the zero matrix): handled by the caller
    lo, hi = np.minimum(small, big), np.maximum(small, big)
    # the eigenvector of lo: the longer of (b, lo - a) and (lo - c, b)
    x, y, x1 = b, lo - a, lo - c
    second = x1 * x1 > y * y
    if second.any():
        x, y = np.where(second, x1, x), np.where(second, b, y)
    n = np.hypot(x, y)
    if not (n > 0).all():
        x, y, n = np.where(n > 0, x, 1.0), np.where(n > 0, y, 0.0), np.where(n > 0, n, 1.0)
    return lo, hi, x / n, y / n


def _positive_definite(s: np.ndarray, tau: np.ndarray, which: np.ndarray) -> np.ndarray:
    """Where ``which`` (k,) bool: whether the symmetric ``s - tau I`` (k, n, n) has a Cholesky
    factorisation (least eigenvalue certainly above ``tau`` [Higham, thm. 10.3]); False elsewhere.
    """
    n = s.shape[1]
    shifted = s - tau[:, None, None] * np.eye(n)
    if not which.all():
        shifted[~which] = np.eye(n)
    try:
        np.linalg.cholesky(shifted)
        return which
    except np.linalg.LinAlgError:
        pass
    low = np.zeros_like(shifted)
    ok = which.copy()
    for j in range(n):
        d = shifted[:, j, j] - (low[:, j, :j] ** 2).sum(axis=1)
        ok &= d > 0
        root = np.sqrt(np.where(ok, d, 1.0))
        low[:, j, j] = root
        low[:, j + 1:, j] = (shifted[:, j + 1:, j] - (low[:, j + 1:, :j] * low[:, j, None, :j]).sum(axis=2)) / root[:, None]
    return ok


def _ellipse_params(c: np.ndarray):
    """Centres (k, 2), semi-axes (a >= b) (k, 2), angles (k,) rad and which are real ellipses (k,) bool
    of symmetric finite conics (k, 3, 3), as :func:`simtest.geometry.conics.conic_to_ellipse` measures one, in closed form.
    """
    eps = TOL.conic_degenerate_rel
    norm = np.sqrt((c * c).sum(axis=2).sum(axis=1))
    # unit norm, the quadratic part made positive (trace >= 0)
    cn = c / np.copysign(norm, c[:, 0, 0] + c[:, 1, 1])[:, None, None]
    a, b, d, g, h = cn[:, 0, 0], cn[:, 0, 1], cn[:, 1, 1], cn[:, 0, 2], cn[:, 1, 2]
    lo, hi, vx, vy = _eigh2(a, b, d)  # ascending: lo gives the major axis
    lam_max = np.maximum(np.abs(lo), np.abs(hi))
    centred = (lam_max > eps) & (np.abs(lo * hi) > eps * lam_max**2)  # else no centre (or NaN)
    det = a * d - b * b
    cu, cv = (b * h - d * g) / det, (b * g - a * h) / det
    cross = cn[:, 2, 0] * cu + cn[:, 2, 1] * cv
    f0 = cn[:, 2, 2] + cross
    point = np.abs(f0) <= eps * np.maximum(lam_max, np.abs(cn[:, 2, 2]) + np.abs(cross))
    ok = centred & ~point & (lo * hi > 0) & (f0 < 0)  # not a point, hyperbola or imaginary
    angle = np.arctan2(vy, vx)
    angle += np.pi * ((angle <= -np.pi / 2).astype(float) - (angle > np.pi / 2))
    axes = np.sqrt(-f0[:, None] / np.column_stack([lo, hi]))
    return np.column_stack([cu, cv]), axes, angle, ok


@np.errstate(all="ignore")
def _fit_stack(pts: np.ndarray, n: np.ndarray) -> list[EllipseFit | Failure]:
    """The fits of :func:`fit_stacked`, set j having ``n[j]`` >= 6 points."""
    k = len(n)
    if k == 1:
        starts = _ZERO
    else:
        starts = np.zeros(k, dtype=np.int64)
        np.cumsum(n[:-1], out=starts[1:])
    fail: list = [None] * k
    alive = np.ones(k, dtype=bool)  # no failure yet

    def refuse(mask, reason, detail):
        mask = mask & alive
        if mask.any():
            for j in np.flatnonzero(mask):
                fail[j] = Failure(reason, detail(j))
            alive[mask] = False

    if not np.isfinite(pts).all():
        finite = np.isfinite(pts)
        bad_rows = np.add.reduceat((~finite.all(axis=1)).astype(np.int64), starts)
        refuse(bad_rows > 0, "non_finite_points", lambda j: f"{int(bad_rows[j])} of {int(n[j])} points")
        pts = np.where(finite, pts, 0.0)
    mean = np.add.reduceat(pts, starts, axis=0) / n[:, None]
    # powers x^i, y^i (i = 0..4) of the centred points (5, 2, M), each row contiguous
    pw = np.empty((5, 2, len(pts)))
    pw[0] = 1.0
    np.subtract(pts.T, np.repeat(mean, n, axis=0).T, out=pw[1])
    np.multiply(pw[1], pw[1], out=pw[2])
    np.multiply(pw[2], pw[1], out=pw[3])
    np.multiply(pw[2], pw[2], out=pw[4])
    mono = np.empty((len(_MONOMIALS), len(pts)))
    for q, (i, j) in enumerate(_MONOMIALS):
        np.multiply(pw[i, 0], pw[j, 1], out=mono[q])
    sums = np.add.reduceat(mono, starts, axis=1).T  # (k, 15)
    # the points scaled to unit RMS distance from their mean: x^i y^j sums over scale^(i + j)
    scale2 = (sums[:, _X2] + sums[:, _Y2]) / n
    scale = np.sqrt(scale2)
    refuse(~(scale > 0.0), "degenerate_points", lambda j: "all points coincide")
    sums = sums / scale[:, None] ** _DEGREE
    spread = np.sqrt(np.maximum.reduceat(pw[2, 0] + pw[2, 1], starts) / scale2)
    # Scatter matrix S = D^T D [eqn. 17] from [1], from the sums of the monomials x^i y^j
    s_full = sums[:, _S_INDEX]  # (k, 6, 6)
    s1, s2, s3 = s_full[:, :3, :3], s_full[:, :3, 3:], s_full[:, 3:, 3:]
    # Collinear points: the linear scatter's eigenvalues ev3[0] <= s3_rcond ev3[2] (bounded by
    # det / (tr / 2)^2 and tr first; LAPACK decides the others)
    cof = sums[:, _COF_A] * sums[:, _COF_B] - sums[:, _COF_C] * sums[:, _COF_D]  # S3's, symmetric
    det = (s3[:, 0] * cof[:, 0]).sum(axis=1)
    tr3 = s3[:, 0, 0] + s3[:, 1, 1] + s3[:, 2, 2]
    unsure = ~(4.0 * det > (_S3_RCOND * (1 + 1e-9) + 2.1e-10) * tr3 * tr3 * tr3) & alive
    if unsure.any():
        ev3 = np.full((k, 3), np.nan)
        ev3[unsure] = np.linalg.eigvalsh(s3[unsure])
        refuse(unsure & ~(ev3[:, 0] > _S3_RCOND * ev3[:, -1]), "degenerate_points",
               lambda j: f"linear scatter is singular (eigenvalues {ev3[j].tolist()})")
    # T = -S3^-1 S2^T, so that a2 = T a1 [eqn. 24] from [1] (S3^-1: cofactors over determinant)
    t = -(cof / det[:, None, None]) @ s2.transpose(0, 2, 1)
    # Reduced scatter matrix M = C1^-1 (S1 + S2 T) [eqn. 29] from [1]
    m = _C1_INV @ (s1 + s2 @ t)
    usable = alive & np.isfinite(m).all(axis=(1, 2))
    if not usable.all():
        m[~usable] = _EYE3
    # M a1 = lambda a1: eigenvectors of the reduced problem [eqn. 28] from [1], as columns
    lam, closed = _cubic_roots(m)
    vec, defined = _null_vectors(m[:, None] - lam[:, :, None, None] * _EYE3)
    eigvec = vec.transpose(0, 2, 1)
    lapack = ~(closed & defined.all(axis=1)) & usable
    if lapack.any():  # complex or repeated eigenvalues
        eigvec[lapack] = np.real(np.linalg.eig(m[lapack])[1])
    # The ellipse solution satisfies the constraint a1^T C1 a1 = 4ac - b^2 > 0 [eqn. 14/30] from [1]
    valid = 4.0 * eigvec[:, 0] * eigvec[:, 2] - eigvec[:, 1] * eigvec[:, 1] > 0  # (k, 3)
    if not usable.all():
        valid &= usable[:, None]
    refuse(~valid.any(axis=1), "not_an_ellipse", lambda j: "no eigenvector meets 4ac - b^2 > 0")
    # coefficient vectors (a, b, c, d, e, f) of the three eigenvectors [eqn. 19] from [1]
    cand = np.concatenate([eigvec, t @ eigvec], axis=1)  # (k, 6, 3)
    # normally one is valid; with rounding keep the smallest algebraic residual |D a|^2 = a^T S a
    resid = (cand * (s_full @ cand)).sum(axis=1)
    resid[~valid] = np.inf
    best = resid.argmin(axis=1) + np.arange(0, 3 * k, 3)
    a_vec = cand.transpose(0, 2, 1).reshape(-1, 6)[best]  # (k, 6)
    _guard(s_full, a_vec, alive, refuse)

    # Point conic in normalised coordinates, then back to pixels: C = T^T A T with x' = T x.
    a_norm = np.ascontiguousarray(a_vec[:, _CONIC_OF]) * _CONIC_HALVES
    tmat = np.zeros((k, 3, 3))
    tmat[:, 0, 0] = tmat[:, 1, 1] = 1 / scale
    tmat[:, :2, 2] = -mean / scale[:, None]
    tmat[:, 2, 2] = 1.0
    conic = tmat.transpose(0, 2, 1) @ a_norm @ tmat
    conic = conic + conic.transpose(0, 2, 1)  # symmetric (the factor 1/2 goes in the norm)
    norm = np.sqrt((conic * conic).sum(axis=2).sum(axis=1))
    conic /= np.copysign(norm, conic[:, 0, 0] + conic[:, 1, 1])[:, None, None]
    refuse(~np.isfinite(conic).all(axis=(1, 2)), "degenerate_points", lambda j: "non-finite conic")
    # Ellipse parameters from the conic of the *normalised* points (O(1)-conditioned), then back to
    # pixels: a pixel conic far from the origin is too ill-conditioned for a degeneracy test
    centre, axes, angle, is_ellipse = _ellipse_params(a_norm)
    refuse(~is_ellipse, "not_an_ellipse", lambda j: "the fitted conic is not a real ellipse")
    # Points on a line or two parallel lines are fitted exactly by ever longer ellipses: an ellipse
    # far larger than the points' spread is not determined by them.
    refuse(axes[:, 0] > MAX_AXIS_TO_SPREAD * spread, "not_an_ellipse", lambda j: (
        f"unbounded: semi-major axis {scale[j] * axes[j, 0]:.4g} px is more than "
        f"{MAX_AXIS_TO_SPREAD:g} times the points' spread (a line or parallel lines)"))
    # RMS Sampson distance of each set's points to its conic, px: |x^T C x| / ||grad (x^T C x)||
    c = np.repeat(conic.reshape(k, 9)[:, _SAMPSON_TERMS].T, n, axis=1)  # c00 c01 c02 c11 c12 c22 (6, M)
    u, v = pts.T
    gu = c[0] * u + c[1] * v + c[2]
    gv = c[1] * u + c[3] * v + c[4]
    f = (gu + c[2]) * u + (gv + c[4]) * v + c[5]
    dist2 = f * f / np.maximum(4.0 * (gu * gu + gv * gv), np.finfo(float).tiny)
    residual = np.sqrt(np.add.reduceat(dist2, starts) / n).tolist()
    # each ellipse's centre and semi-axes rows of two arrays (views)
    centres = list(mean + scale[:, None] * centre)
    semi = list(scale[:, None] * axes)
    if alive.all():
        return [EllipseFit(c_j, Ellipse(m_j, s_j, ang), r, nj) for c_j, m_j, s_j, ang, r, nj in
                zip(conic, centres, semi, angle.tolist(), residual, n.tolist())]
    return [fail[j] if fail[j] is not None else EllipseFit(conic[j], Ellipse(centres[j], semi[j], ang), residual[j], nj)
            for j, (ang, nj) in enumerate(zip(angle.tolist(), n.tolist()))]


#: The conic matrix (3, 3) of a coefficient vector (a, b, c, d, e, f): its entries' indices and halves.
_CONIC_OF = np.array([[0, 1, 3], [1, 2, 4], [3, 4, 5]])
_CONIC_HALVES = np.array([[1.0, 0.5, 0.5], [0.5, 1.0, 0.5], [0.5, 0.5, 1.0]])
#: Flat indices of c00, c01, c02, c11, c12, c22 in a 3 x 3 conic.
_SAMPSON_TERMS = np.array([0, 1, 2, 4, 5, 8])


def _guard(s_full: np.ndarray, a_vec: np.ndarray, alive: np.ndarray, refuse) -> None:
    """Whether the points are not an ellipse: the unconstrained algebraic fit (smallest eigenvector of
    S [eqn. 17 of 1]) is not an ellipse and explains them clearly better (residual 4x smaller).
    """
    r_ellipse = (a_vec * (s_full @ a_vec[:, :, None])[:, :, 0]).sum(axis=1) / (a_vec * a_vec).sum(axis=1)
    check = alive & (r_ellipse > 1e-24)
    tr6 = (s_full[:, 0, 0] + s_full[:, 1, 1]) + (s_full[:, 2, 2] + s_full[:, 3, 3]) + (s_full[:, 4, 4] + s_full[:, 5, 5])
    check &= ~_positive_definite(s_full, r_ellipse / 3.96 * (1 + 1e-9) + 2.1e-10 * tr6, check)
    if not check.any():
        return
    idx = np.flatnonzero(check)
    w_full = np.linalg.eigvalsh(s_full[idx])
    for j, w in zip(idx.tolist(), w_full):
        if not r_ellipse[j] > 3.96 * max(w[0] - 1e-12 * w[-1], 0.0):
            continue
        w_j, v_j = np.linalg.eigh(s_full[j])  # eigh's own eigenvalue and vector where it matters
        r_gen = max(float(w_j[0]), 0.0)
        if r_ellipse[j] > 4.0 * r_gen:
            g = v_j[:, 0]
            g_conic = np.array([[g[0], g[1] / 2, g[3] / 2], [g[1] / 2, g[2], g[4] / 2], [g[3] / 2, g[4] / 2, g[5]]])
            kind = conic_kind(g_conic)
            if kind != "ellipse":
                refuse(np.arange(len(alive)) == j, "not_an_ellipse", lambda _: (
                    f"the points fit a {kind} better (algebraic residual {r_gen:.3g} vs {r_ellipse[j]:.3g})"))
