"""Compiled (numba) kernel of the batched ellipse fit (:mod:`simtest.reconstruct.fit`).

:func:`fit_conics` does, for every point set of a batch in one compiled call, what the numpy form
``simtest.reconstruct.fit._fit_stack`` does with some sixty numpy calls on the whole stack: the
centring and scaling, the sums of the 15 monomials, the reduced 3 x 3 problem of Halir and Flusser
[1] with the ellipse constraint of Fitzgibbon et al. [2], the conic back in pixels, its ellipse
parameters and the RMS Sampson residual. A frame has hundreds of isophotes and a lone highlight
one: there the fixed cost of each numpy call, not the arithmetic, was the time (about 0.4 ms per
call of the numpy form, a few microseconds per set here).

It takes the same floating-point steps in the same order, and the same LAPACK routines (numba
calls the ``dsyevd``, ``dgesv`` and ``dgeev`` of SciPy's OpenBLAS where numpy calls those of its
own), so its results agree with the numpy form to rounding (``tests/test_fit_kernels.py`` bounds
the difference; the numpy form stays in ``fit.py`` as the reference and the fallback).

Where the numpy form refuses a set, the kernel says only that it does and why (a status code):
``fit.py`` then refits that set with the numpy form, whose failure, with the numbers of its detail
string, is the one reported. The kernel also hands over (:data:`SUSPECT`) the sets where the guard
against non-ellipses needs the full eigen-decomposition of the 6 x 6 scatter matrix (points on a
hyperbola or a line pair), and those where LAPACK refuses (:data:`DECLINED`: complex eigenvalues of
the reduced problem, a singular system).

Notes
-----
Compiled with ``cache=True`` (see :mod:`simtest.reconstruct._kernels`). numba does not contract
``a * b + c`` into a fused multiply-add without ``fastmath`` (not set here).

References
----------
.. [1] R. Halir and J. Flusser, "Numerically stable direct least squares fitting of ellipses",
       Proc. WSCG 1998, pp. 125-132 (equation numbers as in :mod:`simtest.reconstruct.fit`).
.. [2] A. Fitzgibbon, M. Pilu and R. B. Fisher, "Direct least square fitting of ellipses",
       IEEE TPAMI 21(5):476-480, 1999. https://doi.org/10.1109/34.765658
"""

from __future__ import annotations

import math

import numba
import numpy as np

#: Exponents (i, j) of the monomials x^i y^j whose sums make the scatter matrix S = D^T D of the
#: design rows d = (x^2, xy, y^2, x, y, 1): every product d_a d_b is one of these 15.
MONOMIALS = [(i, s - i) for s in range(5) for i in range(s, -1, -1)]
_D_EXPONENTS = [(2, 0), (1, 1), (0, 2), (1, 0), (0, 1), (0, 0)]
#: ``S[a, b]`` is the sum of monomial ``S_INDEX[a, b]`` (6, 6).
S_INDEX = np.array([[MONOMIALS.index((a[0] + b[0], a[1] + b[1])) for b in _D_EXPONENTS]
                    for a in _D_EXPONENTS], dtype=np.int64)
_MONO_I = np.array([i for i, _ in MONOMIALS], dtype=np.int64)
_MONO_J = np.array([j for _, j in MONOMIALS], dtype=np.int64)
#: Inverse of the constraint matrix C1 of 4ac - b^2 = 1 [1, eqn. 18].
C1_INV = np.linalg.inv(np.array([[0.0, 0.0, 2.0], [0.0, -1.0, 0.0], [2.0, 0.0, 0.0]]))

#: :func:`fit_conics` status codes, in the order the numpy form checks.
OK = 0  #: fitted
NON_FINITE = 1  #: ``non_finite_points``
COINCIDENT = 2  #: ``degenerate_points``: all points coincide
SINGULAR_SCATTER = 3  #: ``degenerate_points``: the linear scatter S3 is singular (collinear points)
NO_ELLIPSE = 4  #: ``not_an_ellipse``: no eigenvector of the reduced problem meets 4ac - b^2 > 0
SUSPECT = 5  #: the guard against non-ellipses needs the full eigen-decomposition: numpy decides
NON_FINITE_CONIC = 6  #: ``degenerate_points``: non-finite conic
NOT_REAL_ELLIPSE = 7  #: ``not_an_ellipse``: the fitted conic is not a real ellipse
UNBOUNDED = 8  #: ``not_an_ellipse``: the ellipse is far larger than the points' spread
DECLINED = 9  #: LAPACK refused (complex eigenvalues, a singular system): numpy decides

