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
from simtest.decisions import MIN_FIT_POINTS, MAX_AXIS_TO_SPREAD
from simtest.geometry.conics import Ellipse, _ellipses_of, conic_kind
from simtest.reconstruct import _fit_kernels
from simtest.reconstruct._fit_kernels import C1_INV as _C1_INV
from simtest.reconstruct._fit_kernels import MONOMIALS as _MONOMIALS
from simtest.reconstruct._fit_kernels import S_INDEX as _S_INDEX
from simtest.reconstruct.failures import Failure
from simtest.tolerances import TOL

#: Reciprocal condition number of the (normalised) linear scatter S3 below which the points are
#: called collinear: S3 of centred unit-RMS points has eigenvalues O(1) unless they are degenerate.
_S3_RCOND = 1e-10



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
    return np.abs(f) / np.maximum(2.0 * np.hypot(gu, gv), np.finfo(float).tiny)


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
    then come the reduced 3 x 3 eigenproblem [eqn. 28-29 of 1] and the checks. All sets run in
    one compiled call (:func:`fit_stacked`), a few microseconds per set; the numpy form of the
    same steps (``_fit_stack``, on the whole stack at once) is the reference and refits the sets
    the compiled one refuses. A set's fit does not depend on the other sets of the batch (the
    compiled call fits each set from its own points alone; the numpy form sums each set's own
    rows and runs LAPACK on each matrix of a stack alone).
    """
    pts_all = point_sets(points_list)
    if not pts_all:
        return []
    return fit_stacked(np.concatenate(pts_all, axis=0), np.array([len(p) for p in pts_all], dtype=np.int64))


def fit_stacked(pts: np.ndarray, counts: np.ndarray, *, compiled: bool = True) -> list[EllipseFit | Failure]:
    """:func:`fit_ellipses` of point sets given concatenated.

    Parameters
    ----------
    pts : ndarray of shape (M, 2), float64
        The point sets (u, v), px, one after the other.
    counts : ndarray of shape (k,), int
        Points per set (``counts.sum() == M``).
    compiled : bool
        Fit with the compiled kernel (:func:`simtest.reconstruct._fit_kernels.fit_conics`), the
        numpy form refitting the sets it refuses; False: the numpy form only (the reference).

    Returns
    -------
    list of EllipseFit or Failure
        One per set, as :func:`fit_ellipses`.

    Notes
    -----
    The two forms take the same steps with the same LAPACK routines; they agree to rounding
    (``tests/test_fit_kernels.py``). A set the kernel refuses, or hands over, is refitted by the
    numpy form, whose failure (reason and detail, with its numbers) is the one reported: the
    failures are those of the numpy form, word for word.
    """
    counts = np.asarray(counts, dtype=np.int64)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int64)
    out: list = [None] * len(counts)
    todo = []
    for i, m in enumerate(counts.tolist()):
        if m < MIN_FIT_POINTS:
            out[i] = Failure("too_few_points", f"{m} points < {MIN_FIT_POINTS}")
        else:
            todo.append(i)
    if not todo:
        return out
    todo = np.array(todo)
    redo = todo
    if compiled:
        pts = np.ascontiguousarray(pts, dtype=np.float64)
        status, conic, ell, residual = _fit_kernels.fit_conics(
            pts, starts[todo], counts[todo], _S3_RCOND, MAX_AXIS_TO_SPREAD, TOL.conic_degenerate_rel)
        ok = status == _fit_kernels.OK
        e_ok = ell[ok]
        # each ellipse's centre and semi-axes rows of two arrays (views, made at once: not two
        # arrays a fit, a real frame's 1500), float64 as before
        centres, semi = list(np.ascontiguousarray(e_ok[:, :2])), list(np.ascontiguousarray(e_ok[:, 2:4]))
        n_of = counts.tolist()
        for i, c, cen, ax, ang, r in zip(todo[ok].tolist(), conic[ok], centres, semi, e_ok[:, 4].tolist(),
                                         residual[ok].tolist()):
            out[i] = EllipseFit(c, Ellipse(cen, ax, ang), r, n_of[i])
        redo = todo[~ok]
    if len(redo):
        rows = np.concatenate([np.arange(starts[i], starts[i] + counts[i]) for i in redo])
        n = counts[redo]
        sub_starts = np.concatenate([[0], np.cumsum(n)[:-1]])
        sub = pts[rows]
        item = np.repeat(np.arange(len(redo)), n)
        bad_rows = _segment_sums((~np.isfinite(sub)).any(axis=1).astype(np.int64), sub_starts)
        with np.errstate(all="ignore"):
            fits = _fit_stack(sub, n, sub_starts, item, bad_rows)
        for i, f in zip(redo.tolist(), fits):
            out[i] = f
    return out


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
    clean = np.where(np.isfinite(pts), pts, 0.0)
    mean = _segment_sums(clean, starts) / n[:, None]
    centred = clean - mean[item]
    scale = np.sqrt(_segment_sums((centred**2).sum(axis=1), starts) / n)
    refuse(~(scale > 0.0), "degenerate_points", lambda j: "all points coincide")
    safe_scale = np.where(scale > 0.0, scale, 1.0)
    x = centred[:, 0] / safe_scale[item]
    y = centred[:, 1] / safe_scale[item]

    # Scatter matrix S = D^T D [eqn. 17] from [1], from the sums of the monomials x^i y^j
    xp = [np.ones_like(x), x, x * x, x * x * x, (x * x) * (x * x)]
    yp = [np.ones_like(y), y, y * y, y * y * y, (y * y) * (y * y)]
    mono = np.stack([xp[i] * yp[j] for i, j in _MONOMIALS], axis=1)
    s_full = _segment_sums(mono, starts)[:, _S_INDEX]  # (k, 6, 6)
    s1, s2, s3 = s_full[:, :3, :3], s_full[:, :3, 3:], s_full[:, 3:, 3:]
    if not alive.all():
        s3 = np.where(alive[:, None, None], s3, np.eye(3))
    ev3 = np.linalg.eigvalsh(s3)
    refuse(~(ev3[:, 0] > _S3_RCOND * ev3[:, -1]), "degenerate_points",
           lambda j: f"linear scatter is singular (eigenvalues {ev3[j].tolist()})")
    if not alive.all():
        s3 = np.where(alive[:, None, None], s3, np.eye(3))
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
    resid = np.einsum("kic,kij,kjc->kc", cand, s_full, cand)
    best = np.argmin(np.where(valid, resid, np.inf), axis=1)
    a_vec = cand[np.arange(k), :, best]  # (k, 6)

    # Ellipse-specific fitting always returns an ellipse, even for points on a hyperbola or a line
    # pair. Guard: the unconstrained algebraic fit (smallest eigenvector of S [eqn. 17] from [1])
    # is the exact conic of noise-free data; if it is not an ellipse and explains the points
    # clearly better (algebraic residual 4x smaller), the data are not an ellipse.
    r_ellipse = np.einsum("ki,kij,kj->k", a_vec, s_full, a_vec) / np.einsum("ki,ki->k", a_vec, a_vec)
    s_safe = s_full if alive.all() else np.where(alive[:, None, None], s_full, np.eye(6))
    w_full = np.linalg.eigvalsh(s_safe)
    suspect = alive & (r_ellipse > 1e-24) & (r_ellipse > 3.96 * np.maximum(w_full[:, 0] - 1e-12 * w_full[:, -1], 0.0))
    for j in np.flatnonzero(suspect):  # eigh's own eigenvalue and vector where it matters
        w_j, v_j = np.linalg.eigh(s_safe[j])
        r_gen = max(float(w_j[0]), 0.0)
        if r_ellipse[j] > 4.0 * r_gen:
            g = v_j[:, 0]
            g_conic = np.array([[g[0], g[1] / 2, g[3] / 2], [g[1] / 2, g[2], g[4] / 2], [g[3] / 2, g[4] / 2, g[5]]])
            kind = conic_kind(g_conic)
            if kind != "ellipse":
                refuse(np.arange(k) == j, "not_an_ellipse", lambda _: (
                    f"the points fit a {kind} better (algebraic residual {r_gen:.3g} vs {r_ellipse[j]:.3g})"))

    # Point conic in normalised coordinates, then back to pixels: C = T^T A T with x' = T x.
    a, b, c, d, e, f = a_vec.T
    a_norm = np.stack([np.stack([a, b / 2, d / 2], 1), np.stack([b / 2, c, e / 2], 1),
                       np.stack([d / 2, e / 2, f], 1)], 1)
    tmat = np.zeros((k, 3, 3))
    tmat[:, 0, 0] = tmat[:, 1, 1] = 1 / safe_scale
    tmat[:, 0, 2] = -mean[:, 0] / safe_scale
    tmat[:, 1, 2] = -mean[:, 1] / safe_scale
    tmat[:, 2, 2] = 1.0
    conic = np.swapaxes(tmat, 1, 2) @ a_norm @ tmat
    conic = 0.5 * (conic + np.swapaxes(conic, 1, 2))
    conic = conic / np.sqrt(np.einsum("kij,kij->k", conic, conic))[:, None, None]
    conic = np.where((conic[:, 0, 0] + conic[:, 1, 1] < 0)[:, None, None], -conic, conic)
    refuse(~np.isfinite(conic).all(axis=(1, 2)), "degenerate_points", lambda j: "non-finite conic")
    # Ellipse parameters from the conic of the *normalised* points, then back to pixels: a unit-norm
    # pixel conic of a few-px ellipse ~10^3 px from the origin has singular values down to ~1e-13,
    # where a degeneracy test in pixel coordinates would misclassify it; the normalised conic is
    # O(1)-conditioned for any ellipse.
    usable = alive & np.isfinite(a_norm).all(axis=(1, 2))
    centre, axes, angle, is_ellipse = _ellipses_of(
        a_norm if usable.all() else np.where(usable[:, None, None], a_norm, np.eye(3)))
    refuse(~is_ellipse, "not_an_ellipse", lambda j: "the fitted conic is not a real ellipse")
    # Points on a line or two parallel lines are fitted exactly by ever longer ellipses: an ellipse
    # far larger than the points' spread is not determined by them.
    spread = np.sqrt(np.maximum.reduceat(x * x + y * y, starts))
    refuse(axes[:, 0] > MAX_AXIS_TO_SPREAD * spread, "not_an_ellipse", lambda j: (
        f"unbounded: semi-major axis {scale[j] * axes[j, 0]:.4g} px is more than "
        f"{MAX_AXIS_TO_SPREAD:g} times the points' spread (a line or parallel lines)"))
    # RMS Sampson distance of each set's points to its conic, px
    dist = sampson_distance_px(conic[item], clean)
    residual = np.sqrt(_segment_sums(dist**2, starts) / n)
    out = []
    for j in range(k):
        if fail[j] is not None:
            out.append(fail[j])
            continue
        ellipse = Ellipse(center=mean[j] + scale[j] * centre[j], semi_axes=scale[j] * axes[j],
                          angle_rad=float(angle[j]))
        out.append(EllipseFit(conic[j], ellipse, float(residual[j]), int(n[j])))
    return out
