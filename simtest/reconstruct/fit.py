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

from simtest.geometry.conics import conic_kind, conic_to_ellipse
from simtest.reconstruct.failures import Failure

#: An ellipse has 5 degrees of freedom; one more point gives a residual.
MIN_FIT_POINTS = 6
#: Reciprocal condition number of the (normalised) linear scatter S3 below which the points are
#: called collinear: S3 of centred unit-RMS points has eigenvalues O(1) unless they are degenerate.
_S3_RCOND = 1e-10

#: A fitted semi-major axis longer than this many times the largest distance of a point from the
#: points' mean is refused: the points (a line, parallel lines, a short flat arc) do not bound it.
#: An arc of 60 degrees of a circle already gives a ratio under 4; 10 leaves room for short arcs.
MAX_AXIS_TO_SPREAD = 10.0

# Constraint matrix C1 of 4ac - b^2 = 1 [eqn. 18] from [1]
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


def sampson_distance_px(conic: np.ndarray, points_uv: np.ndarray) -> np.ndarray:
    """Sampson distance of each point to a point conic [3].

    The first-order geometric distance ``|x^T C x| / ||grad_(u,v) (x^T C x)||`` with
    ``x = (u, v, 1)``.

    Parameters
    ----------
    conic : ndarray of shape (3, 3)
        Symmetric point conic in pixel coordinates (any scale: the ratio is scale-free).
    points_uv : ndarray of shape (N, 2)
        Points (u, v), px, pixel centres at integer coordinates.

    Returns
    -------
    ndarray of shape (N,)
        Distances in px (>= 0); a point where the gradient vanishes (the conic's centre) gets
        ``|x^T C x| / tiny``, a very large value rather than a division by zero.
    """
    x = np.column_stack([points_uv, np.ones(len(points_uv))])
    cx = x @ conic
    f = np.einsum("ij,ij->i", cx, x)
    grad = 2.0 * cx[:, :2]
    return np.abs(f) / np.maximum(np.hypot(grad[:, 0], grad[:, 1]), np.finfo(float).tiny)


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

    Examples
    --------
    >>> t = np.linspace(0, 2 * np.pi, 50, endpoint=False)
    >>> fit = fit_ellipse(np.column_stack([10 + 5 * np.cos(t), 20 + 3 * np.sin(t)]))
    >>> np.round(fit.ellipse.center, 6).tolist(), np.round(fit.ellipse.semi_axes, 6).tolist()
    ([10.0, 20.0], [5.0, 3.0])
    """

    pts = np.asarray(points_uv, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 2:
        raise ValueError(f"points_uv must have shape (N, 2), got {pts.shape}")
    n = len(pts)
    if n < MIN_FIT_POINTS:
        return Failure("too_few_points", f"{n} points < {MIN_FIT_POINTS}")
    if not np.isfinite(pts).all():
        return Failure("non_finite_points", f"{int((~np.isfinite(pts)).any(axis=1).sum())} of {n} points")

    # Centre and scale the points to unit RMS distance from their mean (Hartley-style conditioning).
    mean = pts.mean(axis=0)
    centred = pts - mean
    scale = float(np.sqrt((centred**2).sum(axis=1).mean()))
    if not scale > 0.0:
        return Failure("degenerate_points", "all points coincide")
    x = centred[:, 0] / scale
    y = centred[:, 1] / scale

    # Design matrix D = (D1 | D2): quadratic part D1 = (x^2, xy, y^2) [eqn. 15] from [1] and
    # linear part D2 = (x, y, 1) [eqn. 16] from [1], built in one array
    d = np.empty((n, 6))
    d[:, 0] = x * x
    d[:, 1] = x * y
    d[:, 2] = y * y
    d[:, 3] = x
    d[:, 4] = y
    d[:, 5] = 1.0
    d1, d2 = d[:, :3], d[:, 3:]
    # Scatter matrix S = D^T D and its blocks S1, S2, S3 [eqn. 17] from [1]
    s_full = d.T @ d
    s1 = s_full[:3, :3]
    s2 = s_full[:3, 3:]
    s3 = s_full[3:, 3:]
    ev3 = np.linalg.eigvalsh(s3)
    if not ev3[0] > _S3_RCOND * ev3[-1]:
        return Failure("degenerate_points", f"linear scatter is singular (eigenvalues {ev3.tolist()})")
    # T = -S3^-1 S2^T, so that a2 = T a1 [eqn. 24] from [1]
    t = -np.linalg.solve(s3, s2.T)
    # Reduced scatter matrix M = C1^-1 (S1 + S2 T) [eqn. 29] from [1]
    m = _C1_INV @ (s1 + s2 @ t)
    # M a1 = lambda a1: eigenvectors of the reduced problem [eqn. 28] from [1]
    _, eigvec = np.linalg.eig(m)
    eigvec = np.real(eigvec)
    # The ellipse solution satisfies the constraint a1^T C1 a1 = 4ac - b^2 > 0 [eqn. 14/30] from [1]
    cond = 4.0 * eigvec[0] * eigvec[2] - eigvec[1] ** 2
    valid = np.flatnonzero(cond > 0)
    if valid.size == 0:
        return Failure("not_an_ellipse", "no eigenvector meets 4ac - b^2 > 0")
    best = None
    for k in valid:  # normally exactly one; with rounding keep the smallest algebraic residual
        a1 = eigvec[:, k]
        a = np.concatenate([a1, t @ a1])  # coefficient vector (a, b, c, d, e, f) [eqn. 19] from [1]
        if valid.size == 1:  # nothing to compare: no residual needed
            best = (None, a)
            break
        r = float(np.linalg.norm(d1 @ a[:3] + d2 @ a[3:]))
        if best is None or r < best[0]:
            best = (r, a)
    a_vec = best[1]
    a, b, c, d, e, f = a_vec

    # Ellipse-specific fitting always returns an ellipse, even for points on a hyperbola or a line
    # pair. Guard: the unconstrained algebraic fit (smallest eigenvector of S = D^T D [eqn. 17]
    # from [1]) is the exact conic of noise-free data; if it is not an ellipse and explains the
    # points clearly better (algebraic residual 4x smaller), the data are not an ellipse.
    r_ellipse = float(a_vec @ s_full @ a_vec) / float(a_vec @ a_vec)
    # Eigenvalues alone first (cheaper); the eigenvectors only near or past the threshold, where
    # the test is made on eigh's own eigenvalue as before (the two differ by rounding, ~1e-16 of
    # the largest eigenvalue: far inside the 1 % and 1e-12 margins taken here).
    w_full = np.linalg.eigvalsh(s_full)
    if r_ellipse > 1e-24 and r_ellipse > 3.96 * max(float(w_full[0] - 1e-12 * w_full[-1]), 0.0):
        w_full, v_full = np.linalg.eigh(s_full)
    r_general = max(float(w_full[0]), 0.0)
    if r_ellipse > 1e-24 and r_ellipse > 4.0 * r_general:
        g = v_full[:, 0]
        g_conic = np.array(
            [[g[0], g[1] / 2, g[3] / 2], [g[1] / 2, g[2], g[4] / 2], [g[3] / 2, g[4] / 2, g[5]]]
        )
        kind = conic_kind(g_conic)
        if kind != "ellipse":
            return Failure(
                "not_an_ellipse",
                f"the points fit a {kind} better (algebraic residual {r_general:.3g} vs {r_ellipse:.3g})",
            )

    # Point conic in normalised coordinates, then back to pixels: C = T^T A T with x' = T x.
    a_norm = np.array([[a, b / 2, d / 2], [b / 2, c, e / 2], [d / 2, e / 2, f]])
    tmat = np.array([[1 / scale, 0.0, -mean[0] / scale], [0.0, 1 / scale, -mean[1] / scale], [0, 0, 1.0]])
    conic = tmat.T @ a_norm @ tmat
    conic = 0.5 * (conic + conic.T)
    conic /= np.linalg.norm(conic)
    if conic[0, 0] + conic[1, 1] < 0:
        conic = -conic
    if not np.isfinite(conic).all():
        return Failure("degenerate_points", "non-finite conic")
    # Ellipse parameters from the conic of the *normalised* points, then back to pixels: a unit-norm
    # pixel conic of a few-px ellipse ~10^3 px from the origin has singular values down to ~1e-13,
    # where a degeneracy test in pixel coordinates would misclassify it; the normalised conic is
    # O(1)-conditioned for any ellipse.
    e_norm = conic_to_ellipse(a_norm)
    if e_norm is None:
        return Failure("not_an_ellipse", "the fitted conic is not a real ellipse")
    # Points on a line or two parallel lines are fitted exactly by ever longer ellipses: an ellipse
    # far larger than the points' spread is not determined by them.
    if e_norm.semi_axes[0] > MAX_AXIS_TO_SPREAD * float(np.sqrt((d1[:, 0] + d1[:, 2]).max())):  # x^2 + y^2
        return Failure(
            "not_an_ellipse",
            f"unbounded: semi-major axis {scale * e_norm.semi_axes[0]:.4g} px is more than "
            f"{MAX_AXIS_TO_SPREAD:g} times the points' spread (a line or parallel lines)",
        )
    ellipse = type(e_norm)(
        center=mean + scale * np.asarray(e_norm.center),
        semi_axes=scale * np.asarray(e_norm.semi_axes),
        angle_rad=e_norm.angle_rad,
    )
    residual = float(np.sqrt(np.mean(sampson_distance_px(conic, pts) ** 2)))
    return EllipseFit(conic, ellipse, residual, n)