#: Columns of :func:`fit_conics`' ellipse result.
CENTRE_U, CENTRE_V, SEMI_MAJOR, SEMI_MINOR, ANGLE = range(5)


@numba.njit(cache=True, nogil=True)
def _matmul3(a, b):
    """``a @ b`` of two 3 x 3 matrices, each entry summed in index order."""
    out = np.empty((3, 3))
    for i in range(3):
        for j in range(3):
            acc = a[i, 0] * b[0, j]
            for q in range(1, 3):
                acc += a[i, q] * b[q, j]
            out[i, j] = acc
    return out


@numba.njit(cache=True, nogil=True)
def _solve3(a, b):
    """``np.linalg.solve(a, b)`` of a 3 x 3 system with k right-hand sides (b (3, k)), written out:
    Gaussian elimination with partial pivoting (LAPACK's ``dgesv`` steps, without its call: a
    numba LAPACK call costs a few microseconds, the arithmetic tens of nanoseconds). Returns
    ``(ok, x)``; ok False where a pivot is exactly zero (LAPACK's refusal of a singular matrix)
    or not finite."""
    m = a.copy()
    x = b.copy()
    k = x.shape[1]
    for c in range(3):
        p = c
        best = abs(m[c, c])
        for r in range(c + 1, 3):
            if abs(m[r, c]) > best:
                p, best = r, abs(m[r, c])
        if not best > 0.0 or not math.isfinite(best):
            return False, x
        if p != c:
            for j in range(3):
                m[c, j], m[p, j] = m[p, j], m[c, j]
            for j in range(k):
                x[c, j], x[p, j] = x[p, j], x[c, j]
        for r in range(c + 1, 3):
            f = m[r, c] / m[c, c]
            for j in range(c + 1, 3):
                m[r, j] -= f * m[c, j]
            for j in range(k):
                x[r, j] -= f * x[c, j]
    for j in range(k):
        for r in range(2, -1, -1):
            acc = x[r, j]
            for q in range(r + 1, 3):
                acc -= m[r, q] * x[q, j]
            x[r, j] = acc / m[r, r]
    return True, x


@numba.njit(cache=True, nogil=True)
def _eig3_real(m):
    """The eigenvalues and unit eigenvectors (columns) of a real 3 x 3 matrix whose eigenvalues are
    real and distinct, in closed form (LAPACK's ``dgeev`` through numba cost more than the rest of
    a fit): the roots of the characteristic cubic by the trigonometric formula, each vector the
    largest cross product of two rows of ``m - lambda I`` (orthogonal to every row: its null
    vector). Returns ``(ok, lam, vec)``; ok False where the cubic has complex roots, a root is
    repeated or no cross product is nonzero (the caller declines the set: numpy's form decides).
    The vectors' signs are arbitrary (as LAPACK's: every use of them is sign-free)."""
    lam = np.empty(3)
    vec = np.empty((3, 3))
    tr = m[0, 0] + m[1, 1] + m[2, 2]
    # the cubic of the shifted matrix b = m - (tr / 3) I: mu^3 - p mu - q = 0, mu = lambda - tr / 3
    sh = tr / 3.0
    b00, b11, b22 = m[0, 0] - sh, m[1, 1] - sh, m[2, 2] - sh
    p = -((b00 * b11 - m[0, 1] * m[1, 0]) + (b00 * b22 - m[0, 2] * m[2, 0]) + (b11 * b22 - m[1, 2] * m[2, 1]))
    q = (b00 * (b11 * b22 - m[1, 2] * m[2, 1]) - m[0, 1] * (m[1, 0] * b22 - m[1, 2] * m[2, 0])
         + m[0, 2] * (m[1, 0] * m[2, 1] - b11 * m[2, 0]))
    if not (p > 0.0 and math.isfinite(p) and math.isfinite(q)):
        return False, lam, vec
    # three real roots: mu = 2 sqrt(p / 3) cos(phi / 3 - 2 pi j / 3), cos(phi) = (q / 2) / (p / 3)^1.5
    r = math.sqrt(p / 3.0)
    c = q / (2.0 * r * r * r)
    if not abs(c) < 1.0:  # complex (|c| > 1) or repeated (|c| = 1) roots
        return False, lam, vec
    phi = math.acos(c) / 3.0
    for j in range(3):
        lam[j] = sh + 2.0 * r * math.cos(phi - 2.0 * math.pi * j / 3.0)
    for j in range(3):
        a0 = (m[0, 0] - lam[j], m[0, 1], m[0, 2])
        a1 = (m[1, 0], m[1, 1] - lam[j], m[1, 2])
        a2 = (m[2, 0], m[2, 1], m[2, 2] - lam[j])
        best = 0.0
        for pair in range(3):
            u, w = (a0, a1) if pair == 0 else ((a0, a2) if pair == 1 else (a1, a2))
            cx = u[1] * w[2] - u[2] * w[1]
            cy = u[2] * w[0] - u[0] * w[2]
            cz = u[0] * w[1] - u[1] * w[0]
            n2 = cx * cx + cy * cy + cz * cz
            if n2 > best:
                best = n2
                vec[0, j], vec[1, j], vec[2, j] = cx, cy, cz
        if not (best > 0.0 and math.isfinite(best)):
            return False, lam, vec
        nrm = math.sqrt(best)
        for i in range(3):
            vec[i, j] /= nrm
    return True, lam, vec


