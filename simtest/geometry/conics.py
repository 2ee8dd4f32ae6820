"""Conics in the image, the normalised conic C' = K^T C K, and circle pose from one conic.

Conventions
-----------
A point conic is a symmetric 3x3 matrix ``C`` with ``x^T C x = 0`` for image points
``x = (u, v, 1)`` in pixels (pixel centres at integer coordinates, u = column, v = row). The
*normalised conic* ``C' = K^T C K`` is the same curve in normalised camera coordinates
``X = K^{-1} x``; read as a quadric of 3D directions it is the cone from the camera centre through
the curve. All 3D quantities are in the OpenCV camera frame (x right, y down, z forward) and
normals are unit vectors facing the camera (``n . ray < 0``, so ``n_z < 0`` for a surface in front).

For a circle seen by a camera whose point light is co-located with it, the cone is a *right*
circular cone whose axis is the plane normal (derivation in the Notes of :func:`cone_axis`): C'
then has a double eigenvalue, both circle-pose normals coincide with the cone axis, and there is no
two-fold ambiguity. How badly the circle pose is conditioned near that case is in the Notes of
:func:`circle_pose`.

References
----------
.. [1] D. Forsyth, J. L. Mundy, A. Zisserman, C. Coelho, A. Heller, C. Rothwell, "Invariant
       descriptors for 3-D object recognition and pose", IEEE TPAMI 13(10), 1991, appendix A.
       https://doi.org/10.1109/34.99233
.. [2] R. Safaee-Rad, I. Tchoukanov, K. C. Smith, B. Benhabib, "Three-dimensional location
       estimation of circular features for machine vision", IEEE T-RA 8(5), 1992.
       https://doi.org/10.1109/70.163777
.. [3] R. Hartley, A. Zisserman, Multiple View Geometry, 2nd ed., 2003, ch. 2 and 8.
       https://doi.org/10.1017/CBO9780511811685
.. [4] K. Makki, A. Bartoli, "Normal Reconstruction from Specularity in the Endoscopic Setting",
       section 2.3 (the reconstruction method).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from simtest.geometry.angles import cross3
from simtest.geometry.camera import validate_intrinsics
from simtest.tolerances import TOL

__all__ = [
    "CirclePose",
    "ConeAxis",
    "Ellipse",
    "circle_pose",
    "conic_kind",
    "conic_to_ellipse",
    "cone_axis",
    "cone_pose",
    "ellipse_to_conic",
    "normalised_conic",
    "plane_basis",
    "project_circle",
    "sample_ellipse",
]


@dataclass(frozen=True)
class Ellipse:
    """Geometric parameters of an image ellipse.

    Attributes
    ----------
    center : ndarray of shape (2,)
        Centre (u, v) in pixels.
    semi_axes : ndarray of shape (2,)
        Semi-axes (a, b) in pixels, a >= b > 0.
    angle_rad : float
        Angle of the major axis from the +u axis toward +v, in radians, in (-pi/2, pi/2].
    """

    center: np.ndarray
    semi_axes: np.ndarray
    angle_rad: float

    def as_dict(self) -> dict:
        """JSON-ready form with the angle in degrees (interface unit)."""
        return {
            "center_px": [float(x) for x in self.center],
            "semi_axes_px": [float(x) for x in self.semi_axes],
            "angle_deg": float(np.degrees(self.angle_rad)),
        }


@dataclass(frozen=True)
class ConeAxis:
    """Axis of the cone C' and how far the cone is from right circular.

    Attributes
    ----------
    axis : ndarray of shape (3,)
        Unit eigenvector of C' for the eigenvalue of unique sign, oriented to face the camera
        (camera frame). For a co-located light on a plane it equals the plane normal.
    eigenvalue_gap : float
        ``(l1 - l2) / (l1 - l3)`` in [0, 1), where l1 >= l2 are the same-sign eigenvalues and l3 the
        other, after normalising signs so that l1, l2 > 0 > l3. Zero for a right circular cone; it is
        also ``sin^2`` of the angle between either circle-pose normal and the axis, so it measures
        the model violation (curvature anisotropy, light offset) in the units of the estimate.
    eigenvalues : ndarray of shape (3,)
        (l1, l2, l3) of the sign-normalised, unit-Frobenius C'.
    """

    axis: np.ndarray
    eigenvalue_gap: float
    eigenvalues: np.ndarray

    @property
    def circle_pose_tilt_deg(self) -> float:
        """Angle in degrees between the circle-pose normals and the cone axis."""
        return float(np.degrees(np.arcsin(np.sqrt(np.clip(self.eigenvalue_gap, 0.0, 1.0)))))


@dataclass(frozen=True)
class CirclePose:
    """The two solutions of the circle pose problem for one image conic.

    Attributes
    ----------
    normals : ndarray of shape (2, 3)
        N+ and N-: unit plane normals in the camera frame, facing the camera.
    centres : ndarray of shape (2, 3)
        Unit viewing directions (z > 0) of the 3D circle centre for each solution. The distance is
        not recoverable without the circle radius.
    eigenvalues : ndarray of shape (3,)
        (l1, l2, l3) as in :class:`ConeAxis`.
    """

    normals: np.ndarray
    centres: np.ndarray
    eigenvalues: np.ndarray


def _check_conic(C, name: str = "C") -> np.ndarray:
    C = np.asarray(C, dtype=np.float64)
    if C.shape != (3, 3):
        raise ValueError(f"{name} must be a 3x3 matrix, got shape {C.shape}")
    if not np.all(np.isfinite(C)):
        raise ValueError(f"{name} has non-finite entries: {C.tolist()}")
    return 0.5 * (C + C.T)


def ellipse_to_conic(center_uv, semi_axes, angle_rad: float) -> np.ndarray:
    """Point conic of an ellipse given by its centre, semi-axes and orientation.

    Parameters
    ----------
    center_uv : array_like of shape (2,)
        Centre (u, v) in pixels.
    semi_axes : array_like of shape (2,)
        Semi-axes (a, b) in pixels, both > 0; ``a`` lies along ``angle_rad``.
    angle_rad : float
        Orientation of the ``a`` axis from +u toward +v, radians.

    Returns
    -------
    ndarray of shape (3, 3)
        Symmetric C with ``x^T C x = 0`` on the ellipse, negative inside, with ``C[2, 2]`` the value
        at the origin (not normalised).

    Raises
    ------
    ValueError
        If a semi-axis is not positive and finite.
    """
    cx, cy = (float(x) for x in center_uv)
    a, b = (float(x) for x in semi_axes)
    if not (np.isfinite(a) and np.isfinite(b) and a > 0 and b > 0):
        raise ValueError(f"semi-axes must be positive and finite, got ({a}, {b})")
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    # (u', v') = R^T (x - centre); u'^2/a^2 + v'^2/b^2 - 1 = 0  [3, sec. 2.2.3]
    A = c * c / a**2 + s * s / b**2
    B = 2.0 * c * s * (1.0 / a**2 - 1.0 / b**2)
    Cc = s * s / a**2 + c * c / b**2
    D = -2.0 * A * cx - B * cy
    E = -B * cx - 2.0 * Cc * cy
    F = A * cx * cx + B * cx * cy + Cc * cy * cy - 1.0
    return np.array([[A, B / 2, D / 2], [B / 2, Cc, E / 2], [D / 2, E / 2, F]])


def conic_kind(C) -> str:
    """Classify a point conic.

    Parameters
    ----------
    C : array_like of shape (3, 3)
        Point conic (any scale).

    Returns
    -------
    str
        One of ``"ellipse"`` (real, non-degenerate), ``"imaginary"`` (no real point),
        ``"hyperbola"``, ``"parabola"``, ``"degenerate"`` (lines or a point: det C ~ 0).

    Raises
    ------
    ValueError
        If C is not 3x3 or has non-finite entries.
    """
    return _classify(_check_conic(C))[0]


def _classify(C: np.ndarray):
    """:func:`conic_kind` of a checked conic, with what :func:`conic_to_ellipse` reuses: the
    unit-norm conic, and its centre and ``f0`` when it has a centre (else None)."""
    norm = np.linalg.norm(C)
    if norm == 0:
        return "degenerate", C, None, None
    C = C / norm
    A2 = C[:2, :2]
    lam = np.linalg.eigvalsh(A2)
    lam_max = np.abs(lam).max()
    eps = TOL.conic_degenerate_rel
    if lam_max <= eps or abs(lam[0] * lam[1]) <= eps * lam_max**2:
        # no centre: a parabola, or parallel lines / a line (det C ~ 0 relative to its scale)
        sv = np.linalg.svd(C, compute_uv=False)
        return ("degenerate" if sv[-1] <= eps * sv[0] else "parabola"), C, None, None
    # Classify in the frame centred on the conic's centre, where it reads diag-block (A2, f0): the
    # test no longer depends on where the curve lies in the image (a 1 px ellipse at (1300, 1000)
    # is as good as one at the origin).
    centre = -np.linalg.solve(A2, C[:2, 2])
    f0 = C[2, 2] + C[2, :2] @ centre
    # f0 is a difference of terms of size |C22|; rounding leaves ~1e-16 of them, so compare with
    # the larger of that and the quadratic part.
    if abs(f0) <= eps * max(lam_max, abs(C[2, 2]) + abs(C[2, :2] @ centre)):
        # a point (ellipse type) or two crossing lines (hyperbola type)
        return "degenerate", C, centre, f0
    if lam[0] * lam[1] < 0:
        return "hyperbola", C, centre, f0
    sign = 1.0 if lam[0] > 0 else -1.0
    return ("ellipse" if sign * f0 < 0 else "imaginary"), C, centre, f0


def conic_to_ellipse(C) -> Ellipse | None:
    """Geometric parameters of a point conic, or None if it is not a real ellipse.

    Parameters
    ----------
    C : array_like of shape (3, 3)
        Point conic in pixel coordinates (any scale or sign).

    Returns
    -------
    Ellipse or None
        None for hyperbolas, parabolas, degenerate and imaginary conics (see :func:`conic_kind`).

    Raises
    ------
    ValueError
        If C is not 3x3 or has non-finite entries.
    """
    kind, C, centre, f0 = _classify(_check_conic(C))
    if kind != "ellipse":
        return None
    A2 = C[:2, :2]
    if np.trace(A2) < 0:
        C = -C
        A2 = C[:2, :2]
        centre = -np.linalg.solve(A2, C[:2, 2])
        f0 = C[2, 2] + C[2, :2] @ centre  # < 0 for a real ellipse
    w, V = np.linalg.eigh(A2)  # ascending: w[0] gives the major axis
    a = np.sqrt(-f0 / w[0])
    b = np.sqrt(-f0 / w[1])
    major = V[:, 0]
    angle = float(np.arctan2(major[1], major[0]))
    if angle <= -np.pi / 2:
        angle += np.pi
    elif angle > np.pi / 2:
        angle -= np.pi
    return Ellipse(center=centre, semi_axes=np.array([a, b]), angle_rad=angle)


def sample_ellipse(ellipse: Ellipse, n: int, *, rng=None, noise_px: float = 0.0) -> np.ndarray:
    """Points on an ellipse, evenly spaced in the eccentric anomaly, optionally with noise.

    Parameters
    ----------
    ellipse : Ellipse
        The ellipse in pixels.
    n : int
        Number of points (> 0).
    rng : numpy.random.Generator, optional
        Required when ``noise_px > 0``; also draws a random phase when given.
    noise_px : float
        Standard deviation of isotropic Gaussian noise added to each coordinate, pixels.

    Returns
    -------
    ndarray of shape (n, 2)
        Points (u, v) in pixels.

    Raises
    ------
    ValueError
        If ``n < 1``, or noise is asked for without a generator.
    """
    if n < 1:
        raise ValueError(f"n must be >= 1, got {n}")
    if noise_px > 0 and rng is None:
        raise ValueError("noise_px > 0 needs an explicit numpy Generator (rng)")
    phase = rng.uniform(0, 2 * np.pi) if rng is not None else 0.0
    t = phase + np.linspace(0.0, 2 * np.pi, n, endpoint=False)
    a, b = ellipse.semi_axes
    c, s = np.cos(ellipse.angle_rad), np.sin(ellipse.angle_rad)
    x = a * np.cos(t)
    y = b * np.sin(t)
    pts = np.stack([ellipse.center[0] + c * x - s * y, ellipse.center[1] + s * x + c * y], axis=1)
    if noise_px > 0:
        pts = pts + rng.normal(0.0, noise_px, size=pts.shape)
    return pts


def normalised_conic(C, K) -> np.ndarray:
    """The normalised conic C' = K^T C K, scaled to unit Frobenius norm (paper section 2.3).

    Parameters
    ----------
    C : array_like of shape (3, 3)
        Point conic in pixel coordinates.
    K : array_like of shape (3, 3)
        Intrinsics (pixel centres at integer coordinates), validated.

    Returns
    -------
    ndarray of shape (3, 3)
        Symmetric C' in normalised camera coordinates, ``||C'||_F = 1``.

    Raises
    ------
    ValueError
        If C or K is malformed (see :func:`simtest.geometry.camera.validate_intrinsics`) or C is zero.
    """

    C = _check_conic(C)
    K = validate_intrinsics(K)
    Cn = K.T @ C @ K
    Cn = 0.5 * (Cn + Cn.T)
    norm = np.linalg.norm(Cn)
    if norm == 0:
        raise ValueError("the conic is zero")
    return Cn / norm


def _cone_eigen(Cn) -> tuple[np.ndarray, np.ndarray]:
    """Eigen-decomposition of a cone with signs normalised so that l1 >= l2 > 0 > l3.

    Returns eigenvalues (3,) and eigenvectors as columns (3, 3) in that order.
    Raises ValueError if the cone is not real and elliptic (signature (2, 1)).
    """
    Cn = _check_conic(Cn, "C'")
    Cn = Cn / np.linalg.norm(Cn)
    w, V = np.linalg.eigh(Cn)
    eps = TOL.conic_degenerate_rel
    n_pos = int(np.sum(w > eps))
    n_neg = int(np.sum(w < -eps))
    if (n_pos, n_neg) == (1, 2):
        w, V = -w[::-1], V[:, ::-1]
    elif (n_pos, n_neg) != (2, 1):
        raise ValueError(
            f"C' is not a real elliptic cone: eigenvalues {w.tolist()} "
            "(need two of one sign and one of the other)"
        )
    # w ascending after eigh: now w = (l3 < 0 < l2 <= l1) in ascending order.
    order = [2, 1, 0]
    return w[order], V[:, order]


def _toward_camera(n: np.ndarray) -> np.ndarray:
    """Orient a direction inside the cone (z != 0) as a normal facing the camera: n_z < 0.

    Right for the cone axis, which lies inside the cone, i.e. along a viewing ray with z > 0;
    not for circle-pose normals, which are oriented against their circle's centre ray instead.
    """
    n = n / np.linalg.norm(n)
    return -n if n[2] > 0 else n


def cone_axis(Cn) -> ConeAxis:
    """Axis of the cone C' (eigenvector of the unique-sign eigenvalue) and the eigenvalue gap.

    This is the ``cone_axis`` estimator: for a co-located light and a plane the cone is right
    circular and its axis is the plane normal (Notes). The public MATLAB code dam410/LightModel
    takes the same eigenvector in its co-located branch (``vanishing_line_paper_co``).

    Parameters
    ----------
    Cn : array_like of shape (3, 3)
        Normalised conic C' = K^T C K (any scale or sign).

    Returns
    -------
    ConeAxis

    Raises
    ------
    ValueError
        If C' is not a real elliptic cone (hyperbola, degenerate or imaginary image conic).

    Notes
    -----
    *The co-located right cone.* Let the plane be ``n . X = -h`` (``h > 0`` its distance to the
    camera centre O, ``n`` the unit normal facing the camera) and the point light at O. Phong's
    intensity (paper eq. 1) is ``I = c max(0, cos beta)^n_s`` with ``beta`` the angle between the
    direction to the viewer and the mirror direction of the light. For the ray of unit direction
    ``d`` hitting X, the light arrives along ``d``, leaves along ``r = d - 2 (d . n) n`` and the
    viewer is in direction ``-d``, so ``cos beta = r . (-d) = 2 (d . n)^2 - 1 = cos 2 gamma`` with
    ``gamma`` the angle between ``-d`` and ``n``. The intensity depends on ``gamma`` only: the
    isophote ``I = t c`` is the set of rays at the fixed angle ``gamma_0`` from ``-n``, with
    ``cos 2 gamma_0 = t^(1/n_s)``. Those rays form a right circular cone of axis ``n`` (it cuts the
    plane in a circle centred on the foot of the perpendicular ``-h n``, paper Props. 1 and 2 with
    the light at the camera). In normalised camera coordinates ``X = K^-1 x`` the cone is
    ``(n . X)^2 = cos^2 gamma_0 |X|^2``, i.e. ``C' ~ cos^2 gamma_0 I - n n^T``: eigenvalues
    ``cos^2 gamma_0`` (twice, any direction orthogonal to ``n``) and ``cos^2 gamma_0 - 1 < 0`` (the
    unique sign, eigenvector ``n``). So the eigenvector of the unique-sign eigenvalue is the plane
    normal and the eigenvalue gap ``(l1 - l2) / (l1 - l3)`` is 0; a gap above 0 measures how far
    the fitted ellipse is from this model (noise, curvature, light offset).

    References
    ----------
    .. [1] K. Makki, A. Bartoli, "Normal Reconstruction from Specularity in the Endoscopic
           Setting", eq. 1 and Props. 1-2.
    .. [2] B. T. Phong, "Illumination for computer generated pictures", Commun. ACM 18(6), 1975.
           https://doi.org/10.1145/360825.360839
    """
    return _cone_axis_of(*_cone_eigen(Cn))


def _cone_axis_of(w: np.ndarray, V: np.ndarray) -> ConeAxis:
    gap = float((w[0] - w[1]) / (w[0] - w[2]))
    return ConeAxis(axis=_toward_camera(V[:, 2]), eigenvalue_gap=gap, eigenvalues=w)


def circle_pose(Cn) -> CirclePose:
    """Normals (and centre directions) of the two planes cutting the cone C' in a circle.

    With C' = V diag(l1, l2, l3) V^T, l1 >= l2 > 0 > l3, a plane of normal
    ``n = +-sin(phi) e1 + cos(phi) e3`` cuts the cone in a circle iff
    ``cos^2 phi = (l2 - l3) / (l1 - l3)`` (the restriction of C' to the plane is then isotropic)
    [1, appendix A], [2]. This is step four of the paper's method [4]. When l1 = l2 both solutions
    equal the cone axis.

    Parameters
    ----------
    Cn : array_like of shape (3, 3)
        Normalised conic C' = K^T C K (any scale or sign).

    Returns
    -------
    CirclePose
        ``normals[0]`` is N+ (``+sin phi``), ``normals[1]`` is N-; both face the camera.

    Raises
    ------
    ValueError
        If C' is not a real elliptic cone.

    Notes
    -----
    *Conditioning near a right cone.* ``sin^2 phi = (l1 - l2) / (l1 - l3)`` is the eigenvalue gap
    ``g`` of :func:`cone_axis`, so N+ and N- leave the cone axis ``e3`` by ``asin(sqrt(g))`` each
    and make ``2 asin(sqrt(g))`` with each other. The square root makes the circle pose badly
    conditioned near a right cone: ``d phi / d g = 1 / (2 sqrt(g (1 - g)))`` is unbounded as
    ``g -> 0``. On a plane lit from the camera the true cone is right (``g = 0``, Notes of
    :func:`cone_axis`), so a fitted gap of ``1e-4`` (a small fit error) already moves N+ and N-
    by 0.57 deg and ``1e-3`` by 1.8 deg, while the cone axis, the eigenvector of the well
    separated eigenvalue ``l3``, moves only in proportion to the error of C'. On a curved surface
    the gap is not a fit error but ``1 - rho^2`` (:func:`simtest.geometry.curvature.curvature_ratio`):
    then N+ and N- err by ``acos(rho)`` whatever the fit.
    """
    return _circle_pose_of(*_cone_eigen(Cn))


def _circle_pose_of(w: np.ndarray, V: np.ndarray) -> CirclePose:
    l1, l2, l3 = w
    sin_phi = np.sqrt(max(l1 - l2, 0.0) / (l1 - l3))
    cos_phi = np.sqrt(max(l2 - l3, 0.0) / (l1 - l3))
    Q = V @ np.diag(w) @ V.T  # sign-normalised, unit cone
    normals = []
    centres = []
    for sgn in (1.0, -1.0):
        n = sgn * sin_phi * V[:, 0] + cos_phi * V[:, 2]
        n /= np.linalg.norm(n)
        c = _section_centre(Q, n)
        # Facing the camera means n . c < 0 along the ray to the circle's centre. n_z < 0 is not
        # the same test: a steep plane seen far off-axis faces the camera with n_z > 0.
        normals.append(-n if n @ c > 0 else n)
        centres.append(c)
    return CirclePose(normals=np.array(normals), centres=np.array(centres), eigenvalues=w)


def cone_pose(Cn) -> tuple[CirclePose, ConeAxis]:
    """:func:`circle_pose` and :func:`cone_axis` of one cone from one eigen-decomposition.

    Parameters
    ----------
    Cn : array_like of shape (3, 3)
        Normalised conic C' = K^T C K (any scale or sign).

    Returns
    -------
    (CirclePose, ConeAxis)
        The same as ``(circle_pose(Cn), cone_axis(Cn))``, bit for bit (the per-highlight path
        of the pipeline calls both).

    Raises
    ------
    ValueError
        If C' is not a real elliptic cone.
    """
    w, V = _cone_eigen(Cn)
    return _circle_pose_of(w, V), _cone_axis_of(w, V)


def plane_basis(normal, axes: tuple[int, int] = (0, 1)) -> tuple[np.ndarray, np.ndarray]:
    """An orthonormal basis (u, w) of the plane perpendicular to ``normal``.

    Parameters
    ----------
    normal : array_like of shape (3,)
        Unit normal.
    axes : tuple of int
        Indices of the two coordinate axes the basis may start from: ``u`` is along
        ``normal x e[axes[0]]`` unless ``|normal[axes[0]]| >= 0.9`` (the normal within about 26 deg
        of that axis), then along ``normal x e[axes[1]]``. The default (x, then y) is the one of the
        conics here; the camera placements of ``simtest.dataset`` and ``simtest.harness`` use
        (z, then x), so their cameras' "up" stays what it was.

    Returns
    -------
    u, w : ndarray of shape (3,)
        Unit vectors with ``(u, w, normal)`` right-handed.
    """
    n = np.asarray(normal, dtype=np.float64)
    first, second = axes
    helper = _AXES[first if abs(n[first]) < 0.9 else second]
    u = cross3(n, helper)
    u /= np.linalg.norm(u)
    return u, cross3(n, u)


#: The coordinate axes as tuples (helpers of :func:`plane_basis`).
_AXES = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))




def _section_centre(Q: np.ndarray, n: np.ndarray) -> np.ndarray:
    """Unit direction (z > 0) of the centre of the section of cone Q by a plane of normal n."""
    # Plane n.X = 1 parametrised as X = n + a u + b w with (u, w) an orthonormal basis of n-perp.
    B = np.stack(plane_basis(n), axis=1)  # (3, 2)
    BtQ = B.T @ Q
    M = BtQ @ B
    g = BtQ @ n
    ab = -np.linalg.solve(M, g)
    X = n + B @ ab
    X /= np.linalg.norm(X)
    return -X if X[2] < 0 else X


def project_circle(centre_mm, normal, radius_mm: float, K) -> np.ndarray:
    """Exact image point conic of a 3D circle, by the plane-to-image homography.

    Parameters
    ----------
    centre_mm : array_like of shape (3,)
        Circle centre in the camera frame, mm, in front of the camera (z > 0).
    normal : array_like of shape (3,)
        Normal of the circle's plane (camera frame; either orientation).
    radius_mm : float
        Radius, mm, > 0.
    K : array_like of shape (3, 3)
        Intrinsics.

    Returns
    -------
    ndarray of shape (3, 3)
        Point conic ``C = H^{-T} diag(1, 1, -r^2) H^{-1}`` with ``H = K [u w c]`` [3, sec. 2.3],
        scaled to unit Frobenius norm.

    Raises
    ------
    ValueError
        If the radius is not positive, the normal is zero, or the plane passes through the camera
        centre (the image is a degenerate line pair).
    """

    K = validate_intrinsics(K)
    c = np.asarray(centre_mm, dtype=np.float64)
    n = np.asarray(normal, dtype=np.float64)
    if not radius_mm > 0:
        raise ValueError(f"radius_mm must be > 0, got {radius_mm}")
    nn = np.linalg.norm(n)
    if nn == 0:
        raise ValueError("normal is zero")
    n = n / nn
    if abs(n @ c) <= 1e-12 * np.linalg.norm(c):
        raise ValueError("the circle's plane passes through the camera centre: degenerate image")
    u, w = plane_basis(n)
    H = K @ np.stack([u, w, c], axis=1)
    Hinv = np.linalg.inv(H)
    C = Hinv.T @ np.diag([1.0, 1.0, -float(radius_mm) ** 2]) @ Hinv
    C = 0.5 * (C + C.T)
    return C / np.linalg.norm(C)