@numba.njit(cache=True, nogil=True)
def _eigh2(a, b, c):
    """The eigenvalues (ascending) of the symmetric 2 x 2 matrix [[a, b], [b, c]] and the unit
    eigenvector (x, y) of the smaller, in closed form (``np.linalg.eigh``'s, to rounding; the
    vector's sign arbitrary). The smaller-magnitude eigenvalue is the determinant over the larger
    one (no cancellation)."""
    m = 0.5 * (a + c)
    d = math.hypot(0.5 * (a - c), b)
    big = m + d if m >= 0.0 else m - d
    small = (a * c - b * b) / big if big != 0.0 else 0.0
    lo, hi = (small, big) if small <= big else (big, small)
    # the eigenvector of lo: the larger of (b, lo - a) and (lo - c, b)
    x0, y0 = b, lo - a
    x1, y1 = lo - c, b
    if x1 * x1 + y1 * y1 > x0 * x0 + y0 * y0:
        x0, y0 = x1, y1
    n = math.hypot(x0, y0)
    if n > 0.0:
        return lo, hi, x0 / n, y0 / n
    return lo, hi, 1.0, 0.0


@numba.njit(cache=True, nogil=True)
def ellipse_of(c, eps):
    """Ellipse parameters of a symmetric finite point conic, as ``conics._ellipses_of`` of it.

    Parameters
    ----------
    c : ndarray of shape (3, 3)
        Symmetric point conic (any scale or sign), finite.
    eps : float
        ``TOL.conic_degenerate_rel``: the relative size under which an eigenvalue of the
        quadratic part, or the conic's value at its centre, counts as zero.

    Returns
    -------
    ok : bool
        Whether the conic is a real ellipse (not imaginary, a hyperbola, a parabola, a point or
        lines); the other results are meaningless where it is not.
    cu, cv : float
        Centre, in the conic's coordinates.
    a, b : float
        Semi-axes, a >= b.
    angle : float
        Angle of the major axis from +u toward +v, rad, in (-pi/2, pi/2].

    Notes
    -----
    The classification of ``conics._classify_many`` (in the frame centred on the conic's centre
    it reads diag-block (A2, f0)), then the axes from the eigen-decomposition of A2 after the
    sign is made positive definite.
    """
    norm = 0.0
    for i in range(3):
        for j in range(3):
            norm += c[i, j] * c[i, j]
    norm = math.sqrt(norm)
    if norm == 0.0:
        return False, np.nan, np.nan, np.nan, np.nan, np.nan
    cn = c / norm
    a, b, d = cn[0, 0], cn[0, 1], cn[1, 1]
    lam0, lam1, _, _ = _eigh2(a, b, d)
    lam_max = max(abs(lam0), abs(lam1))
    if lam_max <= eps or abs(lam0 * lam1) <= eps * lam_max**2:
        return False, np.nan, np.nan, np.nan, np.nan, np.nan  # a parabola, lines (no centre)
    # the centre -A2^-1 (g, h) by Cramer's rule (A2 is far from singular past the test above)
    det = a * d - b * b
    g, h = cn[0, 2], cn[1, 2]
    cu = -(d * g - b * h) / det
    cv = -(a * h - b * g) / det
    cross = cn[2, 0] * cu + cn[2, 1] * cv
    f0 = cn[2, 2] + cross
    if abs(f0) <= eps * max(lam_max, abs(cn[2, 2]) + abs(cross)):
        return False, np.nan, np.nan, np.nan, np.nan, np.nan  # a point or two crossing lines
    if lam0 * lam1 < 0 or (1.0 if lam0 > 0 else -1.0) * f0 >= 0:
        return False, np.nan, np.nan, np.nan, np.nan, np.nan  # a hyperbola or imaginary
    if a + d < 0:  # made positive definite: the centre is the same, f0 and the eigenvalues negated
        a, b, d, f0 = -a, -b, -d, -f0
    w0, w1, vx, vy = _eigh2(a, b, d)  # ascending: w0 gives the major axis
    angle = math.atan2(vy, vx)
    if angle <= -np.pi / 2:
        angle += np.pi
    elif angle > np.pi / 2:
        angle -= np.pi
    return True, cu, cv, math.sqrt(-f0 / w0), math.sqrt(-f0 / w1), angle


@numba.njit(cache=True, nogil=True)
def _least_eigenvalue_above(s, base):
    """Whether the least eigenvalue that LAPACK computes for the symmetric positive semi-definite
    matrix ``s`` (n x n, n <= 6) is certainly above ``base (1 + 1e-9) + 2e-10 trace(s)``, without
    computing it: ``s - tau I`` has a Cholesky factorisation, ``tau = base (1 + 1e-9) + 2.1e-10
    trace(s)``. False decides nothing (the caller computes the eigenvalues).

    Notes
    -----
    A Cholesky factorisation that succeeds in floating point is exact for ``s - tau I + E`` with
    ``|E|`` of the order of ``n^2 eps trace(s)`` (below ``1e-14 trace(s)`` here) [1, thm. 10.3],
    so the exact least eigenvalue exceeds ``tau - 1e-14 trace(s)``, and LAPACK's, backward stable
    with an error far below ``1e-13 trace(s)`` for such a matrix, exceeds ``base (1 + 1e-9) +
    2e-10 trace(s)``; the largest eigenvalue is at most ``trace(s)`` (to ``1e-13`` of it). The two
    checks of :func:`_fit_one` that read eigenvalues ask for less: the linear scatter's
    ``ev[0] > s3_rcond ev[2]`` (``base = s3_rcond trace``) and the guard against non-ellipses'
    ``r_ell <= 3.96 max(w0 - 1e-12 w5, 0)`` (``base = r_ell / 3.96``), each with room for the
    rounding of its product. On the sets of a frame both pass by orders of magnitude and the
    eigenvalue calls (LAPACK through numba, 2.5 and 4 us) are saved.

    References
    ----------
    .. [1] N. J. Higham, *Accuracy and Stability of Numerical Algorithms*, 2nd ed., SIAM, 2002.
           https://doi.org/10.1137/1.9780898718027
    """
    n = s.shape[0]
    t = 0.0
    for i in range(n):
        t += s[i, i]
    tau = base * (1.0 + 1e-9) + 2.1e-10 * t
    low = np.zeros((n, n))
    for j in range(n):
        d = s[j, j] - tau
        for k in range(j):
            d -= low[j, k] * low[j, k]
        if not d > 0.0:
            return False
        low[j, j] = math.sqrt(d)
        for i in range(j + 1, n):
            v = s[i, j]
            for k in range(j):
                v -= low[i, k] * low[j, k]
            low[i, j] = v / low[j, j]
    return True


@numba.njit(cache=True, nogil=True)
def _fit_one(pts, s, m, s3_rcond, axis_to_spread, eps, conic, ell, full_guard=False):
    """Fit the set ``pts[s:s + m]`` (m >= 6) into ``conic`` (3, 3) and ``ell`` (5,); returns its
    residual (px) and status code. ``full_guard``: decide the collinearity check and the guard
    against non-ellipses from the eigenvalues always, not first by
    :func:`_least_eigenvalue_above` (the same statuses, tested)."""
    for i in range(s, s + m):
        if not (np.isfinite(pts[i, 0]) and np.isfinite(pts[i, 1])):
            return np.nan, NON_FINITE
    mu = 0.0
    mv = 0.0
    for i in range(s, s + m):
        mu += pts[i, 0]
        mv += pts[i, 1]
    mu /= m
    mv /= m
    ss = 0.0
    for i in range(s, s + m):
        du = pts[i, 0] - mu
        dv = pts[i, 1] - mv
        ss += du * du + dv * dv
    scale = math.sqrt(ss / m)
    if not scale > 0.0:
        return np.nan, COINCIDENT

    # Scatter matrix S = D^T D [eqn. 17] from [1], from the sums of the monomials x^i y^j
    sums = np.zeros(15)
    xp = np.ones(5)
    yp = np.ones(5)
    spread2 = -np.inf
    for i in range(s, s + m):
        x = (pts[i, 0] - mu) / scale
        y = (pts[i, 1] - mv) / scale
        xp[1], yp[1] = x, y
        xp[2], yp[2] = x * x, y * y
        xp[3], yp[3] = xp[2] * x, yp[2] * y
        xp[4], yp[4] = xp[2] * xp[2], yp[2] * yp[2]
        for q in range(15):
            sums[q] += xp[_MONO_I[q]] * yp[_MONO_J[q]]
        spread2 = max(spread2, x * x + y * y)
    sfull = np.empty((6, 6))
    for a in range(6):
        for b in range(6):
            sfull[a, b] = sums[S_INDEX[a, b]]
    s1 = np.ascontiguousarray(sfull[:3, :3])
    s2 = np.ascontiguousarray(sfull[:3, 3:])
    s3 = np.ascontiguousarray(sfull[3:, 3:])
    if full_guard or not _least_eigenvalue_above(s3, s3_rcond * (s3[0, 0] + s3[1, 1] + s3[2, 2])):
        ev3 = np.linalg.eigvalsh(s3)
        if not ev3[0] > s3_rcond * ev3[2]:
            return np.nan, SINGULAR_SCATTER
    # T = -S3^-1 S2^T, so that a2 = T a1 [eqn. 24] from [1]
    ok, t = _solve3(s3, np.ascontiguousarray(s2.T))
    if not ok:
        return np.nan, DECLINED
    t = -t
    # Reduced scatter matrix M = C1^-1 (S1 + S2 T) [eqn. 29] from [1]
    mred = _matmul3(C1_INV, s1 + _matmul3(s2, t))
    if not np.isfinite(mred).all():
        return np.nan, NO_ELLIPSE
    # M a1 = lambda a1 [eqn. 28], in closed form; complex or repeated eigenvalues are DECLINED
    # (numpy's form decides)
    ok, lam, vec = _eig3_real(mred)
    if not ok:
        return np.nan, DECLINED
    # cand: coefficient vectors (a, b, c, d, e, f) of the eigenvectors [eqn. 19] from [1]
    cand = np.empty((6, 3))
    cand[:3] = vec
    cand[3:] = _matmul3(t, vec)
    # the ellipse meets the constraint 4ac - b^2 > 0 [eqn. 14/30]; with rounding several may:
    # keep the smallest algebraic residual a^T S a (the first of equals, NaN first, as np.argmin)
    any_valid = False
    best = -1
    rbest = np.inf
    for q in range(3):
        r = np.inf
        if 4.0 * vec[0, q] * vec[2, q] - vec[1, q] * vec[1, q] > 0:
            any_valid = True
            r = 0.0
            for a in range(6):
                for b in range(6):
                    r += cand[a, q] * sfull[a, b] * cand[b, q]
        if best < 0 or (not np.isnan(rbest) and (np.isnan(r) or r < rbest)):
            best, rbest = q, r
    if not any_valid:
        return np.nan, NO_ELLIPSE
    av = np.ascontiguousarray(cand[:, best])
    # The guard of the numpy form: the unconstrained fit explains the points clearly better
    r_ell = 0.0
    for a in range(6):
        for b in range(6):
            r_ell += av[a] * sfull[a, b] * av[b]
    r_ell /= np.dot(av, av)
    if r_ell > 1e-24 and (full_guard or not _least_eigenvalue_above(sfull, r_ell / 3.96)):
        w_full = np.linalg.eigvalsh(sfull)
        if r_ell > 3.96 * max(w_full[0] - 1e-12 * w_full[5], 0.0):
            return np.nan, SUSPECT

    # Point conic in normalised coordinates, then back to pixels: C = T^T A T with x' = T x
    an = np.empty((3, 3))
    an[0, 0], an[0, 1], an[0, 2] = av[0], av[1] / 2, av[3] / 2
    an[1, 0], an[1, 1], an[1, 2] = av[1] / 2, av[2], av[4] / 2
    an[2, 0], an[2, 1], an[2, 2] = av[3] / 2, av[4] / 2, av[5]
    tm = np.zeros((3, 3))
    tm[0, 0] = tm[1, 1] = 1 / scale
    tm[0, 2] = -mu / scale
    tm[1, 2] = -mv / scale
    tm[2, 2] = 1.0
    cp = _matmul3(_matmul3(np.ascontiguousarray(tm.T), an), tm)
    cp = 0.5 * (cp + cp.T)
    norm = 0.0
    for i in range(3):
        for j in range(3):
            norm += cp[i, j] * cp[i, j]
    cp = cp / math.sqrt(norm)
    if cp[0, 0] + cp[1, 1] < 0:
        cp = -cp
    if not np.isfinite(cp).all():
        return np.nan, NON_FINITE_CONIC
    conic[:] = cp
    # Ellipse parameters from the conic of the normalised points (why: the numpy form)
    if not np.isfinite(an).all():
        return np.nan, NOT_REAL_ELLIPSE
    ok, cu, cv, ea, eb, angle = ellipse_of(an, eps)
    if not ok:
        return np.nan, NOT_REAL_ELLIPSE
    if ea > axis_to_spread * math.sqrt(spread2):
        return np.nan, UNBOUNDED
    ell[CENTRE_U] = mu + scale * cu
    ell[CENTRE_V] = mv + scale * cv
    ell[SEMI_MAJOR] = scale * ea
    ell[SEMI_MINOR] = scale * eb
    ell[ANGLE] = angle
    # RMS Sampson distance of the points to the pixel conic (fit.sampson_distance_px)
    acc = 0.0
    tiny = np.finfo(np.float64).tiny
    for i in range(s, s + m):
        u = pts[i, 0]
        v = pts[i, 1]
        gu = cp[0, 0] * u + cp[0, 1] * v + cp[0, 2]
        gv = cp[1, 0] * u + cp[1, 1] * v + cp[1, 2]
        f = gu * u + gv * v + cp[2, 0] * u + cp[2, 1] * v + cp[2, 2]
        d = abs(f) / max(2.0 * math.hypot(gu, gv), tiny)
        acc += d * d
    return math.sqrt(acc / m), OK


@numba.njit(cache=True, nogil=True)
def fit_conics(pts, starts, counts, s3_rcond, axis_to_spread, eps, full_guard=False):
    """Direct least-squares ellipse fit of each of several point sets (Fitzgibbon; Halir-Flusser).

    Parameters
    ----------
    pts : ndarray of shape (M, 2), float64
        The point sets (u, v), px, concatenated.
    starts, counts : ndarray of shape (k,), int64
        Set j is ``pts[starts[j]:starts[j] + counts[j]]``, ``counts[j] >= 6``.
    s3_rcond : float
        ``fit._S3_RCOND``: the reciprocal condition of the linear scatter under which the points
        are collinear.
    axis_to_spread : float
        ``fit.MAX_AXIS_TO_SPREAD``.
    eps : float
        ``TOL.conic_degenerate_rel`` (:func:`ellipse_of`).
    full_guard : bool
        Decide every set's collinearity check and guard against non-ellipses from the
        eigenvalues of its scatter matrices (the reference); default False: first by
        :func:`_least_eigenvalue_above`, which passes most sets without them and gives the same
        statuses.

    Returns
    -------
    status : ndarray of shape (k,), int64
        :data:`OK` or why not (the module's codes); the other results of a set are meaningful
        only where it is OK.
    conic : ndarray of shape (k, 3, 3)
        Point conics in pixels, unit Frobenius norm, quadratic part positive definite.
    ellipse : ndarray of shape (k, 5)
        Centre (u, v) px, semi-axes (a >= b) px, angle rad (columns :data:`CENTRE_U` ...).
    residual : ndarray of shape (k,)
        RMS Sampson distance of each set's points to its conic, px.

    Notes
    -----
    Each set is fitted from its own points only, in its own loop iteration, so its results do
    not depend on the other sets of the batch.
    """
    k = len(starts)
    status = np.empty(k, dtype=np.int64)
    conic = np.full((k, 3, 3), np.nan)
    ellipse = np.full((k, 5), np.nan)
    residual = np.full(k, np.nan)
    for j in range(k):
        try:
            residual[j], status[j] = _fit_one(pts, starts[j], counts[j], s3_rcond, axis_to_spread,
                                              eps, conic[j], ellipse[j], full_guard)
        except Exception:  # noqa: BLE001 - LAPACK's refusals, raised by numba
            status[j] = DECLINED
    return status, conic, ellipse, residual
